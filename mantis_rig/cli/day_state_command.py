"""`mantis day-state`: a recording day's own value of one scene key, from that day's strikes.

The identified scenes stand for the robot across days; strikes of one day share its assembly.
This fits one key (default where the arm sits on the latch, `geometry.latch_offset_deg`) to
each day's strikes with the rest of the scene held, reports each day's value and, with
`--cross-validate`, what the day's value predicts for a strike it did not see (leaving one
strike out within days);
`--out` writes today's robot as a scene per day (`<group>_<day>.yaml`).
"""
from __future__ import annotations

import datetime
import json
import math
from pathlib import Path
import re

import yaml

from mantis_rig.cli.options import check_out_folder, json_safe
from mantis_rig.cli.real_strike_commands import _load_strikes, _log, _scenes, _strike_arguments
from mantis_sim.errors import InputError
from mantis_sim.parameters import ParameterError
from mantis_sim.studies.real_strikes import day_state as ds
from mantis_sim.studies.real_strikes import identify as ident
from mantis_sim.studies.shared.parallel import ClusterMap

SAFE_DAY = re.compile(r'[A-Za-z0-9_.-]+')


def add_commands(commands) -> None:
    cmd = commands.add_parser(
        'day-state', help="a recording day's own value of a scene key, from its strikes",
        description='Fit one scene key to each recording day\'s strikes, the rest of the '
                    'scene held: the day\'s own state (default: where the arm sits on the '
                    'latch). With '
                    '--cross-validate, leave one strike out within days and report what the '
                    'day\'s value predicts; with --out, write a scene per day.')
    _strike_arguments(cmd)
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
    strikes = _load_strikes(args)
    scenes, paths = _scenes(args, strikes)
    param = ident.parse_free_parameter(args.key, scenes, option='--key')
    for scene in scenes.values():
        ident.scene_value(scene, param.key)             # refuses a key with nothing to start
    weights = ident.Weights.parse(args.weight)
    if args.iterations < 1:
        raise InputError(f'--iterations {args.iterations}: must be >= 1')
    check_out_folder(args.out)
    chosen = [s for s in strikes if param.applies_to(s.group)]
    undated = [s.trial for s in chosen if not s.recording_day]
    if undated or not chosen:
        raise InputError(f'{args.strikes}: a day\'s state needs each strike\'s recording_day; '
                         f'missing for {", ".join(undated[:5]) or "every strike"}')
    days = sorted({s.recording_day for s in chosen})
    unsafe = [d for d in days if not SAFE_DAY.fullmatch(d)]
    if args.out is not None and unsafe:
        raise InputError(f'{args.strikes}: recording_day {unsafe[0]!r} cannot name a scene '
                         f'file (letters, digits, ".", "_" and "-" only)')
    with ClusterMap(args.scheduler, args.workers, progress=not args.json) as mapper:
        _log(f'day-state: {param.label} for {len(days)} recording day(s), {len(chosen)} '
             f'strikes, on {mapper.where} ({mapper.worker_count} worker(s))')
        model = ds.DayStateFit(scenes, chosen, param, weights, mapper)
        states = model.fit(args.iterations, log=_log)
        left_out = model.leave_one_out() if args.cross_validate else []
    written, not_written = (_write_scenes(args.out, scenes, paths, param, states, chosen)
                            if args.out else ([], []))
    report = {'key': param.label,
              'days': [{'group': s.group, 'day': s.day, 'value': s.value,
                        'std_error': s.std_error, 'strikes': s.strikes,
                        'at_bound': s.at_bound}
                       for s in states],
              'failed_strikes': [f for s in states for f in s.failed],
              'scenes': written, 'scenes_not_written': not_written}
    if args.cross_validate:
        report['leave_one_strike_out'] = ds.left_out_summary(left_out)
    print(json.dumps(json_safe(report)) if args.json else _text(report))
    return 0


def _write_scenes(out: Path, scenes, paths, param, states, strikes) -> tuple[list, list]:
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


def _text(report: dict) -> str:
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
