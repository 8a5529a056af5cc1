"""write_repair_report: the per-sequence report of ``idp repair`` (JSON, Markdown, two PNGs)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from idp.mesh.generate import ellipsoid_surface
from idp.output.repair_report import write_repair_report

CHANGED = {2: 0.05, 4: 0.12}  # frame -> size of the bump the repair pushed in


def _sequence(frames: int = 6) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    mesh = ellipsoid_surface((0.5, 0.4, 0.8), subdivisions=2)
    v, f = mesh.vertices, mesh.faces
    inputs = [v + np.array([0.1 * k, 0.0, 0.02 * k]) for k in range(frames)]
    outputs = [x.copy() for x in inputs]
    for k, size in CHANGED.items():
        near = np.linalg.norm(v - v[0], axis=1)
        weight = np.clip(1.0 - near / 0.4, 0.0, None)  # a smooth bump around vertex 0
        outputs[k] = inputs[k] + size * weight[:, None] * (v / np.linalg.norm(v, axis=1, keepdims=True))
    return f, inputs, outputs


def _record(step: int, x_in: np.ndarray, x_out: np.ndarray, *, initial: bool = False) -> dict:
    d = x_out - x_in
    dist = np.linalg.norm(d, axis=1)
    changed = bool(np.any(d))
    rec = {
        "step": step,
        "certificate": {"ok": True, "min_distance": 1e-3},
        "repair": {
            "frame": step,
            "unchanged": not changed,
            "max_deviation": float(dist.max()),
            "mean_deviation": float(dist.mean()),
            "max_coordinate_deviation": float(np.abs(d).max()),
            "max_deviation_relative": float(dist.max()) / 2.0,
            "changed_vertices": int(np.count_nonzero(dist)),
            "input_crossing_pairs": 7 if changed else 2,
            "input_crossing_pairs_not_preserved": 5 if changed else 0,
            "output_crossing_pairs": 2,
            "output_crossing_pairs_not_preserved": 0,
        },
    }
    if initial:
        rec["initial"] = True
    else:
        rec.update({"wall_time": 0.5, "newton_iterations": 4 if changed else 1, "converged": True})
        rec["exact_minimiser"] = not changed
    return rec


def _records(inputs: list[np.ndarray], outputs: list[np.ndarray]) -> list[dict]:
    recs = [_record(0, inputs[0], outputs[0], initial=True)]
    for s in range(1, len(inputs)):
        recs.append(_record(s, inputs[s], outputs[s]))
        if s == 3:  # a resumed run started from step 3: its initial record repeats that step
            recs.append(_record(3, inputs[3], outputs[3], initial=True))
    return recs


def _nontrivial_png(path: Path) -> None:
    assert path.is_file()
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] >= 200 and img.shape[1] >= 300
    assert not np.all(img == img[0, 0]), f"{path.name} is a blank image"
    assert np.unique(img.reshape(-1, img.shape[2]), axis=0).shape[0] > 20


def test_report_figures_markdown_and_pictures(tmp_path: Path) -> None:
    faces, inputs, outputs = _sequence()
    records = _records(inputs, outputs)
    summary = {"wall_time": 3.2, "newton_iterations": 11, "all_certified": True, "uncertified_frames": 0}
    rep = write_repair_report(
        tmp_path,
        records,
        summary,
        faces=faces,
        read_input=lambda k: inputs[k],
        read_output=lambda k: outputs[k],
        title="test sequence",
    )
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk == json.loads(json.dumps(rep))
    rows, seq = rep["frames"], rep["sequence"]
    assert [r["frame"] for r in rows] == [0, 1, 2, 3, 4, 5]
    assert rows[3]["newton_iterations"] == 1 and not rows[3]["initial"]  # the resume's initial record is skipped
    assert seq["frames"] == 6 and seq["repaired_frames"] == 5
    assert seq["unchanged_frames"] == 4
    assert seq["frames_with_input_crossings"] == 2
    assert seq["frames_with_output_crossings"] == 0
    assert seq["max_deviation_frame"] == 4
    assert seq["max_deviation"] == pytest.approx(CHANGED[4])
    assert seq["max_deviation_relative"] == pytest.approx(CHANGED[4] / 2.0)
    assert seq["max_coordinate_deviation"] <= seq["max_deviation"]
    assert seq["newton_iterations"] == 11 and seq["mean_newton_iterations_per_frame"] == pytest.approx(11 / 5)
    assert seq["wall_time"] == 3.2 and seq["mean_seconds_per_frame"] == pytest.approx(0.5)
    assert seq["all_certified"] is True

    md = (tmp_path / "report.md").read_text()
    table = [line for line in md.splitlines() if line.startswith("| ") and line.split("|")[1].strip()[:1].isdigit()]
    assert len(table) == 6
    assert "| 4 |" in md and "7 (5)" in md

    _nontrivial_png(tmp_path / "deviation.png")
    _nontrivial_png(tmp_path / "worst_frame.png")
    assert not list(tmp_path.glob("*.tmp"))


def test_no_frame_changed_and_picture_failure(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    faces, inputs, _ = _sequence()
    records = [_record(0, inputs[0], inputs[0], initial=True)] + [_record(s, inputs[s], inputs[s]) for s in (1, 2)]
    rep = write_repair_report(
        tmp_path / "a", records, {}, faces=faces, read_input=lambda k: inputs[k], read_output=lambda k: inputs[k]
    )
    seq = rep["sequence"]
    assert seq["unchanged_frames"] == 3 and seq["max_deviation"] == 0.0 and seq["max_deviation_frame"] is None
    assert seq["all_certified"] is True and seq["wall_time"] == pytest.approx(1.0)
    _nontrivial_png(tmp_path / "a" / "worst_frame.png")

    def broken(k: int) -> np.ndarray:
        raise OSError("frame file missing")

    with caplog.at_level(logging.WARNING, logger="idp"):
        write_repair_report(tmp_path / "b", records, {}, faces=faces, read_input=broken, read_output=broken)
    assert "worst_frame.png" in caplog.text
    assert (tmp_path / "b" / "report.json").is_file() and (tmp_path / "b" / "report.md").is_file()
    assert (tmp_path / "b" / "deviation.png").is_file() and not (tmp_path / "b" / "worst_frame.png").exists()
