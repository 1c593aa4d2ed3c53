"""`mantis replay`: republish a trial bag with its original timing."""
from __future__ import annotations

import threading

from .options import err


def run_replay(args) -> int:
    import rclpy

    from mantis_rig.runtime.ros_env import claim_local_domain

    from ..replay import BagPlayer
    from ..replay.schedule import raise_priority

    claim_local_domain()
    if args.realtime:
        # Before rclpy.init: the DDS threads started there inherit the class, so a publish
        # does not wait on a lock held by a preempted ordinary-priority DDS thread.
        try:
            raise_priority()
        except OSError as exc:
            err('replay', f'warning: real-time scheduling refused ({exc}); playing at normal '
                           'priority')
    from rclpy.signals import SignalHandlerOptions

    from mantis_rig.runtime.lean_node import LeanNode
    from mantis_rig.runtime.stopping import StopRequested, StopSignals

    from ..contract import REPLAY_NODE
    signals = StopSignals('mantis replay').install()    # 130 / 143, not rclpy's handler
    rclpy.init(args=None, signal_handler_options=SignalHandlerOptions.NO)
    node = LeanNode(REPLAY_NODE)
    stop = threading.Event()
    relay = None
    try:
        if args.live:
            from ..live import LiveRelay
            relay = LiveRelay(args.live)
            print(f'live view: {relay.url} (Foxglove: Open connection, Foxglove WebSocket)',
                  flush=True)
        player = BagPlayer(node, args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
                           clock_hz=args.clock, realtime=args.realtime,
                           time_jumps=args.time_jumps)
        for problem in player.report.problems:
            err('replay', f'warning: {problem}; replaying the messages before the damage')
        if args.wait_for_subscribers > 0 and not player.wait_for_subscribers(
                args.wait_for_subscribers):
            err('replay', f'warning: not every topic had a subscriber after '
                           f'{args.wait_for_subscribers} s; playing anyway')
        try:
            # inside the try: a stop signal right after this line still ends with the report
            print(f'replaying {args.bag} at {args.rate:g}x real time (Ctrl-C stops)', flush=True)
            report = player.run(stop)
        except StopRequested:
            stop.set()
            report = player.report
            report.interrupted = True
        signals.shield()
        player.wait_for_delivery(timeout_s=2.0)
        print(report)
        if signals.first is not None:
            err('replay', f'{signals.first.reason}')
            return signals.first.exit_status
        if not sum(report.published.values()):
            err('replay', f'nothing was replayed from {args.bag}: no message to play'
                           f'{" on the topics asked for" if args.topics else ""}')
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


def add_commands(commands) -> None:
    replay = commands.add_parser(
        'replay', help='republish a trial bag with its original timing',
        description='Republish a recorded trial (loopback DDS, own domain unless '
                    'ROS_DOMAIN_ID is set) with its original relative timing.')
    replay.add_argument('bag', help='bag directory or .mcap file')
    replay.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1)')
    replay.add_argument('--loop', action='store_true', help='start again at the end')
    replay.add_argument('--live', metavar='[HOST:]PORT',
                        help='also serve the replayed topics to Foxglove over WebSocket '
                        '(foxglove-sdk; host 127.0.0.1 unless given)')
    replay.add_argument('--time-jumps', choices=('refuse', 'skip'), default='refuse',
                        help="a message whose log time lies outside the span the bag's "
                        'metadata.yaml states (a damaged time stamp): refuse the replay, naming '
                        'it (default), or skip such messages and list them in the report')
    replay.add_argument('--topics', nargs='+', metavar='TOPIC', help='only these topics')
    replay.add_argument('--clock', type=float, nargs='?', const=100.0, default=None,
                        metavar='HZ', help='publish /clock from the log times (default 100 Hz)')
    replay.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='SECONDS',
                        help='wait up to this long for a subscriber on every topic')
    replay.add_argument('--realtime', action='store_true',
                        help='play from a SCHED_FIFO thread (needs root or CAP_SYS_NICE): '
                             'keeps timing within ~1 ms on a busy machine')
    replay.set_defaults(run=run_replay)
