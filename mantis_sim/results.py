"""Trajectory and metrics of a simulated trial (internal units g, mm, ms; reported in SI)."""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from . import stiff_tendon
from .hybrid import PHASES, HybridSimulator, RawRun
from .scene import Scene

# The keys of `mantis sim --json`, exactly: other tools read them (issue 2); and WARNINGS.
JSON_KEYS = ('status', 'reason', 'peak_tip_speed_mps', 'max_spring_energy_mJ',
             'deepest_body_angle_rad', 'peak_tendon_force_N', 'phase_start_s', 'phase_duration_s',
             'energy_balance_residual_mJ', 'wall_time_s', 'rhs_evals', 'effects', 'solver', 'rtol')
STATUS_STRIKE, STATUS_NO_STRIKE = 'strike', 'no strike'
# The lab's spring energy is a convention, not a model's: k_s/2 (theta1 - theta1_rest)^2 of the
# body angle at phase IV, with k_s = 47.7 N mm/rad and theta1_rest = 4.0736 rad (every row of
# the authors' table satisfies it with that rest angle, to 3e-4 rad). A simulated strike's is
# computed the same way from the simulated body's deepest turn (metrics'
# deepest_body_angle_rad), so that real and simulated strikes use one formula whatever spring a
# model has.
LAB_SPRING_K_NMM_PER_RAD = 47.7
LAB_THETA1_REST_RAD = 4.0736
# A list of lines, each a load the run asks of the rig that the rig cannot give (issue 30):
# not a number, so not among JSON_KEYS (the sweep's table takes those as its columns).
WARNINGS = 'warnings'


@dataclass
class Trajectory:
    """One row per integrator step and event; time in ms, angles rad, rates rad/ms."""

    t_ms: np.ndarray
    theta1: np.ndarray
    theta3: np.ndarray
    omega1: np.ndarray
    omega3: np.ndarray
    tendon_force_N: np.ndarray
    contact_torque_Nmm: np.ndarray
    phase: np.ndarray              # 'I'..'IV' per sample
    tip_speed_mps: np.ndarray
    spring_energy_mJ: np.ndarray
    kinetic_energy_mJ: np.ndarray
    drive_work_mJ: np.ndarray
    dissipated_mJ: np.ndarray
    balance_residual_mJ: np.ndarray
    tendon_length_mm: np.ndarray
    free_length_mm: np.ndarray


@dataclass
class SimulationResult:
    scene: Scene
    trajectory: Trajectory
    metrics: dict
    events: list
    raw: RawRun
    simulator: Optional[HybridSimulator] = None

    def to_json_dict(self) -> dict:
        """The stable subset of the metrics that `mantis sim --json` prints (JSON_KEYS and
        WARNINGS)."""
        return {**{key: self.metrics[key] for key in JSON_KEYS},
                WARNINGS: list(self.metrics[WARNINGS])}

    def _segment_index(self, times_ms: np.ndarray) -> np.ndarray:
        """For each time, the first segment whose span holds it (-1: outside the run)."""
        index = np.full(times_ms.size, -1)
        for k in range(len(self.raw.segments) - 1, -1, -1):
            seg = self.raw.segments[k]
            index[(times_ms >= seg.t[0]) & (times_ms <= seg.t[-1])] = k
        return index

    def _need_dense(self, what: str) -> None:
        if self.simulator is None or any(seg.dense is None for seg in self.raw.segments):
            raise ValueError(f'{what} needs a run simulated with dense=True')

    def state_at(self, t_ms: float) -> Optional[tuple]:
        """Interpolated (th1, th3, w1, w3) at t_ms, when simulated with dense output."""
        k = self._segment_index(np.array([float(t_ms)]))[0]
        seg = self.raw.segments[k] if k >= 0 else None
        return seg.dense(t_ms)[:4] if seg is not None and seg.dense is not None else None

    def states_and_forces_at(self, times_ms) -> tuple[np.ndarray, np.ndarray]:
        """Full states (rows: theta1, theta3 rad, omega1, omega3 rad/ms, drive work,
        dissipated mJ) and the tendon tension (N) at any times (ms) of a run simulated with
        ``dense=True``, from the integrator's continuous solution; NaN outside the run."""
        self._need_dense('states_and_forces_at')
        times = np.atleast_1d(np.asarray(times_ms, dtype=float))
        states = np.full((times.size, 6), np.nan)
        forces = np.full(times.size, np.nan)
        index = self._segment_index(times)
        for k in np.unique(index[index >= 0]):
            at, seg = index == k, self.raw.segments[k]
            states[at] = seg.dense.states(times[at])
            forces[at] = self.simulator.tensions_at(seg, times[at], states[at])
        return states, forces

    def tendon_force_at(self, times_ms) -> np.ndarray:
        """Tendon tension (N) at any times (ms) of a run simulated with ``dense=True``
        (states_and_forces_at). The trajectory holds the steps only, up to 0.2 ms apart where
        the strike's force rises at 30 N/ms: a straight line between them misses that curve by
        0.2 N."""
        self._need_dense('tendon_force_at')
        return self.states_and_forces_at(times_ms)[1]


