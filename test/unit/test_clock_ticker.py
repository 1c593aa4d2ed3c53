"""ClockTicker: a periodic callback in a clock's time, from a thread of its own."""
import threading
import time

from rclpy.clock import ROSClock
from rclpy.time import Time

from mantis_rig.runtime.clock_ticker import ClockTicker


def simulated_clock(t_s: float = 0.0) -> ROSClock:
    clock = ROSClock()
    clock._set_ros_time_is_active(True)
    clock.set_ros_time_override(Time(nanoseconds=int(t_s * 1e9)))
    return clock


def wait_for(condition, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline
        time.sleep(0.001)


def test_it_ticks_once_per_period_of_simulated_time_and_skips_what_it_missed():
    clock, ticks = simulated_clock(), []
    ticker = ClockTicker(clock, 0.01, lambda: ticks.append(clock.now().nanoseconds), 'tick')
    try:
        time.sleep(0.2)
        assert ticks == [], 'simulated time has not moved: no tick'
        for step in range(1, 11):                 # the world's 10 ms steps
            clock.set_ros_time_override(Time(nanoseconds=step * 10_000_000))
            wait_for(lambda step=step: len(ticks) == step)
        clock.set_ros_time_override(Time(nanoseconds=500_000_000))    # a jump of 40 periods
        wait_for(lambda: len(ticks) == 11)
        time.sleep(0.1)
        assert len(ticks) == 11, 'the missed ticks are skipped, not run in a burst'
    finally:
        ticker.stop()


def test_stop_returns_although_the_clock_stands_still_and_from_within_a_tick():
    clock = simulated_clock(1.0)
    ticker = ClockTicker(clock, 0.01, lambda: None, 'idle')
    started = time.monotonic()
    ticker.stop()
    assert time.monotonic() - started < 1.0
    assert not ticker._thread.is_alive()

    stopped = threading.Event()
    holder = {}

    def tick():
        holder['ticker'].stop()
        stopped.set()

    holder['ticker'] = ClockTicker(clock, 0.01, tick, 'self-stop')
    clock.set_ros_time_override(Time(nanoseconds=2_000_000_000))
    assert stopped.wait(5.0)
    holder['ticker']._thread.join(5.0)
    assert not holder['ticker']._thread.is_alive()


def test_on_wall_time_it_ticks_at_its_period():
    """The real rig: the node clock is ROS time without an override (system time)."""
    clock, ticks = ROSClock(), []
    ticker = ClockTicker(clock, 0.02, lambda: ticks.append(clock.now().nanoseconds), 'wall')
    try:
        wait_for(lambda: len(ticks) >= 4)
    finally:
        ticker.stop()
    # on a grid of 20 ms (a late tick does not move the grid): never faster than the grid
    since_first_s = [(t - ticks[0]) * 1e-9 for t in ticks]
    assert all(s > (k - 1) * 0.02 for k, s in enumerate(since_first_s)), since_first_s


def test_a_backward_jump_starts_the_period_afresh():
    """As an rclpy timer: after the clock jumps back (a bag replayed, a clock reset) the next
    tick is one period after the new time, not when the clock regains the old due time."""
    clock, ticks = simulated_clock(10.0), []
    ticker = ClockTicker(clock, 0.01, lambda: ticks.append(clock.now().nanoseconds), 'back')
    try:
        clock.set_ros_time_override(Time(nanoseconds=10_010_000_000))
        wait_for(lambda: len(ticks) == 1)
        clock.set_ros_time_override(Time(nanoseconds=1_000_000_000))     # 9 s back
        clock.set_ros_time_override(Time(nanoseconds=1_010_000_000))
        wait_for(lambda: len(ticks) == 2)
        assert ticks[1] == 1_010_000_000
    finally:
        ticker.stop()
