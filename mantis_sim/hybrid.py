"""Hybrid integration: continuous motion between events, discrete changes at them.

Modes: latched or not (arm on the body), tendon taut or slack. Each mode has its own state
vector and right-hand side (fewest unknowns: a latched arm on a taut rigid tendon has no
freedom at all, so only the energy accumulators are integrated there). Events are located by the
integrator's root-finding on its dense output: unlatch (lambda = 0), slack (F = 0),
re-tension, re-contact, overcentering (dl_t/dtheta3 = 0), max spring contraction (dtheta1/dt = 0)
and peak tip speed (d|v_tip|/dt = 0). Every event ends the segment; the next segment starts in
the mode and phase the event leads to.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Optional

import numpy as np

from .fast.layout import (
    EV_ARM_STOPS,
    EV_LATCH_MARGIN,
    EV_MAX_CONTRACTION,
    EV_OVERCENTER,
    EV_PEAK,
    EV_RECONTACT,
    EV_SLIP,
    EV_STRETCH,
    EV_TAUT_TENSION,
    EV_TENSION,
)
from .model import Dynamics, Model, SimulationError
from .parameters import ParameterError
from .scene import Scene

PHASES = ('I', 'II', 'III', 'IV')
# A re-contact or re-tension is declared only past this overlap (rad or mm), so that the
# integrator's rounding right after a release cannot be mistaken for a new contact.
EVENT_OVERLAP = 1e-9
# A slack rigid tendon counts as separated (no longer grazing) below this stretch: at least
# SEPARATION mm, and at least what the integrator resolves of a length, rtol x d_t. Below
# that, the sign of the stretch is integration noise (LSODA at rtol 1e-6 drifts it by ~1e-6
# mm within microseconds of a slack event), so only the tension the taut tendon would need
# decides re-tension; with SEPARATION alone, that noise re-tensioned a tendon that was going
# slack and the two chattered.
SEPARATION = 1e-7
# A slack rigid tendon grazes (rather than separates) if its stretch rate would take less than
# this to carry it across the separation band: a tension that fell to zero leaves it grazing, a
# stage stop under a moving arm leaves it separating at the stage's speed.
GRAZING_TIME_MS = 0.1
# A latched arm whose contact torque is within this of zero (N mm) at a segment's end is let go
# there: the next segment's event function, evaluated on its own Newton solve of the latched
# body angle, may already read the torque a rounding below zero and then never sees it cross
# (a stop at the unlatching instant left the arm latched for good).
UNLATCH_TORQUE_TOL_NMM = 1e-9
MAX_EVENTS_AT_ONE_INSTANT = 12
# With the stage still (pull speed 0) and no time given, a run simulates this much of the
# mechanism's own motion: a released arm settles within milliseconds, a latched one never moves.
STILL_STAGE_HORIZON_MS = 1000.0
MIN_SPAN_MS = 1e-9
STATE_SCALE = (1.0, 1.0, 1.0, 1.0, 100.0, 100.0)   # rad, rad, rad/ms, rad/ms, mJ, mJ
# The explicit methods' stability limit, the largest |h lambda| of their stability regions
# (on the negative real axis; a lightly damped mode allows no more): scipy's tableaux.
EXPLICIT_STABILITY = {'RK23': 2.5, 'RK45': 3.3, 'DOP853': 6.4}
# An explicit solver is refused up front when the stiff tendon alone would take more steps
# than this over the run's horizon at its stability limit. That is a floor: on the undamped
# tendon mode they step at 1/50 to 1/90 of the limit, resolving its ringing (RK45 on
# air_23mm_compliant: 23 000 steps, 12 s at 1e3 N/mm; 86 000, 43 s at 1e4; 315 000, 150 s at
# 1e5), where Radau takes ~500 steps at any stiffness.
EXPLICIT_STIFF_STEP_BUDGET = 3000
IMPLICIT_ADVICE = ("use an implicit solver: integration.solver=fast, or scipy's Radau "
                   '(or LSODA/BDF)')
# The backstop of run(): no scene integrates for ever. The shipped scenes take 500-3 000
# right-hand sides, the tightest tolerances of `mantis bench accuracy` up to ~600 000.
MAX_RHS_EVALS = 2_000_000


class StiffSceneError(ParameterError):
    """An explicit solver on a tendon too stiff for it: the run would take minutes or hours."""


@dataclass
class Mode:
    latched: bool                 # the arm held still on the body: at the contact, or stuck
    taut: bool
    saturated: bool = False       # a taut rigid tendon yielding at its saturation tension
    # pivot_friction: the arm stuck at this theta3 away from the contact (None: at the contact)
    stuck_at: Optional[float] = None
    slip: float = 1.0             # pivot_friction: the way a free arm starts to move (w3 = 0)

    def copy(self) -> Mode:
        return Mode(self.latched, self.taut, self.saturated, self.stuck_at, self.slip)

    def held_angle(self, contact_angle: float) -> float:
        """theta3 of an arm held still: where it is stuck, else on the contact."""
        return contact_angle if self.stuck_at is None else self.stuck_at


@dataclass
class Segment:
    """Samples of one stretch of continuous motion (full states, one row per solver step)."""

    phase: str
    latched: bool
    taut: bool
    t: np.ndarray
    states: np.ndarray            # columns: th1, th3, w1, w3, W_drive, E_dissipated
    dense: object = None          # callable t -> full state row, if dense output was asked
    saturated: bool = False
    stuck_at: Optional[float] = None
    slip: float = 1.0


@dataclass
class RawRun:
    scene: Scene
    model: Model
    segments: list
    events: list = field(default_factory=list)     # (name, t_ms, full state)
    phase_start_ms: dict = field(default_factory=dict)
    peak_time_ms: float = math.nan
    wall_time_s: float = 0.0
    energy0_mJ: float = 0.0
    solver_steps: int = 0
    end_reason: str = ''          # why a run ended without a strike ('' if it struck)


class HybridSimulator:
    def __init__(self, scene: Scene, dense: bool = False):
        self.scene = scene
        self.model = Model(scene)
        integ = scene.integration
        self.method, self.rtol, self.atol_scale = integ.solver, integ.rtol, integ.atol_scale
        self.fast = None
        if self.method == 'fast':
            from .fast import FALLBACK_SOLVER, segments_for
            self.fast = segments_for(self.model)
            if self.fast is None:
                self.method = FALLBACK_SOLVER
        self.t_end, self._horizon_cause, self._horizon_kind = self._horizon(scene)
        self._refuse_stiff_explicit()
        self.post_peak = integ.post_peak_ms
        # run()'s budget: the model's rhs_evals beyond which it stops (None: no budget)
        self.max_rhs_evals: Optional[int] = None
        self.dense = dense
        self.separation = max(SEPARATION, self.rtol * self.model.mech.d_t)
        # ten times the absolute tolerance on w3 (rad/ms): see the arm_stops event
        self.arm_stop_speed = 10.0 * self.rtol * self.atol_scale * STATE_SCALE[3]
        self._cache_key = None
        self._cache_value = None
        self._constrained_memo: dict = {}
        # Imported by a simulator, not with the module: scipy.integrate costs a process about
        # 0.65 CPU s, which the processes of a trial that only name the simulation (the command
        # line and supervisor of the multi-process layout) need not pay; a simulating process
        # pays it when it builds its world, before the trial, not at its first integration.
        # The fast path does not need it at all.
        if self.fast is None:
            from scipy.integrate import solve_ivp
            self._solve_ivp = solve_ivp

    def _horizon(self, scene: Scene) -> tuple[float, str, str]:
        """(end time in ms, what ends a run there, and its kind: 'cap', 'still' or 'travel'):
        integration.t_end_s if given, else the time the stage takes to use up its travel; no
        fixed limit cuts off a slow pull."""
        drive = scene.drive
        if scene.integration.t_end_s is not None:
            return (scene.integration.t_end_s * 1e3,
                    f'no strike within integration.t_end_s = {scene.integration.t_end_s:g} s',
                    'cap')
        travel = drive.travel_mm - drive.start_position_mm
        t_travel = self.model.drive.time_to_pull(travel)
        if math.isinf(t_travel):
            return (STILL_STAGE_HORIZON_MS,
                    f'the stage does not pull (drive.pull_speed_mm_per_s = '
                    f'{drive.pull_speed_mm_per_s:g})', 'still')
        return (t_travel,
                f'the stage used up its travel ({travel:g} mm from drive.start_position_mm = '
                f'{drive.start_position_mm:g} to drive.travel_mm = {drive.travel_mm:g}, '
                f'{t_travel * 1e-3:.3g} s at {drive.pull_speed_mm_per_s:g} mm/s)', 'travel')

    def tendon_rate_per_ms(self) -> float:
        """The fastest rate of the compliant tendon's own mode, |lambda| in 1/ms (0 for a rigid
        tendon): its stiffness (and damping) against the inertia it moves through the linkage,
        grad l_t^T M^-1 grad l_t, at the start pose (the arm latched: theta1 alone moves)."""
        m, scene = self.model, self.scene
        if m.rigid:
            return 0.0
        th1 = scene.initial.theta1_rad
        th3_deg = scene.initial.theta3_deg
        th3 = m.contact_angle if th3_deg is None else math.radians(th3_deg)
        tg, mass = m.mech.tendon(th1, th3), m.mech.mass(th3)
        if abs(th3 - m.contact_angle) < 1e-12:
            mobility = tg.d1 * tg.d1 / mass.m11                      # 1/g
        else:
            u1, u3 = mass.solve(tg.d1, tg.d3)
            mobility = tg.d1 * u1 + tg.d3 * u3
        # N/mm = 1e-3 g/ms^2, N ms/mm = 1e-3 g/ms: lambda^2 + c lambda + w^2 = 0
        w2 = 1e-3 * m.k_t * mobility
        c = 1e-3 * m.c_t * mobility
        return 0.5 * (c + math.sqrt(c * c - 4 * w2)) if c * c > 4 * w2 else math.sqrt(w2)

    def _refuse_stiff_explicit(self) -> None:
        """An explicit solver on a stiff compliant tendon: refused before it starts, with the
        stability-limited step count it would need at the least (EXPLICIT_STIFF_STEP_BUDGET)."""
        limit = EXPLICIT_STABILITY.get(self.method)
        if limit is None:
            return
        rate = self.tendon_rate_per_ms()
        if rate == 0.0:
            return
        steps = rate * self.t_end / limit
        if steps > EXPLICIT_STIFF_STEP_BUDGET:
            raise StiffSceneError(
                f'integration.solver = {self.method} on tendon.stiffness_N_per_mm = '
                f'{self.model.k_t:g}: the tendon against the inertia it moves has a time scale '
                f'of {1e3 / rate:.3g} us, so this explicit solver needs at least ~{steps:,.0f} '
                f'steps over the {self.t_end * 1e-3:.3g} s horizon (its stability limit; budget '
                f'{EXPLICIT_STIFF_STEP_BUDGET:,}) and in practice tens of times more: '
                f'{IMPLICIT_ADVICE}')

    def _over_budget(self, t: float, phase: str) -> SimulationError:
        advice = (IMPLICIT_ADVICE if self.method in EXPLICIT_STABILITY
                  else 'loosen integration.rtol, or end the run sooner (integration.t_end_s)')
        return SimulationError(
            f'stopped at t = {t:.6f} ms in phase {phase}: the solver {self.method} (rtol '
            f'{self.rtol:g}) used its budget of {MAX_RHS_EVALS:,} right-hand sides '
            f'(mantis_sim.hybrid.MAX_RHS_EVALS), the scene is too stiff for it: {advice}')

    # --- mode systems ---------------------------------------------------------------------------
    def _constrained(self, mode: Mode) -> bool:
        return mode.latched and mode.taut and self.model.rigid and not mode.saturated

    def _dynamics(self, mode: Mode, t, y) -> Dynamics:
        key = (mode.latched, mode.taut, mode.saturated, mode.stuck_at, mode.slip, t, *y)
        if key == self._cache_key:
            return self._cache_value
        m = self.model
        if self._constrained(mode):
            # Nothing here depends on y: memoise per t, so that every evaluation at one instant
            # agrees to the bit (Newton's result depends at 1e-14 on where it starts, and an
            # event root within that of a segment end then had endpoint values of equal
            # sign for the root finder).
            d = self._constrained_memo.get((t, mode.stuck_at))
            if d is None:
                d = self._constrained_memo[(t, mode.stuck_at)] = m.latched_constrained(
                    t, mode.stuck_at)
        elif mode.latched:
            d = m.latched_free(t, y[0], y[1], mode.taut, mode.stuck_at)
        else:
            d = m.unlatched(t, y[0], y[1], y[2], y[3], mode.taut, mode.saturated, mode.slip)
        self._cache_key, self._cache_value = key, d
        return d

    def _pack(self, mode: Mode, s):
        if self._constrained(mode):
            return [s[4], s[5]]
        if mode.latched:
            return [s[0], s[2], s[4], s[5]]
        return list(s)

    def _unpack(self, mode: Mode, t, y) -> tuple:
        if not mode.latched:
            return tuple(y)                 # the integrated state is the full state
        d = self._dynamics(mode, t, y)
        if self._constrained(mode):
            return (d.th1, d.th3, d.w1, 0.0, y[0], y[1])
        return (y[0], d.th3, y[1], 0.0, y[2], y[3])

    def _rhs(self, mode: Mode, phase: str):
        # float(t), y.tolist(): the model's scalar math runs on Python floats, several times
        # faster than on the numpy scalars the solver hands over (t, or iterating y).
        dyn = self._dynamics
        if self._constrained(mode):
            def rhs(t, y):
                d = dyn(mode, float(t), y.tolist())
                return [d.stage_power, d.loss_power]
        elif mode.latched:
            def rhs(t, y):
                d = dyn(mode, float(t), y.tolist())
                return [d.w1, d.a1, d.stage_power, d.loss_power]
        else:
            def rhs(t, y):
                d = dyn(mode, float(t), y.tolist())
                return [d.w1, d.w3, d.a1, d.a3, d.stage_power, d.loss_power]
        if self.max_rhs_evals is None:
            return rhs
        model, budget, unbudgeted = self.model, self.max_rhs_evals, rhs

        def rhs(t, y):
            if model.rhs_evals > budget:
                raise self._over_budget(float(t), phase)
            return unbudgeted(t, y)
        return rhs

    def _event_specs(self, mode: Mode, phase: str, after_peak: bool, start_stretch: float,
                     start_rate: float = 0.0) -> list:
        """The events that can end a segment in this mode and phase, each (name, kind,
        direction, constant): the event function is kind's value (fast.layout.EV_*) plus the
        constant. One list for both engines (_scipy_events, fast.segment)."""
        m = self.model
        specs = []
        if mode.latched and mode.stuck_at is None:
            specs.append(('unlatch', EV_LATCH_MARGIN, -1, 0.0))
        elif mode.latched:
            # stuck by friction: it slips when the torque needed to hold it exceeds the limit
            specs.append(('slip', EV_SLIP, -1, 0.0))
        else:
            specs.append(('recontact', EV_RECONTACT, -1, EVENT_OVERLAP - m.contact_angle))
            if m.friction_lever > 0.0:
                # the arm comes to rest relative to the body: it sticks or reverses. Past the
                # integrator's resolution of w3 only: at a release the friction just balances,
                # and w3's rounding noise about zero is no reversal (at rtol 1e-3 it chattered).
                specs.append(('arm_stops', EV_ARM_STOPS, -mode.slip,
                              mode.slip * self.arm_stop_speed))
        if m.unilateral:
            if mode.saturated:
                specs.append(('resume', EV_STRETCH, -1, 0.0))
            elif m.rigid and mode.taut:
                specs.append(('slack', EV_TENSION, -1, 0.0))
                if m.saturation_N is not None and not mode.latched:
                    specs.append(('saturate', EV_TENSION, 1, -m.saturation_N))
            elif (m.rigid and not mode.latched and start_stretch > -0.5 * self.separation
                    and start_rate > -self.separation / GRAZING_TIME_MS):
                # Grazing: the tendon is at zero stretch and stretch rate but would have to
                # push. It is taut again as soon as the tension it would need turns positive;
                # only once it has really separated does the stretch itself decide. (Should
                # the stretch grow past the resolution instead, it is taut as well.)
                specs += [('separate', EV_STRETCH, -1, self.separation),
                          ('retension', EV_TAUT_TENSION, 1, 0.0),
                          ('retension', EV_STRETCH, 1, -self.separation)]
            elif m.rigid:
                specs.append(('retension', EV_STRETCH, 1,
                              -(max(start_stretch, 0.0) + EVENT_OVERLAP)))
            elif mode.taut:
                specs.append(('slack', EV_STRETCH, -1, 0.0))
            else:
                specs.append(('retension', EV_STRETCH, 1, 0.0))
        if not mode.latched and not after_peak:
            if phase == 'II':
                specs.append(('overcenter', EV_OVERCENTER, -1, 0.0))
            elif phase == 'III':
                specs.append(('max_contraction', EV_MAX_CONTRACTION, 1, 0.0))
            elif phase == 'IV':
                specs.append(('peak', EV_PEAK, -1, 0.0))
        return specs

    def _scipy_events(self, mode: Mode, specs: list) -> list:
        """solve_ivp's event functions for the specs (terminal, directed, named)."""
        m, dyn = self.model, self._dynamics

        def stretch(t, y):
            th3 = mode.held_angle(m.contact_angle) if mode.latched else y[1]
            return m.mech.tendon_length(y[0], th3) - m.free_length(t)[0]

        def tip_rate(t, y):
            d = dyn(mode, t, y)
            return m.mech.tip_power_rate(d.th3, d.w1, d.w3, d.a1, d.a3)

        taut = Mode(False, True)
        value = {
            EV_LATCH_MARGIN: lambda t, y: m.latch_margin(dyn(mode, t, y)),
            EV_SLIP: lambda t, y: (m.friction_limit(dyn(mode, t, y))
                                   - abs(dyn(mode, t, y).contact_torque_Nmm)),
            EV_RECONTACT: lambda t, y: y[1],
            EV_ARM_STOPS: lambda t, y: y[3],
            EV_STRETCH: stretch,
            EV_TENSION: lambda t, y: dyn(mode, t, y).tension_N,
            EV_TAUT_TENSION: lambda t, y: dyn(taut, t, y).tension_N,
            EV_OVERCENTER: lambda t, y: m.mech.tendon(y[0], y[1]).d3,
            EV_MAX_CONTRACTION: lambda t, y: y[2],
            EV_PEAK: tip_rate,
        }
        events = []
        for name, kind, direction, constant in specs:
            def g(t, y, fn=value[kind], constant=constant):
                return fn(float(t), y.tolist()) + constant
            g.terminal, g.direction, g.__name__ = True, direction, name
            events.append(g)
        return events

    # --- transitions ----------------------------------------------------------------------------
    def _settle(self, mode: Mode, t, s, phase):
        """Leave modes whose multipliers already have the wrong sign; advance phases whose
        condition already holds. Returns the (possibly changed) phase."""
        m = self.model
        for _ in range(4):
            d = self._state_dynamics(mode, t, s)
            if self._constrained(mode) or (m.rigid and mode.taut and not mode.latched):
                if m.unilateral and d.tension_N < 0.0:
                    mode.taut = False
                    self.run_data.events.append(('slack', t, s))
                    continue
            if (mode.latched and mode.stuck_at is None
                    and m.latch_margin(d) < UNLATCH_TORQUE_TOL_NMM):
                mode.latched, mode.slip = False, 1.0
                self.run_data.events.append(('unlatch', t, s))
                phase = self._advance(phase, 'II', t)
                continue
            if (mode.latched and mode.stuck_at is not None
                    and abs(d.contact_torque_Nmm) - m.friction_limit(d) > -UNLATCH_TORQUE_TOL_NMM):
                self._slip(mode, d)
                self.run_data.events.append(('slip', t, s))
                continue
            break
        if not mode.latched:
            if phase == 'II' and m.mech.tendon(s[0], s[1]).d3 <= 0.0:
                phase = self._advance(phase, 'III', t)
            if phase == 'III' and s[2] >= 0.0:
                phase = self._advance(phase, 'IV', t)
        return phase

    def _slip(self, mode: Mode, held: Dynamics) -> None:
        """A stuck arm starts to move the way the torque it was held against pushes it."""
        mode.latched, mode.stuck_at = False, None
        mode.slip = -1.0 if held.contact_torque_Nmm > 0.0 else 1.0

    def _stop_or_stick(self, mode: Mode, t, s) -> None:
        """The free arm has come to rest relative to the body (pivot_friction): it sticks
        where it is if the friction can hold it there, or moves on the way it is pushed."""
        at_contact = s[1] - self.model.contact_angle <= EVENT_OVERLAP
        held = self._state_dynamics(Mode(True, mode.taut, mode.saturated,
                                         stuck_at=None if at_contact else s[1]), t, s)
        if at_contact and self.model.latch_margin(held) > 0.0:
            mode.latched, mode.stuck_at = True, None     # back on the body, held there
        elif not at_contact and abs(held.contact_torque_Nmm) < self.model.friction_limit(held):
            mode.latched, mode.stuck_at = True, s[1]
        else:
            self._slip(mode, held)

    def _advance(self, phase: str, new_phase: str, t: float) -> str:
        if PHASES.index(new_phase) == PHASES.index(phase) + 1:
            self.run_data.phase_start_ms[new_phase] = t
            return new_phase
        return phase

    def _impact(self, mode: Mode, t, s):
        """Re-contact of the arm on the body: restitution, or re-latching when slow."""
        m = self.model
        th1, th3, w1, w3, work, lost = s
        th3 = m.contact_angle
        mass = m.mech.mass(th3)
        ke_before = mass.kinetic_energy(w1, w3)
        target_w3 = -m.restitution * w3
        latch = abs(target_w3) <= m.latch_speed
        if latch:
            target_w3 = 0.0
        tendon_impulse = 0.0
        if m.rigid and mode.taut:
            # both constraints hold after the impact: the velocity is fixed by them
            tg = m.mech.tendon(th1, th3)
            l_free_dot = m.free_length(t)[1]
            new_w1 = (l_free_dot - tg.d3 * target_w3) / tg.d1
            new_w3 = target_w3
            # impulse split: M dw = -grad_l P_t + e3 P_c; the first row gives P_t
            dw1, dw3 = new_w1 - w1, new_w3 - w3
            tendon_impulse = -(mass.m11 * dw1 + mass.m12 * dw3) / tg.d1
            work -= tendon_impulse * l_free_dot
        else:
            u1, u3 = mass.solve(0.0, 1.0)
            impulse = (target_w3 - w3) / u3
            new_w1, new_w3 = w1 + u1 * impulse, w3 + u3 * impulse
        ke_after = mass.kinetic_energy(new_w1, new_w3)
        lost += ke_before - ke_after + (work - s[4])
        mode.latched, mode.stuck_at, mode.slip = latch, None, 1.0
        return (th1, th3, new_w1, new_w3, work, lost)

    def _retension(self, mode: Mode, t, s):
        """A slack rigid tendon snaps taut: an inelastic impulse along grad l_t."""
        m = self.model
        th1, th3, w1, w3, work, lost = s
        tg = m.mech.tendon(th1, th3)
        l_free_dot = m.free_length(t)[1]
        mass = m.mech.mass(th3)
        ke_before = mass.kinetic_energy(w1, w3)
        if mode.latched:
            new_w1, new_w3 = l_free_dot / tg.d1, 0.0
            impulse = -mass.m11 * (new_w1 - w1) / tg.d1
        else:
            u1, u3 = mass.solve(tg.d1, tg.d3)
            impulse = (tg.d1 * w1 + tg.d3 * w3 - l_free_dot) / (tg.d1 * u1 + tg.d3 * u3)
            new_w1, new_w3 = w1 - u1 * impulse, w3 - u3 * impulse
        work -= impulse * l_free_dot
        lost += ke_before - mass.kinetic_energy(new_w1, new_w3) + (work - s[4])
        mode.taut = True
        return (th1, th3, new_w1, new_w3, work, lost)

    def drive_changed(self, t: float) -> None:
        """The drive was commanded anew at t (the current time): its speed may jump. A
        compliant tendon takes the jump in its stretch; a taut rigid tendon on a free arm needs
        an impulse, or goes slack if it would have to push."""
        mode = self.mode
        if not (self.model.rigid and mode.taut) or self._constrained(mode):
            return
        self.state = self._relock(mode, t, self.state)

    def _relock(self, mode: Mode, t, s):
        """A rigid tendon on a free arm whose stretch rate may not be zero (a new drive speed,
        the end of a yield): an impulse makes it taut, or it goes slack if it would have to
        push. Returns the state after."""
        tg = self.model.mech.tendon(s[0], s[1])
        stretch_rate = tg.d1 * s[2] + tg.d3 * s[3] - self.model.free_length(t)[1]
        if stretch_rate < 0.0 and self.model.unilateral:
            mode.taut = False
            return s
        return self._retension(mode, t, s)

    # --- main loop ------------------------------------------------------------------------------
    def initial_state(self):
        m, scene = self.model, self.scene
        th1 = scene.initial.theta1_rad
        th3_deg = scene.initial.theta3_deg
        th3 = m.contact_angle if th3_deg is None else math.radians(th3_deg)
        latched = abs(th3 - m.contact_angle) < 1e-12
        tension, contact = m.initial_tension(th1, th3)
        if latched and (tension < 0 or contact < 0):
            raise SimulationError(
                f'the start pose theta1 = {th1:.4f} rad, theta3 = {math.degrees(th3):.2f} deg is '
                f'not held by the tendon and the latch (static tension {tension:.3f} N, contact '
                f'torque {contact:.3f} N mm: both must be >= 0)')
        length = m.mech.tendon_length(th1, th3)
        m.l_free0 = length if m.rigid else length - max(tension, 0.0) / m.k_t
        return Mode(latched=latched, taut=True), (th1, th3, 0.0, 0.0, 0.0, 0.0)

    def start(self) -> None:
        """Put the rig in its start pose at t = 0; then advance() or run()."""
        mode, s = self.initial_state()
        self.run_data = run = RawRun(self.scene, self.model, segments=[],
                                     phase_start_ms={'I': 0.0})
        self.mode, self.t, self.phase, self.after_peak = mode, 0.0, 'I', False
        self.stop_at = self.t_end
        self.phase = self._settle(mode, 0.0, s, 'I')
        # An ideal drive starts at full speed: the state at t = 0+ already moves with it.
        self.state = self._unpack(mode, 0.0, tuple(self._pack(mode, s)))
        run.energy0_mJ = self.energy(0.0, self.state)
        if self.model.rigid and mode.taut and not mode.latched:
            # A free arm on a taut rigid tendon: the stage's jump to full speed jerks the
            # mechanism (an inelastic impulse along grad l_t, its work and loss booked), or,
            # were the stage to push, leaves the tendon slack.
            m, th1, th3 = self.model, self.state[0], self.state[1]
            tg = m.mech.tendon(th1, th3)
            rate = tg.d1 * self.state[2] + tg.d3 * self.state[3] - m.free_length(0.0)[1]
            if rate > 0.0:
                self.state = self._retension(mode, 0.0, self.state)
            elif rate < 0.0 and m.unilateral:
                mode.taut = False
            self.phase = self._settle(mode, 0.0, self.state, self.phase)
        self._same_instant, self._last_t = 0, -1.0

    def run(self) -> RawRun:
        """Simulate from the start pose to the peak tip speed (+ post_peak_ms) or t_end."""
        start = time.perf_counter()
        self.max_rhs_evals = self.model.rhs_evals + MAX_RHS_EVALS
        try:
            self.start()
            self.advance(self.t_end, stop_after_peak=True)
        finally:
            self.max_rhs_evals = None
        run = self.run_data
        run.wall_time_s = time.perf_counter() - start
        if math.isnan(run.peak_time_ms):
            cause, kind = self._horizon_cause, self._horizon_kind
            if kind == 'cap':
                run.end_reason = cause
            elif 'II' in run.phase_start_ms:
                run.end_reason = f'{cause}: the arm was released, but no strike followed'
            elif kind == 'travel':
                run.end_reason = f'{cause} before the latch released the arm'
            else:
                run.end_reason = f'{cause}: the arm was never released'
        return run

    def advance(self, t_stop: float, stop_after_peak: bool = False) -> None:
        """Integrate from the current time to t_stop ms, handling every event on the way."""
        run, mode = self.run_data, self.mode
        t, s, phase = self.t, self.state, self.phase
        breakpoints = sorted(b for b in self.model.drive.breakpoints() if t < b < t_stop)
        # A span shorter than MIN_SPAN_MS is rounding (a stop a hair past a drive knot), not
        # motion: integrating it makes LSODA refuse its input.
        while min(t_stop, self.stop_at) - t > MIN_SPAN_MS:
            horizon = min([t_stop, self.stop_at]
                          + [b for b in breakpoints if b > t + MIN_SPAN_MS])
            name, t_new, s = self._segment(mode, phase, self.after_peak, t, s, horizon)
            self._same_instant = self._same_instant + 1 if t_new - self._last_t < 1e-9 else 0
            if self._same_instant > MAX_EVENTS_AT_ONE_INSTANT:
                raise SimulationError(f'events keep firing at t = {t_new:.9f} ms '
                                      f'(last: {name}); the contact or tendon is chattering')
            self._last_t = t = t_new
            self.t, self.state = t, s
            if name == 'separate':
                continue
            if name is None:                # a stop or a drive knot: it may fall on a root
                self.phase = phase = self._settle(mode, t, s, phase)
                continue
            run.events.append((name, t, s))
            if name == 'unlatch':
                mode.latched, mode.slip = False, 1.0
                phase = self._advance(phase, 'II', t)
            elif name == 'slip':
                self._slip(mode, self._state_dynamics(mode, t, s))
            elif name == 'arm_stops':
                s = (*s[:3], 0.0, *s[4:])
                self._stop_or_stick(mode, t, s)
            elif name == 'slack':
                mode.taut = False
            elif name == 'saturate':
                mode.saturated = True
            elif name == 'resume':
                # back to its unstretched length: locked again, or slack if still shortening
                mode.saturated = False
                s = self._relock(mode, t, s)
            elif name == 'retension':
                s = self._retension(mode, t, s) if self.model.rigid else s
                mode.taut = True
            elif name == 'recontact':
                s = self._impact(mode, t, s)
            elif name == 'overcenter':
                phase = self._advance(phase, 'III', t)
            elif name == 'max_contraction':
                phase = self._advance(phase, 'IV', t)
            elif name == 'peak':
                run.peak_time_ms, self.after_peak = t, True
                if stop_after_peak:
                    self.stop_at = min(self.t_end, t + self.post_peak)
            phase = self._settle(mode, t, s, phase)
            self.state, self.phase = s, phase

    def _segment(self, mode: Mode, phase, after_peak, t0, s, t1):
        if self._constrained(mode):
            # l_t(theta1) = l_free has two roots: start Newton from where the body is now
            self.model.theta1_guess = s[0]
            self._constrained_memo.clear()
        y0 = np.array(self._pack(mode, s), dtype=float)
        scale = STATE_SCALE[4:] if self._constrained(mode) else (
            (1.0, 1.0, 100.0, 100.0) if mode.latched else STATE_SCALE)
        atol = [self.rtol * self.atol_scale * x for x in scale]
        m = self.model
        start_stretch = start_rate = 0.0
        if m.rigid and m.unilateral and not mode.taut and not mode.saturated:
            # a slack rigid tendon: where it starts decides which re-tension events apply
            tg = m.mech.tendon(s[0], s[1])
            l_free, l_free_dot, _ = m.free_length(t0)
            start_stretch = tg.length - l_free
            start_rate = tg.d1 * s[2] + tg.d3 * s[3] - l_free_dot
        specs = self._event_specs(mode, phase, after_peak, start_stretch, start_rate)
        if self.fast is not None:
            fired, t, states, interpolant = self._fast_segment(mode, phase, t0, y0, t1, atol,
                                                               specs, s[0])
        else:
            fired, t, states, interpolant = self._scipy_segment(mode, phase, t0, y0, t1, atol,
                                                                specs)
        self.run_data.solver_steps += len(t) - 1
        frozen = mode.copy()
        dense = (_DenseSegment(self, frozen, interpolant, s[0]) if interpolant is not None
                 else None)
        self.run_data.segments.append(Segment(phase, mode.latched, mode.taut, t, states,
                                              dense, mode.saturated, mode.stuck_at, mode.slip))
        name = specs[fired][0] if fired is not None else None
        return name, float(t[-1]), tuple(states[-1].tolist())

    def _scipy_segment(self, mode: Mode, phase, t0, y0, t1, atol, specs):
        events = self._scipy_events(mode, specs)
        try:
            sol = self._solve_ivp(self._rhs(mode, phase), (t0, t1), y0, method=self.method,
                                  rtol=self.rtol, atol=atol, events=events,
                                  dense_output=self.dense)
        except ValueError as exc:
            # scipy's event location (brentq) finds no sign change where the step saw one:
            # seen when the state has diverged (|values| ~ 1e31, steps of zero length)
            raise SimulationError(f'integration failed after t = {t0:.6f} ms in phase {phase}: '
                                  f'an event could not be located ({exc})') from exc
        if sol.status == -1:
            raise SimulationError(f'integration failed at t = {sol.t[-1]:.6f} ms in phase '
                                  f'{phase}: {sol.message}')
        frozen = mode.copy()
        states = np.array([self._unpack(frozen, ti, yi)
                           for ti, yi in zip(sol.t.tolist(), sol.y.T.tolist())])
        fired = None
        if sol.status == 1:
            fired = next(i for i, te in enumerate(sol.t_events) if len(te))
        return fired, sol.t, states, sol.sol if self.dense else None

    def _fast_segment(self, mode: Mode, phase, t0, y0, t1, atol, specs, start_theta1):
        from .fast.segment import SegmentFailed
        budget = math.inf if self.max_rhs_evals is None else float(self.max_rhs_evals)
        try:
            return self.fast.run(mode, t0, y0, t1, self.rtol, atol, specs, budget, self.dense,
                                 start_theta1)
        except SegmentFailed as failed:
            if failed.over_budget:
                raise self._over_budget(failed.t_ms, phase) from None
            raise SimulationError(
                f'integration failed at t = {failed.t_ms:.6f} ms in phase {phase}: the step '
                f'size fell below the spacing of floating-point numbers there') from None

    def energy(self, t, s) -> float:
        """Mechanical energy: kinetic + potential (+ compliant tendon), mJ."""
        return (self.model.kinetic_energy(s[1], s[2], s[3])
                + self.model.potential_energy(s[0], s[1], t))

    def tensions_at(self, segment: Segment, times, states=None) -> np.ndarray:
        """Tendon tension (N) at times within a segment simulated with dense output (at the
        full states there, if the caller has them)."""
        times = np.asarray(times, dtype=float)
        if self.fast is None and states is None and self._constrained(segment.dense.mode):
            return self.model.held_tensions(times, segment.dense.mode.stuck_at,
                                            segment.dense.start_theta1)
        if states is None:
            states = segment.dense.states(times)
        if self.fast is not None:
            from .fast.equations import OBS_TENSION
            return self.fast.observe(segment, times, states)[:, OBS_TENSION]
        return np.array([self.dynamics_at(segment, t, s).tension_N
                         for t, s in zip(times, states)])

    def dynamics_at(self, segment: Segment, t, s) -> Dynamics:
        return self._state_dynamics(Mode(segment.latched, segment.taut, segment.saturated,
                                         segment.stuck_at, segment.slip), t, s)

    def _state_dynamics(self, mode: Mode, t, s) -> Dynamics:
        """Dynamics at a full state s. A latched arm on a taut rigid tendon has its theta1
        from l_t(theta1) = l_free(t), which has two roots: Newton must start from s's theta1,
        not from wherever the last constrained segment left it (a re-latch after the strike
        found the far root, a contact torque of the wrong sign, and unlatched and re-latched
        every 0.2 us for ever)."""
        if self.fast is not None:
            return Dynamics(*self.fast.state_dynamics(mode, t, s))
        if self._constrained(mode):
            self.model.theta1_guess = s[0]
            self._constrained_memo.clear()
        return self._dynamics(mode, t, tuple(self._pack(mode, s)))


