"""BLAS on one thread in a process that simulates for a study, set once.

The implicit scipy solvers' LU factorisations give other last digits with two OpenBLAS threads
than with one (Radau at rtol 1e-7: 28.25404482109 against ...112 m/s), and a Dask worker runs
with one: so that a design's row or a strike's fit is the same wherever it ran, every process
that computes them runs BLAS on one thread. Set for the rest of the process, not per call:
threadpoolctl costs about 2 ms a call, as much as a strike on the fast path.

threadpoolctl limits the BLAS libraries loaded when it is called, and scipy.linalg brings an
OpenBLAS of its own (numpy's is another): it is loaded first, or a process that had not yet
imported it (a serial sweep, before its first implicit strike) would run its LU on two threads
after all, and its rows would differ in the last digits from a Dask worker's.
"""
from __future__ import annotations

_limited = False


def one_blas_thread() -> None:
    global _limited
    if not _limited:
        import scipy.linalg  # noqa: F401 - its own BLAS, loaded so that the limit reaches it
        from threadpoolctl import threadpool_limits
        threadpool_limits(limits=1, user_api='blas')
        _limited = True
