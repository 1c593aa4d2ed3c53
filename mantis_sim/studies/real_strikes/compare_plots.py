"""Figures of real strikes beside their simulations: one trial's motion, and parity plots."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .fidelity import SERIES_WINDOW_S, SimulatedStrike
from .strikes import RealStrike, StrikeSeries

GROUP_COLOURS = {'air_19mm': '#4c72b0', 'air_23mm': '#dd8452', 'water_23mm': '#55a868'}


def _rates(series: StrikeSeries) -> tuple[np.ndarray, np.ndarray]:
    """Angular rates (rad/s) of a series by central differences; a recorded one is smoothed
    first over 5 frames, which at the camera's rates keeps the strike's shape."""
    t = series.t_s
    out = []
    for values in (series.theta1_rad, series.theta3_rad):
        smooth = values
        if values.size >= 7:
            kernel = np.ones(5) / 5
            smooth = np.convolve(values, kernel, mode='same')
            smooth[:2], smooth[-2:] = values[:2], values[-2:]
        out.append(np.gradient(smooth, t))
    return out[0], out[1]


def plot_trial(real: RealStrike, sim: SimulatedStrike, path: Path) -> None:
    """theta1, theta3 and their rates against time from phase IV, real and simulated."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    start, stop = SERIES_WINDOW_S[real.medium]
    for series, label, style in ((real.series, 'real', '-'), (sim.series, 'simulated', '--')):
        if series is None:
            continue
        series = series.window(1.5 * start, 1.2 * stop)
        ms = series.t_s * 1e3
        w1, w3 = _rates(series)
        i0 = int(np.argmin(np.abs(series.t_s)))
        axes[0, 0].plot(ms, series.theta1_rad - series.theta1_rad[i0], style, label=label)
        axes[0, 1].plot(ms, series.theta3_rad - series.theta3_rad[i0], style, label=label)
        axes[1, 0].plot(ms, w1, style, label=label)
        axes[1, 1].plot(ms, w3, style, label=label)
    for ax, title in zip(axes.ravel(), ('body turn theta1 - theta1(IV) (rad)',
                                        'arm turn theta3 - theta3(IV) (rad)',
                                        'body rate (rad/s)', 'arm rate, relative (rad/s)')):
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel('time from phase IV (ms)')
    axes[0, 0].legend()
    fig.suptitle(f'{real.trial} ({real.group}, {real.pull_mm_per_s:.2f} mm/s, contact '
                 f'{real.contact_angle_deg:.2f} deg): peak tip speed {real.peak_tip_speed_mps} '
                 f'real, {sim.peak_tip_speed_mps:.2f} m/s simulated', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_parity(rows: list[dict], path: Path) -> None:
    """Simulated against real peak tip speed and spring energy, one point per strike."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, key, label in ((axes[0], 'peak_tip_speed_mps', 'peak tip speed (m/s)'),
                           (axes[1], 'spring_energy_mJ', 'spring energy (mJ)')):
        values = []
        for group in sorted({r['group'] for r in rows}):
            chosen = [r for r in rows if r['group'] == group and r['status'] == 'strike']
            x = [r[f'real_{key}'] for r in chosen]
            y = [r[f'sim_{key}'] for r in chosen]
            values += x + y
            ax.plot(x, y, 'o', color=GROUP_COLOURS.get(group), label=group, alpha=0.8)
        finite = [v for v in values if v is not None and np.isfinite(v)]
        if finite:
            lo, hi = min(finite), max(finite)
            pad = 0.05 * (hi - lo + 1e-9)
            ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], 'k-', lw=0.8)
            for share in (0.9, 1.1):
                ax.plot([lo - pad, hi + pad], [share * (lo - pad), share * (hi + pad)], 'k:',
                        lw=0.6)
        ax.set_xlabel(f'real {label}')
        ax.set_ylabel(f'simulated {label}')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title('dotted: +-10 %', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ['plot_parity', 'plot_trial']


def plot_forecasts(forecasts, path: Path) -> None:
    """Each strike's measured value in its forecast's 50 % and 80 % intervals (median marked),
    per metric, and the PIT histogram of the forecasts (flat when they are calibrated)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from mantis_sim.spread import pit, quantiles

    from .forecast import FORECAST_METRICS
    ordered = sorted(forecasts, key=lambda f: (f.strike.group, f.strike.trial))
    fig, axes = plt.subplots(len(FORECAST_METRICS), 2, figsize=(13, 8),
                             gridspec_kw={'width_ratios': [3, 1]})
    for row, (metric, (_, label, unit)) in zip(axes, FORECAST_METRICS.items()):
        ax, hist = row
        pits = []
        for x, f in enumerate(ordered):
            q = quantiles(f.samples[metric])
            colour = GROUP_COLOURS.get(f.strike.group, 'grey')
            ax.vlines(x, q['q10'], q['q90'], colour, lw=2, alpha=0.45)
            ax.vlines(x, q['q25'], q['q75'], colour, lw=5)
            ax.plot(x, q['q50'], '_', color='black', ms=9)
            measured = f.measured(metric)
            if measured is not None:
                ax.plot(x, measured, 'kx', ms=6)
                pits.append(pit(f.samples[metric], measured))
        ax.set_ylabel(f'{label} ({unit})')
        ax.set_xlabel('strike (by group)')
        ax.set_xticks([])
        for group, colour in GROUP_COLOURS.items():
            if any(f.strike.group == group for f in ordered):
                ax.plot([], [], color=colour, lw=5, label=f'{group}: 50 % / 80 % interval')
        ax.plot([], [], 'kx', label='measured')
        ax.legend(fontsize=8, loc='best')
        hist.hist([p for p in pits if np.isfinite(p)], bins=10, range=(0, 1), color='grey')
        hist.set_xlabel(f'where the measured {label} falls in its forecast (PIT)')
        hist.set_ylabel('strikes')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
