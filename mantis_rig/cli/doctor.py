"""`mantis doctor`: find the rig's devices and check them before the first trial.

Checks, in this order, each OK / WARN / FAIL with what it found and, unless OK, the fix in one
line: the ROS environment (domain, discovery range, middleware) and the free disk space where
trials are written; the NI DAQ devices (hardware); the load cell (the channel exists on the
device, 1 s at rest at the trial's rate: offset, noise, overruns, saturation); the camera
trigger (the line or counter exists and a test pulse is written: nothing is wired back to see
it arrive); the stage (which port and why, identity and firmware and how its status arrives:
streamed, or polled because the controller does not stream; the stage type and travel, the
limits the software enforces); with --move only, the stage homes, moves to 0.1 mm inside the
lower soft limit, jogs 1 mm at 0.5 mm/s and comes back there, guarded by the force ceiling fed
from the load cell (without a working load cell it does not move).

`--backend sim` runs the same checks against the simulated rig's devices (a world of the
params' scene in this process). Exit 0 when nothing FAILs, 1 otherwise; `--json` prints the
report as JSON. Nothing moves without --move; every device is closed, every DAQ task, thread
and the simulated world ended, before the command returns, whatever failed.
"""
from __future__ import annotations

from dataclasses import asdict
import json
from pathlib import Path

from ..commissioning.check_report import FAIL, OK, WARN, Options
from ..commissioning.checks import run_checks
from ..commissioning.rig_params import load_params


def add_commands(commands) -> None:
    from ..contract import BACKENDS
    doctor = commands.add_parser(
        'doctor', help='find the rig\'s devices and check them before a trial',
        description=__doc__.split('\n\n')[0])
    doctor.add_argument('--backend', choices=BACKENDS, default='hardware',
                        help='hardware (default): the KDC101 and the NI DAQ; sim: the '
                             'simulated rig')
    doctor.add_argument('--params', type=Path, metavar='FILE',
                        help='the stack\'s ROS 2 parameters file (a section per node; '
                             'docs/commissioning.md)')
    doctor.add_argument('--move', action='store_true',
                        help='also home the stage and jog it 1 mm at 0.5 mm/s and back '
                             '(nothing moves without it)')
    doctor.add_argument('--json', action='store_true', help='print the report as JSON')
    doctor.set_defaults(run=run)


def run(args) -> int:
    options = Options(backend=args.backend, params=load_params(args.params), move=args.move)
    report = run_checks(options)
    if args.json:
        print(json.dumps({'backend': options.backend, 'params': options.params.source,
                          'moved': report.moved, 'stage_status': report.stage_status,
                          'counts': report.counts(),
                          'ok': not report.failed,
                          'checks': [asdict(c) for c in report.checks]}, indent=2))
    else:
        print(f'mantis doctor: backend {options.backend}, parameters {options.params.source}')
        for check in report.checks:
            print(check.line())
        counts = report.counts()
        moved = '' if options.move else '; the stage was not moved (--move to home and jog it)'
        print(f'{counts[OK]} OK, {counts[WARN]} WARN, {counts[FAIL]} FAIL{moved}')
    return 1 if report.failed else 0


__all__ = ['add_commands', 'run']
