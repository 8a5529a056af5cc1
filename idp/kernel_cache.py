"""The numba kernels a scene needs, compiled before it runs: in parallel, and said out loud.

Every kernel is ``@njit(cache=True)``: the first run on a machine compiles it (seconds each, about a minute for a
contact scene on 2 cores) and writes numba's disk cache; later runs load it in milliseconds. Two things here make
that first run shorter and never silent:

- :func:`prepare` (called by :func:`idp.scene.build.build_scene`) looks up the entry kernels a scene will call
  (:func:`scene_kernels`, exact argument types) in numba's cache index and compiles the missing ones up front,
  shared with one helper process (``python -m idp._compile_helper``) when the machine has a second core: both take
  the largest kernel not yet taken, so the wall time is about half the compile work. A warm cache costs one index
  read per kernel and starts nothing.
- :func:`announcing` (the CLI turns it on unless ``--quiet``; :func:`idp.api.simulate` with ``progress``) shows
  that up-front compilation as a progress bar on stderr, "compiling kernels (first run only) k/N", and reports any
  other kernel that has to be compiled on the way (a code path the list does not cover) as a line on stderr.
  A warm cache prints nothing.

The list is checked against what the demo, a 2D scene, a shell scene and a flow actually call
(``tests/test_kernel_cache.py``); a kernel missing from it is still compiled when first called, as before, and
announced.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger("idp")


@dataclass(frozen=True)
class Kernel:
    """One entry point (a kernel called from Python) and the argument types its caller passes."""

    module: str
    name: str
    signature: str  # numba type names, e.g. "(float64[:, ::1], int64)"
    cost: float  # compile seconds measured on the reference machine (2-core AMD EPYC VM): the order of the work
    # chosen at run time between this entry and another one (thread count, sizes): a run may call either; or called
    # only on a path that some runs of the scene never take (so a run may call neither)
    alternative: bool = False

    @property
    def label(self) -> str:
        return f"{self.module.rsplit('.', 1)[-1]}.{self.name}"


_E = "idp.energies._elastic_kernels"
_CB = "idp.contact.compiled_barrier"
_LP = "idp.solver.triangle_pattern"
_IX = "idp.contact.intersections"

#: the elastic values copied onto the contact pattern once it has grown beyond the elastic one (a run whose contacts
#: never need a coupling the elastic pattern lacks does not call it)
_EMBED = Kernel(
    "idp.solver.contact_pattern",
    "_embed_blocks",
    "(float64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64, float64[::1])",
    0.2,
    alternative=True,
)

#: Entry kernels by feature; the signatures are the ones the Python wrappers pass (contiguous arrays of the
#: dtypes they convert to), so a compiled entry here is the one the run then loads.
GROUPS: dict[str, tuple[Kernel, ...]] = {
    # every run: the Newton matrix (assembly), the fill estimate of its factor (symbolic), the input's surface checks
    "solver": (
        Kernel("idp.solver.assembly", "_scatter_add", "(float64[::1], int64[::1], float64[::1], float64)", 0.05),
        Kernel("idp.solver.symbolic", "_etree", "(int32[::1], int32[::1], int64[::1], int64[::1], int64)", 0.3),
        Kernel("idp.solver.symbolic", "_postorder", "(int64[::1], int64)", 0.3),
        Kernel(
            "idp.solver.symbolic",
            "_colcounts",
            "(int32[::1], int32[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64)",
            0.8,
        ),
        Kernel("idp.solver.symbolic", "_supernodes", "(int64[::1], int64[::1], int64[::1], int64)", 0.2),
        # the input's surface checks (components of boundary loops, face fans, surface parts)
        Kernel("idp.mesh.components", "_component_labels", "(int64, int64[::1], int64[::1], int64[::1])", 0.3),
    ),
    # the CHOLMOD backend's pattern changes (idp.solver.triangle_pattern): every run factors a first pattern; the merge
    # with the analysed pattern from the second on, the ordering's graphs with METIS, the memory count's pattern
    "cholmod": (
        Kernel(_LP, "upper_columns", "(int64[::1], Array(int32, 1, 'C', readonly=True))", 0.2),
        Kernel(
            _LP,
            "locate_entries",
            "(int64[::1], int32[::1], int64[::1], int32[::1], boolean[::1])",
            0.2,
            alternative=True,
        ),
        Kernel(_LP, "union_columns", "(int64[::1], int32[::1], int64[::1], int32[::1], int64)", 0.4, alternative=True),
        Kernel(_LP, "_symmetric_from_triangle", "(int64[::1], int32[::1])", 0.3, alternative=True),
        Kernel(_LP, "vertex_graph_from_triangle", "(int64[::1], int32[::1], int64)", 0.3, alternative=True),
    ),
    # deformable solids (tetrahedra in 3D, triangles in 2D): elasticity and the inversion filter
    "solid": (
        Kernel(  # element energies, gradients, Hessians; or (fused assembly) added per vertex-row part into the matrix
            _E,
            "_element_pass",
            "(int64, int64, float64[:, ::1], int64[:, ::1], float64[:, :, ::1], float64[::1], int64, float64[::1],"
            " float64[::1],"
            " boolean, boolean, boolean, float64, float64[::1], float64[:, ::1], float64[:, :, ::1], int64[::1],"
            " int64[::1], int64[::1], int32[:, :, ::1], int32[:, :, ::1], float64, float64[::1], float64[::1])",
            17.0,
        ),
        Kernel(
            "idp.energies.inversion_filter",
            "_filter_kernel",
            "(int64, int64, float64[:, ::1], float64[:, ::1], int64[:, ::1], float64, float64[::1], float64[::1])",
            1.3,
        ),
    ),
    # shells with an elastic material: membrane and bending
    "shell": (
        Kernel(
            "idp.energies._membrane_kernels",
            "_membrane_chunk",
            "(int64, int64, float64[:, ::1], int64[:, ::1], float64[:, :, ::1], float64[:, :, ::1], float64[::1],"
            " float64[::1], float64[::1], boolean, boolean, boolean, float64[::1], float64[:, ::1],"
            " float64[:, :, ::1])",
            8.0,
        ),
        Kernel(
            "idp.energies._bending_kernels",
            "_bending_chunk",
            "(int64, int64, float64[:, ::1], int64[:, ::1], float64[::1], float64[::1], boolean, boolean, boolean,"
            " boolean, float64[::1], float64[:, ::1], float64[:, :, ::1])",
            8.0,
        ),
        Kernel("idp.energies._bending_kernels", "hinge_angles", "(float64[:, ::1], int64[:, ::1], float64[::1])", 0.5),
        Kernel(  # membrane and bending blocks into the Newton matrix
            "idp.solver.assembly",
            "_scatter_vertex_blocks",
            "(float64[::1], int32[:, :, ::1], int32[:, :, ::1], float64[:, :, ::1], float64, int64[::1])",
            0.7,
        ),
    ),
    # 3D contact with the compiled barrier (the default): broad phase, collision set, barrier derivatives
    "contact3d": (
        Kernel(
            "idp.contact._broad_phase",
            "_run",
            "(float64[:, ::1], float64[:, ::1], boolean, int32[:, ::1], int32[:, ::1], int64, uint8[::1], float64,"
            " int64, float64, int64, int64, int64, float64, float64, float64)",
            8.8,
        ),
        Kernel(
            _CB,
            "_classify_range",
            "(int64, int64, float64[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1],"
            " float64[::1], int64[::1],"
            " float64[::1], float64[::1])",
            6.7,
        ),
        Kernel(
            _CB,
            "_compact",
            "(int32[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1], int64[::1], float64[::1], float64[::1],"
            " float64, int64)",
            2.8,
        ),
        Kernel(
            _CB,
            "_values_chunk",
            "(int64, int64, float64[:, ::1], int32[:, ::1], int8[::1], int8[:, ::1], float64[::1], float64[::1],"
            " float64,"
            " float64[::1])",
            3.1,
        ),
        Kernel(
            _CB,
            "_gradients_chunk",
            "(int64, int64, float64[:, ::1], int32[:, ::1], int8[::1], int8[:, ::1], float64[::1], float64[::1],"
            " float64,"
            " float64[:, ::1])",
            3.0,
        ),
        Kernel(
            _CB,
            "_hessian_chunk",
            "(int64, int64, float64[:, ::1], int32[:, ::1], int8[::1], int8[:, ::1], float64[::1], float64[::1],"
            " float64, float64,"
            " int64[::1], boolean, int32[:, ::1], float64[:, :, ::1])",
            13.1,
        ),
        Kernel(_CB, "_accumulate_gradient", "(int32[:, ::1], float64[:, ::1], float64[::1])", 0.1),
        _EMBED,
        Kernel(
            "idp.solver.contact_pattern",
            "_scatter_blocks",
            "(int32[:, ::1], float64[:, :, ::1], int64[::1], int64[::1], int64[::1], int64, int64, float64[::1],"
            " int64[:, ::1])",
            0.3,
            alternative=True,  # one thread (or one free vertex)
        ),
        Kernel(  # the same on both threads, each adding its own rows
            "idp.solver.contact_pattern",
            "_scatter_blocks_parts",
            "(int32[:, ::1], float64[:, :, ::1], int64[::1], int64[::1], int64[::1], int64, int64, float64[::1],"
            " int64[::1], int64[:, :, ::1], int64[::1])",
            0.5,
            alternative=True,  # two threads or more
        ),
    ),
    # ... and with it the CCD filter in front of Tight Inclusion (idp.contact.ccd_filter)
    "ccd3d": (
        Kernel(
            "idp.contact.ccd_filter",
            "_bounds",
            "(float64[:, ::1], float64[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1], float64,"
            " float64, int64, float64, float64[::1], float64[::1], float64[::1], float64[::1])",
            4.0,
        ),
        Kernel(
            "idp.contact.ccd_filter",
            "_refine",
            "(int64[::1], float64[:, ::1], float64[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1], int32[:, ::1],"
            " float64, int64, float64, float64[::1], float64[::1], float64[::1])",
            4.0,
        ),
        Kernel(  # conservative advancement: pairs far closer than their move, and nearly touching pairs
            "idp.contact.near_contact_ccd",
            "_advance_all",
            "(float64[:, ::1], float64[:, ::1], int64[:, ::1], int64[::1], float64, float64, int64, float64[::1])",
            12.7,
            alternative=True,  # only once such a pair appears (the demo's first 9 steps have none)
        ),
    ),
    # 3D contact (either barrier): the crossing edge/triangle pairs (idp.contact.intersections), checked on the input
    # when the scene is built and by every frame's certificate
    "surface3d": (
        Kernel(_IX, "_grid", "(float64[:, ::1], int64[:, ::1], int64[:, ::1])", 1.0),
        Kernel(
            _IX,
            "_undecided_edge_face_pairs",
            "(float64[:, ::1], int64[:, ::1], int64[:, ::1], float64[::1], float64, int64[::1], float64[:, ::1],"
            " float64[:, ::1], float64, int64[:, ::1])",
            1.5,
        ),
    ),
    # contact through ipctk's barrier (2D, or barrier = "ipctk"): its Hessian scattered into the Newton matrix
    "contact_ipctk": (
        _EMBED,
        Kernel(
            "idp.solver.contact_pattern",
            "_scatter_csc",  # the layout's indptr / indices are read-only (kept by the linear solver as they are)
            "(int32[::1], int32[::1], float64[::1], int64[::1], Array(int32, 1, 'C', readonly=True),"
            " Array(int32, 1, 'C', readonly=True), float64[::1], int64[::1], int64[::1], float64[::1])",
            0.5,
        ),
    ),
}

#: Every kernel of :data:`GROUPS`, in one order shared with the helper process (which is given indices).
KERNELS: tuple[Kernel, ...] = tuple(k for group in GROUPS.values() for k in group)


def scene_groups(scene: Any) -> list[str]:
    """The :data:`GROUPS` a :class:`~idp.scene.schema.Scene` will call (a staged scene: over all its stages)."""
    objects = list(scene.objects) + [o for stage in scene.stages for o in stage.add]
    groups = ["solver"]
    if scene.solver.linear_solver != "scipy" and importlib.util.find_spec("cvxopt") is not None:
        groups.append("cholmod")
    if any(o.kind == "deformable" for o in objects):
        groups.append("solid")
    if any(o.kind == "shell" and o.shell is not None and o.shell.youngs_modulus > 0 for o in objects):
        groups.append("shell")
    if scene.contact.enabled:
        compiled = scene.dim == 3 and scene.contact.barrier == "compiled"
        groups += ["contact3d", "ccd3d"] if compiled else ["contact_ipctk"]
        if scene.dim == 3:
            groups.append("surface3d")
    return groups


def scene_kernels(scene: Any) -> list[Kernel]:
    return [k for g in scene_groups(scene) for k in GROUPS[g]]


# --------------------------------------------------------------------------------------------------
# cache look-up and compilation
# --------------------------------------------------------------------------------------------------


def _dispatcher(k: Kernel) -> Any:
    return getattr(importlib.import_module(k.module), k.name)


def _argtypes(k: Kernel) -> tuple:
    from numba.core import sigutils

    args, _ = sigutils.normalize_signature(k.signature)
    return tuple(args)


def is_cached(k: Kernel) -> bool | None:
    """Whether numba's disk cache (or this process) holds ``k`` for its signature; None when it cannot tell
    (a numba whose cache internals differ: then nothing is compiled ahead, kernels compile when called)."""
    try:
        from numba.core.caching import Cache

        disp = _dispatcher(k)
        sig = _argtypes(k)
        if sig in disp.overloads:
            return True
        cache = disp._cache
        if not isinstance(cache, Cache):
            return None
        key = cache._index_key(sig, disp.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:  # NUMBA_DISABLE_JIT, or a numba without these internals: kernels compile on first call
        log.debug("numba cache look-up unavailable", exc_info=True)
        return None


def missing_kernels(kernels: Sequence[Kernel]) -> list[Kernel]:
    """The kernels of ``kernels`` that are not in the cache (empty when the cache is warm or cannot be read)."""
    return [k for k in kernels if is_cached(k) is False]


def compile_kernel(k: Kernel) -> None:
    """Compile ``k`` for its signature, or load it from the disk cache (numba writes the cache as it compiles)."""
    _dispatcher(k).compile(_argtypes(k))


def _claim(claims: Path, index: int) -> bool:
    """Take kernel ``index`` for this process (atomic across processes: the first to create the file has it)."""
    try:
        os.close(os.open(claims / str(index), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


@contextlib.contextmanager
def _serialized_cache_writes(lock_path: Path) -> Iterator[None]:
    """numba writes a function's cache index read-modify-write and numbers its data files from what it read:
    two processes adding different signatures of one shared helper at once could leave an index entry pointing
    at the other's data file. While both compile, every cache write holds an exclusive lock on ``lock_path``."""
    try:
        import fcntl

        from numba.core.caching import IndexDataCacheFile
    except ImportError:
        yield
        return
    original = IndexDataCacheFile.save

    def save(self, key, data):
        with open(lock_path, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                return original(self, key, data)
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    IndexDataCacheFile.save = save  # type: ignore[method-assign]
    try:
        yield
    finally:
        IndexDataCacheFile.save = original  # type: ignore[method-assign]


def _helper_allowed() -> bool:
    """A second process only where a second core is there and the user did not ask for one thread."""
    if os.environ.get("IDP_COMPILE_HELPER", "1") == "0" or os.name != "posix":
        return False
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS
        cpus = os.cpu_count() or 1
    if os.environ.get("NUMBA_NUM_THREADS") == "1":
        return False
    return cpus >= 2


def _start_helper(claims: Path, indices: Sequence[int], stderr: Any) -> subprocess.Popen | None:
    import idp

    env = dict(os.environ)
    package = Path(idp.__file__).resolve().parent
    if package.parent.name not in ("site-packages", "dist-packages"):
        # a source checkout: the same idp as this process whatever the working directory (the cache is keyed by
        # the source file); an installed idp is found the usual way (site-packages never goes before the stdlib)
        env["PYTHONPATH"] = str(package.parent) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    cmd = [sys.executable, "-m", "idp._compile_helper", str(package), str(claims), *map(str, indices)]
    try:
        return subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr, text=True, env=env
        )
    except OSError:
        log.debug("kernel compile helper not started", exc_info=True)
        return None


