"""`mantis day-state`: a recording day's own value of one scene key, from that day's strikes.

The identified scenes stand for the robot across days; strikes of one day share its assembly.
This fits one key (default where the arm sits on the latch, `geometry.latch_offset_deg`) to
each day's strikes with the rest of the scene held, reports each day's value and, with
`--cross-validate`, what the day's value predicts for a strike it did not see (leaving one
strike out within days);
`--out` writes today's robot as a scene per day (`<group>_<day>.yaml`). The run is the
studies' (mantis_sim.studies.real_strikes.day_state_run); this module turns the options into
its call and prints.
"""
from __future__ import annotations

import json
from pathlib import Path

from mantis_sim.studies.real_strikes import day_state as ds
from mantis_sim.studies.real_strikes import day_state_run

from .options import check_out_folder, json_safe
from .strike_options import add_strike_options, export_series, progress_line, strike_inputs


def add_commands(commands) -> None:
    cmd = commands.add_parser(
        'day-state', help="a recording day's own value of a scene key, from its strikes",
        description='Fit one scene key to each recording day\'s strikes, the rest of the '
                    'scene held: the day\'s own state (default: where the arm sits on the '
                    'latch). With '
                    '--cross-validate, leave one strike out within days and report what the '
                    'day\'s value predicts; with --out, write a scene per day.')
    add_strike_options(cmd)
    cmd.add_argument('--key', default=ds.DEFAULT_DAY_KEY, metavar='KEY[@GROUP[+GROUP]][=LO:HI]',
                     help=f'the scene key that differs by day (default {ds.DEFAULT_DAY_KEY}: '
                          f'where the arm sits on the latch; {ds.HOLD_KEY}, the pivot\'s hold, '
                          f'keeps the braking of the swing at the scene\'s)')
    cmd.add_argument('--iterations', type=int, default=5,
                     help='most Gauss-Newton iterations per day (default 5)')
    cmd.add_argument('--weight', action='append', default=[], metavar='NAME=VALUE',
                     help='weight of a kind of residual, as for `mantis identify`')
    cmd.add_argument('--cross-validate', action='store_true',
                     help='also predict each strike from its day\'s other strikes (a '
                          'one-step estimate of the day\'s value from the scene\'s, then '
                          'simulated)')
    cmd.add_argument('--out', type=Path, metavar='DIR',
                     help='write one scene per group and day, <group>_<day>.yaml, here')
    cmd.set_defaults(run=run_day_state)


def run_day_state(args) -> int:
    request = day_state_run.DayStateRequest(
        inputs=strike_inputs(args), key=args.key, iterations=args.iterations,
        weights=tuple(args.weight), cross_validate=args.cross_validate, out=args.out)
    plan = day_state_run.prepare_day_state(request, export_series)
    check_out_folder(args.out)
    report = day_state_run.run_day_state(plan, log=progress_line)
    print(json.dumps(json_safe(report)) if args.json else day_state_run.day_state_text(report))
    return 0
