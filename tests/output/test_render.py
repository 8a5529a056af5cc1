"""render_frames_png: headless PNGs of 3D and 2D scenes."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from idp.output.parts import Part
from idp.output.render import render_frames_png


def ball_in_cage(levels: int) -> tuple[np.ndarray, list[Part]]:
    """A tet ball (fan of tets from the centre over a subdivided octahedron) inside a box cage."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    for _ in range(levels):
        e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        mid = v.shape[0] + inv.reshape(-1, 3)  # midpoints of edges (01, 12, 20)
        v = np.concatenate([v, v[uniq].mean(axis=1)])
        a, b, c = f.T
        m01, m12, m20 = mid.T
        f = np.concatenate([np.stack(t, 1) for t in ([a, m01, m20], [m01, b, m12], [m20, m12, c], [m01, m12, m20])])
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * 0.8
    v[:, 2] *= 0.8
    nb = v.shape[0] + 1
    verts = np.concatenate([v, [[0.0, 0.0, 0.0]]])
    tets = np.concatenate([f, np.full((f.shape[0], 1), nb - 1)], axis=1)
    tets = tets[:, [0, 2, 1, 3]]  # outward faces + apex inside -> positive volume after swap
    cube = np.array([[(i >> 0) & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=float) * 2.0 - 1.0
    quads = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])
    box = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    x = np.concatenate([verts, cube])
    parts = [
        Part("ball", "deformable", np.arange(nb), tets, f),
        Part("cage", "obstacle", np.arange(nb, nb + 8), None, box + nb),
    ]
    return x, parts


def _check_png(path: Path, size: tuple[int, int]) -> np.ndarray:
    img = mpimg.imread(path)
    assert img.shape[:2] == (size[1], size[0])
    assert img[..., :3].var() > 1e-4
    return img


def test_outward_fixture() -> None:
    x, parts = ball_in_cage(1)
    p = x[parts[0].surface]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (np.einsum("ij,ij->i", n, p.mean(1)) > 0).all()
    p = x[parts[1].surface]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (np.einsum("ij,ij->i", n, p.mean(1)) > 0).all()


def test_render_3d(tmp_path: Path) -> None:
    x, parts = ball_in_cage(2)
    x1 = x.copy()
    x1[:-8, 2] *= 0.5
    out = tmp_path / "r3.png"
    render_frames_png(out, parts, [("step 0", x), ("step 60", x1)], dim=3, size=(640, 320))
    img = _check_png(out, (640, 320))
    # the ball's colour is present (bluish pixels: blue clearly above red)
    rgb = img[..., :3]
    assert ((rgb[..., 2] - rgb[..., 0]) > 0.15).mean() > 0.02


def test_render_views_one_camera_per_panel(tmp_path: Path) -> None:
    x, parts = ball_in_cage(2)
    x[: parts[0].vertex_ids.size, 0] *= 2.0  # an elongated ball: a view along x differs from one across it
    out = tmp_path / "views.png"
    render_frames_png(
        out, parts[:1], [("along y", x), ("along x", x)], dim=3, size=(600, 300), views=[(90.0, 0.0), (0.0, 0.0)]
    )
    img = _check_png(out, (600, 300))
    blue = (img[..., 2] - img[..., 0]) > 0.15
    left, right = blue[:, :300].sum(), blue[:, 300:].sum()
    assert left > 1.3 * right or right > 1.3 * left  # the two cameras see different silhouettes
    with pytest.raises(ValueError, match="one \\(elevation, azimuth\\) per frame"):
        render_frames_png(out, parts, [("a", x)], dim=3, views=[(0.0, 0.0), (1.0, 1.0)])


def test_render_2d(tmp_path: Path) -> None:
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    x = np.concatenate([sq, sq * 3 - 1])
    loop = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    parts = [
        Part("sheet", "deformable", np.arange(4), np.array([[0, 1, 2], [0, 2, 3]]), loop),
        Part("frame", "obstacle", np.arange(4, 8), None, loop + 4),
    ]
    out = tmp_path / "r2.png"
    render_frames_png(out, parts, [("a", x), ("b", x * 1.2), ("c", x * 0.8)], dim=2, size=(900, 300))
    _check_png(out, (900, 300))


def test_render_30k(tmp_path: Path) -> None:
    x, parts = ball_in_cage(6)  # 32768 surface triangles
    assert parts[0].surface.shape[0] > 30000
    render_frames_png(tmp_path / "big.png", parts, [("t", x)], dim=3)
    _check_png(tmp_path / "big.png", (1200, 600))


def test_render_side_obstacle_and_blank_check(tmp_path: Path) -> None:
    """An obstacle that does not enclose the ball is drawn solid, inside the depth sort."""
    x, parts = ball_in_cage(2)
    x[-8:] = x[-8:] * 0.4 + np.array([1.3, 0.0, 0.0])  # small box beside the ball
    out = tmp_path / "side.png"
    render_frames_png(out, parts, [("side", x)], dim=3, view=(35, 10), size=(400, 300))
    img = _check_png(out, (400, 300))
    grey = (np.abs(img[..., 0] - img[..., 2]) < 0.03) & (img[..., 0] < 0.8) & (img[..., 0] > 0.2)
    assert grey.mean() > 0.005  # opaque grey obstacle faces
