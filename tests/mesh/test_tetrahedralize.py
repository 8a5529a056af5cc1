"""Filling a closed triangle surface with tets (TetGen, the optional ``idp[remesh]`` extra): the surface is kept
exactly, the volume equals the enclosed volume, and a scene object can be built from a surface file."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from idp.errors import MeshError, MesherUnavailableError, SceneError
from idp.mesh.generate import box_surface, ellipsoid_surface
from idp.mesh.quality import signed_volumes
from idp.mesh.surface import boundary_faces, enclosed_volume
from idp.scene.build import build_scene
from idp.scene.load import scene_from_dict


def _write_obj(path, v, f) -> None:
    lines = [f"v {a:.17g} {b:.17g} {c:.17g}" for a, b, c in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")


def _tri_set(x, faces):
    return {tuple(sorted(tuple(x[i]) for i in f)) for f in faces}


def test_fills_two_components_keeping_the_surface():
    pytest.importorskip("tetgen", reason="needs idp[remesh]")
    from idp.mesh.remesh import tetrahedralize_surface

    a = ellipsoid_surface(radii=(0.5, 0.3, 0.4), subdivisions=3)
    b = box_surface(lo=(1.0, 0.0, 0.0), hi=(1.5, 0.4, 0.3), resolution=2)
    v = np.vstack([a.vertices, b.vertices])
    f = np.vstack([a.faces, b.faces + a.vertices.shape[0]])
    nodes, tets = tetrahedralize_surface(v, f, max_volume=1e-3)
    assert np.all(signed_volumes(nodes, tets) > 0)
    assert signed_volumes(nodes, tets).sum() == pytest.approx(enclosed_volume(v, f), rel=1e-9)
    assert _tri_set(nodes, boundary_faces(tets)) == _tri_set(v, f)  # same triangles, positions bit for bit


def test_open_or_inward_surfaces_are_refused():
    pytest.importorskip("tetgen", reason="needs idp[remesh]")
    from idp.mesh.remesh import tetrahedralize_surface

    s = ellipsoid_surface(subdivisions=2)
    with pytest.raises(MeshError, match="open"):
        tetrahedralize_surface(s.vertices, s.faces[1:], source="cup.obj")
    with pytest.raises(MeshError, match="wound inwards"):
        tetrahedralize_surface(s.vertices, s.faces[:, ::-1], source="inside_out.obj")


def _scene(path, **over) -> dict:
    ob = {"name": "blob", "mesh": str(path), **over}
    return {"name": "tet", "dim": 3, "output": {"png": False}, "objects": [ob]}


def test_a_scene_object_from_a_surface_file(tmp_path):
    pytest.importorskip("tetgen", reason="needs idp[remesh]")
    s = ellipsoid_surface(radii=(0.5, 0.3, 0.4), subdivisions=3)
    path = tmp_path / "blob.obj"
    _write_obj(path, s.vertices, s.faces)
    with pytest.raises(MeshError, match=r"tetrahedralize = \{\}"):
        build_scene(scene_from_dict(_scene(path)))
    built = build_scene(scene_from_dict(_scene(path, tetrahedralize={"quality": 1.5}, scale=2.0)))
    tets = built.system.bodies[0].elastic.elements
    vol = signed_volumes(built.system.x, tets).sum()
    assert vol == pytest.approx(8.0 * enclosed_volume(s.vertices, s.faces), rel=1e-9)


def test_tetrahedralize_key_rules_and_missing_mesher(tmp_path, monkeypatch):
    s = ellipsoid_surface(subdivisions=2)
    path = tmp_path / "blob.obj"
    _write_obj(path, s.vertices, s.faces)
    with pytest.raises(SceneError, match="tetrahedralize"):
        scene_from_dict(_scene(path, kind="obstacle", tetrahedralize={}))
    monkeypatch.setitem(sys.modules, "tetgen", None)  # `import tetgen` raises ImportError
    with pytest.raises(MesherUnavailableError, match=r'tetrahedralize: .*pip install "idp\[remesh\]"'):
        build_scene(scene_from_dict(_scene(path, tetrahedralize={})))
