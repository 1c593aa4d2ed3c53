"""A study's verdicts where the truth is known: many simulated studies, each effect judged
against the twin's interval and each trial's value placed in its forecast.

    .venv/bin/python bench/bench_study_calibration.py [--studies 24] [--first-seed 1] [--write]
    .venv/bin/python bench/bench_study_calibration.py --chain --studies 4 --first-seed 100

Each study is `mantis study PLAN --out DIR --real-time-factor 0 --seed S` on the simulated
rig (scene air_23mm_rig): S draws the day (its robot's assembly, its strikes' seats) and the
plan, which varies by seed: one or two of the guide distance, the contact angle and the pull
speed at two levels, an order (random, as-listed, split-plot), 2 to 4 repeats. The first two
are the issue's own plans (docs/study.md's, and contact angle x guide distance split-plot).
The truth of each trial is the robot the simulated world built for it (its conditions and the
arm's seat on the latch, from the world's diagnostics in the bag), integrated as the
ensembles are. The tallies are mantis_sim.studies.rig_study.verdict_calibration's.

--chain measures the simulated rig's measuring chain only (measured against true values), on
seeds of its own (it sets quantities.SIMULATED_RIG_ERROR; the calibration runs on others).
With --write the tables go into docs/study.md ("Calibration on known truth").
"""
import argparse
import csv
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.machine import replace_section, stamp  # noqa: E402
from mantis_rig.recording import BagReader  # noqa: E402
from mantis_rig.runtime.ros_env import claim_free_domain, release_domain  # noqa: E402
from mantis_rig.study_session.record import DONE, read_record  # noqa: E402
from mantis_sim.robots import SessionRobots  # noqa: E402
from mantis_sim.scene import load_scene  # noqa: E402
from mantis_sim.studies.rig_study.quantities import QUANTITIES  # noqa: E402
from mantis_sim.studies.rig_study.verdict_calibration import (  # noqa: E402
    CENTRAL_50,
    CENTRAL_95,
    Coverage,
    chain_errors,
    effect_coverage,
    trial_coverage,
    true_quantities,
)
from mantis_sim.trial_conditions import scene_for_conditions  # noqa: E402

SCENE = 'air_23mm_rig'
SECTION = '## Calibration on known truth'
SLACK_FORCE_N = 0.3
LEVELS = {'d_t_mm': ([19, 23], [19, 25], [21, 25]),
          'contact_angle_deg': ([2, 5], [3, 5], [2, 4]),
          'pull_speed_mm_s': ([1.0, 2.3], [1.5, 2.3], [1.0, 2.0])}
NAMED = [
    {'scene': SCENE, 'factors': {'d_t_mm': [19, 25], 'pull_speed_mm_s': [1.0, 2.3]},
     'repeats': 4, 'order': 'random', 'seed': 5, 'fixed': {'contact_angle_deg': 3.0}},
    {'scene': SCENE, 'factors': {'contact_angle_deg': [2, 5], 'd_t_mm': [19, 23]},
     'repeats': 2, 'order': 'split-plot', 'hard_to_change': 'd_t_mm', 'seed': 0,
     'fixed': {'pull_speed_mm_s': 2.0}},
]


def plan_for(seed: int) -> dict:
    """A plan drawn from the seed (module docstring)."""
    rng = np.random.default_rng([seed, 46])
    names = list(LEVELS)
    chosen = [names[i] for i in rng.choice(len(names), size=int(rng.integers(1, 3)),
                                           replace=False)]
    factors = {name: LEVELS[name][int(rng.integers(len(LEVELS[name])))] for name in chosen}
    order = str(rng.choice(['random', 'as-listed', 'split-plot']))
    plan = {'scene': SCENE, 'factors': factors, 'repeats': int(rng.integers(2, 5)),
            'order': order, 'seed': seed}
    if order == 'split-plot':
        plan['hard_to_change'] = chosen[0]
    return plan


def write_plan(plan: dict, path: Path) -> Path:
    import yaml
    path.write_text(yaml.safe_dump(plan, sort_keys=False), encoding='utf-8')
    return path


def run_study(plan: dict, sim_seed: int, out: Path, log: Path) -> float:
    start = time.monotonic()
    with open(log, 'w') as handle:
        subprocess.run([sys.executable, '-m', 'mantis_rig.cli', 'study',
                        str(write_plan(plan, out.with_suffix('.yaml'))), '--out', str(out),
                        '--real-time-factor', '0', '--seed', str(sim_seed)],
                       cwd=REPO, stdout=handle, stderr=subprocess.STDOUT, check=True)
    return time.monotonic() - start


def latching_of(bag: Path) -> tuple[int, dict]:
    """(the number of the latching that struck, its conditions) in a trial's bag: the
    simulated world's latching when the trial began (a latching rebuilt at the trial's
    conditions keeps its number), its conditions as the world last reported them."""
    latching, conditions = None, None
    for message in BagReader(bag, warn=False).messages(['/diagnostics']):
        for status in message.message.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'latch_offset_deg' not in values:
                continue
            if latching is None:
                latching = int(values['strikes'])
            if int(values['strikes']) == latching:
                conditions = {'d_t_mm': float(values['d_t_mm']),
                              'contact_angle_deg': float(values['contact_angle_deg']),
                              'medium': values['medium']}
    if latching is None:
        raise RuntimeError(f'{bag}: the simulated world never reported its robot')
    return latching, conditions


