"""Writing an animation sequence back in the form it came in (OBJ folder, PVD series, ``.npz``, USD).

:func:`sequence_writer` picks the input's form by default; :meth:`SequenceWriter.write` takes frame ``k`` (an index
into the input sequence) and every per-frame file is written atomically (temporary file + ``os.replace``), so an
interrupted run never leaves a truncated frame and can be resumed (:meth:`SequenceWriter.frames_written`). Layouts:

* ``obj``: ``OUT/`` holds one OBJ per frame, named as the input's files when the input is an OBJ sequence (each
  is the input file with only the ``v`` coordinates replaced, every other line kept byte for byte), else
  ``frame_00000.obj`` ...
* ``pvd``: ``OUT/<stem>.pvd`` (the input PVD's stem, else ``frames``) and ``OUT/vtu/<name>.vtu`` (the input VTUs'
  names, each the input mesh with only its points replaced, else ``frame_00000.vtu``); timesteps are the input's
  PVD timesteps or USD time codes when it has them, else the frame index. The PVD is written by ``close()``.
* ``npz``: ``OUT`` (``.npz`` added when missing) with ``vertices`` (F, n, 3) float64 and ``faces`` (m, 3) int64.
* ``usd``: ``OUT`` (``.usd``/``.usda``/``.usdc``): for a USD input, its stage with only the mesh's ``points``
  time samples replaced (and its ``extent`` samples, where the input has them, recomputed), same prim path, time
  codes and rate; a single-layer input is copied as is, a layered one is flattened first. Otherwise a new stage
  with the Mesh ``/Sequence/Mesh`` and time codes 0 .. F-1. USD points are ``point3f[]``: the writer rounds to
  the input's stored precision (``coordinate_dtype``), float32 for the schema type.

npz and usd frames go to ``OUT.partial/frame_00000.npy`` as they come and are assembled one frame at a time by
``close()``, which then removes ``OUT.partial``; a writer opened on an existing partial output keeps its frames.
OBJ and VTU coordinates are written with ``repr`` (shortest exact form), so float64 values read back bit-identical.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from idp.errors import MeshError
from idp.mesh.sequence import (
    FORMATS,
    USD_SUFFIXES,
    FrameSequence,
    ObjSequence,
    PvdSequence,
    UsdSequence,
    import_pxr,
    open_sequence,
)

_FRAME_FILE = re.compile(r"^frame_(\d{5,})\.(obj|vtu|npy)$")


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)


def _atomic_copy(src: Path, dst: Path) -> None:
    tmp = dst.with_name(dst.name + ".tmp")
    shutil.copyfile(src, tmp)
    os.replace(tmp, dst)


def _numbered(folder: Path, ext: str) -> list[int]:
    """Frame indices of the ``frame_XXXXX.<ext>`` files in ``folder``."""
    if not folder.is_dir():
        return []
    found = []
    for q in folder.iterdir():
        m = _FRAME_FILE.match(q.name)
        if m and m.group(2) == ext and q.is_file():
            found.append(int(m.group(1)))
    return sorted(found)


def _unique_names(files: list[Path], where: Path) -> list[str]:
    names = [f.name for f in files]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise MeshError(f"cannot write {where} with the input's file names: several input frames are named {dup}")
    return names


def _format_floats(values: np.ndarray) -> list[str]:
    """Shortest strings that read back as exactly these float64 values."""
    return [repr(v) for v in values.tolist()]


class SequenceWriter:
    """Writes the frames of one sequence; see the module docstring for each format's layout.

    ``num_frames`` (from ``like``, else None: the frames written so far must then be 0 .. K-1 at ``close()``),
    ``coordinate_dtype`` is the precision the output stores (float64 except USD points).
    """

    format: str = ""
    coordinate_dtype: np.dtype = np.dtype(np.float64)

    def __init__(self, out: Path, faces: np.ndarray, like: FrameSequence | None) -> None:
        self.out = out
        self.faces = faces
        self.like = like
        self.num_frames: int | None = None if like is None else like.num_frames
        #: the input frames this output holds, in order (a repair of frames A..B−1); None: all of them
        self.frames: list[int] | None = None
        self.num_vertices: int | None = None if like is None else like.num_vertices
        self._closed = False

    # ------------------------------------------------------------------ API
    def write(self, k: int, vertices: np.ndarray, *, unchanged: bool = False) -> None:
        """Write frame ``k`` at positions ``vertices`` (n, 3).

        ``unchanged``: the frame is the input's own; a per-frame input file (OBJ, VTU) of the same format is then
        copied byte for byte (``vertices`` is not used).
        """
        if self._closed:
            raise RuntimeError(f"{type(self).__name__}.write called after close()")
        k = int(k)
        if k < 0 or (self.num_frames is not None and k >= self.num_frames):
            raise IndexError(f"frame {k} out of range for {self.out} ({self.num_frames} frames)")
        x = np.asarray(vertices, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"frame {k}: vertices must be (n, 3), got shape {x.shape}")
        if self.num_vertices is None:
            self.num_vertices = self._existing_num_vertices()
        if self.num_vertices is not None and x.shape[0] != self.num_vertices:
            raise ValueError(f"frame {k}: {x.shape[0]} vertices, the sequence has {self.num_vertices}")
        if x.shape[0] <= int(self.faces.max()):
            raise ValueError(f"frame {k}: {x.shape[0]} vertices but the faces refer to vertex {int(self.faces.max())}")
        bad = np.flatnonzero(~np.isfinite(x).all(axis=1))
        if bad.size:
            raise ValueError(f"frame {k}: non-finite coordinate at vertex {int(bad[0])}")
        self.num_vertices = x.shape[0]
        self._write(k, np.ascontiguousarray(x), unchanged)

    def frames_written(self) -> list[int]:
        """Indices of the frames present on disk (written by this writer or an earlier, interrupted one)."""
        raise NotImplementedError

    def recover_finished(self, frames: list[int]) -> int:
        """Before a resumed run: take back the frames of an output an earlier run finished (see
        :meth:`_PartialWriter.recover_finished`). Per-frame formats (OBJ, VTU) keep every frame file, so nothing is
        needed; returns how many frames were recovered."""
        return 0

    def close(self) -> None:
        """Finish the output (PVD index, npz/USD assembly); MeshError when frames are missing."""
        if self._closed:
            return
        written = self.frames_written()
        count = self.num_frames if self.num_frames is not None else (written[-1] + 1 if written else 0)
        expected = list(range(count)) if self.frames is None else list(self.frames)
        missing = sorted(set(expected) - set(written))
        if missing or not expected:
            shown = ", ".join(str(k) for k in missing[:10]) + (", ..." if len(missing) > 10 else "")
            raise MeshError(f"cannot finish {self.out}: frame(s) {shown or '0'} not written")
        self._finish(expected)
        self._closed = True

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:  # after an error, leave the partial output for a resumed run
            self.close()

    # ------------------------------------------------------------------ per-format part
    def _write(self, k: int, x: np.ndarray, unchanged: bool) -> None:
        raise NotImplementedError

    def _finish(self, frames: list[int]) -> None:
        raise NotImplementedError

    def _existing_num_vertices(self) -> int | None:
        """The vertex count of frames an earlier run left (None when unknown)."""
        return None

    def _time(self, k: int) -> float:
        times = None if self.like is None else self.like.frame_times
        return float(times[k]) if times is not None else float(k)


class ObjSequenceWriter(SequenceWriter):
    """``OUT/`` with one OBJ per frame."""

    format = "obj"

    def __init__(self, out: Path, faces: np.ndarray, like: FrameSequence | None) -> None:
        super().__init__(out, faces, like)
        self._source = like if isinstance(like, ObjSequence) else None
        self._names = None if self._source is None else _unique_names(self._source.frame_files, out)
        out.mkdir(parents=True, exist_ok=True)
        self._face_text = "".join(f"f {a} {b} {c}\n" for a, b, c in (faces + 1).tolist())

    def _name(self, k: int) -> str:
        return f"frame_{k:05d}.obj" if self._names is None else self._names[k]

    def frames_written(self) -> list[int]:
        if self._names is None:
            return _numbered(self.out, "obj")
        return [k for k, name in enumerate(self._names) if (self.out / name).is_file()]

    def _write(self, k: int, x: np.ndarray, unchanged: bool) -> None:
        target = self.out / self._name(k)
        if self._source is None:
            values = _format_floats(x.reshape(-1))
            vlines = "".join(f"v {values[i]} {values[i + 1]} {values[i + 2]}\n" for i in range(0, len(values), 3))
            text = f"# idp sequence frame {k}\n" + vlines + self._face_text
            _atomic_write_bytes(target, text.encode("utf-8"))
        elif unchanged:
            _atomic_copy(self._source.frame_files[k], target)
        else:
            _atomic_write_bytes(target, _replace_obj_vertices(self._source.frame_files[k], x, k))

    def _finish(self, frames: list[int]) -> None:
        pass


def _replace_obj_vertices(src: Path, x: np.ndarray, k: int) -> bytes:
    """The bytes of OBJ ``src`` with the coordinates of its ``v`` lines replaced by ``x`` (all else kept as is).

    Lines are found as idp's OBJ reader finds them (``str.splitlines`` of the text; a vertex line starts with
    ``v`` followed by whitespace), so vertex ``i`` of the file is row ``i``; tokens after the third coordinate
    (``w`` or vertex colours) are kept. Undecodable bytes pass through unchanged (surrogateescape).
    """
    try:
        text = src.read_bytes().decode("utf-8", errors="surrogateescape")
    except OSError as exc:
        raise MeshError(f"frame {k}: cannot read {src}: {exc}") from None
    values = _format_floats(x.reshape(-1))
    out: list[str] = []
    i = 0
    n = x.shape[0]
    for line in text.splitlines(keepends=True):
        if line and line[0] == "v":
            parts = line.split()
            if parts and parts[0] == "v":
                if i >= n:
                    raise MeshError(f"frame {k} ({src}): more than {n} vertex lines")
                body = line.rstrip("\r\n\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")
                ending = line[len(body) :]
                rest = "".join(" " + t for t in parts[4:])
                line = f"v {values[3 * i]} {values[3 * i + 1]} {values[3 * i + 2]}{rest}{ending}"
                i += 1
        out.append(line)
    if i != n:
        raise MeshError(f"frame {k} ({src}): {i} vertex lines, the sequence has {n} vertices")
    return "".join(out).encode("utf-8", errors="surrogateescape")


class PvdSequenceWriter(SequenceWriter):
    """``OUT/<stem>.pvd`` and ``OUT/vtu/`` with one VTU per frame."""

    format = "pvd"

    def __init__(self, out: Path, faces: np.ndarray, like: FrameSequence | None) -> None:
        super().__init__(out, faces, like)
        self._source = like if isinstance(like, PvdSequence) else None
        self._names = None if self._source is None else _unique_names(self._source.frame_files, out / "vtu")
        self.pvd_path = out / (
            f"{like.path.stem}.pvd" if self._source is not None and like is not None else "frames.pvd"
        )
        (out / "vtu").mkdir(parents=True, exist_ok=True)

    def _name(self, k: int) -> str:
        return f"frame_{k:05d}.vtu" if self._names is None else self._names[k]

    def frames_written(self) -> list[int]:
        if self._names is None:
            return _numbered(self.out / "vtu", "vtu")
        return [k for k, name in enumerate(self._names) if (self.out / "vtu" / name).is_file()]

    def _write(self, k: int, x: np.ndarray, unchanged: bool) -> None:
        import meshio

        from idp.mesh.io import _read_meshio

        target = self.out / "vtu" / self._name(k)
        if self._source is not None and unchanged:
            _atomic_copy(self._source.frame_files[k], target)
            return
        if self._source is not None:
            try:
                mesh = _read_meshio(self._source.frame_files[k])
            except MeshError as exc:
                raise MeshError(f"frame {k}: {exc}") from None
            mesh.points = x  # point and cell data, and every cell block, stay the input's
        else:
            mesh = meshio.Mesh(x, [("triangle", self.faces)])
        tmp = target.with_name(target.name + ".tmp")
        meshio.write(tmp, mesh, file_format="vtu", binary=True, compression="zlib")
        os.replace(tmp, target)

    def _finish(self, frames: list[int]) -> None:
        lines = [
            '<?xml version="1.0"?>',
            '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
            "  <Collection>",
        ]
        for k in frames:
            rel = f"vtu/{self._name(k)}"
            lines.append(f'    <DataSet timestep="{self._time(k)!r}" group="" part="0" file={quoteattr(rel)}/>')
        lines += ["  </Collection>", "</VTKFile>", ""]
        _atomic_write_bytes(self.pvd_path, "\n".join(lines).encode("utf-8"))


class _PartialWriter(SequenceWriter):
    """Frames to ``OUT.partial/frame_XXXXX.npy`` (float64), assembled by ``close()``; resumable."""

    def __init__(self, out: Path, faces: np.ndarray, like: FrameSequence | None) -> None:
        super().__init__(out, faces, like)
        self.partial = out.with_name(out.name + ".partial")
        self.partial.mkdir(parents=True, exist_ok=True)
        faces_file = self.partial / "faces.npy"
        if faces_file.is_file():
            earlier = np.load(faces_file, allow_pickle=False)
            if not np.array_equal(earlier, faces):
                raise MeshError(
                    f"{self.partial} holds frames of a different mesh (other faces): remove it or choose another output"
                )
        else:
            tmp = faces_file.with_name("faces.npy.tmp")
            with open(tmp, "wb") as fh:
                np.save(fh, faces, allow_pickle=False)
            os.replace(tmp, faces_file)

    def _frame_file(self, k: int) -> Path:
        return self.partial / f"frame_{k:05d}.npy"

    def recover_finished(self, frames: list[int]) -> int:
        """Before a resumed run: when an earlier run *finished* this output (assembled it and removed the partial
        store) and is now extended (``--resume`` with more steps), put its frames back into the partial store as
        ``frames[:F]`` (F the frames it holds, the first of the same frame list), so the longer sequence can be
        assembled. Frames already in the partial store are kept. Returns how many were recovered."""
        if not self.out.exists() or self.frames_written():
            return 0
        try:
            done = open_sequence(self.out)
            count = min(int(done.num_frames), len(frames))
            if self.num_vertices is not None and done.num_vertices != self.num_vertices:
                return 0
            for i in range(count):
                self._write(frames[i], np.asarray(done.frame(i), dtype=np.float64), False)
        except (OSError, ValueError, MeshError) as exc:
            raise MeshError(
                f"cannot resume into {self.out}: the finished output of the earlier run is unreadable ({exc}); "
                "remove it and the checkpoint to start over"
            ) from None
        return count

    def frames_written(self) -> list[int]:
        return _numbered(self.partial, "npy")

    def _existing_num_vertices(self) -> int | None:
        done = self.frames_written()
        if not done:
            return None
        return int(np.load(self._frame_file(done[0]), mmap_mode="r", allow_pickle=False).shape[0])

    def _write(self, k: int, x: np.ndarray, unchanged: bool) -> None:
        target = self._frame_file(k)
        tmp = target.with_name(target.name + ".tmp")
        with open(tmp, "wb") as fh:
            np.save(fh, x, allow_pickle=False)
        os.replace(tmp, target)

    def _load(self, k: int) -> np.ndarray:
        return np.load(self._frame_file(k), allow_pickle=False)

    def _finish(self, frames: list[int]) -> None:
        self._assemble(frames)
        shutil.rmtree(self.partial)

    def _assemble(self, frames: list[int]) -> None:
        raise NotImplementedError


class NpzSequenceWriter(_PartialWriter):
    """``OUT.npz`` with ``vertices`` (F, n, 3) float64 and ``faces`` (m, 3) int64."""

    format = "npz"

    def _assemble(self, frames: list[int]) -> None:
        import zipfile

        n = int(self.num_vertices or self._existing_num_vertices() or 0)
        header = {"descr": "<f8", "fortran_order": False, "shape": (len(frames), n, 3)}
        tmp = self.out.with_name(self.out.name + ".tmp")
        with open(tmp, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            with zf.open("vertices.npy", "w", force_zip64=True) as member:  # streamed: one frame in memory
                np.lib.format.write_array_header_1_0(member, header)
                for k in frames:
                    member.write(np.ascontiguousarray(self._load(k), dtype="<f8").tobytes())
            with zf.open("faces.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.ascontiguousarray(self.faces, dtype="<i8"), allow_pickle=False)
        os.replace(tmp, self.out)


class UsdSequenceWriter(_PartialWriter):
    """A USD stage: the input's with new ``points`` samples, or a new one with ``/Sequence/Mesh``."""

    format = "usd"
    coordinate_dtype = np.dtype(np.float32)

    def __init__(self, out: Path, faces: np.ndarray, like: FrameSequence | None) -> None:
        import_pxr()  # fail before any frame is computed
        super().__init__(out, faces, like)
        self._source = like if isinstance(like, UsdSequence) else None
        if self._source is not None:
            self.coordinate_dtype = np.dtype(self._source.points_dtype)

    def _assemble(self, frames: list[int]) -> None:
        pxr = import_pxr()
        Sdf, Usd, UsdGeom, Vt = pxr.Sdf, pxr.Usd, pxr.UsdGeom, pxr.Vt
        tmp = self.out.with_name(f"{self.out.stem}.tmp{self.out.suffix}")
        args: dict[str, str] = {}
        if self._source is not None:
            src = self._source
            stage_in = Usd.Stage.Open(str(src.path))
            layers = [layer for layer in stage_in.GetUsedLayers() if layer != stage_in.GetSessionLayer()]
            layer = Sdf.Layer.CreateAnonymous(f"copy{self.out.suffix}")
            if len(layers) == 1:
                layer.TransferContent(stage_in.GetRootLayer())
            else:
                layer.TransferContent(stage_in.Flatten())
            stage = Usd.Stage.Open(layer)
            mesh = UsdGeom.Mesh(stage.GetPrimAtPath(src.prim_path))
            points, extent = mesh.GetPointsAttr(), mesh.GetExtentAttr()
            times: Any = src.frame_times
            array_type: Any = type(points.Get(times[0]))
            update_extent = extent.GetNumTimeSamples() > 0
            with open(src.path, "rb") as fh:
                crate = fh.read(8) == b"PXR-USDC"
            if self.out.suffix.lower() == ".usd" and not crate:
                args["format"] = "usda"  # a text .usd stays text
        else:
            stage = Usd.Stage.CreateInMemory(f"new{self.out.suffix}")
            UsdGeom.Xform.Define(stage, "/Sequence")
            stage.SetDefaultPrim(stage.GetPrimAtPath("/Sequence"))
            mesh = UsdGeom.Mesh.Define(stage, "/Sequence/Mesh")
            mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(self.faces.shape[0], 3, np.int32)))
            mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(self.faces.astype(np.int32).reshape(-1)))
            stage.SetStartTimeCode(0)
            stage.SetEndTimeCode(len(frames) - 1)
            points, extent = mesh.GetPointsAttr(), mesh.GetExtentAttr()
            times = {k: float(i) for i, k in enumerate(frames)}
            array_type = Vt.Vec3fArray
            update_extent = True
        for k in frames:
            value = array_type.FromNumpy(np.ascontiguousarray(self._load(k), dtype=self.coordinate_dtype))
            points.Set(value, Usd.TimeCode(times[k]))
            if update_extent:
                extent.Set(UsdGeom.PointBased.ComputeExtent(value), Usd.TimeCode(times[k]))
        if not stage.GetRootLayer().Export(str(tmp), args=args):
            raise MeshError(f"cannot write USD file {self.out}")
        os.replace(tmp, self.out)


