"""What the fast strike engine costs against scipy's Radau, and the stiff tendon against the
rigid one (prints figures and writes docs/fast_engine_benchmark.md; not a test).

    .venv/bin/python bench/bench_fast_engine.py [--repeats 5]

1. Every shipped scene at its own tolerance: the median wall time of one strike (the
   simulation, trajectory and metrics) on the fast path and on scipy's Radau, whatever the
   scene's own solver, and how far apart their peak tip speeds are.
2. air_23mm_compliant at 1e6 N/mm against the same scene with a rigid tendon, both on the
   fast path at the scene's tolerance: wall time, and the error in peak tip speed and spring
   energy against the compliant tendon solved in full (its ringing resolved) at rtol 1e-8.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

from machine import REPO, stamp

from mantis_sim.fast import warm_up
from mantis_sim.results import simulate
from mantis_sim.scene import available_scenes, load_scene

STIFF = ['tendon.stiffness_N_per_mm=1e6']
# The compliant tendon resolved in full: at 1e-10 its ringing (tens of kHz, undamped) takes more
# than the 2,000,000 right-hand sides of the backstop within the stage's first 22 ms.
REFERENCE_RTOL = 1e-8


def timed(scene, repeats: int):
    """(median wall s, metrics) of simulate(scene)."""
    walls, metrics = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        metrics = simulate(scene).metrics
        walls.append(time.perf_counter() - started)
    return statistics.median(walls), metrics


def rel(a: float, b: float) -> float:
    return abs(a / b - 1.0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args()
    warm_up()
    lines = ['# The fast strike engine', '', f'Written by `bench/bench_fast_engine.py` '
             f'({stamp()}; medians of {args.repeats} runs, one process).', '',
             '## One strike, each shipped scene at its own tolerance', '',
             '| scene | rtol | fast (ms) | scipy Radau (ms) | speed-up '
             '| peak tip speeds differ by |',
             '|---|---|---|---|---|---|']
    for name in available_scenes():
        scene = load_scene(name, ['integration.solver=fast'])
        fast_s, fast = timed(scene, args.repeats)
        scipy_s, theirs = timed(scene.with_values({'integration.solver': 'Radau'}),
                                max(1, args.repeats // 2))
        lines.append(f'| {name} | {scene.integration.rtol:g} | {fast_s * 1e3:.1f} | '
                     f'{scipy_s * 1e3:.0f} | {scipy_s / fast_s:.0f}x | '
                     f'{rel(fast["peak_tip_speed_mps"], theirs["peak_tip_speed_mps"]):.1e} |')
        print(lines[-1], flush=True)

    base = load_scene('air_23mm_compliant')
    stiff = base.with_overrides(STIFF)
    rigid = base.with_values({'tendon.model': 'rigid'})
    full = stiff.with_values({'integration.rigid_tendon_below': 0.0})
    reference = simulate(full.with_values({'integration.rtol': REFERENCE_RTOL})).metrics
    coarser = simulate(full.with_values({'integration.rtol': REFERENCE_RTOL * 10})).metrics
    floor = rel(coarser['peak_tip_speed_mps'], reference['peak_tip_speed_mps'])
    lines += ['', '## The stiff tendon', '',
              f'air_23mm_compliant at 1e6 N/mm, rtol {base.integration.rtol:g}; errors against '
              f'the compliant tendon solved in full at rtol {REFERENCE_RTOL:g} (peak tip speed '
              f'{reference["peak_tip_speed_mps"]:.9f} m/s; at ten times that tolerance it '
              f'differs by {floor:.1e}: the floor of these errors).', '',
              '| tendon | wall (ms) | against the rigid tendon | tip speed error | '
              'spring energy error | how |', '|---|---|---|---|---|---|']
    rigid_s, _ = timed(rigid, args.repeats)
    for label, scene in (('rigid', rigid), ('1e6 N/mm', stiff),
                         ('1e6 N/mm, ringing resolved', full)):
        wall_s, m = timed(scene, args.repeats)
        how = m['rigid_tendon_limit'] or ('rigid tendon' if label == 'rigid'
                                          else 'compliant tendon integrated')
        lines.append(f'| {label} | {wall_s * 1e3:.1f} | {wall_s / rigid_s:.2f}x | '
                     f'{rel(m["peak_tip_speed_mps"], reference["peak_tip_speed_mps"]):.1e} | '
                     f'{rel(m["max_spring_energy_mJ"], reference["max_spring_energy_mJ"]):.1e} '
                     f'| {how} |')
        print(lines[-1], flush=True)
    path = REPO / 'docs' / 'fast_engine_benchmark.md'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print(f'written: {path.relative_to(REPO)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
