"""UV distortion (symmetric Dirichlet), its summary, and the report of ``idp uv`` (JSON, Markdown, two PNGs)."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

import idp.output.uv_report as uv_report
from idp.mesh.uv_obj import UVMesh, cut_cylinder_obj_text, read_uv_obj, uv_rest_frames
from idp.output.uv_report import distortion_summary, symmetric_dirichlet_distortion, write_uv_report


def _cylinder(tmp_path: Path, uv_scale: tuple[float, float] = (1.0, 1.0)) -> UVMesh:
    p = tmp_path / "cyl.obj"
    p.write_text(cut_cylinder_obj_text(12, 4, uv_scale=uv_scale))
    return read_uv_obj(p)


def test_isometric_layout_has_distortion_four(tmp_path: Path) -> None:
    mesh = _cylinder(tmp_path)
    dm, _ = uv_rest_frames(mesh.positions, mesh.faces_xyz)
    psi = symmetric_dirichlet_distortion(mesh.uv, mesh.faces_uv, dm)
    np.testing.assert_allclose(psi, 4.0, rtol=1e-12)
    # a rigid motion of the layout changes nothing
    c, s = math.cos(0.7), math.sin(0.7)
    moved = mesh.uv @ np.array([[c, s], [-s, c]]) + [3.0, -1.0]
    np.testing.assert_allclose(symmetric_dirichlet_distortion(moved, mesh.faces_uv, dm), 4.0, rtol=1e-12)


def test_stretched_and_flipped_layouts(tmp_path: Path) -> None:
    mesh = _cylinder(tmp_path)
    dm, _ = uv_rest_frames(mesh.positions, mesh.faces_xyz)
    stretched = mesh.uv * [2.0, 1.0]  # F has singular values 2 and 1: Ψ = 4 + 1 + 1/4 + 1
    np.testing.assert_allclose(symmetric_dirichlet_distortion(stretched, mesh.faces_uv, dm), 6.25, rtol=1e-12)
    mirrored = mesh.uv * [-1.0, 1.0]
    assert np.all(np.isposinf(symmetric_dirichlet_distortion(mirrored, mesh.faces_uv, dm)))


def test_summary_figures() -> None:
    psi = np.array([4.0, 5.0, 6.0, 100.0])
    areas = np.array([1.0, 1.0, 1.0, 0.01])
    s = distortion_summary(psi, areas)
    assert s["worst"] == 100.0 and s["count"] == 4 and s["infinite"] == 0
    assert s["median"] == pytest.approx(5.5)
    assert s["p99"] == pytest.approx(np.percentile(psi, 99))
    assert s["mean"] == pytest.approx((4 + 5 + 6 + 1.0) / 3.01)
    with_inf = distortion_summary(np.array([4.0] * 200 + [np.inf]), np.ones(201))
    assert math.isinf(with_inf["worst"]) and math.isinf(with_inf["mean"]) and with_inf["infinite"] == 1
    assert math.isinf(with_inf["p99"]) is False and with_inf["median"] == 4.0


def _nontrivial_png(path: Path) -> None:
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] >= 200 and img.shape[1] >= 300
    assert np.unique(img.reshape(-1, img.shape[2]), axis=0).shape[0] > 20, f"{path.name} is nearly blank"


def _bent(mesh: UVMesh) -> np.ndarray:
    """The isometric layout with a bump pushed into it: some triangles stretch, none flip."""
    uv = mesh.uv.copy()
    centre = uv.mean(axis=0)
    r = np.linalg.norm(uv - centre, axis=1)
    return uv + 0.3 * np.exp(-((r / 0.5) ** 2))[:, None] * [1.0, 0.4]


def test_report_files(tmp_path: Path) -> None:
    mesh = _cylinder(tmp_path)
    dm, areas = uv_rest_frames(mesh.positions, mesh.faces_xyz)
    before = _bent(mesh)
    report = write_uv_report(
        tmp_path / "out",
        mesh=mesh,
        Dm=dm,
        areas=areas,
        uv_before=before,
        uv_after=mesh.uv,
        extra={"wall_time": 1.5, "steps": 12, "newton_iterations": 40, "p": 4, "before": "not replaced"},
        title="cylinder",
    )
    out = tmp_path / "out"
    data = json.loads((out / "report.json").read_text())
    assert data["before"]["worst"] > 4.5
    assert data["after"]["worst"] == pytest.approx(4.0)
    assert data["flipped_after"] == 0 and data["overlapping_pairs_after"] == 0
    assert data["steps"] == 12 and data["p"] == 4 and data["wall_time"] == 1.5
    assert isinstance(data["before"], dict)  # extra never replaces the report's own figures
    assert report["after"]["count"] == len(mesh.faces_uv)
    md = (out / "report.md").read_text()
    assert "| worst Ψ |" in md and "| steps | 12 |" in md and "distortion.png" in md
    _nontrivial_png(out / "distortion.png")
    _nontrivial_png(out / "distortion_hist.png")
    assert not list(out.glob("*.tmp"))


def test_report_with_flipped_and_overlapping_after(tmp_path: Path) -> None:
    mesh = _cylinder(tmp_path)
    dm, areas = uv_rest_frames(mesh.positions, mesh.faces_xyz)
    after = mesh.uv.copy()
    after[mesh.faces_uv[0, 2]] = after[mesh.faces_uv[0, 0]] + [0.3, -0.5]  # folds a corner over its neighbours
    report = write_uv_report(tmp_path, mesh=mesh, Dm=dm, areas=areas, uv_before=mesh.uv, uv_after=after, extra={})
    assert report["flipped_after"] > 0 and report["overlapping_pairs_after"] > 0
    assert math.isinf(report["after"]["worst"])
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["after"]["worst"] == "inf"
    assert "∞" in (tmp_path / "report.md").read_text()
    _nontrivial_png(tmp_path / "distortion.png")


def test_a_drawing_failure_keeps_json_and_markdown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    mesh = _cylinder(tmp_path)
    dm, areas = uv_rest_frames(mesh.positions, mesh.faces_xyz)

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("no canvas")

    monkeypatch.setattr(uv_report, "_plot_layouts", broken)
    with caplog.at_level(logging.WARNING, logger="idp"):
        write_uv_report(tmp_path, mesh=mesh, Dm=dm, areas=areas, uv_before=mesh.uv, uv_after=mesh.uv)
    assert "could not render distortion.png" in caplog.text
    assert (tmp_path / "report.json").is_file() and (tmp_path / "distortion_hist.png").is_file()
    md = (tmp_path / "report.md").read_text()
    assert "distortion_hist.png" in md and "(distortion.png)" not in md
