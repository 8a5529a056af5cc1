"""Shared pieces of the fuzz suite (tests/fuzz): hostile tokens, byte/line mutations, validity checks.

Every fuzz test states one property: a reader, the scene loader or the CLI given random or mutated input
either accepts it and returns something valid, or refuses it with an :class:`idp.errors.IdpError` (exit code 2
from the CLI). Anything else (another exception, a hang, a non-finite coordinate or an out-of-range index
in an accepted mesh) fails the test; hypothesis prints the smallest input it found and the seed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from idp.mesh.types import SurfaceMesh, VolumeMesh


# deadline=None: the machine is shared with long benchmark runs, so per-example wall times are noisy; hangs
# and slow refusals are bounded by the subprocess timeouts of test_fuzz_sizes.py instead.
def fuzz(max_examples: int) -> settings:
    """Hypothesis settings of a fuzz test: ``max_examples`` inputs (sized so the whole suite stays near a
    minute on one core), times ``$IDP_FUZZ_SCALE`` (default 1; e.g. 20 for a longer hunt), no per-example
    deadline.

    ``make test`` (and CI) draws the same inputs on every run (hypothesis's derandomized mode), so a clean
    clone passes or fails the same way each time; ``$IDP_FUZZ_RANDOM=1`` (``make fuzz``) draws new ones on
    every run to hunt for bugs, and what it finds is pinned as an explicit regression test."""
    scale = float(os.environ.get("IDP_FUZZ_SCALE", "1"))
    return settings(
        max_examples=max(1, round(max_examples * scale)),
        derandomize=os.environ.get("IDP_FUZZ_RANDOM", "0") != "1",
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    )


# Numbers and indices a careless reader mistakes for valid ones (or crashes on).
HOSTILE_NUMBERS = [
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "Infinity",
    "1e999",
    "-1e999",
    "1e-999",
    "1e308",
    "-1e308",
    "9" * 30,
    "-" + "9" * 30,
    "9" * 5000,
    "0",
    "-0",
    "-1",
    "-7",
    "2147483648",
    "4294967296",
    "9223372036854775808",
    "18446744073709551616",
    "0x10",
    "1_000",
    "\u0663",  # ARABIC-INDIC DIGIT THREE: Python's float() reads it, an OBJ file should not
    "1e5.5",
    "1..2",
    "+",
    "-",
    ".",
    "e",
    "abc",
    "",
    "1/2/3",
    "//",
    "1//",
    "/1",
    "\x00",
    "\xff",
    "\u202e",
]


def hostile_token() -> st.SearchStrategy[str]:
    """A token from HOSTILE_NUMBERS or a random integer (huge, negative or zero) or float."""
    return st.one_of(
        st.sampled_from(HOSTILE_NUMBERS),
        st.integers(min_value=-(10**25), max_value=10**25).map(str),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.text(max_size=6),
    )


@st.composite
def mutated_bytes(draw: st.DrawFn, base: bytes, *, max_ops: int = 3) -> bytes:
    """``base`` with 1..max_ops random mutations: lines dropped, duplicated, swapped or replaced by hostile lines,
    whitespace-separated tokens replaced by hostile tokens, bytes inserted / flipped, the file truncated,
    emptied or replaced by random bytes."""
    data = base
    for _ in range(draw(st.integers(min_value=1, max_value=max_ops))):
        lines = data.split(b"\n")
        op = draw(
            st.sampled_from(
                ["drop", "dup", "swap", "token", "token", "token", "truncate", "insert", "flip", "line", "garbage"]
            )
        )
        if op == "drop" and len(lines) > 1:
            del lines[draw(st.integers(0, len(lines) - 1))]
            data = b"\n".join(lines)
        elif op == "dup":
            i = draw(st.integers(0, len(lines) - 1))
            lines.insert(i, lines[i])
            data = b"\n".join(lines)
        elif op == "swap" and len(lines) > 1:
            i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            data = b"\n".join(lines)
        elif op == "token":
            i = draw(st.integers(0, len(lines) - 1))
            parts = lines[i].split(b" ")
            k = draw(st.integers(0, len(parts) - 1))
            parts[k] = draw(hostile_token()).encode("utf-8", errors="surrogatepass")
            lines[i] = b" ".join(parts)
            data = b"\n".join(lines)
        elif op == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif op == "insert":
            at = draw(st.integers(0, len(data)))
            data = data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
        elif op == "flip" and data:
            buf = bytearray(data)
            for _ in range(draw(st.integers(1, 8))):
                buf[draw(st.integers(0, len(buf) - 1))] = draw(st.integers(0, 255))
            data = bytes(buf)
        elif op == "line":
            i = draw(st.integers(0, len(lines)))
            tag = draw(st.sampled_from(["v", "vt", "vn", "f", "l", "o", "#", "POINTS", "CELLS", "$Nodes", ""]))
            toks = draw(st.lists(hostile_token(), max_size=5))
            lines.insert(i, " ".join([tag, *toks]).encode("utf-8", errors="surrogatepass"))
            data = b"\n".join(lines)
        elif op == "garbage":
            data = draw(st.sampled_from([b"", b"\x00" * 64, b"\xff\xfe", b"\xef\xbb\xbf"])) + draw(
                st.binary(max_size=256)
            )
    return data


def assert_valid_mesh(mesh: VolumeMesh | SurfaceMesh) -> None:
    """What every accepted mesh must be: finite float64 coordinates, integer cells, indices in range."""
    v = mesh.vertices
    cells = mesh.elements if isinstance(mesh, VolumeMesh) else mesh.faces
    assert isinstance(v, np.ndarray) and v.dtype == np.float64 and v.ndim == 2 and v.shape[1] in (2, 3), v.shape
    assert v.shape[0] > 0
    assert np.isfinite(v).all(), "accepted a mesh with non-finite coordinates"
    assert isinstance(cells, np.ndarray) and cells.ndim == 2 and np.issubdtype(cells.dtype, np.integer)
    assert cells.shape[0] > 0
    expected = {VolumeMesh: (3, 4), SurfaceMesh: (2, 3)}[type(mesh)]
    assert cells.shape[1] in expected, cells.shape
    assert cells.min() >= 0 and cells.max() < v.shape[0], "accepted a mesh with out-of-range indices"


def tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` with its size and modification time (to prove that nothing was written)."""
    out: dict[str, tuple[int, int]] = {}
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            p = Path(dirpath) / name
            st_ = p.stat()
            out[str(p)] = (st_.st_size, st_.st_mtime_ns)
    return out
