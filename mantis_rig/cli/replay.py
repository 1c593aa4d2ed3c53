"""`mantis replay`: republish a trial bag with its original timing."""
from __future__ import annotations

from .options import err


def run_replay(args) -> int:
    from mantis_rig.stack.replay_session import ReplayOptions, replay_on_ros
    options = ReplayOptions(rate=args.rate, loop=args.loop, topics=args.topics,
                            clock=args.clock, realtime=args.realtime,
                            time_jumps=args.time_jumps,
                            wait_for_subscribers=args.wait_for_subscribers, live=args.live)
    return replay_on_ros(args.bag, options, lambda line: err('replay', line))


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
