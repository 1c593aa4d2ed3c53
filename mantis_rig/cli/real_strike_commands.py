"""`mantis identify` and `mantis compare`: the simulated robot against real strikes.

Both read real strikes from a summary table (one row per strike: conditions and the lab's
values), with their recorded motion from processed records (`--processed DIR`, the authors'
`<trial>_data.csv.gz`, timed by the table's t_z1_s) and from tracker exports (`--export
TRIAL=PATH`, analysed here). Each strike is simulated with its group's scene (air_19mm,
air_23mm, water_23mm by default) at its own guide distance, contact angle and measured pull
speed, on a local Dask cluster of this machine's cores (`--workers`, `--scheduler`).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
import sys

import yaml

from mantis_rig.cli.options import (
    add_cluster_options,
    check_out_folder,
    check_spread_request,
    json_safe,
)
from mantis_sim.errors import InputError
from mantis_sim.scene import available_scenes, load_scene
from mantis_sim.studies.real_strikes import fidelity, forecast, spread_fit
from mantis_sim.studies.real_strikes import identify as ident
from mantis_sim.studies.real_strikes.strikes import (
    RECORD_WINDOW_S,
    RealStrike,
    StrikeDataError,
    StrikeSeries,
    read_strikes,
)
from mantis_sim.studies.shared.csv_table import write_rows
from mantis_sim.studies.shared.parallel import ClusterMap


def add_commands(commands) -> None:
    ident_cmd = commands.add_parser(
        'identify', help='fit scene parameters to real strikes; write calibrated scenes',
        description='Fit the scene parameters named by --fit to real strikes, each simulated '
                    'at its own conditions; write one calibrated scene per group with its '
                    'provenance, standard errors and correlations.')
    _strike_arguments(ident_cmd)
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
    _at_seat_argument(ident_cmd)
    ident_cmd.set_defaults(run=run_identify)

    compare = commands.add_parser(
        'compare', help='real strikes beside their simulations: figures and error tables',
        description='Simulate every strike of the table at its own conditions; write the '
                    'errors (errors.csv), parity plots (parity.png) and, for each --figure '
                    'trial with a recorded motion, its motion beside the simulated one.')
    _strike_arguments(compare)
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
    _at_seat_argument(compare)
    compare.set_defaults(run=run_compare)


def _at_seat_argument(parser) -> None:
    parser.add_argument('--at-seat', action='store_true',
                        help='latch each simulated arm where its strike\'s tracks show it at '
                             'overcentering (the table\'s seat_deg, or the processed record at '
                             'the table\'s t_oc_s) rather than at the recorded contact angle; '
                             'strikes without a seat stay at the contact angle and are listed')


def _strike_arguments(parser) -> None:
    parser.add_argument('--strikes', type=Path, required=True,
                        help='summary table (CSV): trial, medium, d_t_mm, contact_angle_deg, '
                             'pull_measured_mm_s, and v_max_mps, PE_max_mJ, ... as measured')
    parser.add_argument('--processed', type=Path,
                        help='folder of processed records <trial>_data.csv[.gz] (phase IV '
                             'from the table\'s t_z1_s)')
    parser.add_argument('--export', action='append', default=[], metavar='TRIAL=PATH',
                        help='a tracker export (.xlsx, .csv) of the table\'s strike TRIAL')
    parser.add_argument('--scene', action='append', default=[], metavar='GROUP=SCENE',
                        help='the scene of a group of strikes (default: the group\'s name, '
                             'e.g. air_23mm); repeatable')
    parser.add_argument('--group', action='append', default=[],
                        help='use only the strikes of this group (air_19mm, ...); repeatable')
    add_cluster_options(parser)
    parser.add_argument('--json', action='store_true', help='print the result as JSON')


def _load_strikes(args) -> list[RealStrike]:
    strikes = read_strikes(args.strikes, args.processed)
    by_trial = {s.trial: i for i, s in enumerate(strikes)}
    for text in args.export:
        trial, sep, path = text.partition('=')
        if not sep or trial not in by_trial:
            raise StrikeDataError(f'--export {text}: expected TRIAL=PATH with TRIAL a trial of '
                                  f'{args.strikes}')
        i = by_trial[trial]
        strikes[i] = strikes[i].with_series(_export_series(Path(path), strikes[i]), path)
    if args.group:
        unknown = sorted(set(args.group) - {s.group for s in strikes})
        if unknown:
            raise StrikeDataError(f'--group {", ".join(unknown)}: no such strikes in '
                                  f'{args.strikes} (groups: '
                                  f'{", ".join(sorted({s.group for s in strikes}))})')
        strikes = [s for s in strikes if s.group in args.group]
    return strikes


def _export_series(path: Path, strike: RealStrike) -> StrikeSeries:
    """The strike's motion from a tracker export, by the rig's own analysis."""
    from mantis_rig.analysis import AnalysisParams, analyze_tracks, load_tracks
    if not path.exists():
        raise StrikeDataError(f'--export {path}: no such file')
    analysis = analyze_tracks(load_tracks(path), AnalysisParams(
        d_t_mm=strike.d_t_mm, contact_angle_rad=math.radians(strike.contact_angle_deg)))
    t_iv = analysis.phases.max_contraction_s
    return StrikeSeries(analysis.time_s - t_iv, analysis.theta1_rad,
                        analysis.theta3_rad).window(*RECORD_WINDOW_S)


def _scenes(args, strikes: list[RealStrike]) -> tuple[dict, dict]:
    """(group -> Scene, group -> scene file path) for every group among the strikes."""
    chosen = {}
    for text in args.scene:
        group, sep, name = text.partition('=')
        if not sep:
            raise InputError(f'--scene {text}: expected GROUP=SCENE')
        chosen[group] = name
    known = available_scenes()
    scenes, paths = {}, {}
    for group in sorted({s.group for s in strikes}):
        name = chosen.get(group, group)
        scenes[group] = load_scene(name)
        paths[group] = Path(name) if Path(name).suffix in ('.yaml', '.yml') else known[name]
    return scenes, paths


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def run_identify(args) -> int:
    strikes = _load_strikes(args)
    scenes, paths = _scenes(args, strikes)
    if not args.fit and not args.spread:
        raise InputError('identify: nothing to fit: give --fit KEY (repeatable), --spread, or '
                         'both')
    if not args.fit:
        return _identify_spread_only(args, strikes, scenes, paths)
    params = [ident.parse_free_parameter(text, scenes) for text in args.fit]
    per_day = [ident.parse_free_parameter(text, scenes, option='--per-day')
               for text in args.per_day]
    for param in per_day:
        params += ident.per_day_parameters(param, strikes)
    weights = ident.Weights.parse(args.weight)
    loss = ident.Loss.parse(args.loss)
    if args.at_seat and any(p.key == fidelity.LATCH_KEY for p in params):
        raise InputError(f'--at-seat latches each arm at its tracked seat, which a fit of '
                         f'{fidelity.LATCH_KEY} (--fit or --per-day) would set again: use one '
                         f'or the other')
    if args.iterations < 1:
        raise InputError(f'--iterations {args.iterations}: must be >= 1')
    if args.cv_iterations < 0:
        raise InputError(f'--cv-iterations {args.cv_iterations}: must be >= 0')
    check_out_folder(args.out)
    with ClusterMap(args.scheduler, args.workers, progress=not args.json) as mapper:
        _log(f'identify: {len(strikes)} strikes ({", ".join(sorted(scenes))}), '
             f'{len(params)} parameters, on {mapper.where} ({mapper.worker_count} worker(s))')
        if args.at_seat:
            _log(_seat_line(_seats(strikes)))
        model = ident.StrikeModel(scenes, strikes, params, weights, mapper,
                                  at_seat=args.at_seat)
        start = _per_day_starts(scenes, strikes, params, per_day, weights, mapper,
                                args.at_seat)
        fit = ident.identify(model, start, max_iterations=args.iterations, log=_log, loss=loss)
        folds, cv_method = None, ''
        if args.cross_validate and args.cv_iterations == 0:
            folds = ident.cross_validate_one_step(model, fit, log=_log)
            cv_method = ('leave one recording day out: one Gauss-Newton step from the full fit '
                         'on the other days')
        elif args.cross_validate:
            folds = ident.cross_validate(model, fit.values, args.cv_iterations, log=_log,
                                         loss=loss)
            cv_method = (f'leave one recording day out: refitted on the other days '
                         f'({args.cv_iterations} iterations at most)')
    args.out.mkdir(parents=True, exist_ok=True)
    sources = [str(args.strikes)] + ([str(args.processed)] if args.processed else []) + [
        t.partition('=')[2] for t in args.export]
    written, dropped = [], []
    for group, path in paths.items():
        base = yaml.safe_load(path.read_text(encoding='utf-8'))
        if 'spread' in base and not args.spread:
            dropped.append(group)
        doc = ident.calibrated_scene(base, fit, group, folds, sources, cv_method, weights)
        target = args.out / path.name
        target.write_text(yaml.safe_dump(doc, sort_keys=False, width=100), encoding='utf-8')
        written.append(str(target))
    report = _identify_report(fit, folds, written)
    if dropped:
        _log(f'identify: the spread of {", ".join(dropped)} was fitted about the parameters '
             f'this fit replaced: not written; add --spread to fit it again')
    if args.spread:
        calibrated = {g: load_scene(str(args.out / paths[g].name)) for g in paths}
        with ClusterMap(args.scheduler, args.workers, progress=not args.json) as mapper:
            report['spread'] = _fit_and_write_spreads(args, mapper, strikes, calibrated, {
                g: (args.out / p.name, args.out / p.name) for g, p in paths.items()})
    if args.json:
        print(json.dumps(json_safe(report)))
    else:
        print(_identify_text(report))
        if 'spread' in report:
            print(_spread_text(report['spread']))
    return 0


def _identify_spread_only(args, strikes, scenes, paths) -> int:
    """`mantis identify --spread` without --fit: each scene as it is, with its spread."""
    check_out_folder(args.out)
    with ClusterMap(args.scheduler, args.workers, progress=not args.json) as mapper:
        _log(f'identify: the spread of {len(strikes)} strikes ({", ".join(sorted(scenes))}) on '
             f'{mapper.where}; the scenes\' parameters kept')
        files = {g: (p, args.out / p.name) for g, p in paths.items()}
        report = {'spread': _fit_and_write_spreads(args, mapper, strikes, scenes, files),
                  'scenes': [str(target) for _, target in files.values()]}
    if args.json:
        print(json.dumps(json_safe(report)))
    else:
        print(_spread_text(report['spread']) + '\nscenes: ' + ', '.join(report['scenes']))
    return 0


def _fit_and_write_spreads(args, mapper, strikes, scenes, files) -> dict:
    """Fit the spread (spread_fit), then write each group's scene file, group -> (the scene
    file, where to write it with its spread); the report's 'spread' entry. Nothing is written
    if the fit fails."""
    sources = [str(args.strikes)] + ([str(args.processed)] if args.processed else [])
    spreads, latents, model = spread_fit.fit_spreads(
        scenes, strikes, mapper, args.spread_latent, sources=sources, log=_log)
    args.out.mkdir(parents=True, exist_ok=True)
    for group, (source, target) in files.items():
        doc = yaml.safe_load(source.read_text(encoding='utf-8'))
        doc['spread'] = json_safe(spreads[group].to_mapping())
        target.write_text(yaml.safe_dump(doc, sort_keys=False, width=100), encoding='utf-8')
    report = {'latent': model.key,
              'means': {g: {'value': m, 'std_error': se} for g, (m, se) in model.means.items()},
              'day_sd': {'value': model.day_sd, 'std_error': model.day_sd_std_error},
              'strike_sd': {'value': model.strike_sd, 'std_error': model.strike_sd_std_error},
              'days': model.days, 'strikes': model.strikes,
              'discrepancy': {d.metric: {'bias': d.bias, 'bias_std_error': d.bias_std_error,
                                         'sd': d.sd}
                              for d in next(iter(spreads.values())).discrepancy},
              'strike_latents': {x.strike.trial: x.value for x in latents}}
    return report


def _std_error_text(value: float) -> str:
    return f'{value:.2f}' if math.isfinite(value) else 'at zero: the days agree'


def _spread_text(spread: dict) -> str:
    lines = [f'spread: {spread["latent"]} over {spread["strikes"]} strikes of '
             f'{spread["days"]} recording days (mixed model, REML)',
             '  group        mean (s.e.)']
    lines += [f'  {g:12s} {m["value"]:+6.2f} ({m["std_error"]:.2f})'
              for g, m in spread['means'].items()]
    lines.append(f'  between days: sd {spread["day_sd"]["value"]:.2f} '
                 f'({_std_error_text(spread["day_sd"]["std_error"])}); within a day: sd '
                 f'{spread["strike_sd"]["value"]:.2f} '
                 f'({_std_error_text(spread["strike_sd"]["std_error"])})')
    lines.append('  discrepancy, measured/simulated - 1, every group: bias (s.e.), scatter (sd)')
    for metric, d in spread['discrepancy'].items():
        lines.append(f'  {metric:20s} {100 * d["bias"]:+5.1f} % ({100 * d["bias_std_error"]:.1f} '
                     f'%)  {100 * d["sd"]:.1f} %')
    return '\n'.join(lines)


def _seats(strikes: list[RealStrike]) -> dict:
    """How many strikes have a tracked seat, and which have none."""
    missing = [s.trial for s in strikes if s.seat_deg is None]
    return {'seated': len(strikes) - len(missing), 'without_seat': missing}


def _seat_line(seats: dict) -> str:
    return (f'arms latched at their tracked seats ({seats["seated"]} strikes)'
            + (f'; no seat, at the contact angle: {", ".join(seats["without_seat"])}'
               if seats['without_seat'] else ''))


def _per_day_starts(scenes, strikes, params, per_day, weights, mapper, at_seat=False):
    """Start values: the scenes' for the robot's parameters; for each day's own parameters,
    that day's fit with the scene held (mantis day-state), so that the joint fit starts near
    the days' states rather than at the scene's value for all of them."""
    if not per_day:
        return None
    from mantis_sim.studies.real_strikes import day_state as ds
    own = {}
    for param in per_day:
        _log(f'identify: each day\'s {param.label} from its strikes, to start from')
        for state in ds.DayStateFit(scenes, strikes, param, weights, mapper,
                                    at_seat=at_seat).fit(3, log=_log):
            own[(param.key, state.group, state.day)] = state.value
    return [own.get((p.key, p.groups[0], p.day)) if p.day is not None
            else ident.default_value(scenes, p) for p in params]


def _identify_report(fit, folds, written) -> dict:
    report = {
        'parameters': {p.label: {'value': float(v), 'std_error': float(s)}
                       for p, v, s in zip(fit.parameters, fit.values, fit.std_errors)},
        'inseparable': [{'a': a, 'b': b, 'correlation': rho}
                        for a, b, rho in fit.inseparable_pairs()],
        'at_bounds': fit.at_bounds(),
        'fitted_errors': ident.error_summary(fit.strikes, fit.simulated),
        'not_struck': [{'trial': m.trial, 'status': m.status, 'reason': m.reason}
                       for m in fit.simulated if m.status != 'strike'],
        'evaluations': fit.evaluations, 'wall_s': fit.wall_s, 'scenes': written,
        'at_seat': fit.at_seat,
    }
    if folds:
        report['cross_validated_errors'] = ident.error_summary(
            [s for f in folds for s in f.strikes], [s for f in folds for s in f.simulated])
        report['cross_validation_by_day'] = {
            f.left_out: ident.error_summary(f.strikes, f.simulated) for f in folds}
    return report


def _identify_text(report: dict) -> str:
    lines = ['parameter                                   value        std. error']
    for label, entry in report['parameters'].items():
        lines.append(f'{label:42s} {entry["value"]:12.5g} {entry["std_error"]:12.3g}')
    for label in report['at_bounds']:
        lines.append(f'{label} ended at a bound: the data want it beyond; its standard error '
                     f'means little')
    for pair in report['inseparable']:
        lines.append(f'the data cannot separate {pair["a"]} and {pair["b"]} (correlation '
                     f'{pair["correlation"]:+.2f})')
    if report['at_seat']:
        lines.append('fitted with each arm latched at its tracked seat (--at-seat)')
    lines.append('median |error|, fitted           strikes  tip speed  spring energy')
    lines += _error_lines(report['fitted_errors'])
    if 'cross_validated_errors' in report:
        lines.append('median |error|, left-out days    strikes  tip speed  spring energy')
        lines += _error_lines(report['cross_validated_errors'])
        for day, errors in report['cross_validation_by_day'].items():
            lines += [f'  day {day}: ' + line.strip() for line in _error_lines(errors)]
    for r in report['not_struck']:
        lines.append(f'{r["status"]} at the fitted values: {r["trial"]}: {r["reason"]}')
    lines.append(f'{report["evaluations"]} evaluations of every strike in '
                 f'{report["wall_s"]:.0f} s; calibrated scenes: {", ".join(report["scenes"])}')
    return '\n'.join(lines)


def _error_lines(errors: dict) -> list[str]:
    return [f'  {group:30s} {e["strikes"]:7d} {100 * e["tip_speed_median_abs_error"]:9.1f} % '
            f'{100 * e["spring_energy_median_abs_error"]:12.1f} %' for group, e in errors.items()]


def run_compare(args) -> int:
    strikes = _load_strikes(args)
    scenes, _ = _scenes(args, strikes)
    trials = {s.trial: s for s in strikes}
    unknown = [t for t in args.figure if t not in trials]
    if unknown:
        raise InputError(f'--figure {", ".join(unknown)}: not a trial of {args.strikes}')
    no_motion = [t for t in args.figure if trials[t].series is None]
    if no_motion:
        raise InputError(f'--figure {", ".join(no_motion)}: no recorded motion (give '
                         f'--processed or --export for it)')
    if args.spread:
        _check_spread_request(args, scenes)
    check_out_folder(args.out)
    with ClusterMap(args.scheduler, args.workers, progress=not args.json) as mapper:
        model = ident.StrikeModel(scenes, strikes, [], ident.Weights(), mapper,
                                  at_seat=args.at_seat)
        simulated = model.simulate([[]])[0]
        forecasts = (forecast.forecast_strikes(scenes, strikes, args.spread, args.seed, mapper)
                     if args.spread else None)
    from mantis_sim.studies.real_strikes import compare_plots
    args.out.mkdir(parents=True, exist_ok=True)
    rows = fidelity.error_rows(strikes, simulated)
    write_rows(args.out / 'errors.csv', rows)
    compare_plots.plot_parity(rows, args.out / 'parity.png')
    for trial in args.figure:
        sim = simulated[strikes.index(trials[trial])]
        compare_plots.plot_trial(trials[trial], sim, args.out / f'trial_{trial}.png')
    report = {'groups': {key: fidelity.group_summary(rows, key)
                         for key, _, _ in fidelity.COMPARED},
              'effects': fidelity.effect_slopes(rows),
              'not_struck': [{'trial': r['trial'], 'status': r['status'], 'reason': r['reason']}
                             for r in rows if r['status'] != 'strike'],
              'at_seat': _seats(strikes) if args.at_seat else None}
    if forecasts is not None:
        report['spread'] = _write_forecasts(forecasts, args, compare_plots)
    report['outputs'] = sorted(str(p) for p in args.out.iterdir())
    if args.json:
        print(json.dumps(json_safe(report)))
    else:
        print(_compare_text(report))
    return 0


def _check_spread_request(args, scenes) -> None:
    check_spread_request(args.spread, scenes, per=' per strike')
    if args.at_seat:
        raise InputError('--spread draws where each arm sits from the scene\'s spread, which '
                         '--at-seat would set from the tracks: use one or the other')


def _write_forecasts(forecasts, args, compare_plots) -> dict:
    """predictions.csv, spread_scores.csv and forecasts.png; the report's 'spread' entry."""
    write_rows(args.out / 'predictions.csv', forecast.prediction_rows(forecasts))
    scores = forecast.scores(forecasts)
    columns = ['metric', 'group', 'strikes', 'coverage_50', 'coverage_80', 'crps',
               'crps_climatology', 'crps_ratio', 'median_abs_error_q50']
    write_rows(args.out / 'spread_scores.csv',
               ({'metric': metric, 'group': group, **entry}
                for metric, groups in scores.items() for group, entry in groups.items()),
               columns)
    compare_plots.plot_forecasts(forecasts, args.out / 'forecasts.png')
    return {'robots_per_strike': args.spread, 'seed': args.seed, 'scores': scores,
            'robots_not_struck': sum(f.not_struck for f in forecasts),
            'strikes': len(forecasts), 'strikes_on_days_seen': sum(f.day_seen for f in forecasts)}


