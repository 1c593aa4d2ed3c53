"""`mantis identify` and `mantis compare`: the simulated robot against real strikes.

Both read real strikes from a summary table (one row per strike: conditions and the lab's
values), with their recorded motion from processed records (`--processed DIR`, the authors'
`<trial>_data.csv.gz`, timed by the table's t_z1_s) and from tracker exports (`--export
TRIAL=PATH`, analysed by the rig's analysis: mantis_rig.analysis.strike_series). Each strike is
simulated with its group's scene (air_19mm, air_23mm, water_23mm by default) at its own guide
distance, contact angle and measured pull speed, on a local Dask cluster of this machine's cores
(`--workers`, `--scheduler`). The runs are the studies' (mantis_sim.studies.real_strikes:
identify_run, compare_run); this module turns the options into their calls and prints.
"""
from __future__ import annotations

import json
from pathlib import Path

from mantis_sim.errors import InputError
from mantis_sim.studies.real_strikes import compare_run, identify_run, spread_fit

from .options import check_out_folder, check_spread_request, json_safe
from .strike_options import (
    add_at_seat_option,
    add_strike_options,
    export_series,
    progress_line,
    strike_inputs,
)


def add_commands(commands) -> None:
    ident_cmd = commands.add_parser(
        'identify', help='fit scene parameters to real strikes; write calibrated scenes',
        description='Fit the scene parameters named by --fit to real strikes, each simulated '
                    'at its own conditions; write one calibrated scene per group with its '
                    'provenance, standard errors and correlations.')
    add_strike_options(ident_cmd)
    ident_cmd.add_argument('--fit', action='append', default=[],
                           metavar='KEY[@GROUP[+GROUP]][=LO:HI]',
                           help='a parameter to fit, for all groups or only the named ones, '
                                'within bounds (default: its valid range); repeatable')
    ident_cmd.add_argument('--spread', action='store_true',
                           help='also fit the spread of the strikes (where the arm sits by day '
                                'and by strike, the parameters\' uncertainty, the discrepancy: '
                                'docs/spread.md) and write it into each scene; without --fit, '
                                'the scenes\' parameters are kept as they are')
    ident_cmd.add_argument('--spread-latent', default=spread_fit.DEFAULT_LATENT,
                           metavar='KEY=LO:HI',
                           help='the scene key through which strikes of one design differ, '
                                f'within bounds (default {spread_fit.DEFAULT_LATENT})')
    ident_cmd.add_argument('--per-day', action='append', default=[],
                           metavar='KEY[@GROUP[+GROUP]][=LO:HI]',
                           help='also fit this key for each recording day on its own, as a '
                                'nuisance: a day\'s state (e.g. geometry.latch_offset_deg=-5:12) '
                                'kept in the provenance, not in the scene; a left-out day is '
                                'predicted at the scene\'s value; repeatable')
    ident_cmd.add_argument('--out', type=Path, required=True,
                           help='folder for the calibrated scenes (<group scene>.yaml)')
    ident_cmd.add_argument('--iterations', type=int, default=6,
                           help='most iterations of the optimiser, each the residuals of every '
                                'strike and, but for the last, their Jacobian (default 6)')
    ident_cmd.add_argument('--cross-validate', action='store_true',
                           help='also leave one recording day out at a time and report the '
                                'errors on the left-out days')
    ident_cmd.add_argument('--cv-iterations', type=int, default=0,
                           help='refit each left-out-day fit with at most this many Jacobian '
                                'evaluations; 0 (default): one Gauss-Newton step from the full '
                                'fit (one simulation of the left-out strikes per day)')
    ident_cmd.add_argument('--weight', action='append', default=[], metavar='NAME=VALUE',
                           help='weight of a kind of residual: tip_speed, spring_energy, '
                                'body_speed, arm_speed (relative errors), series (the recorded '
                                'motion); defaults in mantis_sim/studies/real_strikes/identify.py, '
                                'Weights')
    ident_cmd.add_argument('--loss', default='linear', metavar='linear|NAME:SCALE',
                           help='how residuals count: linear (least squares, the default) or '
                                'a robust loss, soft_l1, huber or cauchy, whose residuals '
                                'beyond SCALE count less than their square (SCALE in weighted-'
                                'residual units: a relative error at weight 1, e.g. '
                                'soft_l1:0.01)')
    add_at_seat_option(ident_cmd)
    ident_cmd.set_defaults(run=run_identify)

    compare = commands.add_parser(
        'compare', help='real strikes beside their simulations: figures and error tables',
        description='Simulate every strike of the table at its own conditions; write the '
                    'errors (errors.csv), parity plots (parity.png) and, for each --figure '
                    'trial with a recorded motion, its motion beside the simulated one.')
    add_strike_options(compare)
    compare.add_argument('--out', type=Path, default=Path('compare'),
                         help='folder for the outputs (default: compare/ here)')
    compare.add_argument('--figure', action='append', default=[], metavar='TRIAL',
                         help='a trial to plot (theta1, theta3 and rates); repeatable')
    compare.add_argument('--spread', type=int, default=0, metavar='N',
                         help='also forecast each strike from N robots drawn from its scene\'s '
                              'spread: predictions.csv (q05..q95 per strike), the coverage of '
                              'the 50 %% and 80 %% intervals and the CRPS against the '
                              'climatological forecast per group (spread_scores.csv), '
                              'forecasts.png')
    compare.add_argument('--seed', type=int, default=1,
                         help='seed of the robots drawn by --spread (default 1)')
    add_at_seat_option(compare)
    compare.set_defaults(run=run_compare)


def run_identify(args) -> int:
    request = identify_run.IdentifyRequest(
        inputs=strike_inputs(args), out=args.out, fit=tuple(args.fit), spread=args.spread,
        spread_latent=args.spread_latent, per_day=tuple(args.per_day),
        iterations=args.iterations, cross_validate=args.cross_validate,
        cv_iterations=args.cv_iterations, weights=tuple(args.weight), loss=args.loss,
        at_seat=args.at_seat)
    plan = identify_run.prepare_identification(request, export_series)
    check_out_folder(args.out)
    report = identify_run.run_identification(plan, log=progress_line)
    print(json.dumps(json_safe(report)) if args.json else identify_run.identify_text(report))
    return 0


def run_compare(args) -> int:
    request = compare_run.CompareRequest(
        inputs=strike_inputs(args), out=args.out, figures=tuple(args.figure),
        spread=args.spread, seed=args.seed, at_seat=args.at_seat)
    plan = compare_run.prepare_comparison(request, export_series)
    if args.spread:
        check_spread_request(args.spread, plan.scenes, per=' per strike')
        if args.at_seat:
            raise InputError('--spread draws where each arm sits from the scene\'s spread, '
                             'which --at-seat would set from the tracks: use one or the other')
    check_out_folder(args.out)
    report = compare_run.run_comparison(plan)
    print(json.dumps(json_safe(report)) if args.json else compare_run.compare_text(report))
    return 0
