"""Wall time of the batch analysis of the seven real trials in test/data, as a user runs it:

    .venv/bin/python bench/bench_batch.py [--jobs N] [--table /tmp/x.csv]

times ``mantis analyze test/data/real_trials test/data/air_23mm_2p3mmps_trial1_tracker_export.xlsx
--table /tmp/x.csv`` (a new process: interpreter start and imports included) and prints it with
what the table says. Reading the .xlsx files (~1.5 s each) costs more than analysing them.
"""
import argparse
import csv
import os
from pathlib import Path
import subprocess
import sys
import time

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / 'test' / 'data'
INPUTS = [DATA / 'real_trials', DATA / 'air_23mm_2p3mmps_trial1_tracker_export.xlsx']


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--jobs', type=int, default=None, help='passed to mantis analyze')
    parser.add_argument('--table', default='/tmp/x.csv')
    args = parser.parse_args()
    command = [sys.executable, '-m', 'mantis_rig.cli', 'analyze', *map(str, INPUTS),
               '--table', args.table]
    if args.jobs is not None:
        command += ['--jobs', str(args.jobs)]
    t0 = time.perf_counter()
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    with open(args.table, newline='') as f:
        rows = list(csv.DictReader(f))
    ok = sum(r['status'] == 'ok' for r in rows)
    frames = sum(int(r['n_frames'] or 0) for r in rows)
    print(f'machine: {os.cpu_count()} CPUs; jobs: {args.jobs or "default (one per core)"}')
    print(f'mantis analyze ... --table {args.table}: exit {done.returncode}, {len(rows)} trials '
          f'({ok} analysed, {frames} frames), wall {wall:.2f} s')
    print(done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '(no stderr)')


if __name__ == '__main__':
    main()