def _forecast_lines(spread: dict) -> list[str]:
    lines = [f'forecasts from {spread["robots_per_strike"]} robots per strike (seed '
             f'{spread["seed"]}): group, strikes, intervals holding the measured value (50 % / '
             f'80 %), CRPS against the climatology\'s, median |error| of the median']
    for metric, groups in spread['scores'].items():
        _, label, unit = forecast.FORECAST_METRICS[metric]
        lines.append(f'{label}:')
        for group, e in groups.items():
            if not e['strikes']:
                continue
            lines.append(f'  {group:11s} {e["strikes"]:3d}  {100 * e["coverage_50"]:3.0f} % / '
                         f'{100 * e["coverage_80"]:3.0f} %  {e["crps"]:.3g} {unit} against '
                         f'{e["crps_climatology"]:.3g} ({e["crps_ratio"]:.2f}x)  '
                         f'{100 * e["median_abs_error_q50"]:.1f} %')
    if spread['strikes_on_days_seen']:
        lines.append(f'{spread["strikes_on_days_seen"]} of {spread["strikes"]} strikes are of '
                     f'recording days the spread has seen: forecast from their day\'s assembly')
    if spread['robots_not_struck']:
        lines.append(f'{spread["robots_not_struck"]} drawn robots did not strike (left out of '
                     f'their forecasts)')
    return lines


