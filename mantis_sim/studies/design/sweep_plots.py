"""`mantis sweep-plot`: the figures a designer looks at, from a sweep's table.

- ``heatmap_<metric>.png``: the metric over the first two varied keys (the mean over any other
  varied key; designs without a strike left blank).
- ``pareto.png``: peak tip speed against peak tendon force and against stored spring energy,
  the Pareto front (the fastest strike for no more force, or for no more energy) marked.
- ``best_designs.csv``: the fastest designs whose peak tendon force stays under the limit.
- with a spread (`mantis sweep --spread N`): ``intervals_<metric>.png``, the metric's median
  and its 50 % and 80 % intervals over each varied key; ``spread_effects.csv``, for each varied
  key the change of the median across its range, whether that change exceeds one strike's
  scatter, and the strikes per design a lab needs to see it (80 % power, 5 % level; the two
  ends of the range).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mantis_sim.studies.design.designs import ID_COLUMN, STATUS_OK
from mantis_sim.studies.design.sweep import SweepError
from mantis_sim.studies.shared.csv_table import write_rows

SPEED, FORCE, ENERGY = 'peak_tip_speed_mps', 'peak_tendon_force_N', 'max_spring_energy_mJ'
NOT_INPUTS = {ID_COLUMN, 'status', 'reason', 'solver', 'rtol', 'wall_time_s', 'rhs_evals'}


def varied_keys(rows: list[dict]) -> list[str]:
    """The inputs of the study: scene keys (section.name) that take more than one value."""
    if not rows:
        return []
    keys = [k for k in rows[0] if '.' in k and k.split('.')[0] not in
            ('phase_start_s', 'phase_duration_s') and k not in NOT_INPUTS]
    return [k for k in keys if len({row.get(k) for row in rows}) > 1]


def pareto_front(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points that no other point beats: less (or equal) x and more y."""
    order = np.lexsort((-y, x))
    front, best = [], -np.inf
    for i in order:
        if y[i] > best:
            front.append(i)
            best = y[i]
    return np.array(front, dtype=int)


def best_designs(rows: list[dict], force_limit_n: float, top: int) -> list[dict]:
    ok = [r for r in rows if r.get('status') == STATUS_OK and r.get(FORCE) is not None
          and r[FORCE] <= force_limit_n]
    return sorted(ok, key=lambda r: -r[SPEED])[:top]


def plot_sweep(rows: list[dict], out_dir: Path, metric: str = SPEED,
               force_limit_n: float = 18.0, top: int = 10) -> list[Path]:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r.get('status') == STATUS_OK]
    if not ok:
        raise SweepError('the table has no design that struck: nothing to plot')
    if metric not in ok[0]:
        numeric = sorted(k for k, v in ok[0].items() if isinstance(v, float))
        raise SweepError(f'--metric {metric}: not a column of the table (columns: '
                         f'{", ".join(numeric)})')
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    keys = varied_keys(rows)
    if len(keys) >= 2:
        written.append(_heatmap(plt, rows, keys[0], keys[1], metric, out_dir))
    written.append(_pareto(plt, ok, out_dir))
    written.append(_best_table(rows, keys, force_limit_n, top, out_dir))
    if f'{metric}_q50' in ok[0] and keys:
        written.append(_intervals(plt, ok, keys, metric, out_dir))
        written.append(_spread_effects_table(spread_effects(ok, keys, metric), out_dir))
    return written


Z_80 = 1.2815516      # the 90 % quantile of the standard normal: q90 - q10 = 2 Z_80 sd


def spread_effects(ok: list[dict], keys: list[str], metric: str) -> list[dict]:
    """For each varied key: the change of the metric's median over the key's range (least
    squares of q50 on all varied keys at once), one strike's scatter (the mean (q90 - q10) /
    2.563, as for a normal), and the strikes per design to see the change."""
    from mantis_sim.studies.design.spread_effects import strikes_needed
    from mantis_sim.studies.real_strikes.fidelity import fit_slopes
    medians = np.array([r[f'{metric}_q50'] for r in ok], float)
    slopes = fit_slopes([np.array([r[k] for r in ok], float) for k in keys], medians)
    sd = float(np.nanmean([(r[f'{metric}_q90'] - r[f'{metric}_q10']) / (2 * Z_80)
                           for r in ok]))
    out = []
    for key, slope in zip(keys, slopes):
        low, high = min(r[key] for r in ok), max(r[key] for r in ok)
        change = slope.value * (high - low)
        out.append({'key': key, 'metric': metric, 'low': low, 'high': high,
                    'change_of_median': change,
                    'one_strike_sd': sd,
                    'exceeds_one_strike_scatter': bool(abs(change) > sd),
                    'strikes_per_design_to_see_it': strikes_needed(change, sd)})
    return out


