"""Compare an idp repair of the mannequin with the authors' repaired sequence, frame by frame, with one check.

For each frame of the input both outputs are measured the same way: crossing edge–triangle pairs that are not
among the input's first-frame crossings (idp.contact.intersections.intersecting_pair_keys, the check behind the
repair report), split into those among the prescribed vertices only (the head box, ``--prescribed``; of those,
how many also cross in the input frame) and the others, the deviation from the input frame (largest per vertex,
largest per coordinate, mean per vertex) and the prescribed vertices' largest deviation. Writes JSON and prints a
Markdown table of the sequence summary.

    python bench/repair_vs_authors.py runs/kick_full/Kick_unfixed.npz --input data:repair/Kick_unfixed.npz \\
        --authors data:repair/Kick_fixed.npz -o bench/results/kick_vs_authors.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from idp.contact.intersections import intersecting_pair_keys
from idp.paper_data import resolve_data_path


def _load(path: str) -> np.ndarray:
    """vertices (F, n, 3) of an .npz sequence, or of the finished frames of an unfinished repair (its
    ``NAME.npz.partial`` folder of ``frame_*.npy``)."""
    if Path(path).is_dir():
        frames = sorted(Path(path).glob("frame_*.npy"))
        return np.stack([np.load(f) for f in frames]).astype(float)
    with np.load(path if Path(path).exists() else resolve_data_path(path)) as d:
        return np.asarray(d["vertices"], dtype=float)


def _faces(path: str) -> np.ndarray:
    with np.load(resolve_data_path(path)) as d:
        return np.asarray(d["faces"], dtype=np.int64)


def _deviation(out: np.ndarray, inp: np.ndarray) -> dict[str, float]:
    d = out - inp
    per_vertex = np.linalg.norm(d, axis=1)
    return {
        "max": float(per_vertex.max()),
        "max_coordinate": float(np.abs(d).max()),
        "mean": float(per_vertex.mean()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ours", help="idp's output: .npz with vertices (F, n, 3), or a run's .npz.partial folder")
    ap.add_argument("--input", required=True, help="the input sequence (data:repair/…_unfixed.npz)")
    ap.add_argument("--authors", required=True, help="the authors' repaired sequence (data:repair/…_fixed.npz)")
    ap.add_argument("--frames", default=None, help="A:B, frames to compare (default: those idp wrote)")
    ap.add_argument(
        "--prescribed",
        default="-0.1,0.867,-0.1,1.1,1.1,1.1",
        help="the prescribed box x0,y0,z0,x1,y1,z1 relative to the first input frame's bounding box (the head)",
    )
    ap.add_argument("-o", "--output", type=Path, required=True, help="JSON file to write")
    args = ap.parse_args(argv)

    inp, ours, theirs = _load(args.input), _load(args.ours), _load(args.authors)
    faces = _faces(args.input)
    first, stop = (0, ours.shape[0]) if args.frames is None else map(int, args.frames.split(":"))
    first_frame_keys = intersecting_pair_keys(inp[0], faces)
    box = np.array([float(v) for v in args.prescribed.split(",")]).reshape(2, 3)
    lo, hi = inp[0].min(axis=0), inp[0].max(axis=0)
    rel = (inp[0] - lo) / (hi - lo)
    group = np.all((rel >= box[0]) & (rel <= box[1]), axis=1)

    def among_group(key) -> bool:
        return bool(group[list(key[0])].all() and group[list(key[1])].all())

    rows: list[dict[str, Any]] = []
    for k in range(max(first, 1), min(stop, ours.shape[0], theirs.shape[0], inp.shape[0])):
        row: dict[str, Any] = {"frame": k}
        input_keys = intersecting_pair_keys(inp[k], faces)
        for name, seq in (("idp", ours), ("authors", theirs)):
            new = intersecting_pair_keys(seq[k], faces) - first_frame_keys
            prescribed = [key for key in new if among_group(key)]
            row[name] = {
                "new_crossings": len(new),
                "new_crossings_prescribed_only": len(prescribed),
                "new_crossings_prescribed_also_in_input": sum(key in input_keys for key in prescribed),
                "new_crossings_outside_prescribed": len(new) - len(prescribed),
                "prescribed_max_deviation": float(np.linalg.norm(seq[k][group] - inp[k][group], axis=1).max()),
                **_deviation(seq[k], inp[k]),
            }
        rows.append(row)

    def summary(name: str) -> dict[str, float | int]:
        per = [r[name] for r in rows]
        return {
            "frames": len(per),
            "max_deviation": max(p["max"] for p in per),
            "max_coordinate_deviation": max(p["max_coordinate"] for p in per),
            "mean_deviation": float(np.mean([p["mean"] for p in per])),
            "max_new_crossings": max(p["new_crossings"] for p in per),
            "frames_with_new_crossings": sum(p["new_crossings"] > 0 for p in per),
            "max_new_crossings_prescribed_only": max(p["new_crossings_prescribed_only"] for p in per),
            "new_crossings_prescribed_not_in_input": sum(
                p["new_crossings_prescribed_only"] - p["new_crossings_prescribed_also_in_input"] for p in per
            ),
            "max_new_crossings_outside_prescribed": max(p["new_crossings_outside_prescribed"] for p in per),
            "prescribed_max_deviation": max(p["prescribed_max_deviation"] for p in per),
        }

    result: dict[str, Any] = {"ours": args.ours, "input": args.input, "authors": args.authors, "frames": rows}
    result["summary"] = {"idp": summary("idp"), "authors": summary("authors")}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1))
    s = result["summary"]
    print("| | idp | authors |\n|---|---|---|")
    for key in s["idp"]:
        print(f"| {key} | {s['idp'][key]:.6g} | {s['authors'][key]:.6g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
