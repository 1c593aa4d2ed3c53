"""One hybrid simulator's segments on the compiled engine (hybrid.HybridSimulator._segment).

The simulator keeps the hybrid logic (modes, impacts, phases) in Python: a strike has a
handful of segments. Each segment's integration, its events, its full states and, for
results, each row's derived values run compiled.
"""
from __future__ import annotations

import math

import numpy as np

from . import equations as eq
from . import layout
from .radau import EVENT, OVER_BUDGET, STEP_TOO_SMALL, integrate


def interruptible(compiled):
    """``compiled``, called so that a Ctrl-C landing while it runs comes back as the
    KeyboardInterrupt it is, which every command answers with one line: numba's dispatcher
    returns it as a SystemError ("returned a result with an exception set"), caused, through
    as many such SystemErrors as the dispatcher nests, by the KeyboardInterrupt. A wrapper
    made once per function, not a context per call: these calls are the strike's hot path."""
    def call(*args):
        try:
            return compiled(*args)
        except SystemError as exc:
            cause = exc.__cause__
            while isinstance(cause, SystemError):
                cause = cause.__cause__
            if isinstance(cause, KeyboardInterrupt):
                raise KeyboardInterrupt from None
            raise
    return call


_integrate = interruptible(integrate)
_full_states = interruptible(eq.full_states)
_state_dynamics = interruptible(eq.state_dynamics)
_observe_rows = interruptible(eq.observe_rows)


class SegmentFailed(RuntimeError):
    """The integration stopped: ``over_budget`` (the right-hand-side budget) or not."""

    def __init__(self, t_ms: float, over_budget: bool):
        super().__init__(t_ms)
        self.t_ms, self.over_budget = t_ms, over_budget


def mode_vector(mode) -> np.ndarray:
    """hybrid.Mode (or a Segment's mode) as the kernel's vector (radau.MODE_SIZE)."""
    return np.array([float(mode.latched), float(mode.taut), float(mode.saturated),
                     math.nan if mode.stuck_at is None else mode.stuck_at, mode.slip])


class FastSegments:
    def __init__(self, model, params: np.ndarray):
        self.model = model
        self._p = params
        self._drive = model.drive
        self._ws = np.zeros(eq.WS_SIZE)
        self._spec_cache: dict = {}

    def params(self) -> tuple[np.ndarray, np.ndarray]:
        """The scene's vector, with the model's start length (set at its start) and its drive
        (a world hands each strike its own after building the simulator), and the drive's
        knots as they are now."""
        if self.model.drive is not self._drive:
            self._p, self._drive = layout.pack(self.model), self.model.drive
        self._p[layout.INDEX['L_FREE0']] = self.model.l_free0
        return self._p, layout.knots(self.model)

    def run(self, mode, t0: float, y0: np.ndarray, t1: float, rtol: float, atol: list,
            specs: list, max_rhs_evals: float, dense: bool, start_theta1: float):
        """Integrate one segment: (index of the event that ended it or None, times, full
        states, dense interpolant or None). Raises SegmentFailed."""
        p, knots = self.params()
        model, ws = self.model, self._ws
        ws[eq.WS_THETA1_GUESS] = model.theta1_guess
        ws[eq.WS_RHS_EVALS] = model.rhs_evals
        vector = mode_vector(mode)
        kinds, directions, constants = self._spec_arrays(specs)
        try:
            status, event, ts, ys, hs, qs = _integrate(
                y0, t0, t1, rtol, np.asarray(atol, dtype=float), vector, p, knots, kinds,
                directions, constants, max_rhs_evals, ws, dense)
            if status in (STEP_TOO_SMALL, OVER_BUDGET):
                raise SegmentFailed(float(ts[-1]), status == OVER_BUDGET)
            ws[eq.WS_THETA1_GUESS] = start_theta1
            states = _full_states(ts, ys, vector, p, knots, ws)
        finally:
            model.rhs_evals = int(ws[eq.WS_RHS_EVALS])
            model.theta1_guess = float(ws[eq.WS_THETA1_GUESS])
        interpolant = DenseSteps(ts, ys, hs, qs) if dense else None
        return (int(event) if status == EVENT else None), ts, states, interpolant

    def state_dynamics(self, mode, t: float, s) -> tuple:
        """hybrid._state_dynamics at the full state s: the model.Dynamics fields, in order."""
        p, knots = self.params()
        out = np.empty(eq.DYN_SIZE)
        self._ws[eq.WS_RHS_EVALS] = self.model.rhs_evals
        _state_dynamics(float(t), np.asarray(s, dtype=float), mode_vector(mode), p, knots,
                        self._ws, out)
        self.model.rhs_evals = int(self._ws[eq.WS_RHS_EVALS])
        return out.tolist()

    def _spec_arrays(self, specs: list) -> tuple:
        """The specs' kinds, directions and constants as the kernel's arrays (a strike asks for
        the same few lists again and again)."""
        key = tuple(specs)
        arrays = self._spec_cache.get(key)
        if arrays is None:
            arrays = self._spec_cache[key] = (
                np.array([spec[1] for spec in specs], dtype=np.int64),
                np.array([spec[2] for spec in specs], dtype=float),
                np.array([spec[3] for spec in specs], dtype=float))
        return arrays

    def observe(self, segment, times=None, states=None) -> np.ndarray:
        """Derived values (equations.OBS_*) of a segment's rows, or of given times and full
        states within it (rows)."""
        p, knots = self.params()
        times = segment.t if times is None else times
        states = segment.states if states is None else states
        return _observe_rows(np.asarray(times, dtype=float),
                             np.ascontiguousarray(states, dtype=float),
                             mode_vector(segment), p, knots, self._ws)

    def states_at(self, mode, interpolant, start_theta1: float, times) -> np.ndarray:
        """Full states (rows) at times along a segment's dense output (a held arm on a taut
        rigid tendon solves theta1 from its start's on)."""
        p, knots = self.params()
        times = np.atleast_1d(np.asarray(times, dtype=float))
        packed = np.ascontiguousarray(interpolant(times).T.reshape(times.size, -1))
        self._ws[eq.WS_THETA1_GUESS] = start_theta1
        return _full_states(times, packed, mode_vector(mode), p, knots, self._ws)


class DenseSteps:
    """The segment's continuous solution: each step's collocation polynomial (radau.integrate),
    called as scipy's OdeSolution is (a time or an array of times; a step's start belongs to
    the step before it)."""

    def __init__(self, ts, ys, hs, qs):
        self.ts, self.ys, self.hs, self.qs = ts, ys, hs, qs

    def __call__(self, t):
        times = np.asarray(t, dtype=float)
        i = np.clip(np.searchsorted(self.ts, times, side='left') - 1, 0, self.hs.size - 1)
        x = (times - self.ts[i]) / self.hs[i]
        powers = np.stack([x, x * x, x * x * x], axis=-1)
        y = self.ys[i] + np.einsum('...nk,...k->...n', self.qs[i], powers)
        return y.T if times.ndim else y
