"""Print the CPU features numpy dispatches on at run time (space separated).

`make test-portable` hands them to NPY_DISABLE_CPU_FEATURES so that numpy runs its baseline loops,
as on a CPU without those extensions (its exp / log / power differ in the last bits between the
AVX-512 and baseline loops, which changes test inputs). Baseline features cannot be disabled and
are not listed."""

try:
    from numpy._core._multiarray_umath import __cpu_dispatch__  # numpy >= 2
except ImportError:  # numpy 1.x
    from numpy.core._multiarray_umath import __cpu_dispatch__

print(" ".join(__cpu_dispatch__))
