"""idp: guaranteed globally injective deformation processing.

Layers (each a sub-package): ``mesh`` -> ``energies`` -> ``contact`` -> ``solver``
-> ``stepper`` -> ``scene`` -> ``output`` -> ``cli``. The Python API is :func:`simulate`
with :class:`Scene` (the same models a scene file is validated against).
"""

import os as _os

__version__ = "0.1.0"

# Three thread pools take turns on few cores: numba's OpenMP (element kernels), ipctk's TBB (contact, CCD)
# and the OpenBLAS under CHOLMOD. By default OpenMP and OpenBLAS workers keep spinning after each parallel
# region and steal the cores the next phase needs (measured on 2 cores, bunny_700: 12.4 s -> 10.0 s with
# these two settings). OpenBLAS workers spin 2^18 cycles (0.1 ms) before sleeping: long enough to stay awake
# between the thousands of BLAS calls of one CHOLMOD factorisation (idp.solver.cholmod_blas; with 2^4 they slept
# between calls and two threads gained nothing), short enough to be idle when the next phase starts. They take
# effect only if set before those libraries load; a user's own value wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
_os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "18")


def _fix_mmap_threshold() -> None:
    # Large arrays freed between Newton iterations go back to the OS instead of staying in glibc's heap
    # (bunnyx30_13K late steps: peak RSS 813 -> 656 MB), while the heap keeps the few MB that smaller ones reuse
    # every iteration (bunny_700: 4x fewer page faults); and numpy's large arrays are not put on transparent huge
    # pages, whose faults compacted memory for seconds (the stored Fig. 21 dumplings: a step 111 -> 82 s); see
    # idp._malloc. Set before the run allocates anything.
    from idp._malloc import decline_numpy_huge_pages, fix_mmap_threshold

    fix_mmap_threshold()
    decline_numpy_huge_pages()


_fix_mmap_threshold()


def __getattr__(name):  # lazy: keep `import idp` cheap
    if name == "simulate":
        from idp.api import simulate

        return simulate
    if name == "load_scene":
        from idp.scene.load import load_scene

        return load_scene
    if name == "Scene":
        from idp.scene.schema import Scene

        return Scene
    if name == "Stage":  # one stage of a multi-stage modeling scene (Scene.stages)
        from idp.scene.stages_schema import StageSpec

        return StageSpec
    if name == "run_stages":
        from idp.applications.modeling import run_stages

        return run_stages
    if name == "run_batch":  # many scenes or a sweep as jobs on Dask (idp.applications.batch; needs idp[batch])
        from idp.applications.batch import run_batch

        return run_batch
    raise AttributeError(name)
