"""Animation sequences: F frames of one triangle mesh (same faces, moving vertices), read one frame at a time.

:func:`open_sequence` accepts the forms DCC tools export (``idp repair`` writes the repaired sequence back in the
same form, see :mod:`idp.output.sequence`):

* a folder of per-frame OBJ files, or a glob pattern of them (``frames/*.obj``, ``shell*.obj``). Frames are ordered
  by the last integer in the file name (natural order: ``shell2.obj`` before ``shell10.obj``); files whose name holds
  no integer come after all numbered ones, by name; two files with the same number are an error (two sequences in
  one folder: select one with a glob). Vertex ``i`` of every file is row ``i`` (idp's OBJ reader keeps the file's
  vertex order and fan-triangulates polygons). A single ``.obj`` file is a one-frame sequence.
* a ``.pvd`` VTU time series: the VTUs' triangle cells, frames ordered by ``timestep`` (file order where a dataset
  has none).
* a ``.npz`` with ``vertices`` (F, n, 3) and 0-based ``faces`` (m, 3). It is read whole: sequences larger than
  memory belong in an OBJ or VTU folder, which is read one frame at a time.
* a USD file (``.usd``/``.usda``/``.usdc``, needs ``pip install 'idp[usd]'``): the first ``UsdGeom.Mesh`` with
  time-sampled ``points`` (or the prim ``usd_prim``); frames are its time samples, polygons are fan-triangulated.

Frame 0 and the topology are checked by :func:`open_sequence`; every other frame is checked when
:meth:`FrameSequence.frame` reads it (same vertex count and faces as frame 0, finite coordinates), and
:func:`check_all_frames` reads them all once up front. Errors are :class:`MeshError` naming the frame and file.
"""

from __future__ import annotations

import glob
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from idp.errors import MeshError
from idp.fs import is_dir, is_file, why
from idp.mesh.io import _read_meshio
from idp.mesh.obj import read_obj

FORMATS = ("obj", "pvd", "npz", "usd")
USD_SUFFIXES = (".usd", ".usda", ".usdc")
# cell blocks a VTU frame may carry besides its triangles (ignored); any other type is rejected
_VTU_IGNORED_CELLS = ("vertex", "line", "line3")
_GLOB_CHARS = re.compile(r"[*?\[]")
_LAST_INT = re.compile(r"(\d+)(?!.*\d)")


def import_pxr() -> Any:
    """The ``pxr`` package (usd-core), imported on first use; MeshError naming the extra when it is missing."""
    try:
        import pxr
        from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: F401  (submodules used through the package)
    except ImportError as exc:
        raise MeshError(f"USD files need usd-core: pip install 'idp[usd]' ({exc})") from None
    return pxr


