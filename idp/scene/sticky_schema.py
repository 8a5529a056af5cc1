"""Scene section `[sticky]`: opt-in weak springs between close surface vertices of chosen bodies (§7.5, Fig. 21).

Outside the paper's energy (see :mod:`idp.stepper.sticky`); the authors' dumplings-on-a-plate run uses it to make
the wrappers and the pusher stick.
"""

from __future__ import annotations

import fnmatch
from typing import Literal

from pydantic import Field

from idp.scene.schema_base import Name, PosFloat, _Model


class StickyConfig(_Model):
    """``bodies``: object names or shell-style patterns (``"wrapper_*"`` matches the instanced copies
    ``wrapper_0`` …); ``distance``: the link radius (scene units); ``stiffness``: k of the springs (the authors'
    value is 1). ``mode = "relink"``: zero-length springs (k/2)‖x_a − x_b‖² between surface vertices of two
    different matched bodies within ``distance``, found afresh at the start of every step. ``mode = "glue"`` (the
    authors' run): once, at the first step start with any pair within ``distance``, springs (k/2)(‖x_a − x_b‖ − ℓ)²
    of rest length ℓ = their distance then, between different bodies and between a body's own surfaces that face
    each other (a seam), kept for the rest of the run."""

    bodies: list[Name] = Field(min_length=1)
    distance: PosFloat
    stiffness: PosFloat = 1.0
    mode: Literal["relink", "glue"] = "relink"

    @property
    def min_bodies(self) -> int:
        """How many matched bodies the links need: glue also joins a body's own facing surfaces."""
        return 1 if self.mode == "glue" else 2

    def matches(self, names: list[str]) -> list[str]:
        """The names among ``names`` that some entry of ``bodies`` matches, in ``names``' order."""
        return [n for n in names if any(fnmatch.fnmatchcase(n, pat) for pat in self.bodies)]


def check_sticky(scene, probs: list[tuple[str, str]]) -> None:
    """Every pattern names some object of the scene (of any stage); 3D only (the links' Hessian joins the 3D
    compiled barrier's blocks)."""
    st = scene.sticky
    if st is None:
        return
    if scene.dim != 3:
        probs.append(("sticky", "sticky contact is for 3D scenes (dim = 3)"))
    if scene.contact.barrier != "compiled":
        probs.append(("sticky", 'sticky contact needs contact.barrier = "compiled" (its springs join its blocks)'))
    names = [ob.name for ob in scene.objects] + [ob.name for stage in scene.stages for ob in stage.add]
    for j, pat in enumerate(st.bodies):
        if not any(fnmatch.fnmatchcase(n, pat) for n in names):
            probs.append((f"sticky.bodies[{j}]", f"{pat!r} matches no object of the scene"))
