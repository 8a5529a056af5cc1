"""FrameWriter: OBJ / VTU / PVD files for 3D and 2D scenes."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from itertools import permutations
from pathlib import Path

import meshio
import numpy as np
import pytest

from idp.output.frames import FrameWriter
from idp.output.parts import Part

CUBE = np.array([[(i >> 0) & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=float)
CUBE_QUADS = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])


def _outward(tri: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Flip triangles whose normal points towards the centroid of ``pts``."""
    p = pts[tri]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", n, p.mean(1) - pts.mean(0)) < 0
    tri = tri.copy()
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def cube_scene() -> tuple[np.ndarray, list[Part]]:
    """A unit cube of 6 tets (ids 0..7) inside a box obstacle of 12 triangles (ids 8..15)."""
    tet_list = []
    for a, b, _ in permutations(range(3)):
        tet_list.append([0, 1 << a, (1 << a) | (1 << b), 7])
    tets = np.array(tet_list)
    p = CUBE[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    surf = _outward(np.concatenate([CUBE_QUADS[:, [0, 1, 2]], CUBE_QUADS[:, [0, 2, 3]]]), CUBE)
    box = CUBE * 3.0 - 1.0
    x = np.concatenate([CUBE, box])
    parts = [
        Part("cube body", "deformable", np.arange(8), tets, surf),
        Part("cage", "obstacle", np.arange(8, 16), None, surf + 8),
    ]
    return x, parts


def square_scene() -> tuple[np.ndarray, list[Part]]:
    """Two triangles (ids 0..3) inside a square polyline obstacle (ids 4..7)."""
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    x = np.concatenate([sq, sq * 3 - 1])
    loop = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    parts = [
        Part("sheet", "deformable", np.arange(4), np.array([[0, 1, 2], [0, 2, 3]]), loop),
        Part("frame", "obstacle", np.arange(4, 8), None, loop + 4),
    ]
    return x, parts


def parse_obj(path: Path) -> dict[str, dict]:
    """Per `o` group: vertex rows, face/line index rows (as written, 1-based global)."""
    groups: dict[str, dict] = {}
    cur = None
    for line in path.read_text().splitlines():
        if not line or line.startswith("#"):
            continue
        tag, *rest = line.split()
        if tag == "o":
            cur = groups.setdefault(rest[0], {"v": [], "f": [], "l": []})
        else:
            assert cur is not None, "element before any o group"
            cur[tag].append([float(r) for r in rest] if tag == "v" else [int(r) for r in rest])
    return groups


def check_obj(path: Path, parts: list[Part], x: np.ndarray, kind: str) -> None:
    groups = parse_obj(path)
    assert list(groups) == [p.name.replace(" ", "_") for p in parts]
    total = sum(len(g["v"]) for g in groups.values())
    start = 1
    for p, g in zip(parts, groups.values(), strict=True):
        ids = np.unique(p.surface)
        v = np.array(g["v"])
        assert v.shape == (ids.size, 3)
        assert len(g[kind]) == p.surface.shape[0]
        f = np.array(g[kind])
        assert f.min() >= start and f.max() < start + ids.size <= total + 1  # 1-based, inside own group
        # each written face is the part's face at the current positions
        pad = np.zeros((x.shape[0], 3))
        pad[:, : x.shape[1]] = x
        # bit for bit: coordinates are written in their shortest exact form (identity by construction)
        assert np.array_equal(v[f - start], pad[p.surface])
        start += ids.size


def read_pvd(path: Path) -> list[tuple[float, str]]:
    root = ET.parse(path).getroot()
    assert root.tag == "VTKFile" and root.get("type") == "Collection"
    collection = root.find("Collection")
    assert collection is not None
    return [(float(d.attrib["timestep"]), d.attrib["file"]) for d in collection]


def test_3d_obj_vtu_pvd(tmp_path: Path) -> None:
    x0, parts = cube_scene()
    fixed = np.zeros(16, dtype=bool)
    fixed[[0, 1]] = True
    w = FrameWriter(tmp_path / "out", parts, 3, fixed_mask=fixed)
    times = [0.0, 0.25, 0.5]
    for k, t in enumerate(times):
        x = x0 + 0.01 * k * np.arange(48).reshape(16, 3)
        disp = x - x0
        paths = w.write(k, x, time=t, point_data={"displacement": disp})
        assert paths == {"obj": f"obj/frame_{k:05d}.obj", "vtu": f"vtu/frame_{k:05d}.vtu", "pvd": "frames.pvd"}
        # an interruption right now must leave a valid PVD of everything written so far
        entries = read_pvd(tmp_path / "out" / "frames.pvd")
        assert entries == [(times[j], f"vtu/frame_{j:05d}.vtu") for j in range(k + 1)]
        check_obj(tmp_path / "out" / paths["obj"], parts, x, "f")
        m = meshio.read(tmp_path / "out" / paths["vtu"])
        assert m.points.shape == (16, 3)
        np.testing.assert_allclose(m.points, x)
        assert [(c.type, len(c.data)) for c in m.cells] == [("tetra", 6), ("triangle", 12)]
        np.testing.assert_array_equal(m.cells[0].data, parts[0].elements)
        np.testing.assert_array_equal(m.point_data["part_id"], [0] * 8 + [1] * 8)
        np.testing.assert_array_equal(m.point_data["fixed"], fixed.astype(int))
        np.testing.assert_allclose(m.point_data["displacement"], disp)
    w.close()
    assert not list((tmp_path / "out").rglob("*.tmp"))
    with pytest.raises(RuntimeError):
        w.write(5, x0)
    # VTU is compressed binary
    assert b'compressor="vtkZLibDataCompressor"' in (tmp_path / "out" / "vtu" / "frame_00000.vtu").read_bytes()


def test_pvd_default_timestep_and_rewrite(tmp_path: Path) -> None:
    x0, parts = cube_scene()
    w = FrameWriter(tmp_path, parts, 3, write_obj=False)
    for k in (0, 10, 20):
        assert set(w.write(k, x0)) == {"vtu", "pvd"}
    w.write(10, x0 + 1.0)  # rewriting a frame replaces its entry
    assert read_pvd(tmp_path / "frames.pvd") == [
        (0.0, "vtu/frame_00000.vtu"),
        (10.0, "vtu/frame_00010.vtu"),
        (20.0, "vtu/frame_00020.vtu"),
    ]
    assert not (tmp_path / "obj").exists()


def test_2d(tmp_path: Path) -> None:
    x, parts = square_scene()
    w = FrameWriter(tmp_path, parts, 2)
    paths = w.write(0, x, point_data={"displacement": np.ones((8, 2))})
    w.write(1, x * 1.5)
    check_obj(tmp_path / paths["obj"], parts, x, "l")
    text = (tmp_path / paths["obj"]).read_text()
    assert "\nf " not in text and all(
        float(line.split()[3]) == 0.0 for line in text.splitlines() if line.startswith("v ")
    )
    m = meshio.read(tmp_path / paths["vtu"])
    assert m.points.shape == (8, 3) and np.all(m.points[:, 2] == 0)
    assert [(c.type, len(c.data)) for c in m.cells] == [("triangle", 2), ("line", 4)]
    assert m.point_data["displacement"].shape == (8, 3)
    assert m.point_data["fixed"].sum() == 0
    assert [e[0] for e in read_pvd(tmp_path / "frames.pvd")] == [0.0, 1.0]


def test_bad_input(tmp_path: Path) -> None:
    x, parts = cube_scene()
    w = FrameWriter(tmp_path, parts, 3)
    with pytest.raises(ValueError):
        w.write(0, x[:, :2])
    bad = x.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="vertex 3"):
        w.write(0, bad)
    with pytest.raises(ValueError):
        FrameWriter(tmp_path, parts, 2)


