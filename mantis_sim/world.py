"""The simulated rig running in simulated time, driven by stage commands (no ROS).

A World starts in the scene's start pose with the stage at rest at drive.start_position_mm. The
stage's velocity is commanded while the world runs (set_stage_velocity); advance_to() integrates
the mechanism with mantis_sim's hybrid simulator up to a time, through unlatching, the strike and
whatever follows. Sensors read the truth back for any time within the kept history: the tendon
tension and the markers' positions in the camera frame. Sensor imperfections (load-cell
bandwidth, noise, ADC, pixel quantisation) belong to mantis_sim.sensors, not here.

The mechanism is simulated in full through the release and the strike, and for
SETTLE_AFTER_PEAK_MS after the peak tip speed. Then the arm is held where it swung to: the
model has no target for the arm to hit, and its free rebound (resting contact, slack-taut
chatter of a rigid tendon) is not what anyone measures on the rig. The body is not frozen:
the spring is still loaded after the strike, so while the stage moves on, the body turns in
the (linearised) quasi-static balance of spring torque and tendon tension, and the tendon
stretches by its own stiffness (tendon.stiffness, also for a rigid-tendon scene). The tension
changes at the series stiffness of tendon and spring-through-linkage (about -0.6 N/mm for
air_23mm: the linkage softens), not at the tendon's 50 N/mm; it never falls below zero.

Re-latching: on the rig a person re-latches the robot between strikes, with the stage back
where the tendon is slack. The world does the same: once the arm is held after a strike and the
stage rests within RELATCH_TOLERANCE_MM of drive.start_position_mm, a new strike begins there,
the robot in the scene's start pose again (or in the pose of the scene ``relatch_scene(n)``
gives for the n-th strike, so that a simulated session may draw each robot). Each strike is
simulated on its own clock from its re-latch; the world maps its times to the rig's. A World
made with ``operator_relatches=False`` plays an operator who forgot: the robot is left
unlatched, its arm free, and the tendon, which then only swings the free arm, carries no
tension (a simplification: the free arm's own hinge stiffness and weight are left out) while the
arm stays where the strike left it. The supervisor's latch check is tried against that.

Rebuilding the latched robot: before a trial pulls on it, the robot on the latch may be swapped
for another (``rebuild_latched``: the trial's conditions, a guide moved, another shim), as a
person sets the rig up before a trial. That is possible only while the robot is latched and
unloaded, i.e. the stage has not moved since the latch; the latching keeps its number.

Stage moves to a position (move_stage_to) are executed by the world, as the KDC101 executes
MOT_MOVE_ABSOLUTE: a trapezoidal profile that ends at rest exactly on the target.

Units at this interface are SI (s, m, N); inside, mantis_sim's g, mm, ms.
"""
from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
import math

import numpy as np

from .drive import CommandedPull
from .hybrid import HybridSimulator
from .model import SimulationError
from .scene import Scene

# Tension is evaluated exactly at every solver step and at least this often (ms), and linearly
# interpolated in between: slow phases are near-linear, fast ones have dense solver steps.
TENSION_GRID_MS = 2.5
DEFAULT_HISTORY_S = 2.0
SETTLE_AFTER_PEAK_MS = 20.0
# The stage counts as back at its start (the robot can be re-latched) this close to it.
RELATCH_TOLERANCE_MM = 0.01
KEPT_STRIKES = 8                # the truths of this many past strikes stay readable


class RobotInUse(SimulationError):
    """The latched robot cannot be rebuilt now (it is loaded, or not latched); says why."""


@dataclass(frozen=True)
class StrikeTruth:
    """What one latching of the robot did, on the rig's clock (s): the truth a simulated
    trial's analysis is judged against."""

    number: int
    phase_start_s: dict
    events: list
    peak_time_s: float