class FrameSequence:
    """F frames of one triangle mesh; :meth:`frame` reads frame ``k`` (lazily for file-per-frame forms).

    ``faces`` (m, 3) int64 are frame 0's triangles; ``frame_labels[k]`` says where frame ``k`` comes from (used in
    messages); ``frame_files`` holds the per-frame file of OBJ/PVD sequences (else None); ``frame_times`` holds the
    PVD timesteps or USD time codes (else None).
    """

    format: str = ""

    def __init__(
        self,
        path: Path,
        faces: np.ndarray,
        num_vertices: int,
        frame_labels: list[str],
        *,
        frame_files: list[Path] | None = None,
        frame_times: list[float] | None = None,
    ) -> None:
        self.path = path
        self.faces = faces
        self.num_vertices = int(num_vertices)
        self.frame_labels = frame_labels
        self.frame_files = frame_files
        self.frame_times = frame_times

    @property
    def num_frames(self) -> int:
        return len(self.frame_labels)

    def __len__(self) -> int:
        return self.num_frames

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({str(self.path)!r}, {self.num_frames} frames, "
            f"{self.num_vertices} vertices, {self.faces.shape[0]} triangles)"
        )

    def describe(self, k: int) -> str:
        """``"frame 12 (path/shell12.obj)"``: how messages name frame ``k``."""
        return f"frame {k} ({self.frame_labels[k]})"

    def frame(self, k: int) -> np.ndarray:
        """Positions of frame ``k`` as (n, 3) float64, C-contiguous; MeshError when the frame is unusable."""
        k = int(k)
        if not 0 <= k < self.num_frames:
            raise IndexError(f"frame {k} out of range: {self.path} has {self.num_frames} frames")
        return self._check_positions(k, self._read_frame(k))

    # ------------------------------------------------------------------ per-format part
    def _read_frame(self, k: int) -> np.ndarray:
        """Frame ``k``'s raw positions; subclasses also check its topology against frame 0's."""
        raise NotImplementedError

    # ------------------------------------------------------------------ checks
    def _check_positions(self, k: int, points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise MeshError(f"{self.describe(k)}: expected (n, 3) vertex coordinates, got shape {pts.shape}")
        if pts.shape[0] != self.num_vertices:
            raise MeshError(f"{self.describe(k)}: {pts.shape[0]} vertices, frame 0 has {self.num_vertices}")
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
        if bad.size:
            raise MeshError(f"{self.describe(k)}: non-finite coordinate at vertex {int(bad[0])}")
        return pts

    def _check_same_faces(self, k: int, faces: np.ndarray) -> None:
        """MeshError unless frame ``k``'s triangles are frame 0's."""
        if faces.shape != self.faces.shape:
            raise MeshError(f"{self.describe(k)}: {faces.shape[0]} triangles, frame 0 has {self.faces.shape[0]}")
        diff = np.flatnonzero((faces != self.faces).any(axis=1))
        if diff.size:
            raise MeshError(
                f"{self.describe(k)}: face list differs from frame 0's (first at triangle {int(diff[0])}: "
                f"{faces[diff[0]].tolist()} vs {self.faces[diff[0]].tolist()})"
            )


def _check_faces(faces: np.ndarray, num_vertices: int, where: str) -> np.ndarray:
    """Frame-0 topology: (m, 3) integer, at least one triangle, indices in [0, n)."""
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"{where}: faces must be (m, 3) triangles, got shape {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise MeshError(f"{where}: faces must hold integer vertex indices, got dtype {f.dtype}")
    if f.shape[0] == 0:
        raise MeshError(f"{where}: no triangles")
    f = np.ascontiguousarray(f, dtype=np.int64)
    bad = np.flatnonzero(((f < 0) | (f >= num_vertices)).any(axis=1))
    if bad.size:
        i = int(bad[0])
        raise MeshError(
            f"{where}: {bad.size} triangles reference vertex indices outside [0, {num_vertices}) "
            f"(first: triangle {i} = {f[i].tolist()})"
        )
    return f


# ---------------------------------------------------------------------- OBJ folder / glob
def _natural_key(p: Path) -> tuple[int, int, str]:
    m = _LAST_INT.search(p.stem)
    return (0, int(m.group(1)), p.name) if m else (1, 0, p.name)


def _obj_files(p: Path, spec: str) -> list[Path]:
    """The OBJ files of a folder or glob pattern in frame order (see the module docstring)."""
    if is_dir(p):
        files = [q for q in p.iterdir() if q.is_file() and q.suffix.lower() == ".obj"]
        if not files:
            raise MeshError(f"sequence folder {p} holds no .obj files")
    else:
        matches = [Path(s) for s in glob.glob(spec)]
        files = [q for q in matches if q.is_file() and q.suffix.lower() == ".obj"]
        if not files:
            what = f"{len(matches)} paths, none an .obj file" if matches else "nothing"
            raise MeshError(f"sequence pattern {spec!r} matches {what}")
    files.sort(key=_natural_key)
    seen: dict[int, Path] = {}
    for q in files:
        key = _natural_key(q)
        if key[0] == 0:
            if key[1] in seen:
                raise MeshError(
                    f"{seen[key[1]]} and {q} both have frame number {key[1]}: two sequences in one folder? "
                    "select one with a glob pattern"
                )
            seen[key[1]] = q
    return files


class ObjSequence(FrameSequence):
    """One OBJ file per frame, read when the frame is asked for."""

    format = "obj"
    frame_files: list[Path]

    def __init__(self, path: Path, files: list[Path]) -> None:
        mesh = self._read(0, files[0])
        faces = _check_faces(mesh.faces, mesh.num_vertices, f"frame 0 ({files[0]})")
        super().__init__(path, faces, mesh.num_vertices, [str(f) for f in files], frame_files=files)
        self._check_positions(0, mesh.vertices)

    @staticmethod
    def _read(k: int, file: Path) -> Any:
        try:
            return read_obj(file)
        except MeshError as exc:  # read_obj's messages name the file (and line)
            raise MeshError(f"frame {k}: {exc}") from None

    def _read_frame(self, k: int) -> np.ndarray:
        mesh = self._read(k, self.frame_files[k])
        if mesh.num_vertices != self.num_vertices:
            raise MeshError(f"{self.describe(k)}: {mesh.num_vertices} vertices, frame 0 has {self.num_vertices}")
        self._check_same_faces(k, mesh.faces)
        return mesh.vertices


# ---------------------------------------------------------------------- PVD (VTU series)
def _pvd_entries(path: Path) -> list[tuple[Path, float | None]]:
    """(VTU file, timestep or None) of each dataset of a PVD, in frame order."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise MeshError(f"cannot read PVD file {path}: {exc}") from None
    entries: list[tuple[Path, float | None]] = []
    for i, ds in enumerate(root.iter("DataSet")):
        rel = ds.get("file")
        if not rel:
            raise MeshError(f"{path}: DataSet {i} has no file attribute")
        ts = ds.get("timestep")
        try:
            t = None if ts is None else float(ts)
        except ValueError:
            raise MeshError(f"{path}: DataSet {i} ({rel}) has a bad timestep {ts!r}") from None
        entries.append((path.parent / rel, t))
    if not entries:
        raise MeshError(f"{path}: the PVD lists no datasets")
    times = [t for _, t in entries]
    if all(t is not None for t in times):
        if len(set(times)) != len(times):
            dup = next(t for t in times if times.count(t) > 1)
            raise MeshError(f"{path}: several datasets at timestep {dup} (multi-part series are not supported)")
        entries.sort(key=lambda e: e[1] if e[1] is not None else 0.0)
    return entries


class PvdSequence(FrameSequence):
    """A PVD collection of VTU files, one per frame, read when the frame is asked for."""

    format = "pvd"
    frame_files: list[Path]

    def __init__(self, path: Path) -> None:
        entries = _pvd_entries(path)
        files = [f for f, _ in entries]
        times = [t for _, t in entries]
        labels = [str(f) if t is None else f"{f}, t={t!r}" for f, t in entries]
        self.timesteps: list[float | None] = times
        points, tris = self._read(0, files[0], labels[0])
        faces = _check_faces(tris, points.shape[0], f"frame 0 ({labels[0]})")
        frame_times = None if any(t is None for t in times) else [float(t) for t in times if t is not None]
        super().__init__(path, faces, points.shape[0], labels, frame_files=files, frame_times=frame_times)
        self._check_positions(0, points)

    @staticmethod
    def _read(k: int, file: Path, label: str) -> tuple[np.ndarray, np.ndarray]:
        if not is_file(file):
            raise MeshError(f"frame {k} ({label}): file not found{why(file)}")
        try:
            mesh = _read_meshio(file)
        except MeshError as exc:  # names the file
            raise MeshError(f"frame {k}: {exc}") from None
        other = sorted({c.type for c in mesh.cells} - {"triangle", *_VTU_IGNORED_CELLS})
        if other:
            raise MeshError(f"frame {k} ({label}): unsupported cell types {', '.join(other)} (triangles only)")
        blocks = [np.asarray(c.data, dtype=np.int64) for c in mesh.cells if c.type == "triangle"]
        tris = np.concatenate(blocks) if blocks else np.zeros((0, 3), np.int64)
        if tris.shape[0] == 0:
            raise MeshError(f"frame {k} ({label}): no triangles")
        return np.asarray(mesh.points), tris

    def _read_frame(self, k: int) -> np.ndarray:
        points, tris = self._read(k, self.frame_files[k], self.frame_labels[k])
        if points.ndim == 2 and points.shape[0] != self.num_vertices:
            raise MeshError(f"{self.describe(k)}: {points.shape[0]} vertices, frame 0 has {self.num_vertices}")
        self._check_same_faces(k, tris)
        return points


# ---------------------------------------------------------------------- npz
class NpzSequence(FrameSequence):
    """An ``.npz`` with ``vertices`` (F, n, 3) and ``faces`` (m, 3), held in memory whole."""

    format = "npz"

    def __init__(self, path: Path) -> None:
        try:
            # the file is opened here: np.load leaves its own handle open when the data is not an npz
            with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
                missing = [key for key in ("vertices", "faces") if key not in data.files]
                if missing:
                    raise MeshError(
                        f"{path}: missing key(s) {', '.join(missing)} (has: {', '.join(data.files) or 'none'}); "
                        "expected vertices (F, n, 3) and faces (m, 3)"
                    )
                vertices = data["vertices"]
                faces = data["faces"]
                for key, value in (("vertices", vertices), ("faces", faces)):
                    if not isinstance(value, np.ndarray):  # np.load gives a member without the .npy magic as bytes
                        raise MeshError(f"{path}: {key} is not a .npy array (the zip member holds other data)")
        except MeshError:
            raise
        except Exception as exc:  # zipfile, pickle and format errors
            raise MeshError(f"cannot read sequence file {path}: {type(exc).__name__}: {exc}") from None
        if vertices.ndim != 3 or vertices.shape[2] != 3 or vertices.shape[0] == 0 or vertices.shape[1] == 0:
            raise MeshError(f"{path}: vertices must be (F, n, 3) with F, n > 0, got shape {vertices.shape}")
        if not (np.issubdtype(vertices.dtype, np.floating) or np.issubdtype(vertices.dtype, np.integer)):
            raise MeshError(f"{path}: vertices must be real numbers, got dtype {vertices.dtype}")
        self._vertices = vertices
        n = int(vertices.shape[1])
        faces = _check_faces(faces, n, f"{path}: faces")
        labels = [f"{path}, vertices[{k}]" for k in range(vertices.shape[0])]
        super().__init__(path, faces, n, labels)
        self._check_positions(0, vertices[0])

    def _read_frame(self, k: int) -> np.ndarray:
        return np.ascontiguousarray(self._vertices[k], dtype=np.float64)  # the paper data is Fortran-ordered


# ---------------------------------------------------------------------- USD
def fan_triangulate(counts: np.ndarray, indices: np.ndarray, where: str) -> np.ndarray:
    """Triangles (i0, ij, ij+1) of polygons given as per-face vertex counts and concatenated indices."""
    counts = np.asarray(counts, dtype=np.int64).reshape(-1)
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    small = np.flatnonzero(counts < 3)
    if small.size:
        raise MeshError(f"{where}: face {int(small[0])} has {int(counts[small[0]])} vertices (needs at least 3)")
    if int(counts.sum()) != indices.size:
        raise MeshError(f"{where}: faceVertexCounts sum to {int(counts.sum())} but there are {indices.size} indices")
    ntri = counts - 2
    starts = np.repeat(np.cumsum(counts) - counts, ntri)
    j = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    return np.stack([indices[starts], indices[starts + j + 1], indices[starts + j + 2]], axis=1)


class UsdSequence(FrameSequence):
    """The time-sampled ``points`` of one ``UsdGeom.Mesh``; a frame per time sample, read when asked for.

    ``prim_path`` is the mesh, ``frame_times`` its time codes, ``time_codes_per_second`` the stage's rate,
    ``had_polygons`` whether the input had non-triangle faces (writing back only replaces points, so the
    polygons stay), ``points_dtype`` the stored precision (float32 for the schema's ``point3f[]``).
    """

    format = "usd"
    frame_times: list[float]

    def __init__(self, path: Path, usd_prim: str | None) -> None:
        pxr = import_pxr()
        Usd, UsdGeom = pxr.Usd, pxr.UsdGeom
        try:
            stage = Usd.Stage.Open(str(path))
        except Exception as exc:  # pxr.Tf.ErrorException
            raise MeshError(f"cannot read USD file {path}: {' '.join(str(exc).split())}") from None
        if stage is None:
            raise MeshError(f"cannot read USD file {path}")
        if usd_prim is not None:
            prim = stage.GetPrimAtPath(usd_prim)
            if not prim or not prim.IsValid():
                raise MeshError(f"{path}: no prim at {usd_prim}")
            if not prim.IsA(UsdGeom.Mesh):
                raise MeshError(f"{path}: prim {usd_prim} is a {prim.GetTypeName() or 'typeless prim'}, not a Mesh")
            if UsdGeom.Mesh(prim).GetPointsAttr().GetNumTimeSamples() == 0:
                raise MeshError(f"{path}: mesh {usd_prim} has no time-sampled points")
        else:
            meshes = [q for q in stage.Traverse() if q.IsA(UsdGeom.Mesh)]
            animated = [q for q in meshes if UsdGeom.Mesh(q).GetPointsAttr().GetNumTimeSamples() > 0]
            if not animated:
                detail = f"{len(meshes)} meshes, none" if meshes else "no Mesh prims, so none"
                raise MeshError(f"{path}: {detail} with time-sampled points")
            prim = animated[0]
        mesh = UsdGeom.Mesh(prim)
        self.stage = stage
        self.prim_path = str(prim.GetPath())
        self.time_codes_per_second = float(stage.GetTimeCodesPerSecond())
        self._points = mesh.GetPointsAttr()
        self._counts_attr = mesh.GetFaceVertexCountsAttr()
        self._indices_attr = mesh.GetFaceVertexIndicesAttr()
        times = [float(t) for t in self._points.GetTimeSamples()]
        labels = [f"{path}, {self.prim_path} t={t!r}" for t in times]
        where = f"frame 0 ({labels[0]})"
        counts, indices = self._topology(times[0])
        if counts.size == 0:
            raise MeshError(f"{where}: no faces (faceVertexCounts is empty)")
        self._counts0, self._indices0 = counts, indices
        self.had_polygons = bool((counts != 3).any())
        first = self._points.Get(Usd.TimeCode(times[0]))
        raw = np.asarray(first)
        self.points_dtype = raw.dtype
        faces = _check_faces(fan_triangulate(counts, indices, where), raw.shape[0], where)
        super().__init__(path, faces, raw.shape[0], labels, frame_times=times)
        self._check_positions(0, raw)

    def _topology(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        counts = self._counts_attr.Get(t)
        indices = self._indices_attr.Get(t)
        return (
            np.asarray(counts if counts is not None else [], dtype=np.int64),
            np.asarray(indices if indices is not None else [], dtype=np.int64),
        )

    def _read_frame(self, k: int) -> np.ndarray:
        t = self.frame_times[k]
        if self._counts_attr.GetNumTimeSamples() > 0 or self._indices_attr.GetNumTimeSamples() > 0:
            counts, indices = self._topology(t)
            if not (np.array_equal(counts, self._counts0) and np.array_equal(indices, self._indices0)):
                raise MeshError(f"{self.describe(k)}: face list differs from frame 0's (time-sampled topology)")
        value = self._points.Get(t)
        if value is None:
            raise MeshError(f"{self.describe(k)}: points have no value")
        return np.asarray(value)


# ---------------------------------------------------------------------- entry points
def open_sequence(path: str | os.PathLike, *, usd_prim: str | None = None) -> FrameSequence:
    """Open an animation sequence (OBJ folder or glob, ``.pvd``, ``.npz``, USD) and check frame 0.

    ``usd_prim`` picks the mesh of a USD file (default: the first Mesh with time-sampled points).
    """
    spec = os.fspath(path)
    p = Path(spec)
    if usd_prim is not None and p.suffix.lower() not in USD_SUFFIXES:
        raise MeshError(f"usd_prim is for USD files, not {p}")
    if is_dir(p):
        return ObjSequence(p, _obj_files(p, spec))
    if is_file(p):
        ext = p.suffix.lower()
        if ext == ".pvd":
            return PvdSequence(p)
        if ext == ".npz":
            return NpzSequence(p)
        if ext in USD_SUFFIXES:
            return UsdSequence(p, usd_prim)
        if ext == ".obj":
            return ObjSequence(p, [p])
        raise MeshError(
            f"{p}: not a sequence (expected a folder or glob of .obj files, a .pvd, a .npz or a .usd/.usda/.usdc)"
        )
    if _GLOB_CHARS.search(spec):
        return ObjSequence(p, _obj_files(p, spec))
    raise MeshError(f"sequence not found: {p}{why(p)}")


def check_all_frames(seq: FrameSequence) -> None:
    """Read every frame once, raising the first frame's MeshError (run before a repair writes anything)."""
    for k in range(seq.num_frames):
        seq.frame(k)
