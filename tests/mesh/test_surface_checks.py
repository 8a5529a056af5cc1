"""Tests of idp.mesh.surface_checks: clean closed surfaces pass with the right summary (components,
Euler characteristic, outward orientation), an open disk has one boundary loop, and each defect made
by editing a clean mesh raises a MeshError naming the file and the offending face / edge / vertex ids;
bow-tie vertices only warn; ``degenerate_triangles`` reports collapsed triangles."""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest

from idp.errors import MeshError
from idp.mesh.generate import box_surface, revolve_profile, tri_disk
from idp.mesh.surface_checks import ShellSurfaceInfo, check_shell_surface, degenerate_triangles


def _box(resolution: int = 2) -> tuple[np.ndarray, np.ndarray]:
    m = box_surface(resolution=resolution)
    return m.vertices.copy(), m.faces.copy()


def _sphere() -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(-0.5 * np.pi, 0.5 * np.pi, 7)
    r = np.cos(t)
    r[[0, -1]] = 0.0  # exact poles: a closed surface
    m = revolve_profile(np.sin(t), r, 10)
    return m.vertices, m.faces


def _has_id(message: str, i: int) -> bool:
    return re.search(rf"(?<![\d.]){i}(?![\d.])", message) is not None


@pytest.mark.parametrize("make", [_box, _sphere])
def test_clean_closed_surfaces_pass(make) -> None:
    X, F = make()
    info = check_shell_surface(X, F, "clean.obj")
    assert isinstance(info, ShellSurfaceInfo)
    assert (info.num_vertices, info.num_faces) == (len(X), len(F))
    assert info.is_closed and info.num_boundary_edges == 0 and info.num_boundary_loops == 0
    assert info.num_components == 1 and info.euler_characteristic == 2
    assert info.num_unreferenced_vertices == 0 and info.num_nonmanifold_vertices == 0
    assert info.outward is True and info.enclosed_volumes[0] > 0


def test_box_volume_and_inward_orientation() -> None:
    X, F = _box()
    assert check_shell_surface(X, F).enclosed_volumes == pytest.approx((8.0,))
    info = check_shell_surface(X, F[:, ::-1])
    assert info.outward is False and info.enclosed_volumes == pytest.approx((-8.0,))


def test_two_disjoint_closed_surfaces_and_an_unreferenced_vertex() -> None:
    X, F = _box()
    Y, G = _sphere()
    V = np.concatenate([X, Y + 5.0, [[9.0, 9.0, 9.0]]])
    info = check_shell_surface(V, np.concatenate([F, G + len(X)]))
    assert info.num_components == 2 and info.euler_characteristic == 4
    assert info.is_closed and info.outward is True and len(info.enclosed_volumes) == 2
    assert info.num_unreferenced_vertices == 1
    # one of the two turned inside out: not outward
    assert check_shell_surface(V, np.concatenate([F, G[:, ::-1] + len(X)])).outward is False


def test_open_disk_has_one_boundary_loop() -> None:
    d = tri_disk(resolution=3)
    X = np.column_stack([d.vertices, np.zeros(len(d.vertices))])
    info = check_shell_surface(X, d.elements, "disk")
    assert info.num_boundary_loops == 1 and not info.is_closed and info.outward is None
    assert info.num_boundary_edges > 0 and info.num_components == 1 and info.euler_characteristic == 1


def test_flipped_face_is_a_winding_error_naming_the_face() -> None:
    X, F = _box()
    f = 13
    F[f] = F[f, ::-1]
    with pytest.raises(MeshError, match="inconsistent winding") as exc:
        check_shell_surface(X, F, "flipped.obj")
    msg = str(exc.value)
    assert msg.startswith("flipped.obj:") and "3 edges" in msg
    assert _has_id(msg, f)
    a, b = sorted(F[f, :2])
    assert f"edge ({a}, {b})" in msg


def test_third_face_on_an_edge_is_non_manifold_naming_the_edge() -> None:
    X, F = _box()
    a, b = sorted(F[0, :2])
    X = np.concatenate([X, [[0.3, 0.2, 3.0]]])
    F = np.concatenate([F, [[a, b, len(X) - 1]]])
    with pytest.raises(MeshError, match="non-manifold edges") as exc:
        check_shell_surface(X, F, "fin.obj")
    msg = str(exc.value)
    assert msg.startswith("fin.obj:") and "1 non-manifold" in msg
    assert f"edge ({a}, {b}) in faces" in msg and _has_id(msg, len(F) - 1) and _has_id(msg, 0)


