"""Inflated text (paper §7.2 "Inflation", Fig. 14): a string is meshed flat, then inflated by normal flow with its
outline fixed, so the letters bulge towards +z without ever touching each other or themselves.

A thin driver: :func:`idp.applications.text_mesh.text_to_mesh` builds the planar mesh, which is written to the
output folder as ``text.obj`` (the scene's input, kept for reproducibility), and :func:`flow_scene` /
:func:`run_flow` do the rest.  Font and text problems raise ``FontError`` before anything is written.
"""

from __future__ import annotations

from pathlib import Path

from idp.applications.normal_flow import DEFAULT_DHAT, flow_scene
from idp.applications.text_mesh import text_to_mesh
from idp.fs import make_output_dir
from idp.scene.schema import Scene

#: cap height of the text in scene units: strokes of ≈ 0.04, like the paper's font meshes (Tao: 0.45 tall)
DEFAULT_HEIGHT = 0.3
TEXT_MESH = "text.obj"


def text_flow_scene(
    text: str,
    out_dir: str | Path,
    *,
    font: str | Path | None = None,
    height: float = DEFAULT_HEIGHT,
    edge_length: float | None = None,
    beta: float = 5e-3,
    gamma: float = 1.0,
    steps: int = 10,
    dhat: float = DEFAULT_DHAT,
    newton_tol: float | None = None,
) -> Scene:
    """Mesh ``text`` with ``font`` (a TrueType/OpenType file; None: DejaVu Sans), write it to
    ``out_dir/text.obj`` and return the validated flow scene that inflates it (outline fixed).

    ``height`` is the cap height and ``edge_length`` the target edge length (default height/40), both in scene
    units; ``beta`` the push per step (> 0 towards +z), ``gamma`` the smoothing."""
    import meshio

    mesh = text_to_mesh(text, font, height=height, edge_length=edge_length)  # FontError before any output
    out = make_output_dir(out_dir)
    path = out / TEXT_MESH
    meshio.write(str(path), meshio.Mesh(mesh.vertices, [("triangle", mesh.faces)]), file_format="obj")
    return flow_scene(
        path,
        beta=beta,
        gamma=gamma,
        steps=steps,
        dhat=dhat,
        name="text",
        fix_boundary=True,
        newton_tol=newton_tol,
        output_dir=out,
    )


__all__ = ["DEFAULT_HEIGHT", "TEXT_MESH", "text_flow_scene"]
