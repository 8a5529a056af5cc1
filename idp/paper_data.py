"""Where the paper's own meshes live: ``$IDP_DATA`` or ``../shared/data`` (never copied into the repo).

Scene files name them as ``data:<folder>/<file>`` (e.g. ``mesh = "data:handles/bar.vtk"``)."""

from __future__ import annotations

import os
from pathlib import Path


def find_data_dir() -> Path | None:
    """The data folder, or None when it is absent (tests and benchmarks then skip with a message)."""
    env = os.environ.get("IDP_DATA")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [
        Path.cwd() / ".." / "shared" / "data",
        here.parents[2] / "shared" / "data",
        here.parents[1] / "shared" / "data",
    ]
    for c in candidates:
        if (c / "benchmark").is_dir():
            return c.resolve()
    return None


def require_data_dir() -> Path:
    d = find_data_dir()
    if d is None:
        raise FileNotFoundError(
            "the paper's data was not found: set IDP_DATA to the folder holding benchmark/ (e.g. ../shared/data)"
        )
    return d


DATA_PREFIX = "data:"


def resolve_data_path(path: str) -> Path:
    """``data:handles/bar.vtk`` → the file in the data folder (FileNotFoundError naming IDP_DATA if absent)."""
    return require_data_dir() / path[len(DATA_PREFIX) :]
