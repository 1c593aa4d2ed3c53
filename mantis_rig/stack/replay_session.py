"""A bag replayed on ROS (`mantis replay`): a node of its own publishing the bag's messages with
their original timing, optionally to the live view, until the end or Ctrl-C."""
from __future__ import annotations

from dataclasses import dataclass
import threading

from mantis_rig.contract import REPLAY_NODE
from mantis_rig.replay.player import BagPlayer
from mantis_rig.replay.schedule import raise_priority
from mantis_rig.runtime.lean_node import LeanNode
from mantis_rig.runtime.ros_env import claim_local_domain
from mantis_rig.runtime.stopping import StopRequested, StopSignals


@dataclass(frozen=True)
class ReplayOptions:
    """How to replay: the speed factor, looping, which topics (None: all), /clock's rate (Hz,
    None: none), from a real-time thread, what to do with a damaged time stamp ('refuse' or
    'skip'), how long to wait for subscribers (s), and the live view's [HOST:]PORT."""

    rate: float = 1.0
    loop: bool = False
    topics: tuple | None = None
    clock: float | None = None
    realtime: bool = False
    time_jumps: str = 'refuse'
    wait_for_subscribers: float = 0.0
    live: str | None = None


def replay_on_ros(bag, options: ReplayOptions, warn) -> int:
    """Republish ``bag`` in a ROS session of its own (a domain of its own unless ROS_DOMAIN_ID
    is set; Ctrl-C stops it with the report); ``warn(line)`` says what the user should know.
    The exit status: 0 replayed, 1 nothing to replay, 130/143 interrupted."""
    import rclpy


    claim_local_domain()
    if options.realtime:
        # Before rclpy.init: the DDS threads started there inherit the class, so a publish
        # does not wait on a lock held by a preempted ordinary-priority DDS thread.
        try:
            raise_priority()
        except OSError as exc:
            warn(f'warning: real-time scheduling refused ({exc}); playing at normal '
                           'priority')
    from rclpy.signals import SignalHandlerOptions
    signals = StopSignals('mantis replay').install()    # 130 / 143, not rclpy's handler
    rclpy.init( signal_handler_options=SignalHandlerOptions.NO)
    node = LeanNode(REPLAY_NODE)
    stop = threading.Event()
    relay = None
    try:
        if options.live:
            from mantis_rig.live import LiveRelay
            relay = LiveRelay(options.live)
            print(f'live view: {relay.url} (Foxglove: Open connection, Foxglove WebSocket)',
                  flush=True)
        player = BagPlayer(node, bag, rate=options.rate, loop=options.loop, topics=options.topics,
                           clock_hz=options.clock, realtime=options.realtime,
                           time_jumps=options.time_jumps)
        for problem in player.report.problems:
            warn(f'warning: {problem}; replaying the messages before the damage')
        if options.wait_for_subscribers > 0 and not player.wait_for_subscribers(
                options.wait_for_subscribers):
            warn(f'warning: not every topic had a subscriber after '
                           f'{options.wait_for_subscribers} s; playing anyway')
        try:
            # inside the try: a stop signal right after this line still ends with the report
            print(f'replaying {bag} at {options.rate:g}x real time (Ctrl-C stops)', flush=True)
            report = player.run(stop)
        except StopRequested:
            stop.set()
            report = player.report
            report.interrupted = True
        signals.shield()
        player.wait_for_delivery(timeout_s=2.0)
        print(report)
        if signals.first is not None:
            warn(f'{signals.first.reason}')
            return signals.first.exit_status
        if not sum(report.published.values()):
            warn(f'nothing was replayed from {bag}: no message to play'
                           f'{" on the topics asked for" if options.topics else ""}')
            return 1
        return 0
    except StopRequested as stop_requested:       # while setting up, before the playback
        return stop_requested.exit_status
    finally:
        signals.shield()
        if relay is not None:
            relay.close()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


__all__ = ['ReplayOptions', 'replay_on_ros']