def simulate(scene: Scene, dense: bool = False) -> SimulationResult:
    """Simulate the scene (a compliant tendon too stiff to matter in its rigid limit on the
    fast path: mantis_sim.stiff_tendon; metrics['rigid_tendon_limit'] then says so)."""
    limit = stiff_tendon.rigid_limit(scene)
    if limit is not None:
        result = _simulate(limit, dense)
        m = result.metrics
        effect = stiff_tendon.compliance_effect(scene, m['peak_tendon_force_N'],
                                                m['max_spring_energy_mJ'])
        if effect < scene.integration.rigid_tendon_below:
            result.scene = scene
            m['rigid_tendon_limit'] = (f'the tendon ({scene.tendon.stiffness_N_per_mm:g} N/mm) '
                                       f'was solved as rigid: its estimated effect on the '
                                       f'strike is {effect:.1e}')
            return result
    return _simulate(scene, dense)


def _simulate(scene: Scene, dense: bool) -> SimulationResult:
    sim = HybridSimulator(scene, dense=dense)
    raw = sim.run()
    rhs_evals = sim.model.rhs_evals      # the run's; building the trajectory evaluates more
    trajectory = _trajectory(sim, raw)
    metrics = _metrics(sim, raw, trajectory, rhs_evals)
    return SimulationResult(scene, trajectory, metrics, raw.events, raw, sim)


def _trajectory(sim: HybridSimulator, raw: RawRun) -> Trajectory:
    if sim.fast is not None:
        return _fast_trajectory(sim, raw)
    model, mech = sim.model, sim.model.mech
    rows = []
    for seg in raw.segments:
        for t, s in zip(seg.t, seg.states):
            d = sim.dynamics_at(seg, t, s)
            rows.append((t, *s[:4], d.tension_N, d.contact_torque_Nmm, seg.phase,
                         mech.tip_speed(s[1], s[2], s[3]), model.spring_energy(s[0]),
                         model.kinetic_energy(s[1], s[2], s[3]), s[4], s[5],
                         sim.energy(t, s), mech.tendon_length(s[0], s[1]),
                         model.free_length(t)[0]))
    cols = list(zip(*rows))
    arr = [np.asarray(c, dtype=float) for i, c in enumerate(cols) if i != 7]
    (t, th1, th3, w1, w3, force, contact, tip, spring, kinetic, work, lost, energy, length,
     free) = arr
    residual = (energy - raw.energy0_mJ) - (work - lost)
    return Trajectory(t, th1, th3, w1, w3, force, contact, np.asarray(cols[7]), tip, spring,
                      kinetic, work, lost, residual, length, free)


def _fast_trajectory(sim: HybridSimulator, raw: RawRun) -> Trajectory:
    """_trajectory's columns, each segment's rows derived in one compiled call."""
    from .fast import equations as eq
    t = np.concatenate([seg.t for seg in raw.segments])
    s = np.concatenate([seg.states for seg in raw.segments])
    obs = np.concatenate([sim.fast.observe(seg) for seg in raw.segments])
    phase = np.concatenate([np.full(len(seg.t), seg.phase) for seg in raw.segments])
    residual = (obs[:, eq.OBS_ENERGY] - raw.energy0_mJ) - (s[:, 4] - s[:, 5])
    return Trajectory(t, s[:, 0], s[:, 1], s[:, 2], s[:, 3], obs[:, eq.OBS_TENSION],
                      obs[:, eq.OBS_CONTACT], phase, obs[:, eq.OBS_TIP_SPEED],
                      obs[:, eq.OBS_SPRING], obs[:, eq.OBS_KINETIC], s[:, 4], s[:, 5], residual,
                      obs[:, eq.OBS_LENGTH], obs[:, eq.OBS_FREE_LENGTH])


def _event_time(raw: RawRun, name: str) -> Optional[float]:
    return next((t for n, t, _ in raw.events if n == name), None)


