"""`mantis sweep-plot`: the figures a designer looks at, from a sweep's table.

- ``heatmap_<metric>.png``: the metric over the first two varied keys (the mean over any other
  varied key; designs without a strike left blank).
- ``pareto.png``: peak tip speed against peak tendon force and against stored spring energy,
  the Pareto front (the fastest strike for no more force, or for no more energy) marked.
- ``best_designs.csv``: the fastest designs whose peak tendon force stays under the limit.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from mantis_sim.designs import ID_COLUMN, STATUS_OK

from .sweep import SweepError

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
    return written


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
    path = out_dir / 'best_designs.csv'
    columns = [ID_COLUMN, *keys, SPEED, FORCE, ENERGY]
    with open(path, 'w', newline='', encoding='utf-8') as f:
        writer = csv.DictWriter(f, columns, extrasaction='ignore')
        writer.writeheader()
        for row in best_designs(rows, force_limit_n, top):
            writer.writerow(row)
    return path
