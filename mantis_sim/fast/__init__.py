"""The compiled strike engine (integration.solver = fast): the model's equations and a Radau
IIA integrator with event location, compiled with numba, so that a segment of a hybrid run costs
no Python call per step. Importing this package does not import numba: `layout` is plain
Python; `segment` compiles on first use and caches the machine code beside the sources.
"""
from __future__ import annotations

import sys

FALLBACK_SOLVER = 'Radau'
_said: set = set()
_loaded = False


def segments_for(model):
    """The compiled segments of a built model, or None where the fast engine cannot take it:
    then one line on stderr says why (once per reason and process) and the caller integrates
    with scipy's FALLBACK_SOLVER instead."""
    global _loaded
    try:
        from . import layout
        from .segment import FastSegments
        params = layout.pack(model)
    except ImportError as exc:
        return _fall_back(f'numba is not importable ({exc})')
    except TypeError as exc:
        return _fall_back(str(exc))
    if not _loaded:
        # load the engine now, so that no strike's own wall time counts numba's start
        _loaded = True
        warm_up()
    return FastSegments(model, params)


def _fall_back(why: str):
    if why not in _said:
        _said.add(why)
        print(f'mantis_sim: the fast engine cannot take this scene: {why}; integrating with '
              f"scipy's {FALLBACK_SOLVER} instead", file=sys.stderr)
    return None


def warm_up() -> float:
    """Compile the engine (the first time on a machine, about a minute) or load it from its
    cache (about a second), by simulating one strike; returns the seconds it took. A process
    that will simulate calls it before its clock starts: a Dask worker, a benchmark."""
    import time

    from ..results import simulate
    from ..scene import load_scene
    started = time.perf_counter()
    simulate(load_scene('reference_air_23mm', ['integration.solver=fast',
                                               'integration.rtol=1e-3']), dense=True)
    return time.perf_counter() - started
