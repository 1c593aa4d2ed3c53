"""Device interfaces of the rig: what a node may ask of a stage, a force DAQ and a camera trigger.

Every quantity is SI (m, s, N, V). Each device has a real backend (hardware) and a simulated
backend (driven by mantis_sim); nodes only see these interfaces. All devices are context
managers: leaving the `with` block releases the device even after an error.
"""
from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
import logging
import math
import threading
import time
from typing import Optional, Union

import numpy as np

# the device faults, under mantis_rig.faults.RigFault; imported from here by the backends
from mantis_rig.faults import ConfigurationError, DeviceError, SafetyLimitError

log = logging.getLogger(__name__)

# The rig's hardware envelope (shared/docs/rig.md): no configuration may go beyond it.
STAGE_TRAVEL_M = 25e-3                 # MTS25/M-Z8 travel, 0 at the home (reverse) end
STAGE_MAX_SPEED_M_PER_S = 2.4e-3       # MTS25/M-Z8 maximum speed
LOADCELL_CAPACITY_N = 111.0            # Futek LSB302, 25 lb


class Device(abc.ABC):
    """Common life cycle: open() acquires the device, close() releases it (idempotent)."""

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device (open the port or task) and check that it answers."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device. Safe to call twice and after a failed open()."""

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()
        return False


# --- translation stage -----------------------------------------------------------------------

@dataclass(frozen=True)
class StageInfo:
    model: str
    serial_number: str
    firmware: str


@dataclass(frozen=True)
class StageState:
    position_m: float
    velocity_m_per_s: float
    moving: bool
    homed: bool
    forward_limit: bool
    reverse_limit: bool
    fault: Optional[str] = None


@dataclass(frozen=True)
class StageLimits:
    """Safety envelope enforced inside the driver layer, whatever the caller asks."""

    min_position_m: float = 0.5e-3
    max_position_m: float = 24.5e-3
    max_speed_m_per_s: float = 2.4e-3
    max_acceleration_m_per_s2: float = 4.0e-3

    def __post_init__(self):
        """Refuse an envelope that is not inside the stage's travel and speed."""
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ConfigurationError(f'stage limit {f.name} {value!r} must be a finite number')
        travel_mm = STAGE_TRAVEL_M * 1e3
        if self.min_position_m < 0.0:
            raise ConfigurationError(
                f'soft travel limit min_position_m {self.min_position_m * 1e3:g} mm is outside '
                f'the stage travel [0, {travel_mm:g}] mm')
        if self.max_position_m > STAGE_TRAVEL_M:
            raise ConfigurationError(
                f'soft travel limit max_position_m {self.max_position_m * 1e3:g} mm is outside '
                f'the stage travel [0, {travel_mm:g}] mm')
        if not self.min_position_m < self.max_position_m:
            raise ConfigurationError(
                f'soft travel limits are empty: min_position_m {self.min_position_m * 1e3:g} mm '
                f'must be below max_position_m {self.max_position_m * 1e3:g} mm')
        if not 0.0 < self.max_speed_m_per_s <= STAGE_MAX_SPEED_M_PER_S:
            raise ConfigurationError(
                f'speed ceiling max_speed_m_per_s {self.max_speed_m_per_s * 1e3:g} mm/s must be '
                f'> 0 and at most the stage maximum {STAGE_MAX_SPEED_M_PER_S * 1e3:g} mm/s')
        if not self.max_acceleration_m_per_s2 > 0.0:
            raise ConfigurationError(
                f'max_acceleration_m_per_s2 {self.max_acceleration_m_per_s2 * 1e3:g} mm/s² '
                f'must be > 0 mm/s²')

    def check_position(self, position_m: float) -> None:
        if not (self.min_position_m <= position_m <= self.max_position_m):
            raise ConfigurationError(
                f'stage position {position_m * 1e3:.4f} mm is outside the soft travel limits '
                f'[{self.min_position_m * 1e3:.3f}, {self.max_position_m * 1e3:.3f}] mm')

    def check_bound(self, velocity_m_per_s: float, here_m: float, bound_m: float) -> None:
        """Refuse a bound for a move at velocity_m_per_s from here_m that is not ahead of the
        stage in the direction of travel, or not inside the soft limits."""
        self.check_position(bound_m)
        if (bound_m - here_m) * velocity_m_per_s <= 0:
            raise ConfigurationError(
                f'bound {bound_m * 1e3:.4f} mm of a move at {velocity_m_per_s * 1e3:+.4f} mm/s '
                f'is not ahead of the stage at {here_m * 1e3:.4f} mm')

    def check_speed(self, speed_m_per_s: float) -> None:
        if not (0.0 <= abs(speed_m_per_s) <= self.max_speed_m_per_s):
            raise ConfigurationError(
                f'stage speed {abs(speed_m_per_s) * 1e3:.4f} mm/s exceeds the ceiling '
                f'{self.max_speed_m_per_s * 1e3:.3f} mm/s')


