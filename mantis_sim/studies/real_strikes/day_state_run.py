"""`mantis day-state`'s run: one scene key fitted to each recording day's strikes, the rest of
the scene held (day_state), optionally left one strike out within days, and one scene per group
and day written; the report and its text.

`prepare_day_state` reads and checks the request before any work; `run_day_state` checks the
strikes' days, then fits and writes.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import datetime
import math
from pathlib import Path
import re
from typing import Optional

import yaml

from mantis_sim.errors import InputError
from mantis_sim.parameters import ParameterError

from . import day_state as ds
from . import identify as ident
from .strike_inputs import SeriesFromExport, StrikeInputs, choose_scenes, load_strikes

SAFE_DAY = re.compile(r'[A-Za-z0-9_.-]+')


@dataclass(frozen=True)
class DayStateRequest:
    """What to fit, as `mantis day-state`'s options give it (``key``: 'KEY[@GROUP[+GROUP]]
    [=LO:HI]'; ``weights``: 'NAME=VALUE'); ``out``: the folder of the day's scenes, or None."""
    inputs: StrikeInputs
    key: str = ds.DEFAULT_DAY_KEY
    iterations: int = 5
    weights: Sequence[str] = ()
    cross_validate: bool = False
    out: Optional[Path] = None


@dataclass(frozen=True)
class DayStatePlan:
    """A checked request: its strikes, scenes (group -> Scene, and -> file), key and
    weights."""
    request: DayStateRequest
    strikes: list
    scenes: dict
    paths: dict
    param: ident.FreeParameter
    weights: ident.Weights


def prepare_day_state(request: DayStateRequest,
                      series_from_export: Optional[SeriesFromExport] = None) -> DayStatePlan:
    """The strikes and scenes read, the key, weights and iterations checked (InputError)."""
    strikes = load_strikes(request.inputs, series_from_export)
    scenes, paths = choose_scenes(request.inputs, strikes)
    param = ident.parse_free_parameter(request.key, scenes, option='--key')
    for scene in scenes.values():
        ident.scene_value(scene, param.key)             # refuses a key with nothing to start
    weights = ident.Weights.parse(request.weights)
    if request.iterations < 1:
        raise InputError(f'--iterations {request.iterations}: must be >= 1')
    return DayStatePlan(request, strikes, scenes, paths, param, weights)


def run_day_state(plan: DayStatePlan, log: Callable[[str], None] = lambda _: None) -> dict:
    """Each day's value (and what it predicts, with ``cross_validate``), the day's scenes
    written into ``out`` if given; the report. The strikes' days are checked first."""
    request, param = plan.request, plan.param
    chosen = [s for s in plan.strikes if param.applies_to(s.group)]
    undated = [s.trial for s in chosen if not s.recording_day]
    if undated or not chosen:
        raise InputError(f'{request.inputs.strikes}: a day\'s state needs each strike\'s '
                         f'recording_day; missing for {", ".join(undated[:5]) or "every strike"}')
    days = sorted({s.recording_day for s in chosen})
    unsafe = [d for d in days if not SAFE_DAY.fullmatch(d)]
    if request.out is not None and unsafe:
        raise InputError(f'{request.inputs.strikes}: recording_day {unsafe[0]!r} cannot name a '
                         f'scene file (letters, digits, ".", "_" and "-" only)')
    with request.inputs.cluster() as mapper:
        log(f'day-state: {param.label} for {len(days)} recording day(s), {len(chosen)} '
            f'strikes, on {mapper.where} ({mapper.worker_count} worker(s))')
        model = ds.DayStateFit(plan.scenes, chosen, param, plan.weights, mapper)
        states = model.fit(request.iterations, log=log)
        left_out = model.leave_one_out() if request.cross_validate else []
    written, not_written = (write_day_scenes(request.out, plan.scenes, plan.paths, param,
                                             states, chosen)
                            if request.out else ([], []))
    report = {'key': param.label,
              'days': [{'group': s.group, 'day': s.day, 'value': s.value,
                        'std_error': s.std_error, 'strikes': s.strikes,
                        'at_bound': s.at_bound}
                       for s in states],
              'failed_strikes': [f for s in states for f in s.failed],
              'scenes': written, 'scenes_not_written': not_written}
    if request.cross_validate:
        report['leave_one_strike_out'] = ds.left_out_summary(left_out)
    return report


