"""CHOLMOD's dense kernels on scipy's multi-threaded OpenBLAS instead of cvxopt's single-threaded copy.

cvxopt's wheel bundles OpenBLAS 0.3.15 built ``SINGLE_THREADED``, and CHOLMOD's supernodal factorisation and
solves spend their time in its ``dgemm``/``dsyrk``/``dtrsm``/``dpotrf``: they run on one core whatever the thread
settings say. scipy's wheel bundles a pthreads OpenBLAS (0.3.30 here) whose symbols carry a ``scipy_`` prefix, so
the dynamic linker cannot bind CHOLMOD's ``dgemm_`` to it. :func:`route_cholmod_blas` writes the addresses of
scipy's routines into the six entries of CHOLMOD's global offset table that hold those BLAS/LAPACK routines (the
table CHOLMOD's calls jump through), after checking that each entry holds exactly the routine of cvxopt's copy
the dynamic linker chose; a small supernodal factorisation must then solve its system to round-off, or the
entries are put back. Anything unexpected (another platform, another wheel layout, a symbol missing) leaves
CHOLMOD as it was, with the reason in :data:`STATUS`.

Measured on the 2-core AMD EPYC VM (bench child ``bunnyx30_13K``, 57K unknowns, the same day): with a threaded
OpenBLAS behind CHOLMOD the run took 225 s instead of 250 s, the numeric factorisations 116.5 instead of 137.3 s.
While idp steps, :func:`idp._blas_threads.quiet_blas` keeps scipy's pool at one thread (spinning workers would
take the cores numba's and ipctk's regions need); :func:`cholmod_threads` widens it for each CHOLMOD call only.

Set ``IDP_CHOLMOD_BLAS=bundled`` to keep cvxopt's own copy.
"""

from __future__ import annotations

import ctypes
import glob
import os
import platform
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

#: The real routines CHOLMOD's supernodal numeric factorisation and solves call.
ROUTINES = ("dgemm_", "dgemv_", "dpotrf_", "dsyrk_", "dtrsm_", "dtrsv_")

#: Why routing is on or off (set by :func:`route_cholmod_blas`).
STATUS = "not tried"

_R_X86_64_GLOB_DAT, _R_X86_64_JUMP_SLOT = 6, 7
_PROT_READ, _PROT_WRITE = 1, 2

_set_threads = None  # scipy's openblas_set_num_threads, once routed
_get_threads = None  # and its openblas_get_num_threads
_threads = 1  # the pool size for CHOLMOD's calls


class _DlPhdrInfo(ctypes.Structure):
    _fields_ = [("addr", ctypes.c_void_p), ("name", ctypes.c_char_p)]


def _load_bias(fragment: str) -> tuple[str, int] | None:
    """(path, load bias) of the loaded shared object whose path contains ``fragment`` (dl_iterate_phdr)."""
    found: list[tuple[str, int]] = []
    callback_type = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(_DlPhdrInfo), ctypes.c_size_t, ctypes.c_void_p)

    def visit(info, _size, _data):
        name = (info.contents.name or b"").decode(errors="replace")
        if fragment in name:
            found.append((name, info.contents.addr or 0))
        return 0

    ctypes.CDLL(None).dl_iterate_phdr(callback_type(visit), None)
    return found[0] if len(found) == 1 else None


