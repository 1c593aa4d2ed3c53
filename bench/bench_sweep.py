"""What a design study costs: `mantis sweep` over many designs of a scene, with 1 and 2 local
Dask workers (prints figures; not a test).

    .venv/bin/python bench/bench_sweep.py [--designs 10000] [--scene reference_air_23mm]
                                          [--accuracy 1e-3]

A Latin hypercube over the tendon guide distance (19-25 mm), the contact angle (1-8 deg) and
the pull speed (0.5-2.4 mm/s). For each worker count: strikes per second of wall time (from a
ready cluster to the last row), and the share of the workers' time that is not the designs'
own computing (their simulation and metrics): scheduling, transfer, writing the table.
Parallel efficiency = rate with 2 workers / (2 x rate with 1).
"""
import argparse
import os
from pathlib import Path
import sys
import tempfile

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mantis_sim.designs import latin_hypercube, parse_range  # noqa: E402
from mantis_sim.studies.accuracy import choose_setting  # noqa: E402
from mantis_sim.studies.sweep import run_sweep  # noqa: E402

RANGES = ('geometry.d_t_mm=19:25', 'geometry.contact_angle_deg=1:8',
          'drive.pull_speed_mm_per_s=0.5:2.4')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--designs', type=int, default=10_000)
    parser.add_argument('--scene', default='reference_air_23mm')
    parser.add_argument('--accuracy', type=float, default=1e-3)
    args = parser.parse_args()
    setting = choose_setting(args.scene, [], args.accuracy)
    print(f'machine: {os.cpu_count()} CPUs; scene {args.scene}; {args.designs} designs; '
          f'--accuracy {args.accuracy:g}: {setting}')
    designs = latin_hypercube([parse_range(r, need_n=False) for r in RANGES], args.designs)
    rates = {}
    work = Path(tempfile.mkdtemp(prefix='bench_sweep_'))
    for workers in (1, 2):
        summary = run_sweep(args.scene, setting.overrides(), designs,
                            work / f'workers{workers}.parquet', workers=workers,
                            estimated_strike_s=setting.wall_ms * 1e-3, progress=False)
        rates[workers] = summary.computed / summary.wall_s
        print(f'{workers} worker(s): {summary.computed} designs in {summary.wall_s:.1f} s = '
              f'{rates[workers]:.0f} strikes/s; the designs themselves {summary.strikes_s:.1f} s '
              f'({1e3 * summary.strikes_s / summary.computed:.2f} ms each); scheduling and '
              f'transfer {100 * summary.overhead_share:.1f} % of the workers\' time; '
              f'{summary.ok} struck')
    print(f'parallel efficiency with 2 workers: {100 * rates[2] / (2 * rates[1]):.0f} % '
          f'(goal >= 80 %)')


if __name__ == '__main__':
    main()
