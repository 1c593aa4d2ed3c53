"""The analysis of the project's real trials (test/data) against the authors' values.

Prints one markdown row per file and the median and worst errors (the README's table).

    .venv/bin/python bench/bench_real_trials.py
"""
from pathlib import Path
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))

from conftest import authors_values, data_file  # noqa: E402

from mantis_rig.analysis import AnalysisParams, analyze_tracks, load_tracks  # noqa: E402


def main() -> None:
    print('| file | frames/s | peak tip speed m/s (authors) | error | phase IV s (authors) | '
          'error frames | L1 mm (authors) | overcentering s (authors) | max spring energy mJ '
          '(authors) |')
    print('|---|---|---|---|---|---|---|---|---|')
    v_err, iv_err, l1_err = [], [], []
    t0 = time.perf_counter()
    for rel, ref in authors_values().items():
        tracks = load_tracks(data_file(rel))
        a = analyze_tracks(tracks, AnalysisParams(d_t_mm=ref['d_t_mm']))
        s = a.summary()
        rate = 1.0 / float(np.median(np.diff(tracks.time_s)))
        v = s['peak_tip_speed_mps'] / ref['v_max_mps'] - 1
        iv = (s['phase_start_s']['IV'] - ref['t_z1_s']) * rate
        dl = s['L1_mm'] - ref['L1_mm']
        if not rel.endswith('_track.csv'):           # the pair's spreadsheet, once
            v_err.append(abs(v))
            iv_err.append(abs(iv))
            l1_err.append(abs(dl))
        print(f'| `{Path(rel).name}` | {rate:,.0f} | {s["peak_tip_speed_mps"]:.2f} '
              f'({ref["v_max_mps"]:.2f}) | {100 * v:+.1f} % | {s["phase_start_s"]["IV"]:.4f} '
              f'({ref["t_z1_s"]:.4f}) | {iv:+.1f} | {s["L1_mm"]:.2f} ({ref["L1_mm"]:.2f}) | '
              f'{s["overcentering_s"]:.4f} ({ref["t_oc_s"]:.4f}, {s["overcentering_method"]}) | '
              f'{s["max_spring_energy_mJ"]:.0f} ({ref["PE_max_mJ"]:.0f}) |')
    print(f'\n{len(v_err)} trials in {time.perf_counter() - t0:.1f} s: peak tip speed error median '
          f'{100 * np.median(v_err):.1f} %, worst {100 * max(v_err):.1f} %; phase IV median '
          f'{np.median(iv_err):.1f} frames, worst {max(iv_err):.1f}; L1 median '
          f'{np.median(l1_err):.2f} mm, worst {max(l1_err):.2f} mm')


if __name__ == '__main__':
    main()
