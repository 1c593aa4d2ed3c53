"""``DIR/report/``: a study's effects, the repeats that would resolve what is still unresolved,
how its strikes sat in their forecasts, and its figures. The numbers come from
mantis_sim.studies.rig_study; this module lays them out."""
from __future__ import annotations

from collections import Counter
import math
from pathlib import Path

from mantis_rig.study_session.record import (
    ABORTED,
    DONE,
    INTERRUPTED,
    OWED,
    RECORD_NAME,
    read_record,
)
from mantis_rig.study_session.runner import plan_as_run, recorded_conditions, study_forecaster
from mantis_sim.studies.rig_study.effects import study_effects
from mantis_sim.studies.rig_study.figures import (
    effects_figure,
    forecast_run_order,
    pit_histogram,
)
from mantis_sim.studies.rig_study.quantities import QUANTITIES, condition_axis
from mantis_sim.studies.shared.csv_table import write_rows

REPORT = 'report'
EFFECT_COLUMNS = ('factor', 'reference', 'level', 'quantity', 'unit', 'measured', 'low_95',
                  'high_95', 'strikes', 'residual_sd', 'twin', 'twin_low_95', 'twin_high_95',
                  'resolved', 'twin_inside', 'more_repeats')


def write_report(directory: Path, say=print, forecaster=None, plan=None) -> Path:
    directory = Path(directory)
    record = read_record(directory / RECORD_NAME)
    plan = plan or plan_as_run(directory)
    forecaster = forecaster or study_forecaster(directory, plan, record.rows, say=say)
    out = directory / REPORT
    out.mkdir(exist_ok=True)
    done = [r for r in record.rows if r['status'] == DONE]
    per_cell = Counter(tuple(str(r[f]) for f in plan.factors) for r in done)
    repeats_run = min(per_cell.values()) if len(per_cell) == len(plan.cells) else 0
    effects = study_effects(plan, done, forecaster, repeats_run, planned=record.rows,
                            conditions_of=recorded_conditions(record.rows, forecaster.scene))
    write_rows(out / 'effects.csv', [_effect_row(e) for e in effects], EFFECT_COLUMNS)
    figures = [forecast_run_order(record.rows, out / 'forecast_run_order.png'),
               effects_figure(effects, out / 'effects.png'),
               pit_histogram(done, out / 'pit_histogram.png')]
    text = _markdown(plan, record.rows, effects, [f for f in figures if f is not None])
    (out / 'report.md').write_text(text, encoding='utf-8')
    for effect in effects:
        if not effect.resolved and 0 < effect.more_repeats < math.inf:
            say(f'unresolved: {QUANTITIES[effect.quantity].label} from '
                f'{_change(effect)}: {_repeats_text(effect.more_repeats)}')
    return out


def _effect_row(e) -> dict:
    return {'factor': e.factor, 'reference': e.reference, 'level': e.level,
            'quantity': e.quantity, 'unit': QUANTITIES[e.quantity].unit, 'measured': e.measured,
            'low_95': e.low, 'high_95': e.high, 'strikes': e.strikes,
            'residual_sd': e.residual_sd, 'twin': e.twin, 'twin_low_95': e.twin_low,
            'twin_high_95': e.twin_high, 'resolved': e.resolved,
            'twin_inside': e.twin_inside, 'more_repeats': e.more_repeats}


def _change(e) -> str:
    name = condition_axis(e.factor)
    if isinstance(e.level, str):
        return f'{name} {e.reference} to {e.level}'
    return f'{name} {e.reference:g} to {e.level:g}'


def _repeats_text(more: float) -> str:
    if math.isnan(more):
        return 'the strikes give no scatter to plan repeats from'
    if math.isinf(more):
        return ('the twin forecasts no difference worth resolving (give the plan a '
                'smallest_effect for it)')
    return f'{int(more)} more repeat(s) per combination would resolve it (80 % power, 5 % level)'


def _number(value: float) -> str:
    return 'none' if value is None or not math.isfinite(value) else f'{value:.4g}'


def _coverage(rows, quantity: str, low: float, high: float) -> str:
    pits = [r.get(f'{quantity}_pit') for r in rows]
    pits = [p for p in pits if p is not None and math.isfinite(p)]
    if not pits:
        return 'none measured'
    inside = sum(low <= p <= high for p in pits)
    return f'{inside} of {len(pits)}'


def _markdown(plan, rows, effects, figures) -> str:
    done = [r for r in rows if r['status'] == DONE]
    status = Counter(r['status'] for r in rows)
    lines = [f'# Study: {plan.scene}, {", ".join(plan.factors)}', '',
             f'{status[DONE]} trial(s) done, {status[ABORTED]} aborted, '
             f'{status[INTERRUPTED]} interrupted, {sum(status[s] for s in OWED)} owed; '
             f'order {plan.order}, {plan.repeats} repeat(s) per '
             f'combination, seed {plan.seed}; the twin: scene {plan.scene}, {plan.robots} '
             f'robots per combination.', '', '## Effects (95 % intervals)', '',
             '| change | quantity | measured | twin\'s forecast | resolved | inside the twin\'s | '
             'more repeats |', '|---|---|---|---|---|---|---|']
    for e in effects:
        q = QUANTITIES[e.quantity]
        lines.append(
            f'| {_change(e)} | {q.axis} | {_number(e.measured)} [{_number(e.low)}, '
            f'{_number(e.high)}] | {_number(e.twin)} [{_number(e.twin_low)}, '
            f'{_number(e.twin_high)}] | {"yes" if e.resolved else "no"} | '
            f'{"yes" if e.twin_inside else "no"} | '
            f'{"" if e.resolved else _repeats_text(e.more_repeats)} |')
    lines += ['', '## The strikes in their forecasts', '',
              '| quantity | measured | inside q25-q75 | inside q10-q90 | inside the 95 % |',
              '|---|---|---|---|---|']
    for name, q in QUANTITIES.items():
        measured = sum(r.get(name) is not None and math.isfinite(r[name]) for r in done)
        if measured:
            lines.append(f'| {q.axis} | {measured} | {_coverage(done, name, 0.25, 0.75)} | '
                         f'{_coverage(done, name, 0.10, 0.90)} | '
                         f'{_coverage(done, name, 0.025, 0.975)} |')
    flagged = [r for r in done if r.get('flags')]
    if flagged:
        lines += ['', '## Outside their 95 % interval', '']
        lines += [f'- run {r["run"]}: {r["cause"]}' for r in flagged]
    lines += ['', '## Figures', ''] + [f'![{f.stem}]({f.name})' for f in figures]
    return '\n'.join(lines) + '\n'


__all__ = ['write_report']
