"""`mantis identify`'s run: the scene parameters fitted to real strikes (identify), each day's
own parameters started from that day's fit (day_state), optionally the spread too (spread_run);
one calibrated scene file per group written, and the report and its text.

`prepare_identification` reads and checks everything before any work; `run_identification`
then simulates, fits and writes.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import yaml

from mantis_sim.errors import InputError
from mantis_sim.scene import load_scene

from . import day_state as ds
from . import fidelity, spread_fit
from . import identify as ident
from .spread_run import fit_and_write_spreads, spread_text
from .strike_inputs import (
    SeriesFromExport,
    StrikeInputs,
    choose_scenes,
    load_strikes,
    seat_line,
    seat_summary,
)

Log = Callable[[str], None]


@dataclass(frozen=True)
class IdentifyRequest:
    """What to fit, as `mantis identify`'s options give it (``fit``, ``per_day``: 'KEY[@GROUP
    [+GROUP]][=LO:HI]'; ``weights``: 'NAME=VALUE'; ``loss``: 'linear' or 'NAME:SCALE')."""
    inputs: StrikeInputs
    out: Path
    fit: Sequence[str] = ()
    spread: bool = False
    spread_latent: str = spread_fit.DEFAULT_LATENT
    per_day: Sequence[str] = ()
    iterations: int = 6
    cross_validate: bool = False
    cv_iterations: int = 0
    weights: Sequence[str] = ()
    loss: str = 'linear'
    at_seat: bool = False


@dataclass
class IdentifyPlan:
    """A checked request: its strikes, scenes (group -> Scene, and -> file) and, unless only
    the spread is fitted, its parsed parameters."""
    request: IdentifyRequest
    strikes: list
    scenes: dict
    paths: dict
    params: list = field(default_factory=list)
    per_day: list = field(default_factory=list)
    weights: Optional[ident.Weights] = None
    loss: Optional[ident.Loss] = None

    @property
    def spread_only(self) -> bool:
        return not self.request.fit


def prepare_identification(request: IdentifyRequest,
                           series_from_export: Optional[SeriesFromExport] = None
                           ) -> IdentifyPlan:
    """The strikes and scenes read, the request checked (InputError), before any work."""
    strikes = load_strikes(request.inputs, series_from_export)
    scenes, paths = choose_scenes(request.inputs, strikes)
    plan = IdentifyPlan(request, strikes, scenes, paths)
    if not request.fit and not request.spread:
        raise InputError('identify: nothing to fit: give --fit KEY (repeatable), --spread, or '
                         'both')
    if plan.spread_only:
        return plan
    plan.params = [ident.parse_free_parameter(text, scenes) for text in request.fit]
    plan.per_day = [ident.parse_free_parameter(text, scenes, option='--per-day')
                    for text in request.per_day]
    for param in plan.per_day:
        plan.params += ident.per_day_parameters(param, strikes)
    plan.weights = ident.Weights.parse(request.weights)
    plan.loss = ident.Loss.parse(request.loss)
    if request.at_seat and any(p.key == fidelity.LATCH_KEY for p in plan.params):
        raise InputError(f'--at-seat latches each arm at its tracked seat, which a fit of '
                         f'{fidelity.LATCH_KEY} (--fit or --per-day) would set again: use one '
                         f'or the other')
    if request.iterations < 1:
        raise InputError(f'--iterations {request.iterations}: must be >= 1')
    if request.cv_iterations < 0:
        raise InputError(f'--cv-iterations {request.cv_iterations}: must be >= 0')
    return plan


