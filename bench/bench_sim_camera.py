"""What `mantis analyze` recovers from the simulated camera, over the frame phase.

One strike of the scene's world, filmed at N evenly spaced frame phases (pixel-quantised as the
scene asks), each film analysed as a trial bag of that scene is: the spread of the errors
against the world's truth (mantis_rig.analysis.sim_camera_study).

    .venv/bin/python bench/bench_sim_camera.py [--scene air_23mm_rig] [--phases 16]
                                               [--frame-rate 19000 37000]
"""
import argparse
from pathlib import Path
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mantis_rig.analysis.sim_camera_study import (  # noqa: E402
    PHASES,
    phase_sweep,
    run_strike,
    truth_of,
)
from mantis_sim.scene import load_scene  # noqa: E402


def _row(name, values, unit, fmt):
    v = np.asarray(values)
    return (f'| {name} | {fmt.format(v.min())} | {fmt.format(np.median(v))} | '
            f'{fmt.format(v.max())} | {fmt.format(np.max(np.abs(v)))} | {unit} |')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scene', default='air_23mm_rig')
    ap.add_argument('--phases', type=int, default=16)
    ap.add_argument('--frame-rate', type=float, nargs='+', default=None)
    args = ap.parse_args()
    scene = load_scene(args.scene)
    world = run_strike(scene)
    truth = truth_of(world)
    print(f'scene {scene.name}: phase starts (world) '
          + ', '.join(f'{p} {truth.phase_start_s[p]:.6f} s' for p in PHASES)
          + f', peak {truth.peak_time_s:.6f} s at {truth.peak_tip_speed_mps:.4f} m/s; '
          f'pixel {scene.camera.pixel_mm} mm')
    for rate in args.frame_rate or [scene.camera.frame_rate_hz]:
        t0 = time.perf_counter()
        films = phase_sweep(world, truth, rate, args.phases)
        wall = time.perf_counter() - t0
        print(f'\n{rate:g} frames/s, {args.phases} frame phases '
              f'({wall / args.phases:.2f} s per film analysed)\n')
        print('| error | min | median | max | max abs | unit |')
        print('|---|---|---|---|---|---|')
        print(_row('peak tip speed', [100 * f.peak_tip_speed_rel for f in films], '%',
                   '{:+.2f}'))
        print(_row('peak tip speed time', [f.peak_time_frames for f in films], 'frames',
                   '{:+.2f}'))
        for p in PHASES:
            print(_row(f'start of {p}', [f.phase_frames[p] for f in films], 'frames',
                       '{:+.2f}'))
        within = sum(abs(f.peak_tip_speed_rel) < 0.01 for f in films)
        print(f'\npeak tip speed within 1 %: {within} of {len(films)} phases')


if __name__ == '__main__':
    main()
