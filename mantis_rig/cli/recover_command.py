"""`mantis recover`: rewrite a crashed/truncated bag into a valid one."""
from __future__ import annotations


def run_recover(args) -> int:
    from mantis_rig.recording import main_recover

    return main_recover([args.bag] + (['-o', args.output] if args.output else []))


def add_commands(commands) -> None:
    rec = commands.add_parser(
        'recover', help='rewrite a crashed/truncated bag into a valid one',
        description='Rewrite a crashed/truncated trial bag into a valid rosbag2 MCAP bag.')
    rec.add_argument('bag', help='bag directory (or its .mcap file)')
    rec.add_argument('-o', '--output', help='new bag directory (default: <bag>_recovered)')
    rec.set_defaults(run=run_recover)
