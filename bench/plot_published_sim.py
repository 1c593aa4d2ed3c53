"""The scene published_s12 against the authors' published simulation, over the strike.

Four panels (theta1, theta3, tip speed, tendon force) from the arm leaving contact to just past
the peak tip speed, the published curves (their Fig. S12 .mat, test/data/published_sims) and
this model's, and the figures of the README's table printed.

    .venv/bin/python bench/plot_published_sim.py [--out docs/published_s12.png]
"""
import argparse
from pathlib import Path
import sys

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))

from conftest import published_s12_run  # noqa: E402

from mantis_sim.results import simulate  # noqa: E402
from mantis_sim.scene import load_scene  # noqa: E402

WINDOW_MS = (1583.0, 1593.0)


def published_curves() -> dict:
    run = published_s12_run()
    return {'t_ms': run['t_ms'], 'theta1': run['theta1'], 'theta3': run['theta3'],
            'tip': run['tip_mps'], 'force': run['force_N'],
            'saturated_from_ms': run['saturated_from_ms'],
            'peak_arm_radps': float(np.abs(run['omega3']).max() * 1e3)}


def dense_curves(run, t_ms: np.ndarray) -> dict:
    """This model's curves at the given times, from the integrator's continuous solution (its
    steps are up to 0.2 ms apart in the strike)."""
    states = np.array([run.state_at(t) for t in t_ms])
    th1, th3, w1, w3 = states.T
    return {'t_ms': t_ms, 'theta1': th1, 'theta3': th3,
            'tip': np.array([run.simulator.model.mech.tip_speed(*s) for s in zip(th3, w1, w3)]),
            'force': run.tendon_force_at(t_ms)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=ROOT / 'docs' / 'published_s12.png')
    args = parser.parse_args()
    pub = published_curves()
    run = simulate(load_scene('published_s12', ['integration.rtol=1e-9']), dense=True)
    end_ms = min(WINDOW_MS[1], float(run.trajectory.t_ms[-1]))    # the run stops at the peak
    ours = dense_curves(run, np.append(np.arange(WINDOW_MS[0], end_ms, 0.005), end_ms))

    peak_pub = float(pub['tip'].max())
    print(f"peak tip speed: published {peak_pub:.2f} m/s, published_s12 "
          f"{run.metrics['peak_tip_speed_mps']:.2f} m/s "
          f"({100 * (run.metrics['peak_tip_speed_mps'] / peak_pub - 1):+.2f} %)")
    arm_pub = pub['peak_arm_radps']
    print(f"peak arm speed: published {arm_pub:.0f} rad/s, published_s12 "
          f"{run.metrics['peak_arm_speed_radps']:.0f} rad/s "
          f"({100 * (run.metrics['peak_arm_speed_radps'] / arm_pub - 1):+.2f} %)")
    t_pub = pub['t_ms']
    before = (t_pub >= run.trajectory.t_ms[0]) & (t_pub < pub['saturated_from_ms'])
    gap = np.abs(run.tendon_force_at(t_pub[before]) - pub['force'][before])
    print(f'tendon force before it saturates: up to {gap.max():.3f} N apart '
          f'(at {t_pub[before][np.argmax(gap)]:.3f} ms)')

    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    panels = (('theta1', 'θ1 (rad)'), ('theta3', 'θ3 (rad)'), ('tip', 'tip speed (m/s)'),
              ('force', 'tendon force (N)'))
    for ax, (key, label) in zip(axes.flat, panels):
        for curves, style, name in ((pub, 'k-', 'published (Fig. S12)'),
                                    (ours, 'r--', 'published_s12')):
            inside = (curves['t_ms'] >= WINDOW_MS[0]) & (curves['t_ms'] <= WINDOW_MS[1])
            ax.plot(curves['t_ms'][inside], curves[key][inside], style, lw=1.4, label=name)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel('time (ms)')
    axes[0, 0].legend(loc='best', fontsize=8)
    fig.suptitle('published_s12 against the authors\' published air run, over the strike')
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f'figure: {args.out}')


if __name__ == '__main__':
    main()