def run_identification(plan: IdentifyPlan, log: Log = lambda _: None) -> dict:
    """Fit, write the calibrated scenes into ``request.out``; the report."""
    if plan.spread_only:
        return _spread_only(plan, log)
    request, strikes, scenes = plan.request, plan.strikes, plan.scenes
    with request.inputs.cluster() as mapper:
        log(f'identify: {len(strikes)} strikes ({", ".join(sorted(scenes))}), '
            f'{len(plan.params)} parameters, on {mapper.where} ({mapper.worker_count} worker(s))')
        if request.at_seat:
            log(seat_line(seat_summary(strikes)))
        model = ident.StrikeModel(scenes, strikes, plan.params, plan.weights, mapper,
                                  at_seat=request.at_seat)
        start = per_day_starts(scenes, strikes, plan.params, plan.per_day, plan.weights,
                               mapper, request.at_seat, log)
        fit = ident.identify(model, start, max_iterations=request.iterations, log=log,
                             loss=plan.loss)
        folds, cv_method = None, ''
        if request.cross_validate and request.cv_iterations == 0:
            folds = ident.cross_validate_one_step(model, fit, log=log)
            cv_method = ('leave one recording day out: one Gauss-Newton step from the full fit '
                         'on the other days')
        elif request.cross_validate:
            folds = ident.cross_validate(model, fit.values, request.cv_iterations, log=log,
                                         loss=plan.loss)
            cv_method = (f'leave one recording day out: refitted on the other days '
                         f'({request.cv_iterations} iterations at most)')
    request.out.mkdir(parents=True, exist_ok=True)
    sources = request.inputs.sources(exports=True)
    written, dropped = [], []
    for group, path in plan.paths.items():
        base = yaml.safe_load(path.read_text(encoding='utf-8'))
        if 'spread' in base and not request.spread:
            dropped.append(group)
        doc = ident.calibrated_scene(base, fit, group, folds, sources, cv_method, plan.weights)
        target = request.out / path.name
        target.write_text(yaml.safe_dump(doc, sort_keys=False, width=100), encoding='utf-8')
        written.append(str(target))
    report = identify_report(fit, folds, written)
    if dropped:
        log(f'identify: the spread of {", ".join(dropped)} was fitted about the parameters '
            f'this fit replaced: not written; add --spread to fit it again')
    if request.spread:
        calibrated = {g: load_scene(str(request.out / p.name)) for g, p in plan.paths.items()}
        files = {g: (request.out / p.name, request.out / p.name) for g, p in plan.paths.items()}
        with request.inputs.cluster() as mapper:
            report['spread'] = fit_and_write_spreads(request.inputs, request.spread_latent,
                                                     request.out, mapper, strikes, calibrated,
                                                     files, log)
    return report


def _spread_only(plan: IdentifyPlan, log: Log) -> dict:
    """`mantis identify --spread` without --fit: each scene as it is, with its spread."""
    request = plan.request
    with request.inputs.cluster() as mapper:
        log(f'identify: the spread of {len(plan.strikes)} strikes '
            f'({", ".join(sorted(plan.scenes))}) on {mapper.where}; the scenes\' parameters '
            f'kept')
        files = {g: (p, request.out / p.name) for g, p in plan.paths.items()}
        return {'spread': fit_and_write_spreads(request.inputs, request.spread_latent,
                                                request.out, mapper, plan.strikes, plan.scenes,
                                                files, log),
                'scenes': [str(target) for _, target in files.values()]}


def per_day_starts(scenes, strikes, params, per_day, weights, mapper, at_seat=False,
                   log: Log = lambda _: None):
    """Start values: the scenes' for the robot's parameters; for each day's own parameters,
    that day's fit with the scene held (mantis day-state), so that the joint fit starts near
    the days' states rather than at the scene's value for all of them."""
    if not per_day:
        return None
    own = {}
    for param in per_day:
        log(f'identify: each day\'s {param.label} from its strikes, to start from')
        for state in ds.DayStateFit(scenes, strikes, param, weights, mapper,
                                    at_seat=at_seat).fit(3, log=log):
            own[(param.key, state.group, state.day)] = state.value
    return [own.get((p.key, p.groups[0], p.day)) if p.day is not None
            else ident.default_value(scenes, p) for p in params]


def identify_report(fit, folds, written) -> dict:
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


def identify_text(report: dict) -> str:
    """The report as `mantis identify` prints it: the fit's, then the spread's."""
    if 'parameters' not in report:                      # the spread alone
        return spread_text(report['spread']) + '\nscenes: ' + ', '.join(report['scenes'])
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
    if 'spread' in report:
        lines.append(spread_text(report['spread']))
    return '\n'.join(lines)


def _error_lines(errors: dict) -> list[str]:
    return [f'  {group:30s} {e["strikes"]:7d} {100 * e["tip_speed_median_abs_error"]:9.1f} % '
            f'{100 * e["spring_energy_median_abs_error"]:12.1f} %' for group, e in errors.items()]