def helper_main(argv: Sequence[str]) -> int:
    """The helper process (arguments: the parent's idp package folder, the claims folder, kernel indices into
    :data:`KERNELS`): compile the kernels it can claim, largest first, printing ``start i`` / ``done i`` for the
    parent's progress bar. Exit 2 without compiling when this is not the parent's idp (another cache)."""
    import idp

    if Path(idp.__file__).resolve().parent != Path(argv[0]):
        print(f"idp compile helper: imported {idp.__file__}, not the parent's {argv[0]}", file=sys.stderr)
        return 2
    claims = Path(argv[1])
    with _serialized_cache_writes(claims / "lock"):
        for i in map(int, argv[2:]):
            if not _claim(claims, i):
                continue
            print(f"start {i}", flush=True)
            compile_kernel(KERNELS[i])
            print(f"done {i}", flush=True)
    return 0


# --------------------------------------------------------------------------------------------------
# announcing
# --------------------------------------------------------------------------------------------------

_announce_depth = 0
_preparing = False
_listener: Any = None


def _say(message: str) -> None:
    try:
        from tqdm import tqdm

        tqdm.write(message, file=sys.stderr)
    except ImportError:  # pragma: no cover - tqdm is a dependency
        print(message, file=sys.stderr, flush=True)


def _make_listener() -> Any:
    from numba.core import event

    class CompileNotice(event.Listener):
        """Says so when an idp kernel starts compiling outside :func:`prepare` (its callees are part of it)."""

        def __init__(self) -> None:
            self.depth = 0

        def on_start(self, ev: Any) -> None:
            self.depth += 1
            if self.depth != 1 or _preparing or not _announce_depth:
                return
            fn = ev.data["dispatcher"].py_func
            if fn.__module__.startswith("idp."):
                name = f"{fn.__module__.rsplit('.', 1)[-1]}.{fn.__name__}"
                _say(f"idp: compiling kernel {name} (first run only; cached for later runs) ...")

        def on_end(self, ev: Any) -> None:
            self.depth -= 1

    return CompileNotice()


