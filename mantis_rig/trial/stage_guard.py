"""The force ceiling at the stage: a Stage wrapped so that every pull is refused, and a pull in
flight stopped, once the tendon force it is fed reaches the ceiling or its readings grow stale.

One of the rig's safety limits (mantis_rig.trial.safety_limits holds the others and says
where each is enforced): the stage node wraps its stage in it and feeds it every force block,
so the ceiling holds in the driver's layer even if the supervisor is gone.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import logging
import math
import threading
import time
from typing import Optional, Union

import numpy as np

from mantis_rig.faults import ConfigurationError, DeviceError, SafetyLimitError
from mantis_rig.hardware.device_interfaces import (
    LOADCELL_CAPACITY_N,
    ForceBlock,
    Stage,
    StageInfo,
    StageLimits,
    StageState,
)

log = logging.getLogger(__name__)

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
