"""A study's figures, axes in words and units:

- ``forecast_run_order.png``: each quantity's measured value in run order inside its forecast's
  80 % (q10-q90) and 90 % (q05-q95) intervals; values outside their 95 % interval in red;
- ``effects.png``: each factor level's measured effect with its 95 % interval beside the twin's
  forecast of it;
- ``pit_histogram.png``: the PITs of every measured quantity (flat when the twin is calibrated).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from pathlib import Path

import numpy as np

from .effects import Effect
from .quantities import CONDITION_LABELS, QUANTITIES


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _measured(rows: Sequence[Mapping]) -> list[str]:
    return [q for q in QUANTITIES if any(_finite(r.get(q)) for r in rows)]


def _finite(value) -> bool:
    return value is not None and isinstance(value, float) and math.isfinite(value)


def forecast_run_order(rows: Sequence[Mapping], path: Path) -> Path | None:
    quantities = _measured(rows)
    if not quantities:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(len(quantities), 1, figsize=(9, 2.4 * len(quantities)),
                             sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], quantities):
        q = QUANTITIES[name]
        runs = np.array([r['run'] for r in rows], float)
        for lo, hi, alpha in (('q05', 'q95', 0.25), ('q10', 'q90', 0.45)):
            low = np.array([_or_nan(r.get(f'{name}_{lo}')) for r in rows])
            high = np.array([_or_nan(r.get(f'{name}_{hi}')) for r in rows])
            ax.vlines(runs, low, high, colors='tab:blue', alpha=alpha, linewidth=6)
        value = np.array([_or_nan(r.get(name)) for r in rows])
        out = np.array([r.get(f'{name}_flag') == 'outside' for r in rows])
        ax.plot(runs[~out], value[~out], 'o', color='black', markersize=4, label='measured')
        if out.any():
            ax.plot(runs[out], value[out], 'o', color='tab:red', markersize=5,
                    label='outside its 95 % interval')
        ax.set_ylabel(q.axis)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc='best', fontsize=8)
    axes[-1, 0].set_xlabel('trial in run order')
    fig.suptitle('measured values in the twin\'s forecast intervals (80 % dark, 90 % light)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _or_nan(value) -> float:
    return float(value) if _finite(value) else math.nan


EFFECT_COLUMNS = 2


def effects_figure(effects: Sequence[Effect], path: Path) -> Path | None:
    """One panel per quantity in a grid of EFFECT_COLUMNS columns, each factor level's change
    on a row of its own, at the type size of the study's other figures."""
    if not effects:
        return None
    plt = _pyplot()
    quantities = list(dict.fromkeys(e.quantity for e in effects))
    columns = min(EFFECT_COLUMNS, len(quantities))
    rows = math.ceil(len(quantities) / columns)
    per_panel = max(sum(e.quantity == q for e in effects) for q in quantities)
    fig, axes = plt.subplots(rows, columns, figsize=(6.0 * columns, (1.4 + 0.6 * per_panel) * rows),
                             squeeze=False)
    for ax, name in zip(axes.flat, quantities):
        mine = [e for e in effects if e.quantity == name]
        y = np.arange(len(mine))
        ax.errorbar([e.measured for e in mine], y + 0.12,
                    xerr=_err([(e.measured, e.low, e.high) for e in mine]),
                    fmt='o', color='black', capsize=3, label='measured (95 %)')
        ax.errorbar([e.twin for e in mine], y - 0.12,
                    xerr=_err([(e.twin, e.twin_low, e.twin_high) for e in mine]),
                    fmt='s', color='tab:blue', capsize=3, label='twin\'s forecast (95 %)')
        ax.axvline(0.0, color='grey', linewidth=0.8)
        ax.set_yticks(y, [_change_label(e) for e in mine])
        ax.set_ylim(-0.6, len(mine) - 0.4)
        ax.set_xlabel(f'change in {QUANTITIES[name].axis}')
        ax.grid(alpha=0.3, axis='x')
    for ax in axes.flat[len(quantities):]:
        ax.set_visible(False)
    axes[0, 0].legend(loc='best', fontsize=9)
    fig.suptitle('each factor\'s effect: the study\'s strikes beside the twin')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _change_label(e: Effect) -> str:
    if isinstance(e.level, str):
        return f'{e.factor}\n{e.reference} to {e.level}'
    label, unit = CONDITION_LABELS.get(e.factor, (e.factor, ''))
    return f'{label}\n{e.reference:g} to {e.level:g} {unit}'.rstrip()


def _err(triples) -> np.ndarray:
    lower = [v - lo if math.isfinite(lo) else 0.0 for v, lo, _ in triples]
    upper = [hi - v if math.isfinite(hi) else 0.0 for v, _, hi in triples]
    return np.array([lower, upper])


def pit_histogram(rows: Sequence[Mapping], path: Path) -> Path | None:
    pits = [r.get(f'{q}_pit') for q in QUANTITIES for r in rows]
    pits = [p for p in pits if _finite(p)]
    if not pits:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.4))
    ax.hist(pits, bins=10, range=(0, 1), color='tab:blue', edgecolor='white')
    ax.axhline(len(pits) / 10, color='black', linestyle='--', linewidth=1,
               label='a calibrated forecast')
    ax.set_xlabel('where the measured value fell in its forecast (PIT)')
    ax.set_ylabel('measured values (count)')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ['effects_figure', 'forecast_run_order', 'pit_histogram']
