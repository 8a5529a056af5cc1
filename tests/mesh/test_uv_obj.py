"""OBJ meshes with a UV layout (idp uv): reading, rest frames, orientation, overlaps and the byte-exact writer."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.uv_obj import (
    cut_cylinder_obj_text,
    orient_uv_mesh,
    read_uv_obj,
    uv_overlaps,
    uv_rest_frames,
    uv_signed_areas,
    write_uv_obj,
)

SEGMENTS, RINGS = 8, 3


def _write(tmp_path: Path, text: str, name: str = "m.obj", newline: str = "\n") -> Path:
    p = tmp_path / name
    p.write_bytes(text.replace("\n", newline).encode())
    return p


def _cylinder(tmp_path: Path, **kw) -> Path:
    p = tmp_path / "cyl.obj"
    p.write_bytes(cut_cylinder_obj_text(SEGMENTS, RINGS, **kw).encode())
    return p


def _error(path: Path, match: str) -> str:
    with pytest.raises(MeshError, match=match) as info:
        read_uv_obj(path)
    return str(info.value)


# ------------------------------------------------------------------------------------------------------- reading


def test_cut_cylinder_reads_with_seam_vertices_doubled(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path))
    assert mesh.positions.shape == (SEGMENTS * (RINGS + 1), 3)
    assert mesh.uv.shape == ((SEGMENTS + 1) * (RINGS + 1), 2)
    assert mesh.faces_xyz.shape == mesh.faces_uv.shape == (2 * SEGMENTS * RINGS, 3)
    assert mesh.faces_xyz.dtype == mesh.faces_uv.dtype == np.int64
    assert mesh.source == str(tmp_path / "cyl.obj")
    # each v has one vt except the seam's, which have two
    pairs = np.unique(np.stack([mesh.faces_xyz.ravel(), mesh.faces_uv.ravel()], axis=1), axis=0)
    per_v = np.bincount(pairs[:, 0], minlength=mesh.positions.shape[0])
    assert sorted(set(per_v.tolist())) == [1, 2]
    assert np.count_nonzero(per_v == 2) == RINGS + 1
    # face lines point at the f lines
    lines = (tmp_path / "cyl.obj").read_text().splitlines()
    assert all(lines[k - 1].startswith("f ") for k in mesh.face_lines)
    assert (uv_signed_areas(mesh.uv, mesh.faces_uv) > 0).all()


def test_relative_indices_w_component_and_normals(tmp_path: Path) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0 0.5\nvt 1 0 0.5\nvt 0 1 0.5\nvn 0 0 1\nf -3/-3/1 -2/-2/1 -1/-1/1\n"
    mesh = read_uv_obj(_write(tmp_path, text))
    assert mesh.faces_xyz.tolist() == [[0, 1, 2]]
    assert mesh.faces_uv.tolist() == [[0, 1, 2]]
    assert mesh.uv.tolist() == [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
    assert mesh.face_lines.tolist() == [8]


@pytest.mark.parametrize(
    ("body", "line", "match"),
    [
        ("f 1/1 2/2 3/3 4/4", 9, "triangulate"),
        ("f 1 2 3", 9, "no texture coordinate index"),
        ("f 1//1 2//1 3//1", 9, "no texture coordinate index"),
        ("f 1/1 2/2 5/3", 9, "v index 5 out of range"),
        ("f 1/1 2/2 3/7", 9, "vt index 7 out of range"),
        ("f 0/1 2/2 3/3", 9, "index 0 is invalid"),
        ("f 1/-9 2/2 3/3", 9, "relative vt index -9"),
        ("f 1/1 2/2", 9, "2 corners"),
        ("vt 0.5", 9, "at least 2 numbers"),
        ("vt 0.5 nan", 9, "non-finite"),
        ("v 1 inf 0", 9, "non-finite"),
        ("vt 0.5 x", 9, "bad number 'x'"),
        ("f 1/a 2/2 3/3", 9, "bad vt index"),
    ],
)
def test_errors_name_file_and_line(tmp_path: Path, body: str, line: int, match: str) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n" + body + "\nf 1/1 2/2 3/3\n"
    p = _write(tmp_path, text)
    msg = _error(p, match)
    assert msg.startswith(f"{p}:{line}: ")


def test_missing_file_no_vt_no_faces(tmp_path: Path) -> None:
    _error(tmp_path / "absent.obj", "not found")
    msg = _error(_write(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), "has no texture coordinates")
    assert "idp uv needs a UV layout" in msg
    _error(_write(tmp_path, "v 0 0 0\nvt 0 0\n"), "no faces")


# -------------------------------------------------------------------------------------------------- rest frames


def test_rest_frames_are_upper_triangular_with_det_twice_the_area() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 3))
    faces = np.array([rng.choice(30, size=3, replace=False) for _ in range(20)])
    dm, area = uv_rest_frames(x, faces)
    tri = x[faces]
    expected = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    np.testing.assert_allclose(area, expected, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.det(dm), 2 * area, rtol=1e-12)
    assert np.all(dm[:, 1, 0] == 0) and np.all(dm[:, 0, 0] > 0) and np.all(dm[:, 1, 1] > 0)
    # the columns keep the edge lengths and the angle between them
    np.testing.assert_allclose(np.linalg.norm(dm[:, :, 0], axis=1), np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1))
    np.testing.assert_allclose(np.linalg.norm(dm[:, :, 1], axis=1), np.linalg.norm(tri[:, 2] - tri[:, 0], axis=1))


def test_degenerate_3d_triangles_are_named() -> None:
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 1, 3], [1, 3, 0]])
    with pytest.raises(MeshError, match=r"2 triangle\(s\) of 3 have no 3D area") as info:
        uv_rest_frames(x, faces, face_lines=np.array([10, 11, 12]), source="a.obj")
    msg = str(info.value)
    assert msg.startswith("a.obj:11: ") and "1 (line 11), 2 (line 12)" in msg and "rest metric is undefined" in msg
    x[2, 1] = np.nan
    with pytest.raises(MeshError, match=r"triangles 0$"):
        uv_rest_frames(x, faces[:1])


# -------------------------------------------------------------------------------------------------- orientation


def test_positive_layout_is_kept(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path))
    oriented, mirrored = orient_uv_mesh(mesh)
    assert not mirrored and oriented is mesh


def test_mirrored_layout_is_turned_in_both_index_sets(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path, uv_scale=(-1.0, 1.0)))
    assert (uv_signed_areas(mesh.uv, mesh.faces_uv) < 0).all()
    oriented, mirrored = orient_uv_mesh(mesh)
    assert mirrored
    assert (uv_signed_areas(oriented.uv, oriented.faces_uv) > 0).all()
    assert oriented.faces_xyz.tolist() == mesh.faces_xyz[:, [0, 2, 1]].tolist()
    assert oriented.faces_uv.tolist() == mesh.faces_uv[:, [0, 2, 1]].tolist()
    assert np.array_equal(oriented.uv, mesh.uv) and np.array_equal(oriented.face_lines, mesh.face_lines)


def test_mixed_orientation_is_refused_naming_the_minority(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path))
    flip = [3, 7]
    mesh.faces_uv[flip] = mesh.faces_uv[flip][:, [0, 2, 1]]
    with pytest.raises(MeshError, match=r"2 flipped triangle\(s\) of 48") as info:
        orient_uv_mesh(mesh)
    msg = str(info.value)
    lines = mesh.face_lines
    assert msg.startswith(f"{mesh.source}:{lines[3]}: ")
    assert f"3 (line {lines[3]}), 7 (line {lines[7]})" in msg


def test_zero_area_uv_triangle_is_refused(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path))
    a, b, c = mesh.faces_uv[5]
    mesh.uv[c] = 0.5 * (mesh.uv[a] + mesh.uv[b])  # collinear corners (also collapses neighbours)
    with pytest.raises(MeshError, match="have no area in the UV layout") as info:
        orient_uv_mesh(mesh)
    assert "5 (line" in str(info.value)


# ----------------------------------------------------------------------------------------------------- overlaps


def test_a_valid_layout_has_no_overlaps(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path))
    assert uv_overlaps(mesh.uv, mesh.faces_uv).shape == (0, 2)


def test_two_charts_touching_along_an_edge_and_a_corner_do_not_overlap() -> None:
    # two separate charts (own vt) meeting along x = 1 without sharing indices, and a third touching at a corner
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [1, 0], [2, 0], [2, 1], [1, 1], [2, 1], [3, 1], [3, 2]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10]])
    assert uv_overlaps(uv, faces).shape == (0, 2)


def test_overlapping_charts_and_a_fold_are_found(tmp_path: Path) -> None:
    mesh = read_uv_obj(_cylinder(tmp_path))
    shift = np.array([0.4, 0.1])
    # a second copy of the layout shifted a little: a chart on top of another
    uv = np.concatenate([mesh.uv, mesh.uv + shift])
    faces = np.concatenate([mesh.faces_uv, mesh.faces_uv + len(mesh.uv)])
    pairs = uv_overlaps(uv, faces)
    m = len(mesh.faces_uv)
    assert pairs.shape[1] == 2 and len(pairs) > m
    assert np.all(pairs[:, 0] < pairs[:, 1])
    assert np.all(pairs[:, 0] < m) and np.all(pairs[:, 1] >= m)  # each chart alone is injective
    assert len(uv_overlaps(uv, faces, max_pairs=5)) == 5
    # a fold inside one chart: a vertex whose triangles wind around it twice, all positively oriented
    ring = 5
    angles = 4 * np.pi * np.arange(ring) / ring
    fan = np.concatenate([[[0.0, 0.0]], np.stack([np.cos(angles), np.sin(angles)], axis=1)])
    fan_faces = np.array([[0, 1 + k, 1 + (k + 1) % ring] for k in range(ring)])
    assert (uv_signed_areas(fan, fan_faces) > 0).all()
    assert len(uv_overlaps(fan, fan_faces)) > 0


def test_a_sliver_past_a_shared_corner_overlaps_and_touching_does_not() -> None:
    # both triangles have corner 0; the second's edge 4 → 0 rises 1e-9 above y = 0, into the first
    uv = np.array([[0, 0], [1, 0], [0, 1], [0.5, -1], [1, 1e-9]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 3, 4]])
    assert (uv_signed_areas(uv, faces) > 0).all()
    assert uv_overlaps(uv, faces).tolist() == [[0, 1]]
    uv[4, 1] = 0.0  # vertex 4 on vertex 1: the triangles share the edge y = 0 without sharing indices
    assert uv_overlaps(uv, faces).shape == (0, 2)
    uv[4, 1] = -1e-9  # below: they meet at corner 0 only
    assert uv_overlaps(uv, faces).shape == (0, 2)


# ------------------------------------------------------------------------------------------------------ writing


def _vt_lines(data: bytes) -> list[bytes]:
    return [ln for ln in data.splitlines(keepends=True) if ln.split()[:1] == [b"vt"]]


def _other_lines(data: bytes) -> list[bytes]:
    return [ln for ln in data.splitlines(keepends=True) if ln.split()[:1] != [b"vt"]]


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_round_trip_changes_only_the_vt_numbers(tmp_path: Path, newline: str) -> None:
    src = tmp_path / "cyl.obj"
    src.write_bytes(cut_cylinder_obj_text(SEGMENTS, RINGS, newline=newline, w=True).encode())
    mesh = read_uv_obj(src)
    rng = np.random.default_rng(0)
    new_uv = mesh.uv * 1.7 + rng.normal(scale=1e-3, size=mesh.uv.shape)
    out = write_uv_obj(src, tmp_path / "sub" / "out.obj", new_uv)
    assert out == tmp_path / "sub" / "out.obj"
    a, b = src.read_bytes(), out.read_bytes()
    assert _other_lines(a) == _other_lines(b)  # v, vn, f, g, usemtl, comments, blank lines: byte-identical
    assert b.count(b"\r\n") == a.count(b"\r\n")
    vt_a, vt_b = _vt_lines(a), _vt_lines(b)
    assert len(vt_a) == len(vt_b) == len(new_uv)
    assert all(x != y for x, y in zip(vt_a, vt_b, strict=True))
    assert all(y.endswith(b" 0" + newline.encode()) for y in vt_b)  # the w component is kept
    again = read_uv_obj(out)
    assert np.array_equal(again.uv, new_uv)  # repr round-trips exactly
    assert np.array_equal(again.positions, mesh.positions)
    assert np.array_equal(again.faces_xyz, mesh.faces_xyz) and np.array_equal(again.faces_uv, mesh.faces_uv)
    assert not list(out.parent.glob("*.tmp"))


def test_writer_keeps_spacing_and_trailing_text(tmp_path: Path) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\n  vt\t0.0   0.0 # corner\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    src = _write(tmp_path, text)
    out = write_uv_obj(src, tmp_path / "o.obj", np.array([[0.25, 0.5], [1.0, 0.0], [0.0, 1.0]]))
    assert out.read_bytes().splitlines()[3] == b"  vt\t0.25   0.5 # corner"


def test_writer_refusals(tmp_path: Path) -> None:
    src = _cylinder(tmp_path)
    uv = read_uv_obj(src).uv
    with pytest.raises(MeshError, match="refusing to overwrite"):
        write_uv_obj(src, src, uv)
    with pytest.raises(MeshError, match="refusing to overwrite"):
        write_uv_obj(src, tmp_path / "." / "cyl.obj", uv)
    with pytest.raises(MeshError, match=re.escape("shape (nt, 2)")):
        write_uv_obj(src, tmp_path / "o.obj", uv[:, :1])
    with pytest.raises(MeshError, match="not finite"):
        write_uv_obj(src, tmp_path / "o.obj", np.where(np.arange(len(uv))[:, None] == 2, np.nan, uv))
    with pytest.raises(MeshError, match=f"has {len(uv)} vt lines but {len(uv) - 1}"):
        write_uv_obj(src, tmp_path / "o.obj", uv[:-1])
    assert not (tmp_path / "o.obj").exists()
    before = src.read_bytes()
    write_uv_obj(src, src, uv * 2.0, overwrite=True)
    assert read_uv_obj(src).uv.tolist() == (uv * 2.0).tolist()
    assert _other_lines(src.read_bytes()) == _other_lines(before)


def test_overlaps_agree_with_geos_on_all_pairs_of_random_grid_triangles() -> None:
    # corners on a coarse grid: many shared corners, touching edges, collinear corners and true overlaps
    import shapely

    rng = np.random.default_rng(7)
    uv = rng.integers(0, 6, size=(60, 2)).astype(float) * 0.1
    faces = np.array([rng.choice(60, size=3, replace=False) for _ in range(150)])
    live = np.flatnonzero(uv_signed_areas(uv, faces) != 0)
    polys = shapely.polygons(np.concatenate([uv[faces], uv[faces[:, :1]]], axis=1))
    i, j = np.triu_indices(len(faces), k=1)
    keep = np.isin(i, live) & np.isin(j, live)
    i, j = i[keep], j[keep]
    expected = np.stack([i, j], axis=1)[shapely.relate_pattern(polys[i], polys[j], "2********")]
    found = uv_overlaps(uv, faces)
    assert 0 < len(found) < len(i)
    assert found.tolist() == expected.tolist()
