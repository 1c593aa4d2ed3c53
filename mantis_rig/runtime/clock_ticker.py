"""A periodic callback on a node's clock, from a thread of its own instead of an rclpy timer.

An rclpy timer on a node spun by a MultiThreadedExecutor wakes that executor at every tick, and
every wake-up rebuilds the wait set in Python over all the entities of all its nodes (three
device nodes: about forty services). The stage's 100 Hz joint state cost the device executor
0.6 CPU s in a 7 s simulated trial; from a ClockTicker it costs the publishes alone.

The period is in the clock's time: simulated time when the clock follows the simulated world
(it is woken by each time update and otherwise only looks at its stop flag every CHECK_S of
wall time), wall time otherwise (it sleeps until the tick is due). Like an rclpy timer, it
skips ticks it could not keep up with rather than running them in a burst, and it starts its
period afresh when the clock jumps back or switches between simulated and system time.
"""
from __future__ import annotations

import sys
import threading

from rclpy.clock import ClockChange, JumpThreshold
from rclpy.duration import Duration

CHECK_S = 0.05          # longest wall-time wait: how soon a stop (or a missed update) is seen


class ClockTicker:
    def __init__(self, clock, period_s: float, tick, name: str):
        """Call tick() every period_s of `clock`'s time, the first one period from now."""
        self._clock = clock
        self._period_ns = int(round(period_s * 1e9))
        self._tick = tick
        self._wake = threading.Condition()
        self._stopped = False
        self._restart_at: int | None = None     # the clock's time (ns) at a jump back
        self._jumps = clock.create_jump_callback(
            JumpThreshold(min_forward=Duration(nanoseconds=1),
                          min_backward=Duration(nanoseconds=-1), on_clock_change=True),
            post_callback=self._on_time_update)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _on_time_update(self, jump) -> None:
        with self._wake:
            if (jump.delta.nanoseconds < 0
                    or jump.clock_change in (ClockChange.ROS_TIME_ACTIVATED,
                                             ClockChange.ROS_TIME_DEACTIVATED)):
                self._restart_at = self._clock.now().nanoseconds
            self._wake.notify()

    def _run(self) -> None:
        due = self._clock.now().nanoseconds + self._period_ns
        while True:
            with self._wake:
                if self._stopped:
                    return
                now = self._clock.now().nanoseconds
                if self._restart_at is not None:
                    due, self._restart_at = self._restart_at + self._period_ns, None
                if now < due:
                    # simulated time moves only by updates, which notify: a wall-time wait for
                    # the remaining simulated time would poll while the world holds still
                    simulated = getattr(self._clock, 'ros_time_is_active', False)
                    self._wake.wait(CHECK_S if simulated else min((due - now) * 1e-9, CHECK_S))
                    continue
            try:
                self._tick()
            except Exception as exc:       # noqa: BLE001 - as an executor would: report, go on
                print(f'{self._thread.name}: a tick failed: {exc!r}', file=sys.stderr,
                      flush=True)
            due += self._period_ns
            if due <= now:                 # behind: skip the missed ticks
                due = now + self._period_ns

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop ticking; waits for a tick in progress unless called from a tick."""
        with self._wake:
            self._stopped = True
            self._wake.notify()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        self._jumps.unregister()