def _metrics(sim: HybridSimulator, raw: RawRun, tr: Trajectory, rhs_evals: int) -> dict:
    model, mech = sim.model, sim.model.mech
    starts = {p: raw.phase_start_ms.get(p) for p in PHASES}
    peak_t = raw.peak_time_ms if not math.isnan(raw.peak_time_ms) else None
    ends = {'I': starts['II'], 'II': starts['III'], 'III': starts['IV'], 'IV': peak_t}
    durations = {p: (ends[p] - starts[p]) * 1e-3
                 if starts[p] is not None and ends[p] is not None else None for p in PHASES}
    peak_state = next((s for n, _, s in raw.events if n == 'peak'), None)
    peak_tip = mech.tip_speed(*peak_state[1:4]) if peak_state else float(tr.tip_speed_mps.max())
    arm_share = None
    tendon_work_iv = None
    if peak_state is not None:
        total = model.kinetic_energy(*peak_state[1:4])
        arm_share = 1.0 - mech.body_kinetic_energy(peak_state[2]) / total if total > 0 else None
        iv_state = next((s for n, _, s in raw.events if n == 'max_contraction'), None)
        if iv_state is not None:
            tendon_work_iv = peak_state[4] - iv_state[4]
    strike = tr.phase == 'IV'
    peak_force = float(tr.tendon_force_N.max())
    return {
        'scene': raw.scene.name,
        'status': STATUS_STRIKE if peak_t is not None else STATUS_NO_STRIKE,
        'reason': raw.end_reason,
        'peak_tip_speed_mps': peak_tip,
        'max_spring_energy_mJ': float(tr.spring_energy_mJ.max()),
        # The body's deepest turn before the strike: the angle from which a spring energy of
        # any convention (the lab's k_s/2 (theta1 - theta1_rest)^2) is computed.
        'deepest_body_angle_rad': float(tr.theta1[:_strike_end(tr)].min()),
        'peak_tendon_force_N': peak_force,
        WARNINGS: force_warnings(raw.scene.loadcell.capacity_N, peak_force),
        'phase_start_s': {p: (v * 1e-3 if v is not None else None) for p, v in starts.items()},
        'phase_duration_s': durations,
        'peak_time_s': peak_t * 1e-3 if peak_t is not None else None,
        'strike_reached': peak_t is not None,
        'peak_body_speed_radps': float(np.abs(tr.omega1).max() * 1e3),
        'peak_arm_speed_radps': float(np.abs(tr.omega3).max() * 1e3),
        'peak_body_speed_in_strike_radps': float(np.abs(tr.omega1[strike]).max() * 1e3)
        if strike.any() else None,
        'arm_kinetic_energy_share_at_peak': arm_share,
        'tendon_work_phase_IV_mJ': tendon_work_iv,
        'energy_balance_residual_mJ': float(np.abs(tr.balance_residual_mJ).max()),
        'max_constraint_drift_mm': _constraint_drift(raw, tr),
        'events': [(n, t * 1e-3) for n, t, _ in raw.events],
        'wall_time_s': raw.wall_time_s,
        'rhs_evals': rhs_evals,
        'solver_steps': raw.solver_steps,
        'effects': list(model.effects),
        'solver': sim.method,
        'rtol': sim.rtol,
        'rigid_tendon_limit': None,
    }


def lab_spring_energy_mJ(theta1_rad: float) -> float:
    """The lab's spring energy (mJ) of a body angle (rad): the convention above."""
    return 0.5 * LAB_SPRING_K_NMM_PER_RAD * (theta1_rad - LAB_THETA1_REST_RAD) ** 2


def force_warnings(capacity_N: float, peak_force_N: float) -> list[str]:
    """What the scene's own rig cannot take: a peak tendon force beyond its load cell's range
    (the scene's loadcell.capacity_N). The rig's force ceiling is not the physics' to know:
    the rig's command line adds that comparison."""
    capacity = capacity_N
    if peak_force_N <= capacity:
        return []
    return [f'peak tendon force {peak_force_N:.1f} N exceeds the load cell\'s range of '
            f'{capacity:g} N (loadcell.capacity_N): more than the rig can apply or measure']


def _strike_end(tr: Trajectory) -> int:
    """Index one past the last sample before the peak tip speed (all samples if none)."""
    after = np.flatnonzero(tr.phase == 'IV')
    return int(after[-1]) + 1 if after.size else len(tr.t_ms)


def _constraint_drift(raw: RawRun, tr: Trajectory) -> float:
    """Largest |l_t - l_free| while a rigid tendon was taut (mm); 0 for a compliant tendon."""
    if not raw.model.rigid:
        return 0.0
    taut = np.concatenate([np.full(len(seg.t), seg.taut) for seg in raw.segments])
    if not taut.any():
        return 0.0
    return float(np.abs(tr.tendon_length_mm - tr.free_length_mm)[taut].max())
