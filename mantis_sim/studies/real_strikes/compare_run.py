"""`mantis compare`'s run: every strike simulated at its own conditions beside its measured
values (fidelity), its errors, parity plot and trial figures written (compare_plots), and with a
spread the forecasts of robots drawn from it (forecast); the report and its text.

`prepare_comparison` reads and checks everything before any work; `run_comparison` then
simulates and writes.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Optional

from mantis_sim.errors import InputError
from mantis_sim.studies.shared.csv_table import write_rows

from . import fidelity, forecast
from . import identify as ident
from .strike_inputs import (
    SeriesFromExport,
    StrikeInputs,
    choose_scenes,
    load_strikes,
    seat_line,
    seat_summary,
)


@dataclass(frozen=True)
class CompareRequest:
    """What to compare, as `mantis compare`'s options give it: ``figures`` the trials plotted,
    ``spread`` robots drawn per strike (0: no forecasts) from ``seed``."""
    inputs: StrikeInputs
    out: Path
    figures: Sequence[str] = ()
    spread: int = 0
    seed: int = 1
    at_seat: bool = False


@dataclass(frozen=True)
class ComparePlan:
    """A checked request: its strikes and scenes (group -> Scene)."""
    request: CompareRequest
    strikes: list
    scenes: dict


def prepare_comparison(request: CompareRequest,
                       series_from_export: Optional[SeriesFromExport] = None) -> ComparePlan:
    """The strikes and scenes read, the figures checked (InputError), before any work."""
    strikes = load_strikes(request.inputs, series_from_export)
    scenes, _ = choose_scenes(request.inputs, strikes)
    trials = {s.trial: s for s in strikes}
    unknown = [t for t in request.figures if t not in trials]
    if unknown:
        raise InputError(f'--figure {", ".join(unknown)}: not a trial of '
                         f'{request.inputs.strikes}')
    no_motion = [t for t in request.figures if trials[t].series is None]
    if no_motion:
        raise InputError(f'--figure {", ".join(no_motion)}: no recorded motion (give '
                         f'--processed or --export for it)')
    return ComparePlan(request, strikes, scenes)


def run_comparison(plan: ComparePlan) -> dict:
    """Simulate, write errors.csv, parity.png, the figures (and the forecasts' files) into
    ``request.out``; the report."""
    request, strikes, scenes = plan.request, plan.strikes, plan.scenes
    with request.inputs.cluster() as mapper:
        model = ident.StrikeModel(scenes, strikes, [], ident.Weights(), mapper,
                                  at_seat=request.at_seat)
        simulated = model.simulate([[]])[0]
        forecasts = (forecast.forecast_strikes(scenes, strikes, request.spread, request.seed,
                                               mapper)
                     if request.spread else None)
    from . import compare_plots
    out = request.out
    out.mkdir(parents=True, exist_ok=True)
    rows = fidelity.error_rows(strikes, simulated)
    write_rows(out / 'errors.csv', rows)
    compare_plots.plot_parity(rows, out / 'parity.png')
    trials = {s.trial: s for s in strikes}
    for trial in request.figures:
        sim = simulated[strikes.index(trials[trial])]
        compare_plots.plot_trial(trials[trial], sim, out / f'trial_{trial}.png')
    report = {'groups': {key: fidelity.group_summary(rows, key)
                         for key, _, _ in fidelity.COMPARED},
              'effects': fidelity.effect_slopes(rows),
              'not_struck': [{'trial': r['trial'], 'status': r['status'], 'reason': r['reason']}
                             for r in rows if r['status'] != 'strike'],
              'at_seat': seat_summary(strikes) if request.at_seat else None}
    if forecasts is not None:
        report['spread'] = write_forecasts(forecasts, request)
    report['outputs'] = sorted(str(p) for p in out.iterdir())
    return report


def write_forecasts(forecasts, request: CompareRequest) -> dict:
    """predictions.csv, spread_scores.csv and forecasts.png; the report's 'spread' entry."""
    from . import compare_plots
    write_rows(request.out / 'predictions.csv', forecast.prediction_rows(forecasts))
    scores = forecast.scores(forecasts)
    columns = ['metric', 'group', 'strikes', 'coverage_50', 'coverage_80', 'crps',
               'crps_climatology', 'crps_ratio', 'median_abs_error_q50']
    write_rows(request.out / 'spread_scores.csv',
               ({'metric': metric, 'group': group, **entry}
                for metric, groups in scores.items() for group, entry in groups.items()),
               columns)
    compare_plots.plot_forecasts(forecasts, request.out / 'forecasts.png')
    return {'robots_per_strike': request.spread, 'seed': request.seed, 'scores': scores,
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


def compare_text(report: dict) -> str:
    """The report as `mantis compare` prints it."""
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
        lines.append(seat_line(report['at_seat']))
    if 'spread' in report:
        lines += _forecast_lines(report['spread'])
    lines.append('outputs: ' + ', '.join(report['outputs']))
    return '\n'.join(lines)
