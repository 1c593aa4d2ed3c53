"""Simulated translation stage: its motion is the tendon drive of the simulated world.

The soft travel limits and the speed ceiling are enforced here as in the real driver: speeds
above the ceiling and targets outside the limits are refused, and a velocity move is stopped
by a watchdog thread before it leaves the soft limits. A stop is immediate (the controller's
abort). Moves to a position, and bounded velocity moves (a pull: ``move_at(v, bound_m)``), are
executed by the world, as the controller executes them: they end at rest on the target (the
bound), with nothing else commanding the stage. Positions are the world's stage positions; the
stage starts homed at drive.start_position_mm, as after the session's homing.
"""
from __future__ import annotations

import threading
import time

from mantis_rig.hardware.device_interfaces import (
    ConfigurationError,
    DeviceError,
    Stage,
    StageInfo,
    StageLimits,
    StageState,
)
from mantis_rig.simulated.world_port import WorldPort

HOME_POSITION_M = 0.0
HOMING_SPEED_M_PER_S = 2.0e-3
# A move is checked for arrival this often (simulated time); the world ends it on the target.
POLL_S = 0.002
ARRIVED_M = 1e-9
WALL_POLL_S = 0.001


class SimStage(Stage):
    def __init__(self, port: WorldPort, limits: StageLimits | None = None,
                 start_homed: bool = True):
        self.port = port
        self.limits = limits or StageLimits()
        self._homed = start_homed
        self._open = False
        self._lock = threading.Lock()
        self._velocity_cmd = 0.0
        self._limit_hit: tuple[bool, bool] = (False, False)
        self._watchdog: threading.Thread | None = None
        self._watchdog_done = threading.Event()   # ends the current limit watchdog
        self._stop_watch = threading.Event()      # ends the current move

    # --- life cycle ----------------------------------------------------------------------
    def open(self) -> None:
        self.port.now_s()
        self._open = True

    def close(self) -> None:
        if self._open:
            try:
                self.stop()
            finally:
                self._open = False

    def identify(self) -> StageInfo:
        self._require_open('identify')
        return StageInfo(model='simulated KDC101 + Z825B', serial_number='SIM-27000001',
                         firmware='mantis_sim')

    # --- motion ---------------------------------------------------------------------------
    def home(self, timeout_s: float = 60.0) -> None:
        self._require_open('home')
        self._drive_until(HOME_POSITION_M, HOMING_SPEED_M_PER_S, timeout_s)
        self._homed = True

    def move_to(self, position_m: float, speed_m_per_s: float, timeout_s: float = 60.0) -> None:
        self._require_open('move_to')
        self.limits.check_position(position_m)
        self.limits.check_speed(speed_m_per_s)
        self._require_homed('move_to')
        self._drive_until(position_m, abs(speed_m_per_s), timeout_s)

    def move_at(self, velocity_m_per_s: float, bound_m: float | None = None) -> None:
        """A velocity move, or with ``bound_m`` a bounded one that the world executes as the
        controller does: a move to the bound at this speed, ending at rest on it, whatever
        this stage (or the process that commands it) does after. Returns at once."""
        self._require_open('move_at')
        self.limits.check_speed(velocity_m_per_s)
        if velocity_m_per_s == 0.0:
            self.stop()
            return
        self._require_homed('move_at')
        position, _ = self.port.stage_state()
        limit = self._limit_towards(velocity_m_per_s)
        if (position - limit) * velocity_m_per_s >= 0:
            raise ConfigurationError(
                f'cannot move {"forward" if velocity_m_per_s > 0 else "in reverse"}: the stage '
                f'is at {position * 1e3:.4f} mm, at or beyond the soft travel limit '
                f'{limit * 1e3:.3f} mm')
        if bound_m is None:
            self._command(velocity_m_per_s)
            self._start_watchdog(velocity_m_per_s)
            return
        self.limits.check_bound(velocity_m_per_s, position, bound_m)
        self._watchdog_done.set()          # inside the soft limits: no watchdog needed
        self._limit_hit = (False, False)
        with self._lock:
            self._velocity_cmd = velocity_m_per_s
            self.port.move_stage_to(bound_m, abs(velocity_m_per_s))

    def stop(self) -> None:
        self._stop_watch.set()
        self._watchdog_done.set()
        self._command(0.0)

    def state(self) -> StageState:
        self._require_open('state')
        position, velocity = self.port.stage_state()
        forward, reverse = self._limit_hit
        return StageState(position_m=position, velocity_m_per_s=velocity,
                          moving=abs(velocity) > 0.0, homed=self._homed,
                          forward_limit=forward, reverse_limit=reverse)

    # --- internals ------------------------------------------------------------------------
    def _command(self, velocity_m_per_s: float) -> None:
        with self._lock:
            self._velocity_cmd = velocity_m_per_s
            self.port.set_stage_velocity(velocity_m_per_s)

    def _limit_towards(self, velocity: float) -> float:
        return self.limits.max_position_m if velocity > 0 else self.limits.min_position_m

    def _drive_until(self, target_m: float, speed: float, timeout_s: float) -> None:
        """Have the world move the stage to target_m (as the controller executes an absolute
        move) and wait until it rests there; a stop() meanwhile ends the move."""
        deadline = time.monotonic() + timeout_s
        self._stop_watch.clear()
        self._limit_hit = (False, False)       # a move to a position leaves the limit
        with self._lock:
            self._velocity_cmd = 0.0
            self.port.move_stage_to(target_m, speed)
        while True:
            position, velocity = self.port.stage_state()
            if abs(position - target_m) <= ARRIVED_M and velocity == 0.0:
                return
            if self._stop_watch.is_set():
                raise DeviceError(f'move to {target_m * 1e3:.4f} mm was stopped at '
                                  f'{position * 1e3:.4f} mm')
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.stop()
                raise DeviceError(f'simulated stage did not reach {target_m * 1e3:.4f} mm '
                                  f'within {timeout_s} s (at {position * 1e3:.4f} mm)')
            self.port.wait_until(self.port.now_s() + POLL_S, remaining)

    def _start_watchdog(self, velocity: float) -> None:
        # Each watchdog has an event of its own: a move clearing _stop_watch must not revive
        # a watchdog that was told to end (it would poll the world every ms for ever).
        self._watchdog_done.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=1.0)
        done = self._watchdog_done = threading.Event()
        limit = self._limit_towards(velocity)
        direction = 1.0 if velocity > 0 else -1.0
        margin_m = abs(velocity) * POLL_S

        def watch():
            while not done.wait(WALL_POLL_S):
                position, _ = self.port.stage_state()
                if (limit - position) * direction <= margin_m:
                    self._command(0.0)
                    self._limit_hit = (velocity > 0, velocity < 0)
                    return

        self._limit_hit = (False, False)
        self._watchdog = threading.Thread(target=watch, name='sim-stage-limits', daemon=True)
        self._watchdog.start()

    def _require_open(self, what: str) -> None:
        if not self._open:
            raise DeviceError(f'cannot {what}: the simulated stage is not open')

    def _require_homed(self, what: str) -> None:
        if not self._homed:
            raise DeviceError(f'cannot {what}: the stage is not homed')
