"""What a design study costs: `mantis sweep` over many designs of a scene on this machine's
local Dask workers, and how close each design is to the reference path (prints figures and
writes docs/sweep_benchmark.md; not a test).

    .venv/bin/python bench/bench_sweep.py [--designs 2000] [--scene air_23mm]
                                          [--accuracy 1e-3] [--judged 4]

A Latin hypercube over the tendon guide distance (19-25 mm), the contact angle (1-8 deg) and
the pull speed (0.5-2.4 mm/s). `mantis sweep --accuracy` chooses the solver and tolerance (its
time is printed apart); the sweep runs with 1 and 2 workers: strikes per second of wall time
(from a ready cluster to the last row), also scaled to a yardstick of 0.5 s. Then every design
is solved again by the fast path at rtol 1e-10, and that by the judge, scipy's Radau at rtol
1e-10, on --judged designs: the largest relative errors in peak tip speed and spring energy.
"""
import argparse
from pathlib import Path
import sys
import tempfile
import time

from machine import REPO, stamp, yardstick_s

from mantis_sim.studies.design.accuracy import choose_setting
from mantis_sim.studies.design.designs import latin_hypercube, parse_range, run_chunk
from mantis_sim.studies.design.sweep import read_table, run_sweep
from mantis_sim.studies.shared.parallel import ClusterMap

RANGES = ('geometry.d_t_mm=19:25', 'geometry.contact_angle_deg=1:8',
          'drive.pull_speed_mm_per_s=0.5:2.4')
COMPARED = ('peak_tip_speed_mps', 'max_spring_energy_mJ')
FAST_REFERENCE = ['integration.solver=fast', 'integration.rtol=1e-10']
JUDGE = ['integration.solver=Radau', 'integration.rtol=1e-10']


def _rows(scene, overrides, designs, mapper, per_chunk=20):
    chunks = [designs[i:i + per_chunk] for i in range(0, len(designs), per_chunk)]
    return [row for rows in mapper(_chunk, [(scene, overrides, c) for c in chunks])
            for row in rows]


def _chunk(task):
    return run_chunk(*task)


def worst_error(rows, reference) -> dict:
    worst = {}
    for key in COMPARED:
        worst[key] = max(abs(r[key] / ref[key] - 1.0) for r, ref in zip(rows, reference)
                         if r['status'] == 'ok' and ref['status'] == 'ok')
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--designs', type=int, default=2000)
    parser.add_argument('--scene', default='air_23mm')
    parser.add_argument('--accuracy', type=float, default=1e-3)
    parser.add_argument('--judged', type=int, default=4,
                        help='designs solved by the judge (scipy Radau at 1e-10: slow)')
    args = parser.parse_args()
    lines = [f'# What a sweep costs: {args.scene}', '',
             f'Written by `bench/bench_sweep.py` ({stamp()}).', '']

    def say(text=''):
        print(text, flush=True)
        lines.append(text)

    designs = latin_hypercube([parse_range(r, need_n=False) for r in RANGES], args.designs)
    setting = choose_setting(args.scene, [], args.accuracy, designs)
    say(f'- `--accuracy {args.accuracy:g}` chose {setting}.')
    work = Path(tempfile.mkdtemp(prefix='bench_sweep_'))
    rates = {}
    for workers in (1, 2):
        yard = yardstick_s()           # the machine idle, just before
        summary = run_sweep(args.scene, setting.overrides(), designs,
                            work / f'workers{workers}.parquet', workers=workers,
                            estimated_strike_s=setting.wall_ms * 1e-3, progress=False)
        rates[workers] = summary.computed / summary.wall_s
        say(f'- {workers} worker(s): {summary.computed} designs in {summary.wall_s:.2f} s = '
            f'**{rates[workers]:.0f} strikes/s** (yardstick {yard:.2f} s; at yardstick 0.5: '
            f'{rates[workers] * yard / 0.5:.0f}/s); the designs themselves '
            f'{1e3 * summary.strikes_s / summary.computed:.2f} ms each; scheduling and '
            f'transfer {100 * summary.overhead_share:.1f} % of the workers\' time; '
            f'{summary.ok} struck.')
    say(f'- parallel efficiency with 2 workers: {100 * rates[2] / (2 * rates[1]):.0f} %.')
    swept = read_table(work / 'workers2.parquet')
    inputs = [{k: row[k] for k in designs[0]} for row in swept]
    # the fine solutions are kept between runs of this script (the sweep resumes from them)
    cache = Path(tempfile.gettempdir()) / f'bench_sweep_{args.scene}_fine.parquet'
    started = time.monotonic()
    run_sweep(args.scene, FAST_REFERENCE, inputs, cache, workers=2, estimated_strike_s=0.3,
              progress=False)
    fine_s = time.monotonic() - started
    by_id = {row['design_id']: row for row in read_table(cache)}
    fine = [by_id[row['design_id']] for row in swept]
    with ClusterMap(workers=2) as mapper:
        started = time.monotonic()
        judged = _rows(args.scene, JUDGE, inputs[:args.judged], mapper, per_chunk=1)
        judge_s = time.monotonic() - started
    errors = worst_error(swept, fine)
    say(f'- every design against the fast path at rtol 1e-10 ({fine_s:.0f} s, or from the '
        f'cache of an earlier run): largest '
        f'relative error {errors["peak_tip_speed_mps"]:.1e} in peak tip speed, '
        f'{errors["max_spring_energy_mJ"]:.1e} in spring energy (goal 1e-3).')
    agreement = worst_error(fine[:args.judged], judged)
    direct = worst_error(swept[:args.judged], judged)
    say(f'- {args.judged} designs against the judge, scipy\'s Radau at rtol 1e-10 '
        f'({judge_s:.0f} s): the fast path at 1e-10 agrees to '
        f'{max(agreement.values()):.1e}; the swept rows are within '
        f'{direct["peak_tip_speed_mps"]:.1e} (tip speed) and '
        f'{direct["max_spring_energy_mJ"]:.1e} (spring energy).')
    path = REPO / 'docs' / 'sweep_benchmark.md'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print(f'written: {path.relative_to(REPO)}')


if __name__ == '__main__':
    sys.exit(main())