def _spread_effects_table(effects: list[dict], out_dir: Path) -> Path:
    return write_rows(out_dir / 'spread_effects.csv', effects)


def _intervals(plt, ok, keys, metric, out_dir) -> Path:
    fig, axes = plt.subplots(1, len(keys), figsize=(4.5 * len(keys), 3.8), squeeze=False)
    for ax, key in zip(axes[0], keys):
        xs = sorted({r[key] for r in ok})
        mean = {q: np.array([np.nanmean([r[f'{metric}_{q}'] for r in ok if r[key] == x])
                             for x in xs]) for q in ('q10', 'q25', 'q50', 'q75', 'q90')}
        ax.fill_between(xs, mean['q10'], mean['q90'], color='C0', alpha=0.2,
                        label='80 % of strikes')
        ax.fill_between(xs, mean['q25'], mean['q75'], color='C0', alpha=0.4,
                        label='50 % of strikes')
        ax.plot(xs, mean['q50'], 'o-', color='C0', ms=3, label='median')
        ax.set_xlabel(_label(key))
        ax.set_ylabel(_label(metric))
        ax.legend(fontsize=8)
    fig.suptitle('where strikes of each design fall (the other varied keys averaged)',
                 fontsize=10)
    path = out_dir / f'intervals_{metric}.png'
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


#: Axis labels in words, with units, for the keys a sweep usually varies and its metrics.
LABELS = {'geometry.d_t_mm': 'guide distance (mm)',
          'geometry.contact_angle_deg': 'contact angle (degrees)',
          'drive.pull_speed_mm_per_s': 'pull speed (mm/s)',
          'peak_tip_speed_mps': 'peak tip speed (m/s)',
          'spring_energy_mJ': 'spring energy, the lab\'s (mJ)',
          'max_spring_energy_mJ': 'most spring energy (mJ)',
          'peak_tendon_force_N': 'peak tendon force (N)'}


def _label(key: str) -> str:
    return LABELS.get(key, key)


def _heatmap(plt, rows, kx, ky, metric, out_dir) -> Path:
    xs = sorted({r[kx] for r in rows})
    ys = sorted({r[ky] for r in rows})
    grid = np.full((len(ys), len(xs)), np.nan)
    sums = np.zeros_like(grid)
    counts = np.zeros_like(grid)
    for r in rows:
        if r.get('status') == STATUS_OK and r.get(metric) is not None:
            i, j = ys.index(r[ky]), xs.index(r[kx])
            sums[i, j] += r[metric]
            counts[i, j] += 1
    np.divide(sums, counts, out=grid, where=counts > 0)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    if len(xs) * len(ys) == len(rows) or (len(xs) < 60 and len(ys) < 60):
        mesh = ax.pcolormesh(_edges(xs), _edges(ys), np.ma.masked_invalid(grid), shading='flat')
    else:                                     # a Latin hypercube: scattered, not a grid
        pts = [r for r in rows if r.get('status') == STATUS_OK]
        mesh = ax.scatter([r[kx] for r in pts], [r[ky] for r in pts],
                          c=[r[metric] for r in pts], s=12)
    fig.colorbar(mesh, ax=ax, label=metric)
    ax.set_xlabel(kx)
    ax.set_ylabel(ky)
    ax.set_title(f'{metric}\nover {kx} and {ky}', fontsize=9)
    path = out_dir / f'heatmap_{metric}.png'
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _edges(values) -> np.ndarray:
    v = np.asarray(values, float)
    if len(v) == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])


def _pareto(plt, ok, out_dir) -> Path:
    speed = np.array([r[SPEED] for r in ok])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, key, label in ((axes[0], FORCE, 'peak tendon force (N)'),
                           (axes[1], ENERGY, 'max spring energy (mJ)')):
        x = np.array([r[key] for r in ok])
        front = pareto_front(x, speed)
        ax.scatter(x, speed, s=6, color='0.6', label='designs')
        ax.plot(x[front], speed[front], 'o-', color='C3', ms=4, label='Pareto front')
        ax.set_xlabel(label)
        ax.set_ylabel('peak tip speed (m/s)')
        ax.legend()
    fig.suptitle('fastest strike for a given force and stored energy')
    path = out_dir / 'pareto.png'
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _best_table(rows, keys, force_limit_n, top, out_dir) -> Path:
    return write_rows(out_dir / 'best_designs.csv', best_designs(rows, force_limit_n, top),
                      [ID_COLUMN, *keys, SPEED, FORCE, ENERGY])