class Stage(Device):
    """A linear translation stage. Positive velocity increases the position."""

    limits: StageLimits

    @abc.abstractmethod
    def identify(self) -> StageInfo: ...

    @abc.abstractmethod
    def home(self, timeout_s: float = 60.0) -> None:
        """Home and block until homed; raise DeviceError on timeout or fault."""

    @abc.abstractmethod
    def move_to(self, position_m: float, speed_m_per_s: float, timeout_s: float = 60.0) -> None:
        """Move to an absolute position at the given speed and block until it is reached."""

    @abc.abstractmethod
    def move_at(self, velocity_m_per_s: float, bound_m: Optional[float] = None) -> None:
        """Start moving at a constant velocity (sign gives direction); returns at once.

        With ``bound_m`` (a position ahead in the direction of travel, inside the soft limits)
        the move is a bounded one: the controller itself is told to stop there, as an absolute
        move at this speed that ends at rest on ``bound_m``, so that the stage stops there
        even if nothing commands it again (its driver's process dead). Without, the stage
        moves until stopped or until the driver's soft-limit check stops it."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop at once (abort). Never raises for an already stopped stage."""

    @abc.abstractmethod
    def state(self) -> StageState: ...


# --- force DAQ --------------------------------------------------------------------------------

@dataclass(frozen=True)
class DaqConfig:
    channel: str = 'Dev1/ai0'
    sample_rate_hz: float = 20_000.0
    input_range_v: float = 10.0
    newtons_per_volt: float = 11.12      # Futek IAA100 set to 10 V at 111 N (25 lb)
    offset_v: float = 0.0                # tare: the voltage read with the tendon slack
    block_size: int = 1000               # samples per read


@dataclass(frozen=True)
class ForceBlock:
    """A block of consecutive load-cell samples, SI: sample i [N] was taken at
    t0_s + i * period_s [s].

    The rig's one type of force data: a DAQ's read (device clock), and the same block on
    /loadcell/force_block and in bags (ROS time; recording.force_block carries it).
    """

    t0_s: float
    period_s: float
    force_n: np.ndarray
    first_index: Optional[int] = None    # index of the first sample since start() (DAQ reads)
    overrun: bool = False                 # samples were lost before this block

    @property
    def end_s(self) -> float:
        """The time one period after its last sample, s: where the next block starts."""
        return self.t0_s + self.period_s * self.force_n.size


class ForceDaq(Device):
    max_sample_rate_hz: float

    @abc.abstractmethod
    def configure(self, config: DaqConfig) -> None:
        """Validate and apply; raise ConfigurationError naming the value and the limit."""

    @abc.abstractmethod
    def start(self) -> None: ...

    @abc.abstractmethod
    def stop(self) -> None: ...

    @abc.abstractmethod
    def read_block(self, timeout_s: float = 1.0) -> ForceBlock:
        """The next block of `block_size` samples, in order, none skipped."""

    @abc.abstractmethod
    def tare(self, duration_s: float = 0.2) -> float:
        """Average the input for a while, make that zero force; return the new offset in V."""


# --- camera trigger -----------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraConfig:
    frame_rate_hz: float = 19_000.0
    pre_trigger_s: float = 0.05
    post_trigger_s: float = 0.05


@dataclass(frozen=True)
class CameraStatus:
    armed: bool
    triggered: bool
    trigger_time_s: Optional[float] = None


@dataclass
class MarkerFrames:
    """Marker positions per frame, SI: metres in the camera frame (the tracker's convention:
    left-handed, image y down, unless a bag's trial conditions say otherwise), times in
    seconds; a lost marker is NaN.

    The rig's one type of marker data: the simulated camera's recording (device clock), and
    the same frames on /camera/markers and in bags (ROS time; recording.marker_block carries
    them). The analysis reads them as MarkerTracks, in millimetres like the tracker's exports.
    """

    time_s: np.ndarray                     # (n,)
    markers_m: dict = field(default_factory=dict)    # name -> (n, 2) array; mb1..mb3, ma1, ma2

    def __len__(self) -> int:
        return len(self.time_s)


