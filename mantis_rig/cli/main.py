"""The `mantis` command line: `mantis <command> --help` for each command."""
from __future__ import annotations

import argparse
import sys

from mantis_sim.errors import InputError
from mantis_sim.model import SimulationError

from . import analyze, doctor, import_tracking, recover, replay, sim, sweep, trial
from .options import USAGE_ERROR


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='mantis', description=__doc__)
    commands = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    sim.add_commands(commands)
    replay.add_commands(commands)
    import_tracking.add_commands(commands)
    analyze.add_commands(commands)
    recover.add_commands(commands)
    trial.add_commands(commands)
    sweep.add_commands(commands)
    doctor.add_commands(commands)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args) or 0
    except InputError as exc:     # bad input, named in the message: one line, no traceback
        print(f'mantis {args.command}: {exc}', file=sys.stderr)
        return USAGE_ERROR
    except SimulationError as exc:
        print(f'mantis {args.command}: simulation failed: {exc}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
