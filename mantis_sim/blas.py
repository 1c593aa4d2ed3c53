"""BLAS on one thread in a process that simulates for a study, set once.

The implicit scipy solvers' LU factorisations give other last digits with two OpenBLAS threads
than with one (Radau at rtol 1e-7: 28.25404482109 against ...112 m/s), and a Dask worker runs
with one: so that a design's row or a strike's fit is the same wherever it ran, every process
that computes them runs BLAS on one thread. Set for the rest of the process, not per call:
threadpoolctl costs about 2 ms a call, as much as a strike on the fast path.
"""
from __future__ import annotations

_limited = False


def one_blas_thread() -> None:
    global _limited
    if not _limited:
        from threadpoolctl import threadpool_limits
        threadpool_limits(limits=1, user_api='blas')
        _limited = True
