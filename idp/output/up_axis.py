"""Which scene axis a picture draws upwards (kept apart from the renderer: choosing it must not load matplotlib)."""

from __future__ import annotations

import numpy as np


def up_axis(dim: int, up: str, gravity) -> str:
    """``up`` when it names an axis, else (``"auto"``) the axis most against ``gravity`` in 3D, else z."""
    if up in ("x", "y", "z"):
        return up
    g = np.asarray(gravity if gravity is not None else [0.0, 0.0, 0.0], dtype=float).reshape(-1)
    if dim != 3 or g.size != 3 or not np.all(np.isfinite(g)) or not np.any(g):
        return "z"
    return "xyz"[int(np.argmax(np.abs(g)))]
