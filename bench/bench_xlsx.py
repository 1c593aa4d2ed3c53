"""Reading the tracker's spreadsheets: the shared .xlsx exports read now (python-calamine) and
as before (openpyxl, the tree of ``--before``), the same tracks from both.

    .venv/bin/python bench/bench_xlsx.py [--before fadfc3f] [--repeat 3]

"Before" is ``load_tracks`` of the commit ``--before`` (default: the last one that read the
.xlsx with openpyxl), extracted with ``git archive`` and run in a process of its own; "now" is
``load_tracks`` of this tree. Each is the best of ``--repeat`` reads of the file, in processes
that have imported everything first. The tracks each gives (times, frames, every coordinate,
camera frame, rate, unit, the header block) must be identical, or the script fails. Prints a
Markdown table for docs/performance.md, its caption stamped by bench/machine.py.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import pickle
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import REPO, stamp  # noqa: E402

DATA = REPO / 'test' / 'data'
EXPORTS = ['air_23mm_2p3mmps_trial1_tracker_export.xlsx', 'real_trials/air_19mm_11kfps.xlsx',
           'real_trials/air_19mm_6kfps.xlsx', 'real_trials/air_23mm_19kfps_4markers.xlsx',
           'real_trials/air_23mm_19kfps_ma3.xlsx', 'real_trials/air_23mm_19kfps_pair.xlsx',
           'real_trials/water_23mm_19kfps.xlsx']
BEFORE = 'fadfc3f'

# Run in a process of its own, with the tree to measure first on sys.path: the best time of
# `repeat` reads of each file, and the tracks of the last, as plain values.
_WORKER = r'''
import pickle, sys, time
sys.path.insert(0, sys.argv[1])
from mantis_rig.analysis import load_tracks
files, repeat = sys.argv[3].split('\n'), int(sys.argv[4])
out = {}
for f in files:
    best = float('inf')
    for _ in range(repeat):
        start = time.perf_counter()
        tracks = load_tracks(f)
        best = min(best, time.perf_counter() - start)
    out[f] = (best, {'time_s': tracks.time_s, 'frames': tracks.frames,
                     'markers_mm': tracks.markers_mm, 'handedness': tracks.handedness,
                     'tilt_deg': tracks.tilt_deg, 'frame_rate_hz': tracks.frame_rate_hz,
                     'length_unit': tracks.length_unit, 'source': tracks.source})
with open(sys.argv[2], 'wb') as f:
    pickle.dump(out, f)
'''


def measure(tree: Path, files: list[Path], repeat: int, out: Path) -> dict:
    """{file: (best seconds, tracks as values)} of ``load_tracks`` from ``tree``."""
    subprocess.run([sys.executable, '-c', _WORKER, str(tree), str(out),
                    '\n'.join(map(str, files)), str(repeat)], check=True, cwd=tempfile.gettempdir())
    with open(out, 'rb') as f:
        return pickle.load(f)


def differences(a: dict, b: dict) -> list[str]:
    """What differs between two tracks, as values (empty: identical; NaN equals NaN)."""
    found = []
    for key in ('time_s', 'frames'):
        if not np.array_equal(a[key], b[key]):
            found.append(key)
    if a['markers_mm'].keys() != b['markers_mm'].keys():
        found.append('marker names')
    else:
        found += [f'marker {n}' for n, xy in a['markers_mm'].items()
                  if not np.array_equal(xy, b['markers_mm'][n], equal_nan=True)]
    found += [k for k in ('handedness', 'tilt_deg', 'frame_rate_hz', 'length_unit', 'source')
              if a[k] != b[k]]
    return found


def extract(commit: str, into: Path) -> Path:
    """The packages of ``commit``, as files under ``into``."""
    archive = subprocess.run(['git', 'archive', commit, 'mantis_rig', 'mantis_sim'], cwd=REPO,
                             capture_output=True, check=True).stdout
    subprocess.run(['tar', '-x', '-C', str(into)], input=archive, check=True)
    return into


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--before', default=BEFORE, help=f'the commit to compare with '
                        f'(default {BEFORE}: openpyxl)')
    parser.add_argument('--repeat', type=int, default=3, help='reads of each file (best of)')
    args = parser.parse_args(argv)
    files = [DATA / rel for rel in EXPORTS]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / 'before').mkdir()
        before_tree = extract(args.before, tmp / 'before')
        now = measure(REPO, files, args.repeat, tmp / 'now.pkl')
        before = measure(before_tree, files, args.repeat, tmp / 'before.pkl')
    print(f'{stamp()}; before: commit {args.before}; best of {args.repeat} reads each\n')
    print('| export | frames | markers | before (openpyxl), s | now (python-calamine), s '
          '| speed-up | tracks |')
    print('|---|---:|---:|---:|---:|---:|---|')
    failed = False
    total_before = total_now = 0.0
    for path in files:
        key = str(path)
        (t_before, a), (t_now, b) = before[key], now[key]
        diff = differences(a, b)
        failed |= bool(diff)
        total_before, total_now = total_before + t_before, total_now + t_now
        print(f'| `{path.relative_to(DATA)}` | {len(b["time_s"]):,} | {len(b["markers_mm"])} '
              f'| {t_before:.2f} | {t_now:.3f} | {t_before / t_now:.1f}x '
              f'| {"identical" if not diff else "DIFFER: " + ", ".join(diff)} |')
    speedups = [before[str(p)][0] / now[str(p)][0] for p in files]
    print(f'| all {len(files)} | | | {total_before:.2f} | {total_now:.3f} '
          f'| {total_before / total_now:.1f}x (each {min(speedups):.1f}-{max(speedups):.1f}x) | |')
    if failed:
        print('\nthe tracks differ', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