@contextlib.contextmanager
def announcing(enabled: bool = True) -> Iterator[None]:
    """While active (and ``enabled``), compiling kernels is shown on stderr: :func:`prepare`'s progress bar, and a
    line for any idp kernel compiled on first call. Nothing is shown for a warm cache."""
    global _announce_depth, _listener
    if not enabled:
        yield
        return
    from numba.core import event

    if _announce_depth == 0:
        _listener = _make_listener()
        event.register("numba:compile", _listener)
    _announce_depth += 1
    try:
        yield
    finally:
        _announce_depth -= 1
        if _announce_depth == 0:
            event.unregister("numba:compile", _listener)
            _listener = None


class _Bar:
    """The progress bar of :func:`prepare` (tqdm on stderr), or nothing when not announcing."""

    def __init__(self, total: int, show: bool):
        self._bar = None
        self._lock = threading.Lock()
        self._running: dict[str, None] = {}
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None
        if not show:
            return
        from tqdm import tqdm

        self._bar = tqdm(
            total=total,
            desc="compiling kernels (first run only)",
            file=sys.stderr,
            dynamic_ncols=True,
            # no rate or ETA: one kernel takes 0.1 s, another 15 s
            bar_format="{desc}: {n_fmt}/{total_fmt} |{bar}| {elapsed}{postfix}",
        )
        if sys.stderr.isatty():  # keep the elapsed time moving during a long kernel
            self._ticker = threading.Thread(target=self._tick, daemon=True)
            self._ticker.start()

    def _tick(self) -> None:
        while not self._stop.wait(1.0):
            with self._lock:
                if self._bar is not None:
                    self._bar.refresh()

    def started(self, k: Kernel) -> None:
        with self._lock:
            self._running[k.label] = None
            self._show()

    def done(self, k: Kernel) -> None:
        with self._lock:
            self._running.pop(k.label, None)
            if self._bar is not None:
                self._bar.update(1)
            self._show()

    def _show(self) -> None:
        if self._bar is not None:
            self._bar.set_postfix_str(", ".join(self._running), refresh=True)

    def close(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        with self._lock:
            if self._bar is not None:
                self._bar.set_postfix_str("", refresh=False)
                self._bar.close()
                self._bar = None


def _read_helper(proc: subprocess.Popen, bar: _Bar, done: set[int]) -> None:
    assert proc.stdout is not None
    for line in proc.stdout:
        what, _, index = line.strip().partition(" ")
        if not (index.isdigit() and int(index) < len(KERNELS)):
            continue
        if what == "start":
            bar.started(KERNELS[int(index)])
        elif what == "done":
            done.add(int(index))
            bar.done(KERNELS[int(index)])


def prepare(
    kernels: Sequence[Kernel] | Any, *, progress: bool | None = None, helper: bool | None = None
) -> list[Kernel]:
    """Compile the kernels of ``kernels`` (a list, or a Scene: :func:`scene_kernels`) that the disk cache lacks,
    shared with a helper process where allowed. ``progress``: show the bar (default: when :func:`announcing`);
    ``helper``: use the helper process (default: when the machine has a second core, see ``IDP_COMPILE_HELPER``).
    Returns the kernels that were missing (none for a warm cache: then this only reads the cache index)."""
    global _preparing
    if not isinstance(kernels, Sequence):
        kernels = scene_kernels(kernels)
    todo = sorted(missing_kernels(kernels), key=lambda k: -k.cost)
    if not todo:
        return []
    show = bool(_announce_depth) if progress is None else progress
    use_helper = (_helper_allowed() if helper is None else helper) and len(todo) > 1
    bar = _Bar(len(todo), show)
    claims = Path(tempfile.mkdtemp(prefix="idp-compile-"))
    done: set[int] = set()
    proc = None
    t0 = time.perf_counter()
    _preparing = True
    try:
        with _serialized_cache_writes(claims / "lock"), open(claims / "helper.err", "w") as helper_err:
            if use_helper:
                proc = _start_helper(claims, [KERNELS.index(k) for k in todo], helper_err)
            reader = None
            if proc is not None:
                reader = threading.Thread(target=_read_helper, args=(proc, bar, done), daemon=True)
                reader.start()
            for k in todo:
                i = KERNELS.index(k)
                if _claim(claims, i):
                    bar.started(k)
                    compile_kernel(k)
                    done.add(i)
                    bar.done(k)
            if proc is not None:
                proc.wait()
                if reader is not None:
                    reader.join()
                if proc.returncode != 0:
                    log.warning("kernel compile helper failed (exit %s); compiling its kernels here", proc.returncode)
                    log.debug("helper stderr:\n%s", (claims / "helper.err").read_text(errors="replace"))
        # load what the helper compiled; compile here what it did not finish
        for k in todo:
            i = KERNELS.index(k)
            if i not in done:
                bar.started(k)
            compile_kernel(k)
            if i not in done:
                done.add(i)
                bar.done(k)
    finally:
        _preparing = False
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        bar.close()
        shutil.rmtree(claims, ignore_errors=True)
    log.info("compiled %d kernels in %.1f s (numba disk cache)", len(todo), time.perf_counter() - t0)
    return todo
