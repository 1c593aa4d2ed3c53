"""The compiled strike engine (integration.solver = fast): the model's equations and a Radau
IIA integrator with event location, compiled with numba, so that a segment of a hybrid run costs
no Python call per step. Importing this package does not import numba: `layout` is plain
Python; `segment` compiles on first use and caches the machine code beside the sources.

The engine imports nothing that simulates (not `hybrid`, not `results`): `load` brings its
kernels into the process (from the cache, or compiled the first time on a machine) by calling
each once on a microsecond of a built model's start pose, not by simulating a strike. The first
`segments_for` of a process loads them, so that no strike's own wall time counts numba's start;
a process whose clock starts earlier (a Dask worker, a benchmark, `python -m mantis_sim.fast`)
calls `warm_up` first.
"""
from __future__ import annotations

import sys

FALLBACK_SOLVER = 'Radau'
#: the scene `warm_up` loads the kernels with (any scene the engine takes would do)
WARM_UP_SCENE = 'reference_air_23mm'
_said: set = set()
_loaded = False


def segments_for(model):
    """The compiled segments of a built model, or None where the fast engine cannot take it:
    then one line on stderr says why (once per reason and process) and the caller integrates
    with scipy's FALLBACK_SOLVER instead."""
    try:
        from . import layout
        from .segment import FastSegments
        params = layout.pack(model)
    except ImportError as exc:
        return _fall_back(f'numba is not importable ({exc})')
    except TypeError as exc:
        return _fall_back(str(exc))
    load(model)
    return FastSegments(model, params)


def _fall_back(why: str):
    if why not in _said:
        _said.add(why)
        print(f'mantis_sim: the fast engine cannot take this scene: {why}; integrating with '
              f"scipy's {FALLBACK_SOLVER} instead", file=sys.stderr)
    return None


def load(model) -> None:
    """Bring the compiled kernels into this process, once: each kernel a strike calls
    (segment's integrate, full states, state dynamics, observed rows) is called once, with the
    argument types a strike passes, on a built model (mantis_sim.model.Model) held at its start
    pose for 0.01 ms. The model itself is left as it was."""
    global _loaded
    if _loaded:
        return
    import math

    import numpy as np

    from . import equations as eq
    from . import layout
    from .segment import _full_states, _integrate, _observe_rows, _state_dynamics

    th1 = model.scene.initial.theta1_rad
    th3 = model.contact_angle
    tension, _ = model.initial_tension(th1, th3)
    length = model.mech.tendon_length(th1, th3)
    p = layout.pack(model)
    p[layout.INDEX['L_FREE0']] = length if model.rigid else length - max(tension, 0.0) / model.k_t
    knots = layout.knots(model)
    ws = np.zeros(eq.WS_SIZE)
    ws[eq.WS_THETA1_GUESS] = th1
    # the arm latched on a taut tendon, packed as hybrid.HybridSimulator._pack packs it
    mode = np.array([1.0, 1.0, 0.0, math.nan, 1.0])
    y0 = np.array([0.0, 0.0] if model.rigid else [th1, 0.0, 0.0, 0.0], dtype=float)
    atol = np.full(y0.size, 1e-9)
    no_events = (np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0))
    _, _, ts, ys, _, _ = _integrate(y0, 0.0, 0.01, 1e-3, atol, mode, p, knots, *no_events,
                                    200.0, ws, True)
    states = _full_states(ts, ys, mode, p, knots, ws)
    _observe_rows(np.ascontiguousarray(ts, dtype=float), np.ascontiguousarray(states), mode, p,
                  knots, ws)
    _state_dynamics(0.0, np.ascontiguousarray(states[0]), mode, p, knots, ws,
                    np.empty(eq.DYN_SIZE))
    _loaded = True


def warm_up() -> float:
    """Load the engine (the first time on a machine it compiles, about a minute; then it loads
    from its cache, about a second) before a process's clock starts; returns the seconds it
    took. Simulates nothing: see `load`."""
    import time

    from ..model import Model
    from ..scene import load_scene
    started = time.perf_counter()
    load(Model(load_scene(WARM_UP_SCENE, ['integration.solver=fast'])))
    return time.perf_counter() - started