_WRITERS: dict[str, type[SequenceWriter]] = {
    "obj": ObjSequenceWriter,
    "pvd": PvdSequenceWriter,
    "npz": NpzSequenceWriter,
    "usd": UsdSequenceWriter,
}


def _check_not_input(out: Path, like: FrameSequence) -> None:
    """MeshError when ``out`` would overwrite the input sequence."""
    inputs = [like.path, *(like.frame_files or []), *(f.parent for f in like.frame_files or [])]
    if like.format == "pvd":
        inputs.append(like.path.parent)  # OUT/<stem>.pvd would be the input PVD
    target = out.resolve()
    if any(target == q.resolve() for q in inputs):
        raise MeshError(f"output {out} would overwrite the input sequence {like.path}: choose another output")


def sequence_writer(
    out: str | os.PathLike,
    faces: np.ndarray,
    *,
    like: FrameSequence | None = None,
    format: str | None = None,
    frames: list[int] | None = None,
) -> SequenceWriter:
    """A writer of a sequence with triangles ``faces`` to ``out``, in the form of ``like`` unless ``format`` is given.

    Without both, the format follows from the suffix of ``out`` (``.npz``, ``.usd``/``.usda``/``.usdc``).
    ``faces`` must be ``like.faces`` when ``like`` is given (a repair keeps the topology). ``frames``: the input
    frames the output holds, in order (default all): an npz/PVD/new USD output then has exactly those; a copied
    USD stage keeps the input's samples at the other time codes.
    """
    path = Path(out)
    fmt = format if format is not None else (like.format if like is not None else None)
    if fmt is None:
        suffix = path.suffix.lower()
        fmt = "npz" if suffix == ".npz" else "usd" if suffix in USD_SUFFIXES else None
        if fmt is None:
            raise ValueError(f"cannot tell the sequence format of {path}: pass format= ({', '.join(FORMATS)})")
    if fmt not in FORMATS:
        raise ValueError(f"unknown sequence format {fmt!r}; expected one of {', '.join(FORMATS)}")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0 or not np.issubdtype(f.dtype, np.integer) or f.min() < 0:
        raise ValueError(f"faces must be a non-empty (m, 3) array of vertex indices >= 0, got shape {f.shape}")
    f = np.ascontiguousarray(f, dtype=np.int64)
    if like is not None:
        if not np.array_equal(f, like.faces):
            raise ValueError(f"faces differ from the input sequence's ({like.path})")
        if f.max() >= like.num_vertices:
            raise ValueError(f"faces refer to vertex {int(f.max())} but the sequence has {like.num_vertices}")
    if fmt == "npz" and path.suffix.lower() != ".npz":
        path = path.with_name(path.name + ".npz")
    if fmt == "usd" and path.suffix.lower() not in USD_SUFFIXES:
        raise MeshError(f"USD output {path} needs a .usd, .usda or .usdc suffix")
    if like is not None:
        _check_not_input(path, like)
    writer = _WRITERS[fmt](path, f, like)
    if frames is not None:
        writer.frames = [int(k) for k in frames]
    return writer
