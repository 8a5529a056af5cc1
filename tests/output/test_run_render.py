"""idp render: pictures of a run drawn from its VTU frames alone."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from idp.cli import main
from idp.errors import OutputError
from idp.output.frames import FrameWriter
from idp.output.parts import Part
from idp.output.run_render import parts_from_frame, render_run

TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward for TET


def _scene() -> tuple[np.ndarray, list[Part], np.ndarray]:
    """Two one-tet bodies (one VTU cell block once read back), a moving shell triangle and a fixed floor."""
    x = np.concatenate(
        [
            TET,
            TET + np.array([2.0, 0.0, 0.0]),
            [[0.0, 2.0, 0.0], [1.0, 2.0, 0.0], [0.0, 3.0, 0.0]],
            [[-1.0, -1.0, -0.5], [4.0, -1.0, -0.5], [4.0, 4.0, -0.5], [-1.0, 4.0, -0.5]],
        ]
    )
    parts = [
        Part("a", "deformable", np.arange(4), np.array([[0, 1, 2, 3]]), TET_FACES),
        Part("b", "deformable", np.arange(4, 8), np.array([[4, 5, 6, 7]]), TET_FACES + 4),
        Part("sheet", "shell", np.arange(8, 11), None, np.array([[8, 9, 10]])),
        Part("floor", "obstacle", np.arange(11, 15), None, np.array([[11, 12, 13], [11, 13, 14]])),
    ]
    fixed = np.zeros(15, dtype=bool)
    fixed[11:] = True
    return x, parts, fixed


def _run(tmp_path: Path, steps=(0, 1, 2)) -> tuple[Path, np.ndarray, list[Part]]:
    x, parts, fixed = _scene()
    w = FrameWriter(tmp_path / "run", parts, 3, write_obj=False, fixed_mask=fixed)
    for k in steps:
        y = x.copy()
        y[:8, 2] += 0.1 * k  # the bodies rise
        w.write(k, y)
    w.close()
    return tmp_path / "run", x, parts


def _faces(surface: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(np.roll(f, -int(np.argmin(f)))) for f in surface.tolist()}  # same triangle, same orientation


def test_parts_come_back_from_a_frame(tmp_path: Path) -> None:
    run, x, parts = _run(tmp_path)
    got, y = parts_from_frame(run / "vtu" / "frame_00000.vtu", 3)
    assert np.array_equal(y, x)
    assert [p.kind for p in got] == ["deformable", "deformable", "shell", "obstacle"]  # the tet block split by part
    for p, q in zip(got, parts, strict=True):
        assert _faces(p.surface) == _faces(q.surface)
        assert np.array_equal(p.vertex_ids, q.vertex_ids)


def _size(path: Path) -> tuple[int, int]:
    img = mpimg.imread(path)
    assert img[..., :3].var() > 1e-4  # something was drawn
    return img.shape[1], img.shape[0]


def test_steps_side_by_side_and_views(tmp_path: Path) -> None:
    run, _, _ = _run(tmp_path)
    assert _size(render_run(run, tmp_path / "default.png")) == (800, 500)  # first and last step
    assert _size(render_run(run, tmp_path / "three.png", steps=[0, 1, 2])) == (1200, 500)
    views = render_run(run, tmp_path / "views.png", steps=[2], views=["oblique", "side", "above"], up="z")
    assert _size(views) == (1500, 500)
    assert _size(render_run(run, tmp_path / "bare.png", hide_obstacles=True)) == (800, 500)


def test_bad_requests_are_named(tmp_path: Path) -> None:
    run, _, _ = _run(tmp_path, steps=(0, 5))
    with pytest.raises(OutputError, match=r"no frame for step\(s\) \[3\] \(frames written: 0, 5\)"):
        render_run(run, tmp_path / "x.png", steps=[0, 3])
    with pytest.raises(OutputError, match="unknown view"):
        render_run(run, tmp_path / "x.png", views=["underneath"])
    with pytest.raises(OutputError, match="no vtu/ folder"):
        render_run(tmp_path / "nowhere", tmp_path / "x.png")
    (run / "vtu" / "frame_00007.vtu").write_text("not a VTU")
    with pytest.raises(OutputError, match=r"frame_00007\.vtu: cannot be read"):
        render_run(run, tmp_path / "x.png", steps=[7])


def test_cli_reads_dim_and_up_from_the_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run, _, _ = _run(tmp_path)
    (run / "scene.resolved.toml").write_text('dim = 3\ngravity = [0.0, -9.8, 0.0]\n[output]\nup = "auto"\n')
    assert main(["render", str(run), "--steps", "0", "2", "-o", str(tmp_path / "cli.png")]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "cli.png")
    assert _size(tmp_path / "cli.png") == (800, 500)
    assert main(["render", str(run), "--steps", "9"]) == 2  # a clear error, exit code 2
    assert "no frame for step(s) [9]" in capsys.readouterr().err


def test_2d_run(tmp_path: Path) -> None:
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-1.0, -1.0], [2.0, -1.0]])
    parts = [
        Part("tri", "deformable", np.arange(3), np.array([[0, 1, 2]]), np.array([[0, 1], [1, 2], [2, 0]])),
        Part("ground", "obstacle", np.arange(3, 5), None, np.array([[3, 4]])),
    ]
    w = FrameWriter(tmp_path / "run2", parts, 2, write_obj=False)
    w.write(0, x)
    w.write(1, x * 1.1)
    w.close()
    got, y = parts_from_frame(tmp_path / "run2" / "vtu" / "frame_00001.vtu", 2)
    assert [p.kind for p in got] == ["deformable", "obstacle"] and np.allclose(y, x * 1.1)
    assert _size(render_run(tmp_path / "run2", tmp_path / "2d.png", dim=2)) == (800, 400)