def check_camera_config(config: CameraConfig, max_frame_rate_hz: float) -> None:
    """Refuse a frame rate outside (0, max] and pre/post-trigger durations that are not >= 0."""
    rate_hz = config.frame_rate_hz
    if not rate_hz > 0:
        raise ConfigurationError(f'frame rate {rate_hz} frames/s must be > 0 frames/s')
    if rate_hz > max_frame_rate_hz:
        raise ConfigurationError(f'frame rate {rate_hz:g} frames/s exceeds the camera '
                                 f'ceiling {max_frame_rate_hz:g} frames/s')
    for name in ('pre_trigger_s', 'post_trigger_s'):
        value = getattr(config, name)
        if not (value >= 0 and math.isfinite(value)):
            raise ConfigurationError(f'{name} {value} s must be finite and ≥ 0 s')


class CameraTrigger(Device):
    max_frame_rate_hz: float

    @abc.abstractmethod
    def arm(self, config: CameraConfig) -> None: ...

    @abc.abstractmethod
    def trigger(self) -> float:
        """Fire the trigger now; return its time in seconds (device clock)."""

    @abc.abstractmethod
    def status(self) -> CameraStatus: ...

    def frame_timestamps(self) -> Optional[np.ndarray]:
        """Frame times in seconds where the hardware reports them, else None."""
        return None

    def marker_frames(self) -> Optional[MarkerFrames]:
        """Marker tracks of the recorded window where the backend has them (simulation)."""
        return None


# --- safety: the force ceiling at the stage -------------------------------------------------

ForceReading = Union[float, np.ndarray, ForceBlock]


def _check_force_ceiling(force_ceiling_n) -> None:
    if isinstance(force_ceiling_n, bool) or not (
            isinstance(force_ceiling_n, (int, float))
            and 0.0 < force_ceiling_n <= LOADCELL_CAPACITY_N):
        raise ConfigurationError(
            f'force ceiling {force_ceiling_n!r} N must be > 0 N and at most the load cell '
            f'capacity {LOADCELL_CAPACITY_N:g} N')