class _DenseSegment:
    def __init__(self, sim: HybridSimulator, mode: Mode, interpolant, start_theta1: float):
        self.sim, self.mode, self.interpolant = sim, mode, interpolant
        self.start_theta1 = start_theta1

    def __call__(self, t: float) -> tuple:
        return self.sim._unpack(self.mode, t, tuple(self.interpolant(t)))

    def states(self, times_ms) -> np.ndarray:
        """Full states (rows) at many times; one compiled call on the fast path."""
        if self.sim.fast is not None:
            return self.sim.fast.states_at(self.mode, self.interpolant, self.start_theta1,
                                           times_ms)
        if self.sim._constrained(self.mode):
            return self._held_states(times_ms)
        return np.array([self(t) for t in times_ms], dtype=float).reshape(-1, 6)

    def _held_states(self, times_ms) -> np.ndarray:
        # The pose follows from the stage alone: no state-by-state dynamics, one call of the
        # interpolant for the integrated energies.
        times_ms = np.atleast_1d(np.asarray(times_ms, dtype=float))
        th1, w1 = self.sim.model.held_pose(times_ms, self.mode.stuck_at, self.start_theta1)
        stage_work, loss = np.asarray(self.interpolant(times_ms)).reshape(2, -1)
        zeros = np.zeros(times_ms.size)
        return np.column_stack([th1, np.full(times_ms.size, self._held_th3()), w1, zeros,
                                stage_work, loss])

    def _held_th3(self) -> float:
        stuck_at = self.mode.stuck_at
        return self.sim.model.contact_angle if stuck_at is None else stuck_at

    def angles(self, times_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta1, theta3) at many times: with the arm free the integrated state starts with
        them, and one call of the interpolant serves every time; held on a taut rigid tendon,
        they follow from the stage; otherwise latched, state by state."""
        if not self.mode.latched:
            th1, th3 = self.interpolant(times_ms)[:2]
            return th1, th3
        if self.sim.fast is None and self.sim._constrained(self.mode):
            th1 = self.sim.model.held_pose(times_ms, self.mode.stuck_at, self.start_theta1)[0]
            return th1, np.full(th1.size, self._held_th3())
        states = self.states(times_ms)
        return states[:, 0], states[:, 1]