def test_collapsed_face_is_zero_area_naming_it() -> None:
    X, F = _box()
    f = 7
    a, b, c = F[f]
    X[c] = 0.25 * X[a] + 0.75 * X[b]  # c on the edge ab: face f has no area
    bad = degenerate_triangles(X, F)
    assert f in bad
    with pytest.raises(MeshError, match="zero-area faces") as exc:
        check_shell_surface(X, F, "flat.obj")
    msg = str(exc.value)
    assert _has_id(msg, f) and f"({bad.size} in total)" in msg


def test_duplicate_face_is_named() -> None:
    X, F = _box()
    F = np.concatenate([F, F[[4]][:, [1, 2, 0]]])
    with pytest.raises(MeshError, match="duplicate faces") as exc:
        check_shell_surface(X, F, "dup.obj")
    assert f"faces 4, {len(F) - 1}" in str(exc.value)


@pytest.mark.parametrize(
    "defect, pattern",
    [
        ("out_of_range", r"faces \[5\] \(1 in total\) index vertices outside \[0, 26\)"),
        ("negative", r"faces \[2, 9\] \(2 in total\) index vertices outside"),
        ("repeat", r"faces \[6\] \(1 in total\) repeat a vertex"),
        ("nan", r"non-finite .* vertices \[7\] \(1 in total\)"),
        ("inf", r"non-finite .* vertices \[0, 3\] \(2 in total\)"),
    ],
)
def test_bad_indices_and_coordinates(defect: str, pattern: str) -> None:
    X, F = _box()
    if defect == "out_of_range":
        F[5, 1] = len(X) + 3
    elif defect == "negative":
        F[[2, 9], 0] = -1
    elif defect == "repeat":
        F[6, 2] = F[6, 0]
    elif defect == "nan":
        X[7, 2] = np.nan
    else:
        X[[0, 3], 1] = np.inf
    with pytest.raises(MeshError, match=pattern) as exc:
        check_shell_surface(X, F, "bad.obj")
    assert str(exc.value).startswith("bad.obj:")


def test_bad_shapes() -> None:
    X, F = _box()
    with pytest.raises(MeshError, match=r"\(n, 3\)"):
        check_shell_surface(X[:, :2], F)
    with pytest.raises(MeshError, match="no faces"):
        check_shell_surface(X, F[:0])
    with pytest.raises(MeshError, match="integer"):
        check_shell_surface(X, F.astype(float))


def test_many_offenders_are_counted_but_only_a_few_listed() -> None:
    X, F = _box(3)
    F = F[:, ::-1].copy()
    F[::2] = F[::2, ::-1]  # half the faces flipped back: many inconsistent edges
    with pytest.raises(MeshError, match="inconsistent winding") as exc:
        check_shell_surface(X, F)
    msg = str(exc.value)
    assert msg.startswith("<array>:") and msg.count("edge (") == 5 and "; ..." in msg


def test_bow_tie_vertex_only_warns(caplog: pytest.LogCaptureFixture) -> None:
    X, F = _box()
    Y = X + np.array([2.0, 2.0, 2.0])  # second box touching the first at its corner (1, 1, 1)
    corner = int(np.flatnonzero(np.all(X == 1.0, axis=1))[0])
    other = int(np.flatnonzero(np.all(X == -1.0, axis=1))[0])
    G = F + len(X)
    G[G == other + len(X)] = corner  # merge the second box's (-1,-1,-1)+2 corner into the first's
    V = np.concatenate([X, Y])
    with caplog.at_level(logging.WARNING, logger="idp"):
        info = check_shell_surface(V, np.concatenate([F, G]), "bowtie.obj")
    assert info.num_nonmanifold_vertices == 1 and info.num_unreferenced_vertices == 1
    assert info.num_components == 2 and info.is_closed and info.outward is True
    assert any("bowtie.obj" in r.getMessage() and _has_id(r.getMessage(), corner) for r in caplog.records)


def test_degenerate_triangles_reports_collapsed_and_slivers() -> None:
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [0.5, 1e-7, 0], [np.nan, 0, 0]])
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 3, 4], [0, 1, 5], [1, 3, 2]])
    np.testing.assert_array_equal(degenerate_triangles(X, F), [1, 3])
    np.testing.assert_array_equal(degenerate_triangles(X, F, rel_tol=1e-6), [1, 2, 3])
    np.testing.assert_array_equal(degenerate_triangles(X.ravel(), F[:0]), np.zeros(0, dtype=np.int64))
    # scale-free
    np.testing.assert_array_equal(degenerate_triangles(1e6 * X, F, rel_tol=1e-6), [1, 2, 3])
