"""StatsRecorder / to_jsonable / load_stats."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from idp.output.stats import StatsRecorder, load_stats, to_jsonable


@dataclass
class _Cfg:
    dt: float
    mesh: Path
    sizes: np.ndarray


def test_to_jsonable_types() -> None:
    obj = {
        "i": np.int64(3),
        "f": np.float32(0.5),
        "b": np.bool_(True),
        "inf": np.inf,
        "ninf": -math.inf,
        "nan": float("nan"),
        "arr": np.array([[1.0, np.inf], [np.nan, -np.inf]]),
        "iarr": np.arange(3, dtype=np.int32),
        "path": Path("a/b.msh"),
        "cfg": _Cfg(1e-3, Path("m.msh"), np.array([1, 2])),
        "tup": (1, np.float64(2.0)),
        7: "int key",
    }
    out = to_jsonable(obj)
    text = json.dumps(out, allow_nan=False)  # strict JSON
    back = json.loads(text)
    assert back["i"] == 3 and type(back["i"]) is int
    assert back["f"] == 0.5 and back["b"] is True
    assert back["inf"] == "inf" and back["ninf"] == "-inf" and back["nan"] == "nan"
    assert back["arr"] == [[1.0, "inf"], ["nan", "-inf"]]
    assert back["iarr"] == [0, 1, 2]
    assert back["path"] == "a/b.msh"
    assert back["cfg"] == {"dt": 1e-3, "mesh": "m.msh", "sizes": [1, 2]}
    assert back["tup"] == [1, 2.0] and back["7"] == "int key"


def test_recorder_roundtrip_and_crash(tmp_path: Path) -> None:
    path = tmp_path / "run" / "stats.json"
    rec = StatsRecorder(path, {"scene": Path("s.toml"), "n_vertices": np.int64(100)})
    assert load_stats(path) == {"meta": {"scene": "s.toml", "n_vertices": 100}, "steps": [], "summary": None}
    for k in range(5):
        rec.add_step(
            {
                "step": np.int64(k),
                "energy": np.float64(1.5 * k),
                "toi": np.inf if k % 2 else 0.25,
                "res": np.array([1e-3, np.nan]),
            }
        )
        # simulated crash after each step: whatever is on disk is complete, strict JSON
        raw = json.loads(path.read_text(), parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
        assert len(raw["steps"]) == k + 1 and raw["summary"] is None
        assert not path.with_name("stats.json.tmp").exists()
    data = load_stats(path)
    assert [s["step"] for s in data["steps"]] == list(range(5))
    assert data["steps"][1]["toi"] == math.inf and data["steps"][2]["toi"] == 0.25
    assert data["steps"][0]["res"][0] == 1e-3 and math.isnan(data["steps"][0]["res"][1])
    assert load_stats(path, decode_nonfinite=False)["steps"][1]["toi"] == "inf"
    assert len(rec.steps) == 5 and rec.steps[3]["energy"] == 4.5
    rec.set_summary({"steps": 5, "min_toi": np.float64(0.25), "wall_s": 1.2})
    data = load_stats(path)
    assert data["summary"] == {"steps": 5, "min_toi": 0.25, "wall_s": 1.2}
    assert len(data["steps"]) == 5


def test_recorder_many_steps(tmp_path: Path) -> None:
    rec = StatsRecorder(tmp_path / "stats.json", {})
    rec_fields = {f"f{i}": float(i) for i in range(20)}
    for k in range(1000):
        rec.add_step({"step": k, **rec_fields})
    steps = load_stats(tmp_path / "stats.json")["steps"]
    assert [s["step"] for s in steps] == list(range(1000)) and steps[-1]["f19"] == 19.0
