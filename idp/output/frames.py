"""Per-frame output: OBJ surfaces (Blender), VTU volumes (ParaView) and a PVD time series.

Layout under ``out_dir``::

    obj/frame_00000.obj   all part surfaces, one ``o <name>`` group per part
    vtu/frame_00000.vtu   all points, one cell block per part, point data
    frames.pvd            the VTU time series, rewritten atomically after every frame

OBJ indices are 1-based and refer to the file's vertex list (as OBJ requires): each part
writes only its own surface vertices (compactly renumbered), and its faces index those.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from idp._faults import kill_point
from idp.output.parts import Part, check_parts

if TYPE_CHECKING:  # imported when a VTU frame is written (a run without VTU output never loads meshio and rich)
    import meshio

#: ``%r`` formats a float as its shortest exact form (``repr``): an OBJ frame reads back bit for bit as the positions
#: that were certified. Fewer digits would not: ``%.10g`` moves a vertex at |x| ≈ 0.05 by up to ~5e-12, while
#: blocked handles press gaps down to ~1e-15 (Fig. 2), so a certified frame could be written crossing itself.
_OBJ_FLOAT = "%r"


def _atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and ``os.replace``."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(text)
    kill_point("pvd" if path.suffix == ".pvd" else "frame_tmp")
    os.replace(tmp, path)


def _obj_name(name: str) -> str:
    """An OBJ-safe object name (no whitespace)."""
    cleaned = re.sub(r"\s+", "_", name.strip())
    return cleaned or "part"


class FrameWriter:
    """Writes one OBJ and/or one VTU per frame plus the PVD index of the VTUs.

    ``parts`` use global vertex ids into the ``x`` given to :meth:`write`; ``fixed_mask`` is a
    per-vertex boolean (Dirichlet / pinned) array written as the ``fixed`` point field.
    """

    def __init__(
        self,
        out_dir: str | Path,
        parts: list[Part],
        dim: int,
        *,
        write_obj: bool = True,
        write_vtu: bool = True,
        fixed_mask: np.ndarray | None = None,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.parts = list(parts)
        self.dim = int(dim)
        self.write_obj = bool(write_obj)
        self.write_vtu = bool(write_vtu)
        self._min_vertices = check_parts(self.parts, self.dim)
        self.fixed_mask = None if fixed_mask is None else np.asarray(fixed_mask).reshape(-1).astype(bool)
        self._pvd_entries: dict[int, tuple[float, str]] = {}
        self._closed = False
        if self.write_obj:
            (self.out_dir / "obj").mkdir(parents=True, exist_ok=True)
        if self.write_vtu:
            (self.out_dir / "vtu").mkdir(parents=True, exist_ok=True)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._prepare_obj()
        self._prepare_vtu()

    # ------------------------------------------------------------------ setup
    def _prepare_obj(self) -> None:
        """Precompute per-part surface vertex ids and the (frame-independent) face text."""
        keyword = "f" if self.dim == 3 else "l"
        self._obj_ids: list[np.ndarray] = []
        self._obj_face_text: list[str] = []
        offset = 0
        for p in self.parts:
            ids, inv = np.unique(p.surface.reshape(-1), return_inverse=True)
            local: np.ndarray = inv.reshape(p.surface.shape) + offset + 1
            k = p.surface.shape[1]
            line = keyword + (" %d" * k) + "\n"
            self._obj_face_text.append((line * local.shape[0]) % tuple(local.reshape(-1).tolist()))
            self._obj_ids.append(ids.astype(np.int64))
            offset += ids.size

    def _prepare_vtu(self) -> None:
        """Precompute the cell blocks (one per non-empty part) and their part ids."""
        vol_type = "tetra" if self.dim == 3 else "triangle"
        surf_type = "triangle" if self.dim == 3 else "line"
        self._cells: list[tuple[str, np.ndarray]] = []
        self._cell_part: list[np.ndarray] = []
        self._block_part: list[int] = []
        for i, p in enumerate(self.parts):
            if p.kind == "deformable":
                assert p.elements is not None  # check_parts (in __init__) rejects a deformable part without elements
                block = (vol_type, p.elements)
            else:
                block = (surf_type, p.surface)
            if block[1].shape[0] == 0:
                continue
            self._cells.append(block)
            self._cell_part.append(np.full(block[1].shape[0], i, dtype=np.int32))
            self._block_part.append(i)

    # ------------------------------------------------------------------ writing
    def _check_x(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"x must be (n, {self.dim}), got {x.shape}")
        if x.shape[0] < self._min_vertices:
            raise ValueError(f"x has {x.shape[0]} vertices but the parts refer to {self._min_vertices}")
        if not np.isfinite(x).all():
            bad = int(np.flatnonzero(~np.isfinite(x).all(axis=1))[0])
            raise ValueError(f"x has a non-finite coordinate at vertex {bad}")
        if self.fixed_mask is not None and self.fixed_mask.shape[0] != x.shape[0]:
            raise ValueError(f"fixed_mask has {self.fixed_mask.shape[0]} entries but x has {x.shape[0]} vertices")
        return x

    def _obj_text(self, x: np.ndarray) -> str:
        """The full OBJ file for positions ``x`` (vectorised formatting, one op per part)."""
        chunks = [f"# idp frame, {len(self.parts)} parts\n"]
        vline = "v " + " ".join([_OBJ_FLOAT] * 3) + "\n"
        for p, ids, faces in zip(self.parts, self._obj_ids, self._obj_face_text, strict=True):
            pts = np.zeros((ids.size, 3))
            pts[:, : self.dim] = x[ids]
            chunks.append(f"o {_obj_name(p.name)}\n")
            chunks.append((vline * ids.size) % tuple(pts.reshape(-1).tolist()))
            chunks.append(faces)
        return "".join(chunks)

    def _vtu_mesh(
        self,
        x: np.ndarray,
        point_data: dict[str, np.ndarray] | None,
        cell_data: dict[str, dict[int, np.ndarray]] | None = None,
    ) -> meshio.Mesh:
        import meshio

        n = x.shape[0]
        pts = np.zeros((n, 3))
        pts[:, : self.dim] = x
        part_id = np.full(n, -1, dtype=np.int32)
        for i, p in enumerate(self.parts):
            part_id[p.vertex_ids] = i
        fixed = np.zeros(n, dtype=np.int32) if self.fixed_mask is None else self.fixed_mask.astype(np.int32)
        pdata: dict[str, np.ndarray] = {"part_id": part_id, "fixed": fixed}
        for name, arr in (point_data or {}).items():
            a = np.asarray(arr)
            if a.shape[0] != n:
                raise ValueError(f"point_data[{name!r}] has {a.shape[0]} rows, expected {n}")
            if a.dtype == bool:
                a = a.astype(np.uint8)
            if self.dim == 2 and a.ndim == 2 and a.shape[1] == 2:
                a = np.concatenate([a, np.zeros((n, 1), dtype=a.dtype)], axis=1)  # ParaView vectors are 3D
            pdata[name] = np.ascontiguousarray(a)
        cdata = {"part_id": list(self._cell_part)} if self._cells else {}
        for name, per_part in (cell_data or {}).items():
            blocks = []
            for (_, cells), i in zip(self._cells, self._block_part, strict=True):
                vals = per_part.get(i)
                if vals is None:
                    vals = np.zeros(cells.shape[0])
                elif vals.shape[0] != cells.shape[0]:
                    raise ValueError(f"cell_data[{name!r}] part {i}: {vals.shape[0]} values for {cells.shape[0]} cells")
                blocks.append(np.ascontiguousarray(vals, dtype=float))
            cdata[name] = blocks
        return meshio.Mesh(pts, list(self._cells), point_data=pdata, cell_data=cdata)

    def _pvd_text(self) -> str:
        from xml.sax.saxutils import quoteattr  # VTU output only (it imports urllib, http and email: 2 MB)

        lines = [
            '<?xml version="1.0"?>',
            '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
            "  <Collection>",
        ]
        for frame in sorted(self._pvd_entries):
            t, rel = self._pvd_entries[frame]
            lines.append(f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(rel)}/>')
        lines += ["  </Collection>", "</VTKFile>", ""]
        return "\n".join(lines)

    def write(
        self,
        frame: int,
        x: np.ndarray,
        time: float | None = None,
        point_data: dict[str, np.ndarray] | None = None,
        cell_data: dict[str, dict[int, np.ndarray]] | None = None,
    ) -> dict[str, str]:
        """Write frame ``frame`` at positions ``x`` (n, dim); return {"obj"|"vtu"|"pvd": relative path}.

        The PVD timestep is ``time`` when given, else ``frame``. Writing a frame number again
        replaces its files and its PVD entry. ``cell_data``: VTU cell fields, per field {part index: one value
        per element of that part} (parts left out get zeros).
        """
        if self._closed:
            raise RuntimeError("FrameWriter.write called after close()")
        frame = int(frame)
        if frame < 0:
            raise ValueError(f"frame must be >= 0, got {frame}")
        t = float(frame if time is None else time)
        if not np.isfinite(t):
            raise ValueError(f"time must be finite, got {time}")
        x = self._check_x(x)
        written: dict[str, str] = {}
        stem = f"frame_{frame:05d}"
        if self.write_obj:
            rel = f"obj/{stem}.obj"
            _atomic_write_text(self.out_dir / rel, self._obj_text(x))
            written["obj"] = rel
            kill_point("frame_between")
        if self.write_vtu:
            rel = f"vtu/{stem}.vtu"
            mesh = self._vtu_mesh(x, point_data, cell_data)
            target = self.out_dir / rel
            tmp = target.with_name(target.name + ".tmp")
            import meshio

            meshio.write(tmp, mesh, file_format="vtu", binary=True, compression="zlib")
            kill_point("frame_tmp")
            os.replace(tmp, target)
            written["vtu"] = rel
            self._pvd_entries[frame] = (t, rel)
            _atomic_write_text(self.out_dir / "frames.pvd", self._pvd_text())
            written["pvd"] = "frames.pvd"
        return written

    def resume(self, last_frame: int, time_of: Callable[[int], float]) -> None:
        """Continue an interrupted series after frame ``last_frame``: adopt the frames on disk up to it (their PVD
        times ``time_of(frame)``, the formula they were written with), remove later frames and temporary files an
        interruption left (they are rewritten by the resumed run), and rewrite the PVD index."""
        pattern = re.compile(r"frame_(\d{5,})\.(obj|vtu)$")
        for sub in ("obj", "vtu"):
            folder = self.out_dir / sub
            if not folder.is_dir():
                continue
            for f in sorted(folder.iterdir()):
                m = pattern.match(f.name)
                if f.name.endswith(".tmp") or (m is not None and int(m.group(1)) > last_frame):
                    f.unlink(missing_ok=True)
                elif m is not None and sub == "vtu" and self.write_vtu:
                    frame = int(m.group(1))
                    self._pvd_entries[frame] = (float(time_of(frame)), f"vtu/{f.name}")
        for f in self.out_dir.glob("*.tmp"):
            f.unlink(missing_ok=True)
        if self.write_vtu:
            _atomic_write_text(self.out_dir / "frames.pvd", self._pvd_text())

    def close(self) -> None:
        """Finish the series (the PVD is already complete after every write); further writes fail."""
        if not self._closed and self.write_vtu and self._pvd_entries:
            _atomic_write_text(self.out_dir / "frames.pvd", self._pvd_text())
        self._closed = True

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