def test_obj_20k_frame_reads_back_exactly(tmp_path: Path) -> None:
    """A 20K-vertex frame (written by the vectorised formatter) reads back bit for bit."""
    n = 20000
    rng = np.random.default_rng(0)
    x = rng.random((n, 3))
    tris = rng.integers(0, n, size=(2 * n, 3))
    parts = [Part("big", "obstacle", np.arange(n), None, tris)]
    w = FrameWriter(tmp_path, parts, 3, write_vtu=False)
    w.write(0, x)
    w.write(1, x)
    (g,) = parse_obj(tmp_path / "obj" / "frame_00001.obj").values()
    ids = np.unique(tris)
    assert np.array_equal(np.array(g["v"]), x[ids])


def test_obj_keeps_gaps_at_the_resolution_of_the_coordinates(tmp_path: Path) -> None:
    """Blocked handles can press two surfaces to ~1e-15 apart at |x| ≈ 0.05 (Fig. 2): the written frame must keep
    the certified positions exactly, or the file could show the surfaces crossing (10 digits moved them ~1e-12)."""
    base = 0.05123456789012345
    gap = 4 * np.spacing(base)  # a few units in the last place, ~3e-17
    tri = np.array([[0.0, 0.0, base], [1.0, 0.0, base], [0.0, 1.0, base]])
    x = np.vstack([tri, tri + np.array([0.1, 0.1, gap])])
    assert x[3, 2] > x[0, 2]
    parts = [
        Part("lower", "obstacle", np.arange(3), None, np.array([[0, 1, 2]])),
        Part("upper", "obstacle", np.arange(3, 6), None, np.array([[3, 4, 5]])),
    ]
    FrameWriter(tmp_path, parts, 3, write_vtu=False).write(0, x)
    groups = parse_obj(tmp_path / "obj" / "frame_00000.obj")
    lower, upper = (np.array(groups[name]["v"]) for name in ("lower", "upper"))
    assert np.array_equal(lower, x[:3]) and np.array_equal(upper, x[3:])
    assert upper[:, 2].min() - lower[:, 2].max() == x[3, 2] - x[0, 2] > 0.0
