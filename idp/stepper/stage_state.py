"""The state one stage of a modeling scene hands to the next (paper §4.5, §7.5): per object, its current shape
(a mesh file) and, for deformable bodies, its rest frames, rest volumes and accumulated plastic strain (.npz).

Both are written atomically (temporary file + rename) so an interrupted run never leaves half a state, and
read back with checks that name the file: a stage starts from exactly what the previous one ended with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from idp.errors import MeshError

REST_KEYS = ("rest_frames", "volumes")


def write_rest_state(
    path: str | Path, rest_frames: np.ndarray, volumes: np.ndarray, plastic_strain: np.ndarray | None = None
) -> None:
    """Save (m,d,d) effective rest frames Dm (columns: rest edge vectors), (m,) rest volumes and optionally the
    (m,) accumulated plastic strain."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp.npz")
    arrays = {"rest_frames": np.asarray(rest_frames, dtype=float), "volumes": np.asarray(volumes, dtype=float)}
    if plastic_strain is not None:
        arrays["plastic_strain"] = np.asarray(plastic_strain, dtype=float)
    np.savez(tmp, **arrays)  # type: ignore[arg-type]
    tmp.replace(p)


def read_rest_state(path: str | Path, num_elements: int, dim: int) -> dict[str, np.ndarray]:
    """The arrays of a rest-state file, checked against a mesh of ``num_elements`` elements in ``dim`` D."""
    p = Path(path)
    try:
        with open(p, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            st = {k: np.array(data[k]) for k in data.files}
    except FileNotFoundError:
        raise MeshError(f"rest state {p}: no such file") from None
    except Exception as exc:  # zip, npy-format and pickle refusals: numpy raises many types
        raise MeshError(f"rest state {p} is unreadable ({type(exc).__name__}: {exc})") from None
    missing = [k for k in REST_KEYS if k not in st]
    if missing:
        raise MeshError(f"rest state {p} lacks {', '.join(missing)}")
    want = {"rest_frames": (num_elements, dim, dim), "volumes": (num_elements,), "plastic_strain": (num_elements,)}
    for k, shape in want.items():
        if k in st and st[k].shape != shape:
            raise MeshError(f"rest state {p}: {k} has shape {st[k].shape}, the mesh needs {shape}")
        if k in st and not (st[k].dtype.kind == "f" and np.isfinite(st[k]).all()):
            raise MeshError(f"rest state {p}: {k} is not finite floating point")
    det = np.linalg.det(st["rest_frames"]) if num_elements else np.zeros(0)
    bad = np.flatnonzero(~(det > 0))
    if bad.size:
        raise MeshError(f"rest state {p}: element {int(bad[0])} has a rest frame with det {det[bad[0]]:.3e} <= 0")
    if not (st["volumes"] > 0).all():
        raise MeshError(f"rest state {p}: element {int(np.argmin(st['volumes']))} has a rest volume <= 0")
    return st


def write_shape(path: str | Path, mesh) -> None:
    """Write a stage's end shape (a VolumeMesh or SurfaceMesh) atomically as VTU (float64, exact)."""
    from idp.mesh.io import write_mesh

    p = Path(path)
    tmp = p.with_name(p.stem + ".tmp" + p.suffix)
    write_mesh(tmp, mesh)
    tmp.replace(p)