def write_day_scenes(out: Path, scenes, paths, param, states, strikes) -> tuple[list, list]:
    """One scene file per (group, day): the group's file at the day's mean contact angle with
    the day's value (and, for the hold, the scene's braking pinned), its day state on record in
    the provenance. Every day is checked before any file is written; a day whose value its mean
    angle cannot take is not written, with the reason. Returns (written, not written)."""
    docs, refused = [], []
    for state in states:
        day = [s for s in strikes if (s.group, s.recording_day) == (state.group, state.day)]
        angle = float(f'{sum(s.contact_angle_deg for s in day) / len(day):.6g}')
        base = scenes[state.group]
        values = {'geometry.contact_angle_deg': angle,
                  **ds.day_values(base, param.key, state.value)}
        try:
            base.with_values(values)
        except ParameterError as exc:
            refused.append(f'{state.group} {state.day}: {exc}')
            continue
        doc = yaml.safe_load(paths[state.group].read_text(encoding='utf-8'))
        for key, value in values.items():
            section, _, field = key.partition('.')
            doc.setdefault(section, {})[field] = float(f'{value:.6g}')
        scene_name = f'{state.group}_{state.day}'
        doc['name'] = scene_name
        doc['description'] = (f'{(doc.get("description") or "").strip()} Recording day '
                              f'{state.day}: {param.key} fitted to that day\'s strikes, at '
                              f'their mean contact angle (mantis day-state).').strip()
        provenance = doc.setdefault('provenance', {})
        for label, entry in (provenance.get('parameters') or {}).items():
            key, groups = ident.split_label(label)
            if key in values and (groups is None or state.group in groups):
                entry['superseded_by'] = 'day_state'
        provenance['day_state'] = {
            'key': param.key, 'day': state.day, 'value': float(f'{state.value:.6g}'),
            'std_error': float(f'{state.std_error:.3g}'), 'strikes': state.strikes,
            'trials': [s.trial for s in day],
            'date': datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}
        docs.append((out / f'{scene_name}.yaml', doc))
    out.mkdir(parents=True, exist_ok=True)
    for target, doc in docs:
        target.write_text(yaml.safe_dump(doc, sort_keys=False, width=100), encoding='utf-8')
    return [str(target) for target, _ in docs], refused


def day_state_text(report: dict) -> str:
    """The report as `mantis day-state` prints it."""
    lines = [f'{report["key"]}: each recording day\'s own value',
             'group          day        strikes        value   std. error']
    for d in report['days']:
        mark = '  (at a bound)' if d['at_bound'] else ''
        lines.append(f'{d["group"]:14s} {d["day"]:10s} {d["strikes"]:7d} {d["value"]:12.5g} '
                     f'{d["std_error"]:12.3g}{mark}')
    if 'leave_one_strike_out' in report:
        lines.append('leaving one strike out within days (a one-step estimate of the day\'s '
                     'value from its other strikes), median |error|:')
        lines.append('group          strikes   tip speed: scene -> day\'s own   spring energy: '
                     'scene -> day\'s own')
        for group, e in report['leave_one_strike_out'].items():
            lines.append(f'{group:14s} {e["strikes"]:7d}   {_pct(e["tip_speed_shared"])} -> '
                         f'{_pct(e["tip_speed_own_day"])}            '
                         f'{_pct(e["spring_energy_shared"])} -> '
                         f'{_pct(e["spring_energy_own_day"])}')
    for failed in report['failed_strikes']:
        lines.append(f'failed at its day\'s value: {failed}')
    if report['scenes']:
        lines.append('scenes: ' + ', '.join(report['scenes']))
    for refused in report['scenes_not_written']:
        lines.append(f'not written: {refused}')
    return '\n'.join(lines)


def _pct(x: float) -> str:
    return f'{100 * x:5.1f} %' if math.isfinite(x) else '  n/a'
