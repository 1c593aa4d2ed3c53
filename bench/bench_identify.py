"""Time `mantis identify` on the whole training set (goal: at most 2 minutes on 2 cores).

    .venv/bin/python bench/bench_identify.py [--data ../shared/data/real_trials] [--iterations 6]

Fits the parameters the shipped scenes were identified with (their provenance), starting from
the shipped values, on a local Dask cluster of this machine's cores, and prints the wall time,
the strikes simulated per second and the machine's yardstick, and writes them to
docs/identify_benchmark.md.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

from machine import REPO, stamp

from mantis_sim.scene import load_scene
from mantis_sim.studies.real_strikes import identify as ident
from mantis_sim.studies.real_strikes.strikes import read_strikes
from mantis_sim.studies.shared.parallel import ClusterMap

GROUPS = ('air_19mm', 'air_23mm', 'water_23mm')


def free_parameters(scenes) -> list:
    """The labels fitted for the shipped scenes, with the bounds they were fitted within."""
    seen = {}
    for scene in scenes.values():
        for label, entry in ((scene.provenance or {}).get('parameters') or {}).items():
            lo, hi = entry['bounds']
            seen[label] = f'{label}={lo}:{hi}'
    return [ident.parse_free_parameter(text, scenes) for text in seen.values()]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--data', type=Path,
                        default=REPO.parent / 'shared' / 'data' / 'real_trials')
    parser.add_argument('--iterations', type=int, default=6)
    parser.add_argument('--workers', type=int, default=None)
    args = parser.parse_args()
    strikes = read_strikes(args.data / 'authors_summary_train.csv',
                           args.data / 'authors_processed')
    scenes = {g: load_scene(g) for g in GROUPS}
    params = free_parameters(scenes)
    if not params:
        print('the shipped scenes carry no identification provenance', file=sys.stderr)
        return 1
    started = time.monotonic()
    with ClusterMap(None, args.workers, progress=True) as mapper:
        up = time.monotonic() - started
        model = ident.StrikeModel(scenes, strikes, params, ident.Weights(), mapper)
        fit = ident.identify(model, max_iterations=args.iterations)
        workers = mapper.worker_count
    wall = time.monotonic() - started
    simulated = fit.evaluations * len(strikes)
    line = (f'mantis identify, {len(strikes)} strikes, {len(params)} parameters, '
            f'{args.iterations} iterations at most: {wall:.0f} s wall (cluster up in {up:.1f} s) '
            f'on {workers} workers; {fit.evaluations} evaluations of the set, {simulated} '
            f'strikes, {simulated / max(wall - up, 1e-9):.1f} strikes/s; goal 120 s')
    text = (f'# What identification costs\n\nWritten by `bench/bench_identify.py` ({stamp()}): '
            f'the whole training set, the parameters the shipped scenes were fitted with, '
            f'starting from the shipped values.\n\n{line}\n')
    (REPO / 'docs' / 'identify_benchmark.md').write_text(text, encoding='utf-8')
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
