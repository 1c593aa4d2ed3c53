"""The `mantis` command line: `mantis <command> --help` for each command."""
from __future__ import annotations

import argparse
import sys

from mantis_sim.errors import InputError
from mantis_sim.model import SimulationError

from ..faults import RIG_FAULT, USAGE_ERROR, RigFault
from . import (
    analyze,
    control,
    day_state_command,
    doctor,
    import_tracking,
    real_strike_commands,
    recover_command,
    replay,
    sim,
    study,
    sweep_commands,
    track_command,
    trial_commands,
)

EXIT_STATUSES = f"""exit status:
  0    done
  1    the command ran but its result is a failure: a trial that did not end 'done', a
       refused trial in a batch, a simulation that could not be integrated
  {USAGE_ERROR}    bad input: an option, a file, a scene or a value that cannot be used (one line
       names it)
  {RIG_FAULT}    a rig fault: a device or the node stack failed (one line names it; the stage
       was stopped first)
  130  interrupted (Ctrl-C), 143 terminated: the stage stopped and the log closed
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='mantis', description=__doc__, epilog=EXIT_STATUSES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    sim.add_commands(commands)
    replay.add_commands(commands)
    import_tracking.add_commands(commands)
    track_command.add_commands(commands)
    analyze.add_commands(commands)
    recover_command.add_commands(commands)
    trial_commands.add_commands(commands)
    control.add_commands(commands)
    study.add_commands(commands)
    sweep_commands.add_commands(commands)
    doctor.add_commands(commands)
    real_strike_commands.add_commands(commands)
    day_state_command.add_commands(commands)
    return parser


def main(argv=None) -> int:
    """Run one command; the one place where its errors become a line and an exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    status = _run(args)
    if argv is None and getattr(args, 'end_process', False):
        # the command line's own `mantis trial` / `mantis bringup`: its stack is stopped, its
        # log closed and rclpy shut down; the interpreter's teardown would only cost CPU
        from mantis_rig.runtime.stopping import end_process
        end_process(status)
    return status


def _run(args) -> int:
    try:
        return args.run(args) or 0
    except InputError as exc:     # bad input, named in the message: one line, no traceback
        _say(f'mantis {args.command}: {exc}')
        return USAGE_ERROR
    except RigFault as exc:       # the device's or the stack's own words; the stage is stopped
        _say(f'mantis {args.command}: {exc}')
        return RIG_FAULT
    except SimulationError as exc:
        _say(f'mantis {args.command}: simulation failed: {exc}')
        return 1
    except KeyboardInterrupt:     # commands without a stage (sim, sweep, identify, ...)
        _say(f'mantis {args.command}: interrupted; what it writes at the end was not written')
        return 130


def _say(line: str) -> None:
    """One line on stderr in one write (node threads or processes may write there too)."""
    sys.stderr.write(line + '\n')
    sys.stderr.flush()


if __name__ == '__main__':
    sys.exit(main())