def _got_slots(path: str, names: tuple[str, ...]) -> dict[str, list[int]]:
    """Offsets (from the load bias) of the GLOB_DAT / JUMP_SLOT relocations for ``names`` in an ELF64 x86-64 file."""
    data = Path(path).read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1 or struct.unpack_from("<H", data, 18)[0] != 62:
        raise ValueError("not a little-endian ELF64 x86-64 object")
    (shoff,) = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]
    wanted: dict[str, list[int]] = {n: [] for n in names}
    for sh_type, _flags, _addr, offset, size, link, entsize in (
        (s[1], s[2], s[3], s[4], s[5], s[6], s[9]) for s in sections
    ):
        if sh_type != 4 or entsize != 24:  # SHT_RELA
            continue
        symtab = sections[link]
        strtab = sections[symtab[6]]
        for k in range(size // 24):
            r_offset, r_info, _addend = struct.unpack_from("<QQq", data, offset + 24 * k)
            if (r_info & 0xFFFFFFFF) not in (_R_X86_64_GLOB_DAT, _R_X86_64_JUMP_SLOT):
                continue
            (st_name,) = struct.unpack_from("<I", data, symtab[4] + (r_info >> 32) * symtab[9])
            start = strtab[4] + st_name
            name = data[start : data.index(b"\0", start)].decode()
            if name in wanted:
                wanted[name].append(r_offset)
    return wanted


def _address(lib: ctypes.CDLL, name: str) -> int:
    return ctypes.cast(getattr(lib, name), ctypes.c_void_p).value or 0


def _protection(address: int) -> int:
    """The current mprotect flags (read / write / exec) of the mapping holding ``address`` (/proc/self/maps)."""
    with open("/proc/self/maps") as maps:
        for line in maps:
            span, perms = line.split()[:2]
            lo, hi = (int(v, 16) for v in span.split("-"))
            if lo <= address < hi:
                return (perms[0] == "r") * _PROT_READ | (perms[1] == "w") * _PROT_WRITE | (perms[2] == "x") * 4
    raise OSError(f"address {address:#x} is not mapped")


def _write_pointers(slots: list[tuple[int, int]]) -> None:
    """Write (address, value) pointer pairs, making their pages writable for the writes (the table is read-only
    after loading: RELRO) and giving each page its protection back after."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    page = os.sysconf("SC_PAGE_SIZE")
    pages = {p: _protection(p) for p in sorted({addr - addr % page for addr, _ in slots})}
    opened: list[int] = []
    try:
        for p, prot in pages.items():
            if libc.mprotect(p, page, prot | _PROT_READ | _PROT_WRITE) != 0:
                raise OSError(ctypes.get_errno(), "mprotect failed")
            opened.append(p)
        for addr, value in slots:
            ctypes.c_void_p.from_address(addr).value = value
    finally:
        for p in opened:
            libc.mprotect(p, page, pages[p])


def _check_factorisation() -> bool:
    """A supernodal CHOLMOD factorisation with updates between supernodes (so it calls dsyrk, dgemm, dtrsm and
    dpotrf; the solve dtrsv / dgemv) solves a well-conditioned system to round-off."""
    import cvxopt
    from cvxopt import cholmod

    from idp.solver.cholmod_cvxopt import _options  # (that module imports this one: imported here, at call time)

    m = 20  # a 2D grid Laplacian, shifted: 400 unknowns, AMD's separators give supernodes that update each other
    T = 2.0 * np.eye(m) - np.eye(m, k=1) - np.eye(m, k=-1)
    A = np.kron(T, np.eye(m)) + np.kron(np.eye(m), T) + 0.5 * np.eye(m * m)
    rows, cols = np.nonzero(np.tril(A))
    n = m * m
    S = cvxopt.spmatrix(
        A[rows, cols], cvxopt.matrix(rows.astype(np.int64)), cvxopt.matrix(cols.astype(np.int64)), (n, n)
    )
    b = np.random.default_rng(0).standard_normal(n)
    with _options(supernodal=2):
        F = cholmod.symbolic(S, uplo="L")
        cholmod.numeric(S, F)
        x = cvxopt.matrix(b.copy())
        cholmod.solve(F, x)
    # A's condition number is below 17 (eigenvalues in [0.5, 8.5]): a small residual means the right solution
    residual = A @ np.array(x).ravel() - b
    return bool(np.linalg.norm(residual) <= 1e-12 * np.linalg.norm(b))


def scipy_openblas_path() -> str | None:
    """The OpenBLAS shipped in scipy's wheel (its symbols carry a ``scipy_`` prefix); None when not exactly one."""
    import scipy

    libs = glob.glob(str(Path(scipy.__file__).parent.parent / "scipy.libs" / "libscipy_openblas*.so"))
    return libs[0] if len(libs) == 1 else None


def route_cholmod_blas(threads: int) -> bool:
    """Route CHOLMOD's BLAS to scipy's threaded OpenBLAS (once per process); ``threads``: the pool size for CHOLMOD's
    calls. Returns whether CHOLMOD now uses it; :data:`STATUS` says why not."""
    global STATUS, _set_threads, _get_threads, _threads
    _threads = max(1, int(threads))
    if _set_threads is not None:
        return True
    if os.environ.get("IDP_CHOLMOD_BLAS", "").lower() in ("bundled", "cvxopt", "0", "off"):
        STATUS = "off (IDP_CHOLMOD_BLAS)"
        return False
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        STATUS = f"unsupported platform {platform.system()} {platform.machine()}"
        return False
    try:
        import cvxopt.cholmod  # noqa: F401  (loads libcholmod and cvxopt's OpenBLAS)

        cholmod_lib = _load_bias("libcholmod")
        ours = _load_bias("cvxopt.libs/libopenblas")
        scipy_lib = scipy_openblas_path()
        if cholmod_lib is None or ours is None or scipy_lib is None:
            STATUS = "cvxopt's CHOLMOD / OpenBLAS or scipy's OpenBLAS not found as expected"
            return False
        scipy_blas = ctypes.CDLL(scipy_lib)
        bundled = ctypes.CDLL(ours[0])
        path, bias = cholmod_lib
        offsets = _got_slots(path, ROUTINES)
        plan: list[tuple[int, int]] = []
        undo: list[tuple[int, int]] = []
        for name in ROUTINES:
            old, new = _address(bundled, name), _address(scipy_blas, "scipy_" + name)
            if not offsets[name] or not old or not new:
                STATUS = f"{name}: no table entry or routine"
                return False
            for off in offsets[name]:
                current = ctypes.c_void_p.from_address(bias + off).value
                if current != old:
                    STATUS = f"{name}: CHOLMOD's table entry does not hold cvxopt's routine"
                    return False
                plan.append((bias + off, new))
                undo.append((bias + off, old))
        _write_pointers(plan)
        set_threads = scipy_blas.scipy_openblas_set_num_threads
        set_threads.argtypes = [ctypes.c_int]
        get_threads = scipy_blas.scipy_openblas_get_num_threads
        get_threads.restype = ctypes.c_int
        before = get_threads()
        set_threads(_threads)  # the check runs the pool as CHOLMOD's threaded calls will
        try:
            ok = _check_factorisation()
        finally:
            set_threads(before)  # scipy's pool as the process had it
        if not ok:
            _write_pointers(undo)
            STATUS = "check factorisation disagreed: routing undone"
            return False
        _set_threads, _get_threads = set_threads, get_threads
    except (OSError, ValueError, AttributeError, IndexError, struct.error) as exc:
        STATUS = f"not routed: {exc}"
        return False
    get_config = scipy_blas.scipy_openblas_get_config
    get_config.restype = ctypes.c_char_p
    STATUS = f"scipy's OpenBLAS ({get_config().decode()}), {_threads} thread(s)"
    return True


#: The smallest largest-update block (entries; 1000 rows below a supernode) for which CHOLMOD's calls run threaded.
THREADED_MIN_UPDATE = 1_000_000


def worth_threads(max_update: int) -> bool:
    """Whether a factor whose largest supernodal update block has ``max_update`` entries gains from the threaded pool.

    Measured per numeric factorisation (routed, 1 against 2 threads, medians of 7, the same matrices): bunnyx30_13K
    (max_update 1.55 M) 0.329 → 0.250 s; bunny_3376 (0.37–0.48 M) 42 → 41 ms, within the noise; the Fig. 12 cat
    (0.07–0.14 M) 16.8 → 17.0 ms; and whole bunny_700 runs (small blocks) 5–10 % slower numeric time threaded."""
    return max_update >= THREADED_MIN_UPDATE


@contextmanager
def cholmod_threads(enabled: bool = True) -> Iterator[None]:
    """Within the block CHOLMOD's routed BLAS runs the routed thread count (scipy's pool size is restored after it);
    nothing when not routed or not ``enabled``."""
    if not enabled or _set_threads is None or _get_threads is None:
        yield
        return
    before = _get_threads()
    if before == _threads:
        yield
        return
    _set_threads(_threads)
    try:
        yield
    finally:
        _set_threads(before)