# Where the markers sit: (across, along) mm in the body frame (along = a->b), and in the arm
# frame (across, along the arm axis from b towards the tip). Like the real rig's five markers.
BODY_MARKERS_MM = {'mb1': (4.0, 8.0), 'mb2': (-3.0, 14.0), 'mb3': (6.0, 17.0)}
ARM_MARKERS_MM = {'ma1': (1.0, 7.0), 'ma2': (-1.0, 14.0)}
# The mechanism's frame (x towards the tendon guide, y up) seen by the camera: image y points
# down (left-handed, as the tracking software writes), origin at an arbitrary image point.
CAMERA_ORIGIN_MM = (-4.0, 9.0)


class World:
    def __init__(self, scene: Scene, history_s: float = DEFAULT_HISTORY_S,
                 relatch_scene: Callable[[int], Scene] | None = None,
                 operator_relatches: bool = True):
        self.scene = scene
        self.operator_relatches = operator_relatches
        self.history_s = history_s
        self._relatch_scene = relatch_scene or (lambda n: scene)
        self._drive = CommandedPull(scene.drive.acceleration_mm_per_s2 * 1e-6)
        self._start_position_mm = scene.drive.start_position_mm
        self._t_ms = 0.0
        self._strikes: list[_Strike] = [_Strike(scene, self._drive, 0.0)]
        self._past: deque[StrikeTruth] = deque(maxlen=KEPT_STRIKES)

    # --- time and the stage ---------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return self._t_ms * 1e-3

    @property
    def strikes(self) -> int:
        """How many times the robot was latched: 1 at the start, one more per re-latch."""
        return self._strikes[-1].number

    @property
    def held(self) -> bool:
        """True once the current strike's mechanism is held in its post-strike pose."""
        return self._current.held is not None

    @property
    def latched(self) -> bool:
        """Whether the robot is latched and loading: not yet struck, or re-latched."""
        return not self.held

    @property
    def _current(self) -> _Strike:
        return self._strikes[-1]

    @property
    def robot(self) -> Scene:
        """The scene of the robot of the current latching (``scene`` is the first one's)."""
        return self._current.scene

    # --- the robot on the latch -------------------------------------------------------------
    def rebuild_problem(self) -> str | None:
        """Why the latched robot cannot be rebuilt now, or None if it can: it must be latched
        and not loaded, i.e. the stage has not moved since the latch."""
        current = self._current
        if self.held:
            return (f'the robot of latching {current.number} has struck and is not latched '
                    f'again yet (the stage must rest back at its start first)')
        if self._stage_moved_since(current.t0_ms):
            return (f'the robot of latching {current.number} is loaded: the stage has moved '
                    f'since it was latched at t = {current.t0_ms * 1e-3:.3f} s (a trial has '
                    f'pulled on it)')
        return None

    def rebuild_latched(self, scene: Scene) -> None:
        """Put ``scene``'s robot on the latch in place of the current one, in its start pose,
        from now on: the same latching (its number kept), as a person sets the rig up before a
        trial. RobotInUse (saying why) unless the robot is latched and unloaded
        (:meth:`rebuild_problem`). The times before now stay the replaced robot's."""
        problem = self.rebuild_problem()
        if problem is not None:
            raise RobotInUse(f'cannot rebuild the latched robot: {problem}')
        current = self._current
        strike = _Strike(scene, self._drive, self._t_ms, current.number)
        if current.t0_ms == self._t_ms:      # nothing of the replaced robot to keep
            self._strikes[-1] = strike
        else:
            self._strikes.append(strike)

    def _stage_moved_since(self, t0_ms: float) -> bool:
        """Whether the stage moved (or is commanded to) at any time from t0_ms on."""
        knots = self._drive.knots
        first = max(bisect.bisect_right(knots, t0_ms, key=lambda k: k[0]) - 1, 0)
        return any(v != 0.0 or a != 0.0 for _, _, v, a in knots[first:])

    def set_stage_velocity(self, velocity_m_per_s: float) -> None:
        """Command the stage from now on (m/s equals mm/ms, the model's unit)."""
        self._drive.command(self._t_ms, float(velocity_m_per_s))
        self._current.drive_changed(self._t_ms)

    def move_stage_to(self, position_m: float, speed_m_per_s: float) -> None:
        """Move the stage to position_m at up to speed_m_per_s, ending at rest on the target."""
        target_mm = position_m * 1e3 - self._start_position_mm
        self._drive.move_to(self._t_ms, target_mm, abs(float(speed_m_per_s)))
        self._current.drive_changed(self._t_ms)

    def stage_position_m(self) -> float:
        return (self._start_position_mm + self._drive.pulled(self._t_ms)[0]) * 1e-3

    def stage_velocity_m_per_s(self) -> float:
        return self._drive.pulled(self._t_ms)[1]

    def advance_to(self, t_s: float) -> None:
        target = t_s * 1e3
        if target <= self._t_ms:
            return
        self._current.advance_to(target)
        self._t_ms = target
        if self._ready_to_relatch():
            if self.operator_relatches:
                self._relatch()
            elif self._current.free_from_ms is None:
                self._current.free_from_ms = self._t_ms
        self._forget_before(self._t_ms - self.history_s * 1e3)

    def _ready_to_relatch(self) -> bool:
        pulled_mm, velocity, _ = self._drive.pulled(self._t_ms)
        return self.held and velocity == 0.0 and abs(pulled_mm) <= RELATCH_TOLERANCE_MM

    def _relatch(self) -> None:
        self._past.append(self._current.truth())
        scene = self._relatch_scene(self.strikes + 1)
        self._strikes.append(_Strike(scene, self._drive, self._t_ms, self.strikes + 1))

    # --- the mechanism (the current strike's) ---------------------------------------------
    @property
    def phase(self) -> str:
        return self._current.sim.phase

    @property
    def phase_start_s(self) -> dict:
        return self._current.truth().phase_start_s

    @property
    def events(self) -> list:
        """(name, t_s) of every event of the current strike: unlatch, overcenter, peak, ..."""
        return self._current.truth().events

    @property
    def peak_time_s(self) -> float:
        return self._current.truth().peak_time_s

    @property
    def last_strike(self) -> StrikeTruth | None:
        """The truth of the latest latching that struck (the current one once it has peaked,
        else the one before the re-latch); None before any strike."""
        current = self._current.truth()
        if math.isfinite(current.peak_time_s):
            return current
        return self._past[-1] if self._past else None

    def tendon_force_N(self, times_s) -> np.ndarray:
        """True tendon tension at each time (within the kept history, not past time_s)."""
        times_ms = self._check_times(times_s)
        last = self._strikes[-1]
        if times_ms.size and times_ms.min() > last.t0_ms:
            # all in the current latching (the load cell's stream, block after block)
            return last.tendon_force_N(times_ms)
        forces = np.empty(times_ms.size)
        for strike, at in self._by_strike(times_ms):
            forces[at] = strike.tendon_force_N(times_ms[at])
        return forces

    def marker_positions_m(self, times_s) -> dict:
        """Marker positions (name -> (n, 2) m) in the camera frame at each time: the one place
        the markers leave the simulation's millimetres for SI (docs/data_path.md)."""
        th1, th3, l1_mm = self._pose(times_s)
        return {name: xy * 1e-3 for name, xy in self._markers_mm(th1, th3, l1_mm).items()}

    def joint_angles_rad(self, times_s) -> tuple[np.ndarray, np.ndarray]:
        """(theta1, theta3) at each time (within the kept history, not past time_s)."""
        th1, th3, _ = self._pose(times_s)
        return th1, th3

    # --- internals -------------------------------------------------------------------------
    def _pose(self, times_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(theta1, theta3, the body's L1 mm) at each time, each from the robot latched then."""
        times_ms = self._check_times(times_s)
        th1, th3, l1_mm = (np.empty(times_ms.size) for _ in range(3))
        for strike, at in self._by_strike(times_ms):
            th1[at], th3[at] = strike.joint_angles_rad(times_ms[at])
            l1_mm[at] = strike.mech.L1
        return th1, th3, l1_mm

    def _by_strike(self, times_ms: np.ndarray):
        """(strike, indices of the times that fall in it) for each strike that has some. The
        instant of a re-latch belongs to the strike before it: the new one is simulated only
        from there on."""
        starts = [strike.t0_ms for strike in self._strikes]
        index = np.searchsorted(starts, times_ms, side='left') - 1
        for i in np.unique(index):
            yield self._strikes[max(i, 0)], np.flatnonzero(index == i)

    def _check_times(self, times_s) -> np.ndarray:
        times_ms = np.atleast_1d(np.asarray(times_s, dtype=float)) * 1e3
        if times_ms.size == 0:
            return times_ms
        earliest = self._strikes[0].earliest_ms()
        latest = self._t_ms
        low, high = float(times_ms.min()), float(times_ms.max())
        if low < earliest - 1e-9 or high > latest + 1e-9:
            raise SimulationError(
                f'asked for the world at {low * 1e-3:.6f}..{high * 1e-3:.6f} s; it holds '
                f'{earliest * 1e-3:.6f}..{latest * 1e-3:.6f} s (history {self.history_s} s)')
        if low < earliest or high > latest:
            return np.clip(times_ms, earliest, latest)
        return times_ms

    @staticmethod
    def _markers_mm(th1: np.ndarray, th3: np.ndarray, l1_mm: np.ndarray) -> dict:
        """Marker positions (name -> (n, 2) mm, camera frame) for arrays of joint angles."""
        b = (l1_mm * np.cos(th1), l1_mm * np.sin(th1))
        frames = {'mb': ((0.0, 0.0), th1), 'ma': (b, th1 + math.pi - th3)}
        out = {}
        for name, (across, along) in {**BODY_MARKERS_MM, **ARM_MARKERS_MM}.items():
            origin, axis = frames[name[:2]]
            cos, sin = np.cos(axis), np.sin(axis)
            x = origin[0] + along * cos + across * sin
            y = origin[1] + along * sin - across * cos
            out[name] = np.column_stack([x + CAMERA_ORIGIN_MM[0], -y + CAMERA_ORIGIN_MM[1]])
        return out

    def _forget_before(self, t_ms: float) -> None:
        while len(self._strikes) > 1 and self._strikes[1].t0_ms < t_ms:
            del self._strikes[0]
        self._strikes[0].forget_before(t_ms)


class _StrikeDrive:
    """The stage as one strike's simulation sees it: on the strike's own clock (0 at its
    latch) and pulled from where the stage stood then."""

    def __init__(self, drive: CommandedPull, t0_ms: float):
        self.drive, self.t0_ms = drive, t0_ms
        self.x0_mm = drive.pulled(t0_ms)[0] if t0_ms > 0.0 else 0.0

    def pulled(self, t: float) -> tuple[float, float, float]:
        x, v, a = self.drive.pulled(t + self.t0_ms)
        return x - self.x0_mm, v, a

    def pulled_mm(self, times_ms: np.ndarray) -> np.ndarray:
        return self.drive.pulled_mm(np.asarray(times_ms) + self.t0_ms) - self.x0_mm

    def breakpoints(self) -> list[float]:
        return [t - self.t0_ms for t in self.drive.breakpoints() if t > self.t0_ms]


class _Strike:
    """One latching of the robot and what followed: its hybrid simulation (on its own clock,
    0 at the latch), and once it settled after the strike, the held pose. Times in and out are
    the world's, in ms."""

    def __init__(self, scene: Scene, drive: CommandedPull, t0_ms: float, number: int = 1):
        self.scene, self.t0_ms, self.number = scene, t0_ms, number
        self.drive = _StrikeDrive(drive, t0_ms)
        self.sim = HybridSimulator(scene, dense=True)
        self.sim.model.drive = self.drive
        self.sim.start()
        self.sim.stop_at = math.inf         # the rig runs until told otherwise
        self.mech = self.sim.model.mech
        self.held: _HeldPose | None = None
        self.free_from_ms: float | None = None   # world time the arm was left free (unlatched)
        self._tension_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def world_ms(self, t_ms: float) -> float:
        return t_ms + self.t0_ms

    def truth(self) -> StrikeTruth:
        run = self.sim.run_data
        return StrikeTruth(
            self.number, {k: self.world_ms(v) * 1e-3 for k, v in run.phase_start_ms.items()},
            [(name, self.world_ms(t) * 1e-3) for name, t, _ in run.events],
            self.world_ms(run.peak_time_ms) * 1e-3)

    def drive_changed(self, world_t_ms: float) -> None:
        if self.held is None:
            self.sim.drive_changed(world_t_ms - self.t0_ms)

    def advance_to(self, world_target_ms: float) -> None:
        if self.held is not None:
            return
        target = world_target_ms - self.t0_ms
        sim = self.sim
        peak = sim.run_data.peak_time_ms
        stop = min(target, peak + SETTLE_AFTER_PEAK_MS) if math.isfinite(peak) else target
        sim.advance(stop)
        peak = sim.run_data.peak_time_ms
        if math.isfinite(peak) and sim.t >= peak + SETTLE_AFTER_PEAK_MS:
            self._hold()

    def earliest_ms(self) -> float:
        segments = self.sim.run_data.segments
        return self.world_ms(segments[0].t[0] if segments else self.sim.t)

    def tendon_force_N(self, world_ms: np.ndarray) -> np.ndarray:
        times_ms = world_ms - self.t0_ms
        forces = np.empty(times_ms.size)
        moving = self._simulated(times_ms)
        if self.held is not None:
            forces[~moving] = self.held.balance(self.drive.pulled_mm(times_ms[~moving]))[1]
            forces[self._free(world_ms)] = 0.0
        segments = self.sim.run_data.segments
        simulated_ms = times_ms[moving]
        index = self._segment_index(simulated_ms)
        if index.size and index.min() == index.max():        # one segment: most blocks
            knots_t, knots_f = self._tension_knots(segments[index[0]])
            forces[moving] = np.interp(simulated_ms, knots_t, knots_f)
            return forces
        simulated = np.empty(index.size)
        for i in np.unique(index):
            knots_t, knots_f = self._tension_knots(segments[i])
            mask = index == i
            simulated[mask] = np.interp(simulated_ms[mask], knots_t, knots_f)
        forces[moving] = simulated
        return forces

    def joint_angles_rad(self, world_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times_ms = world_ms - self.t0_ms
        moving = self._simulated(times_ms)
        th1, th3 = np.empty(times_ms.size), np.empty(times_ms.size)
        if self.held is not None and not moving.all():
            pulled_mm = self.drive.pulled_mm(times_ms[~moving])
            if self.free_from_ms is not None:     # the free arm stays where it was left
                free = self._free(world_ms[~moving])
                pulled_mm[free] = self.drive.pulled_mm(self.free_from_ms - self.t0_ms)
            th1[~moving] = self.held.balance(pulled_mm)[0]
            th3[~moving] = self.held.th3
        segments = self.sim.run_data.segments
        index = self._segment_index(times_ms)
        for i in np.unique(index[moving]):
            seg = segments[i]
            at = np.flatnonzero(moving & (index == i))
            th1[at], th3[at] = seg.dense.angles(np.clip(times_ms[at], seg.t[0], seg.t[-1]))
        return th1, th3

    def forget_before(self, world_t_ms: float) -> None:
        t_ms = world_t_ms - self.t0_ms
        segments = self.sim.run_data.segments
        keep_from = 0
        while keep_from < len(segments) - 1 and segments[keep_from].t[-1] < t_ms:
            self._tension_cache.pop(id(segments[keep_from]), None)
            keep_from += 1
        del segments[:keep_from]

    def _simulated(self, times_ms: np.ndarray) -> np.ndarray:
        """Which times the integrated motion covers (the rest fall in the held pose)."""
        if self.held is None:
            return np.ones(times_ms.size, dtype=bool)
        return times_ms <= self.held.t_ms

    def _free(self, world_ms: np.ndarray) -> np.ndarray:
        """Which times fall after the arm was left free (the operator did not re-latch)."""
        if self.free_from_ms is None:
            return np.zeros(np.shape(world_ms), dtype=bool)
        return world_ms >= self.free_from_ms

    def _segment_index(self, times_ms: np.ndarray) -> np.ndarray:
        """The segment each time falls in (-1 before the first). Only the segments from the
        last one that starts at or before the earliest time are searched: the stream asks for
        the newest few of the many kept."""
        segments = self.sim.run_data.segments
        first = len(segments) - 1
        if times_ms.size:
            earliest = times_ms.min()
            while first > 0 and segments[first].t[0] > earliest:
                first -= 1
        first = max(first, 0)
        starts = [seg.t[0] for seg in segments[first:]]
        return np.searchsorted(starts, times_ms, side='right') - 1 + first

    def _hold(self) -> None:
        sim = self.sim
        seg = sim.run_data.segments[-1]
        tension = sim.dynamics_at(seg, sim.t, sim.state).tension_N
        self.held = _HeldPose(self.mech, sim.t, float(sim.state[0]), float(sim.state[1]),
                              tension, self.drive.pulled(sim.t)[0], sim.model.k_t,
                              self.scene.spring.k_Nmm_per_rad)

    def _tension_knots(self, seg) -> tuple[np.ndarray, np.ndarray]:
        key = id(seg)
        if key not in self._tension_cache:
            t0, t1 = seg.t[0], seg.t[-1]
            grid = np.arange(t0, t1, TENSION_GRID_MS)
            knots = np.union1d(seg.t, grid)
            forces = self.sim.tensions_at(seg, knots)
            self._tension_cache[key] = (knots, forces)
        return self._tension_cache[key]


class _HeldPose:
    """The arm held at th3 after the strike; the body in quasi-static balance, linearised about
    the pose at the hold.

    With the arm fixed, the torques on the body balance, F l_1(theta1) = k_s (rest - theta1) +
    tau0 (tau0: what the spring does not explain at the hold: gravity, the strike's residue),
    and the tendon stretches by its stiffness k_t. For a stage that has pulled dp further:
    dF = k dp with 1/k = 1/k_t + l_1^2 / (k_s + F l_11) (tendon in series with the spring as
    the linkage presents it), and the body turns by -(dp - dF/k_t)/l_1. Linearised on purpose:
    the exact balance runs into the body's toggle (l_1 -> 0, F -> inf) when the stage returns a
    few mm, a pose the real arm, which is not held, never reaches. A tension that would fall
    below zero is a slack tendon: zero.
    """

    def __init__(self, mech, t_ms: float, th1: float, th3: float, tension_N: float,
                 pulled_mm: float, k_tendon_N_per_mm: float, k_spring_Nmm_per_rad: float):
        self.t_ms, self.th1, self.th3 = t_ms, th1, th3
        self.tension_N, self.pulled_mm = max(tension_N, 0.0), pulled_mm
        self.k_t = k_tendon_N_per_mm
        tg = mech.tendon(th1, th3)
        self.l_1 = tg.d1
        linkage = k_spring_Nmm_per_rad + self.tension_N * tg.d11
        self.stiffness_N_per_mm = linkage / (linkage / self.k_t + self.l_1 ** 2)

    def balance(self, pulled_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta1 rad, tension N) for the stage pulled this far (mm, same origin as held)."""
        further = np.asarray(pulled_mm, dtype=float) - self.pulled_mm
        change = self.stiffness_N_per_mm * further
        th1 = self.th1 - (further - change / self.k_t) / self.l_1
        return th1, np.maximum(self.tension_N + change, 0.0)
