"""Trial figure in the paper's manner: phase-coloured rates, energies, (θ3, θ1) path."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mantis_rig.analysis.pipeline import TrialAnalysis  # noqa: E402

PHASE_COLOURS = {'I': '#4C72B0', 'II': '#55A868', 'III': '#C44E52', 'IV': '#8172B2'}


def _phase_masks(a: TrialAnalysis) -> dict[str, np.ndarray]:
    p, t = a.phases, a.time_s
    edges = [p.loading_start_s, p.unlatch_s, p.overcentering_s, p.max_contraction_s,
             p.peak_tip_speed_s]
    if not np.isfinite(edges[0]):          # the recording began during the loading
        edges[0] = float(t[0])
    if not np.isfinite(edges[2]):
        edges[2] = edges[1]
    return {name: (t >= lo) & (t <= hi)
            for name, lo, hi in zip(PHASE_COLOURS, edges[:-1], edges[1:], strict=True)}


def plot_trial(a: TrialAnalysis, path: str | Path, title: str = '') -> Path:
    """Write a 2×3 PNG: slow and fast rates, energies, trajectory. Returns the path."""
    masks = _phase_masks(a)
    t_ms = 1e3 * (a.time_s - a.phases.max_contraction_s)
    fig, ax = plt.subplots(2, 3, figsize=(15, 8.5), constrained_layout=True)
    if title:
        fig.suptitle(title)

    fast = (t_ms >= -5) & (t_ms <= 15)
    for row, (rate, label) in enumerate([(a.omega1_radps, 'body θ̇1'),
                                         (a.omega3_radps, 'arm θ̇3 (rel. body)')]):
        slow_ax, fast_ax = ax[row, 0], ax[row, 1]
        for name, m in masks.items():
            c = PHASE_COLOURS[name]
            if name != 'IV':
                slow_ax.plot(a.time_s[m], rate[m], color=c, lw=0.6, label=f'phase {name}')
            fast_ax.plot(t_ms[m & fast], rate[m & fast], color=c, lw=1.2)
        rest = fast & ~np.any(list(masks.values()), axis=0)
        fast_ax.plot(t_ms[rest], rate[rest], color='0.6', lw=0.8, label='after peak')
        slow_ax.set(xlabel='time (s)', ylabel=f'{label} (rad/s)', title=f'{label}: phases I–III')
        fast_ax.set(xlabel='time from max contraction (ms)', ylabel=f'{label} (rad/s)',
                    title=f'{label}: strike (phase IV)')
        lo, hi = np.percentile(rate[masks['I'] | masks['II'] | masks['III']], [0.5, 99.5])
        pad = 0.2 * (hi - lo + 1e-9)
        slow_ax.set_ylim(lo - pad, hi + pad)
        slow_ax.legend(fontsize=8, loc='upper left')
        fast_ax.axvline(0, color='k', lw=0.5, ls=':')
        for s in (slow_ax, fast_ax):
            s.grid(alpha=0.3)

    e = ax[0, 2]
    e.plot(a.time_s, a.spring_energy_mJ, color='k', lw=1, label='spring')
    e.plot(a.time_s, a.ke_body_mJ + a.ke_arm_mJ, color='tab:orange', lw=1, label='kinetic')
    for name, m in masks.items():
        if m.any():
            e.axvspan(a.time_s[m][0], a.time_s[m][-1], color=PHASE_COLOURS[name], alpha=0.12)
    e.set(xlabel='time (s)', ylabel='energy (mJ)', title='energy (phase bands shaded)')
    e.legend(fontsize=8)
    e.grid(alpha=0.3)

    tr = ax[1, 2]
    upto = a.time_s <= a.phases.peak_tip_speed_s
    for name, m in masks.items():
        tr.plot(np.degrees(a.theta3_rad[m & upto]), np.degrees(a.theta1_rad[m & upto]),
                color=PHASE_COLOURS[name], lw=1, label=f'phase {name}')
    if np.isfinite(a.phases.overcentering_s):
        i = int(np.argmin(np.abs(a.time_s - a.phases.overcentering_s)))
        tr.plot(np.degrees(a.theta3_rad[i]), np.degrees(a.theta1_rad[i]), 'k*', ms=12,
                label='overcentering')
    tr.set(xlabel='θ3 (deg)', ylabel='θ1 (deg)', title='trajectory (θ3, θ1)', xscale='log')
    tr.legend(fontsize=8)
    tr.grid(alpha=0.3, which='both')

    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