class StageGuard(Stage):
    """A Stage that stops the wrapped stage when the tendon force passes a ceiling.

    The stage driver cannot see the force, so the force reaches it here: whoever reads the
    load cell calls `observe_force()` with every reading (a ForceBlock in the process that owns
    the DAQ, the samples of each /loadcell/force_block message in the stage's process). A
    sample above `force_ceiling_n` (or a non-finite one) stops the stage at once and latches a
    trip: moves in the pull direction (`pull_direction`, +1: increasing position pulls) are
    then refused with SafetyLimitError until `clear_force_trip()`, which itself is refused
    while the latest reading is above the ceiling. Stop, home and moves that slacken the tendon
    stay allowed, so the stage can be returned. A move_to cut short by the trip raises
    SafetyLimitError.

    Blind pulls: with `max_force_age_s` (default 0.5 s) a pull needs a reading younger than
    that to start, and a watchdog thread (while open) stops a pull in progress, with a trip,
    when the readings stop coming: a dead load-cell reader must not leave the stage pulling.
    The watchdog also repeats the stop if a pull command raced a trip. `max_force_age_s=None`
    turns the freshness rule off (the ceiling then holds only while readings arrive).
    """

    def __init__(self, stage: Stage, force_ceiling_n: float, *, pull_direction: int = 1,
                 max_force_age_s: Optional[float] = 0.5,
                 clock_s: Callable[[], float] = time.monotonic,
                 watchdog_period_s: float = 0.02):
        _check_force_ceiling(force_ceiling_n)
        if pull_direction not in (1, -1):
            raise ConfigurationError(f'pull direction {pull_direction!r} must be +1 or -1')
        if max_force_age_s is not None and not (max_force_age_s > 0
                                                and math.isfinite(max_force_age_s)):
            raise ConfigurationError(
                f'max_force_age_s {max_force_age_s!r} s must be finite and > 0 s (or None)')
        if not watchdog_period_s > 0:
            raise ConfigurationError(f'watchdog period {watchdog_period_s!r} s must be > 0 s')
        self.stage = stage
        self.force_ceiling_n = float(force_ceiling_n)
        self.pull_direction = pull_direction
        self.max_force_age_s = max_force_age_s
        self._clock_s = clock_s
        self._watchdog_period_s = watchdog_period_s
        self._lock = threading.Lock()
        self._trip: Optional[SafetyLimitError] = None
        self._trips = 0                  # trips so far: a move compares it before and after
        self._restopped = False          # the watchdog repeated the stop for the current trip
        self._pull_active = False        # a pull was admitted and has not ended
        self._pull_call_trips: Optional[int] = None   # trip count when the blocking pull call
        #                                               (move_to, home) in progress was admitted
        self._last_force_n: Optional[float] = None
        self._last_force_time_s: Optional[float] = None
        self._watchdog: Optional[threading.Thread] = None
        self._stop_watchdog = threading.Event()

    @property
    def limits(self) -> StageLimits:
        return self.stage.limits

    @property
    def tripped(self) -> Optional[SafetyLimitError]:
        """The latched trip, or None."""
        with self._lock:
            return self._trip

    # --- life cycle -------------------------------------------------------------------------

    def open(self) -> None:
        self.stage.open()
        if self._watchdog is None:
            self._stop_watchdog.clear()
            self._watchdog = threading.Thread(target=self._watch, daemon=True,
                                              name='stage-guard watchdog')
            self._watchdog.start()

    def close(self) -> None:
        self._stop_watchdog.set()
        watchdog, self._watchdog = self._watchdog, None
        if watchdog is not None and watchdog is not threading.current_thread():
            watchdog.join(timeout=5.0)
            if watchdog.is_alive():
                log.error('stage guard watchdog did not stop')
        with self._lock:
            self._pull_active = False
        self.stage.close()

    # --- the force path -----------------------------------------------------------------------

    def set_force_ceiling(self, force_ceiling_n: float) -> None:
        """A new ceiling, in force from the next reading on."""
        _check_force_ceiling(force_ceiling_n)
        with self._lock:
            self.force_ceiling_n = float(force_ceiling_n)

    def observe_force(self, force: ForceReading) -> Optional[SafetyLimitError]:
        """Take force readings (N): a number, an array of samples or a ForceBlock. Returns the
        SafetyLimitError if this reading tripped the ceiling (the stage is then stopped)."""
        samples = np.asarray(force.force_n if isinstance(force, ForceBlock) else force,
                             dtype=np.float64).ravel()
        if samples.size == 0:
            return None
        finite = np.isfinite(samples)
        if not finite.all():
            bad = float(samples[~finite][0])
            reason = (f'non-finite force reading {bad} N: the force ceiling '
                      f'{self.force_ceiling_n:g} N cannot be checked')
            peak = math.inf
        else:
            peak = float(samples.max())
            reason = (f'force {peak:.3f} N above the ceiling {self.force_ceiling_n:g} N')
        with self._lock:
            self._last_force_n = peak
            self._last_force_time_s = self._clock_s()
        if peak > self.force_ceiling_n:
            return self._trip_now(reason)
        return None

    def clear_force_trip(self) -> None:
        """Re-allow pulls after a trip; refused while the latest reading is above the ceiling."""
        with self._lock:
            last = self._last_force_n
            if self._trip is not None and last is not None and last > self.force_ceiling_n:
                raise SafetyLimitError(
                    f'force trip not cleared: the latest force {last:.3f} N is still above the '
                    f'ceiling {self.force_ceiling_n:g} N')
            self._trip = None
            self._restopped = False

    def _trip_now(self, reason: str) -> Optional[SafetyLimitError]:
        with self._lock:
            first = self._trip is None
            if first:
                self._trip = SafetyLimitError(f'{reason}; stage stopped')
                self._trips += 1
                self._restopped = False
                self._pull_active = False
            trip = self._trip
        if not first:        # already stopped for this trip; slackening moves stay allowed
            return None
        log.error('stage guard: %s', trip)
        try:
            self.stage.stop()
        except DeviceError as exc:   # nothing more can be done here: say so loudly
            log.error('stage guard: stopping the stage after "%s" failed: %s', reason, exc)
        return trip

    def _fresh_force_problem(self) -> Optional[str]:
        """Called with the lock held: why the force readings are too old to pull, or None."""
        if self.max_force_age_s is None:
            return None
        if self._last_force_time_s is None:
            return (f'no force reading yet: the force ceiling {self.force_ceiling_n:g} N '
                    f'cannot be enforced')
        age_s = self._clock_s() - self._last_force_time_s
        if age_s > self.max_force_age_s:
            return (f'no force reading for {age_s:.2f} s (limit {self.max_force_age_s:g} s): '
                    f'the force ceiling {self.force_ceiling_n:g} N cannot be enforced')
        return None

    def _admit_pull(self, what: str, blocking: bool = False) -> int:
        """Refuse a pull while tripped or blind; mark it active; return the trip count."""
        with self._lock:
            if self._trip is not None:
                raise SafetyLimitError(f'{what} refused: {self._trip} (clear_force_trip() '
                                       f'once the force is below the ceiling)')
            problem = self._fresh_force_problem()
            if problem is not None:
                raise SafetyLimitError(f'{what} refused: {problem}')
            self._pull_active = True
            if blocking:
                self._pull_call_trips = self._trips
            return self._trips

    def _after_pull(self, trips_before: int, keep_active: bool) -> None:
        """After a pull command: if a trip happened meanwhile, stop (again) and raise."""
        with self._lock:
            trip = self._trip if self._trips != trips_before else None
            self._pull_call_trips = None
            if trip is not None or not keep_active:
                self._pull_active = False
        if trip is not None:
            try:
                self.stage.stop()
            except DeviceError as exc:
                log.error('stage guard: repeated stop failed: %s', exc)
            raise SafetyLimitError(str(trip))

    def _watch(self) -> None:
        while not self._stop_watchdog.wait(self._watchdog_period_s):
            with self._lock:
                active = self._pull_active
                # a blocking pull admitted before the latest trip is still running: its move
                # command may have reached the controller after the trip's stop, so stop again
                call_trips = self._pull_call_trips
                restop = (call_trips is not None and call_trips != self._trips
                          and not self._restopped)
                if restop:
                    self._restopped = True
                stale = (active and self._trip is None
                         and self._fresh_force_problem())
            try:
                if restop:
                    self.stage.stop()
                elif stale:
                    if self.stage.state().moving:
                        self._trip_now(stale)
                    else:
                        with self._lock:
                            self._pull_active = False
            except DeviceError as exc:   # the driver failed and closed itself: nothing to stop
                log.error('stage guard watchdog: %s', exc)
                with self._lock:
                    self._pull_active = False

    # --- Stage --------------------------------------------------------------------------------

    def identify(self) -> StageInfo:
        return self.stage.identify()

    def home(self, timeout_s: float = 60.0) -> None:
        if self.pull_direction > 0:        # homing runs to the reverse end: it slackens
            self.stage.home(timeout_s)
            return
        trips = self._admit_pull('homing', blocking=True)
        try:
            self.stage.home(timeout_s)
        finally:
            self._after_pull(trips, keep_active=False)

    def move_to(self, position_m: float, speed_m_per_s: float, timeout_s: float = 60.0) -> None:
        self.limits.check_position(position_m)
        self.limits.check_speed(speed_m_per_s)
        here_m = self.stage.state().position_m
        if (position_m - here_m) * self.pull_direction <= 0:
            self._end_pull()
            self.stage.move_to(position_m, speed_m_per_s, timeout_s)
            return
        trips = self._admit_pull(f'move to {position_m * 1e3:.4f} mm', blocking=True)
        try:
            self.stage.move_to(position_m, speed_m_per_s, timeout_s)
        except BaseException:
            self._after_pull(trips, keep_active=False)   # a trip's SafetyLimitError wins
            raise
        self._after_pull(trips, keep_active=False)

    def move_at(self, velocity_m_per_s: float, bound_m: Optional[float] = None) -> None:
        self.limits.check_speed(velocity_m_per_s)
        if velocity_m_per_s * self.pull_direction <= 0:
            self._end_pull()
            self.stage.move_at(velocity_m_per_s, bound_m)
            return
        trips = self._admit_pull(f'velocity move at {velocity_m_per_s * 1e3:+.4f} mm/s')
        try:
            self.stage.move_at(velocity_m_per_s, bound_m)
        except BaseException:
            self._after_pull(trips, keep_active=False)
            raise
        self._after_pull(trips, keep_active=True)

    def stop(self) -> None:
        self._end_pull()
        self.stage.stop()

    def _end_pull(self) -> None:
        with self._lock:
            self._pull_active = False

    def state(self) -> StageState:
        state = self.stage.state()
        trip = self.tripped
        if trip is None:
            return state
        return replace(state, fault='; '.join(filter(None, [state.fault, str(trip)])))