def truth_pairs(directory: Path, scene, sim_seed: int) -> list:
    """(row, true quantities) of each done trial: its robot drawn as the simulated world drew
    it (mantis_sim.robots.SessionRobots, the session's seed, the latching's number)."""
    robots = SessionRobots(scene, sim_seed)
    pairs = []
    for row in read_record(directory / 'study.csv').rows:
        if row['status'] != DONE or not row.get('bag'):
            continue
        latching, conditions = latching_of(directory / row['bag'])
        conditions['pull_speed_mm_s'] = row['pull_speed_mm_s']
        seat = robots(latching, scene_for_conditions(scene, conditions)).geometry.latch_offset_deg
        pairs.append((row, true_quantities(scene, conditions, seat, SLACK_FORCE_N)))
    return pairs


def read_effects(directory: Path) -> list:
    with open(directory / 'report' / 'effects.csv', newline='', encoding='utf-8') as handle:
        return list(csv.DictReader(handle))


def tables(studies: list, chain_only: bool) -> str:
    rows = [r for s in studies for r in s['rows'] if r['status'] == DONE]
    effects = [e for s in studies for e in s['effects']]
    errors = chain_errors(p for s in studies for p in s['pairs'])
    lines = [f'{len(studies)} simulated studies, {len(rows)} trials done, '
             f'{len(effects)} effects.', '']
    if not chain_only:
        total = Coverage(0, 0)
        lines += ['| quantity | effects inside the twin\'s 95 % | trials inside their 50 % | '
                  'trials inside their 95 % |', '|---|---|---|---|']
        for name, q in QUANTITIES.items():
            cover = effect_coverage(effects, name)
            total = total + cover
            lines.append(f'| {q.axis} | {cover.text()} | '
                         f'{trial_coverage(rows, name, CENTRAL_50).text()} | '
                         f'{trial_coverage(rows, name, CENTRAL_95).text()} |')
        lines += [f'| all | {total.text()} | | |', '']
    lines += ['The simulated rig\'s measuring chain, measured against the true robot of each '
              'trial (relative):', '', '| quantity | bias | scatter (sd) | trials |',
              '|---|---|---|---|']
    for name, (bias, sd, n) in errors.items():
        lines.append(f'| {QUANTITIES[name].axis} | {100 * bias:+.2f} % | {100 * sd:.2f} % | '
                     f'{n} |')
    return '\n'.join(lines) + '\n'


def named_tables(studies: list) -> str:
    lines = []
    for s in studies[:len(NAMED)]:
        factors = ' x '.join(s['plan']['factors'])
        lines += ['', f'{factors} ({s["plan"]["order"]}, {s["plan"]["repeats"]} repeats, plan '
                  f'seed {s["plan"]["seed"]}, rig seed {s["sim_seed"]}):', '',
                  '| change | quantity | measured (95 %) | twin\'s forecast (95 %) | inside |',
                  '|---|---|---|---|---|']
        for e in s['effects']:
            inside = float(e['twin_low_95']) <= float(e['measured']) <= float(e['twin_high_95'])
            lines.append(f'| {e["factor"]} {e["reference"]} to {e["level"]} | '
                         f'{QUANTITIES[e["quantity"]].axis} | {float(e["measured"]):.4g} '
                         f'[{float(e["low_95"]):.4g}, {float(e["high_95"]):.4g}] | '
                         f'{float(e["twin"]):.4g} [{float(e["twin_low_95"]):.4g}, '
                         f'{float(e["twin_high_95"]):.4g}] | {"yes" if inside else "no"} |')
    return '\n'.join(lines) + '\n'


def write_docs(text: str) -> None:
    replace_section(REPO / 'docs' / 'study.md', SECTION, text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--studies', type=int, default=24)
    parser.add_argument('--first-seed', type=int, default=1)
    parser.add_argument('--chain', action='store_true',
                        help='measure the measuring chain only (no named plans)')
    parser.add_argument('--keep', type=Path, help='keep the studies in this folder')
    parser.add_argument('--write', action='store_true', help='write docs/study.md\'s table')
    args = parser.parse_args()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    domain = claim_free_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    scene = load_scene(SCENE)
    plans = [] if args.chain else [(dict(p), 0) for p in NAMED]
    plans += [(plan_for(s), s) for s in range(args.first_seed, args.first_seed + args.studies)]
    studies = []
    started = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix='calibration_') as tmp:
            base = args.keep or Path(tmp)
            base.mkdir(parents=True, exist_ok=True)
            for k, (plan, sim_seed) in enumerate(plans, start=1):
                out = base / f'study_{k:02d}_seed{sim_seed}'
                wall = run_study(plan, sim_seed, out, base / f'study_{k:02d}.log')
                record = read_record(out / 'study.csv')
                studies.append({'plan': plan, 'sim_seed': sim_seed, 'rows': record.rows,
                                'effects': [] if args.chain else read_effects(out),
                                'pairs': truth_pairs(out, scene, sim_seed)})
                print(f'study {k}/{len(plans)}: {len(record.rows)} trials, {wall:.0f} s '
                      f'({time.monotonic() - started:.0f} s in all)', flush=True)
    finally:
        release_domain(domain)
    text = (f'{stamp()}\n\n' + tables(studies, args.chain)
            + ('' if args.chain else named_tables(studies)))
    print(text)
    if args.write and not args.chain:
        write_docs(text)


if __name__ == '__main__':
    main()
