"""A small Wavefront OBJ reader (vertices and faces only).

meshio refuses OBJ files whose ``vt``/``vn`` counts differ from the ``v`` count, which is
common for textured models, so idp reads OBJ itself: ``v`` and ``f`` lines are used,
everything else (``vt``, ``vn``, ``g``, ``o``, ``s``, ``usemtl``, ``mtllib``, comments) is
ignored. Polygons are fan-triangulated.
"""

from __future__ import annotations

import codecs
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from idp.errors import MeshError
from idp.fs import is_file, why
from idp.mesh.types import SurfaceMesh

# an OBJ index beyond int64 can never be in range (and numpy could not store it): refused where it is read
_MAX_INDEX = int(np.iinfo(np.int64).max)
# No OBJ line may be longer (a vertex line is ~40 characters, a 10^4-corner polygon ~10^5). Files are read in
# _CHUNK pieces (read_lines) and a longer line is refused as soon as MAX_LINE + _CHUNK of it has been read, so
# reading holds O(MAX_LINE) of text whatever the file's size: a single 2 GB line costs about 1 MB, never the line,
# a copy of it or a list of millions of tokens.
MAX_LINE = 2**20
_CHUNK = 2**16


def _fail(path: Path, lineno: int, msg: str) -> MeshError:
    return MeshError(f"{path}:{lineno}: {msg}")


def _too_long(path: Path, lineno: int, length: int, unit: str) -> MeshError:
    return _fail(path, lineno, f"line of {length}+ {unit}, longer than the {MAX_LINE} an OBJ line may have")


def read_lines(path: Path, *, text: bool) -> Iterator[tuple[int, Any]]:
    """``(line number, line)`` of an OBJ file, exactly as ``str.splitlines()`` of its UTF-8 text (``text``; bad
    bytes replaced) or ``bytes.splitlines()`` of its bytes would give them, read _CHUNK bytes at a time.

    A line longer than MAX_LINE is a MeshError naming it; an unreadable file a MeshError naming the file."""
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace") if text else None
    carry: Any = "" if text else b""
    lineno = 0
    unit = "characters" if text else "bytes"
    try:
        with open(path, "rb") as fh:
            while True:
                raw = fh.read(_CHUNK)
                buf = carry + (decoder.decode(raw, final=not raw) if decoder else raw)
                carry = buf[:0]
                if raw:  # the last line may continue in the next chunk: no line break yet, or a "\r" before a "\n"
                    tail = buf.splitlines(keepends=True)[-1:] or [buf[:0]]
                    last = tail[0]
                    if last and (len(last.splitlines()[0]) == len(last) or last[-1:] in ("\r", b"\r")):
                        carry, buf = last, buf[: len(buf) - len(last)]
                lines = buf.splitlines()
                if lines and max(map(len, lines)) > MAX_LINE:
                    k = next(i for i, line in enumerate(lines) if len(line) > MAX_LINE)
                    raise _too_long(path, lineno + k + 1, len(lines[k]), unit)
                for line in lines:
                    lineno += 1
                    yield lineno, line
                if len(carry) > MAX_LINE:
                    raise _too_long(path, lineno + 1, len(carry), unit)
                if not raw:
                    return
    except OSError as exc:
        raise MeshError(f"cannot read mesh file {path}: {exc}") from None


def read_obj(path: str | os.PathLike) -> SurfaceMesh:
    """Read the triangle surface of an OBJ file; errors name the file and line number."""
    p = Path(path)
    if not is_file(p):
        raise MeshError(f"mesh file not found: {p}{why(p)}")

    coords: list[float] = []
    tri_a: list[int] = []
    tri_b: list[int] = []
    tri_c: list[int] = []
    tri_line: list[int] = []
    num_polygons = 0
    nv = 0
    for lineno, line in read_lines(p, text=True):
        if not line or line[0] not in "vf":
            continue
        parts = line.split()
        if not parts:
            continue
        tag = parts[0]
        if tag == "v":
            if len(parts) < 4:
                raise _fail(p, lineno, f"vertex needs 3 coordinates: {line.strip()!r}")
            try:
                coords.extend((float(parts[1]), float(parts[2]), float(parts[3])))
            except ValueError:
                raise _fail(p, lineno, f"bad number in vertex line: {line.strip()!r}") from None
            nv += 1
        elif tag == "f":
            idx: list[int] = []
            for tok in parts[1:]:
                head = tok.split("/", 1)[0]
                try:
                    k = int(head)
                except ValueError:
                    raise _fail(p, lineno, f"bad vertex index {tok!r} in face") from None
                if k > _MAX_INDEX:
                    raise _fail(p, lineno, f"face index {k} out of range")
                if k > 0:
                    idx.append(k - 1)
                elif k < 0:
                    if nv + k < 0:
                        raise _fail(
                            p, lineno, f"relative index {k} refers before the first vertex ({nv} vertices read so far)"
                        )
                    idx.append(nv + k)
                else:
                    raise _fail(p, lineno, "vertex index 0 is invalid (OBJ indices start at 1)")
            if len(idx) < 3:
                raise _fail(p, lineno, f"face with {len(idx)} vertices (needs at least 3)")
            num_polygons += 1
            first = idx[0]
            for j in range(1, len(idx) - 1):
                tri_a.append(first)
                tri_b.append(idx[j])
                tri_c.append(idx[j + 1])
                tri_line.append(lineno)

    if not tri_a:
        raise MeshError(f"{p}: no faces found in OBJ file")
    vertices = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    faces = np.stack(
        [np.asarray(tri_a, np.int64), np.asarray(tri_b, np.int64), np.asarray(tri_c, np.int64)],
        axis=1,
    )
    bad = np.flatnonzero((faces >= nv).any(axis=1))
    if bad.size:
        i = int(bad[0])
        raise _fail(
            p,
            tri_line[i],
            f"face index {int(faces[i].max()) + 1} out of range (file has {nv} vertices)",
        )
    return SurfaceMesh(
        vertices=vertices,
        faces=faces,
        source=str(p),
        extra={"num_polygons": num_polygons},
    )