def _compare_text(report: dict) -> str:
    lines = ['group           strikes   median error (median |error|)']
    for key, label, _ in fidelity.COMPARED:
        lines.append(f'{label}:')
        for group, e in report['groups'][key].items():
            if not e['strikes']:
                lines.append(f'  {group:14s} {0:7d}   n/a (none measured)')
                continue
            lines.append(f'  {group:14s} {e["strikes"]:7d}   {100 * e["median_error"]:+6.1f} % '
                         f'({100 * e["median_abs_error"]:.1f} %)')
    lines.append('effect                                                   real (+- s.e.)    '
                 '   simulated')
    for e in report['effects']:
        if not (math.isfinite(e['real']) and math.isfinite(e['real_std_error'])):
            lines.append(f'{e["effect"]:56s} n/a: too few strikes of the kind to estimate it')
            continue
        mark = 'within 2 s.e.' if e['within_two_std_errors'] else 'OUTSIDE 2 s.e.'
        lines.append(f'{e["effect"]:56s} {e["real"]:+7.3f} +- {e["real_std_error"]:.3f}  '
                     f'{e["sim"]:+7.3f} {e["unit"]}  {mark}')
    for r in report['not_struck']:
        lines.append(f'{r["status"]}: {r["trial"]}: {r["reason"]}')
    if report['at_seat']:
        lines.append(_seat_line(report['at_seat']))
    if 'spread' in report:
        lines += _forecast_lines(report['spread'])
    lines.append('outputs: ' + ', '.join(report['outputs']))
    return '\n'.join(lines)
