"""The simulated world in this process: a WorldPort over a World, and the thread that runs it.

WorldRunner advances the World by step_s of simulated time per tick, paced so that simulated
time runs real_time_factor times as fast as the wall clock (0 or inf: as fast as it can).
When a step takes longer than its share (the strike), simulated time slips behind instead of
catching up later: like ROS sim time, it is the world's clock, not the wall's.
Backends block in wait_until() on a condition the runner notifies after every step.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np

from mantis_rig.hardware.device_interfaces import DeviceError
from mantis_rig.simulated.world_port import WorldPort, WorldTimeout
from mantis_sim.world import World

HOLD_POLL_S = 0.002


class WorldRunner:
    def __init__(self, world: World, real_time_factor: float = 1.0, step_s: float = 0.01,
                 hold=None):
        """hold: optional callable; while it returns True the world waits before its next
        step (back-pressure from the world's consumers, sim_world_node)."""
        self.world = world
        self.real_time_factor = real_time_factor
        self.step_s = step_s
        self.hold = hold or (lambda: False)
        self.lock = threading.Condition()
        self.failure: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='world-runner', daemon=True)

    def start(self) -> WorldRunner:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=10.0)

    def step(self) -> None:
        """Advance by one step (also usable without the thread, for lock-step tests)."""
        with self.lock:
            self.world.advance_to(self.world.time_s + self.step_s)
            self.lock.notify_all()

    def _run(self) -> None:
        paced = 0.0 < self.real_time_factor < math.inf
        wall0, sim0 = time.monotonic(), self.world.time_s
        try:
            while not self._stop.is_set():
                if self.hold():
                    self._stop.wait(HOLD_POLL_S)
                    wall0, sim0 = time.monotonic(), self.world.time_s   # no catch-up burst
                    continue
                self.step()
                if paced:
                    due = wall0 + (self.world.time_s - sim0) / self.real_time_factor
                    delay = due - time.monotonic()
                    if delay > 0:
                        self._stop.wait(delay)
                    elif delay < -self.step_s / self.real_time_factor:
                        # Behind (the strike is costly): let simulated time slip rather than
                        # catch up in a burst that would starve the sensors' readers.
                        wall0, sim0 = time.monotonic(), self.world.time_s
                else:
                    time.sleep(0)             # let the backends' threads in
        except BaseException as exc:  # noqa: BLE001 - the world thread's boundary: its failure goes to every waiter
            with self.lock:
                self.failure = exc
                self.lock.notify_all()


class LocalWorldPort(WorldPort):
    def __init__(self, runner: WorldRunner):
        self.runner = runner
        self.world = runner.world

    def now_s(self) -> float:
        with self.runner.lock:
            return self.world.time_s

    def wait_until(self, t_s: float, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        with self.runner.lock:
            while self.world.time_s < t_s - 1e-12:
                if self.runner.failure is not None:
                    raise DeviceError(f'the simulated world failed: {self.runner.failure}')
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise WorldTimeout(
                        f'the simulated world is at {self.world.time_s:.4f} s; waited '
                        f'{timeout_s} s of wall time for {t_s:.4f} s')
                self.runner.lock.wait(remaining)

    def set_stage_velocity(self, velocity_m_per_s: float) -> None:
        with self.runner.lock:
            self.world.set_stage_velocity(velocity_m_per_s)

    def move_stage_to(self, position_m: float, speed_m_per_s: float) -> None:
        with self.runner.lock:
            self.world.move_stage_to(position_m, speed_m_per_s)

    def stage_state(self) -> tuple[float, float]:
        with self.runner.lock:
            return self.world.stage_position_m(), self.world.stage_velocity_m_per_s()

    def tendon_force(self, t0_s: float, period_s: float, n: int,
                     timeout_s: float) -> np.ndarray:
        times = t0_s + period_s * np.arange(n)
        if n:
            self.wait_until(times[-1], timeout_s)
        with self.runner.lock:
            try:
                return self.world.tendon_force_N(times)
            except Exception as exc:
                raise DeviceError(f'simulated load cell: {exc}') from exc

    def marker_frames(self, times_s: np.ndarray, timeout_s: float) -> dict:
        times_s = np.asarray(times_s, dtype=float)
        if times_s.size:
            self.wait_until(times_s.max(), timeout_s)
        with self.runner.lock:
            try:
                return self.world.marker_positions_m(times_s)
            except Exception as exc:
                raise DeviceError(f'simulated camera: {exc}') from exc

    def record_frames(self, frame_times_s: np.ndarray, tolerance_mm: float, timeout_s: float):
        frame_times_s = np.asarray(frame_times_s, dtype=float)
        if frame_times_s.size:      # one frame interval past the last: its exposure
            interval = frame_times_s[1] - frame_times_s[0] if frame_times_s.size > 1 else 1e-3
            self.wait_until(frame_times_s.max() + interval, timeout_s)
        from mantis_sim.camera.recorded_pose import record_frames
        from mantis_sim.camera.render import world_poses
        with self.runner.lock:          # the world stands still while its history is copied
            try:
                return record_frames(world_poses(self.world), frame_times_s, tolerance_mm,
                                     medium=self.world.robot.medium.name)
            except Exception as exc:
                raise DeviceError(f'simulated camera: recording the poses to film: {exc}') \
                    from exc
