"""Real strikes forecast from their scenes' spread, and how good the forecasts are.

Each strike is simulated at its own conditions for N robots drawn from its group's spread
(mantis_sim.spread), of its recording day's assembly where the spread has seen that day, else
of a new day's; its forecast of a metric is the N simulated values, each times its
discrepancy factor. A forecast is judged against the measured value by:

- the coverage of its central 50 % and 80 % intervals (q25-q75, q10-q90);
- its CRPS (continuous ranked probability score, in the metric's units; lower is better),
  beside the CRPS of the climatological forecast: the group's training strikes quoted as they
  were measured. A forecast no better than that says nothing the lab's past did not;
- its PIT (where the measured value falls in the forecast: uniform when calibrated);
- the median |error| of its median (q50).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from mantis_sim.robots import scene_spread
from mantis_sim.scene import Scene
from mantis_sim.spread import (
    Spread,
    crps,
    pit,
    quantiles,
)

from .identify import simulate_task
from .strikes import RealStrike

#: metric -> (its column stem in predictions.csv, its label and unit)
FORECAST_METRICS = {'peak_tip_speed_mps': ('tip_speed_mps', 'peak tip speed', 'm/s'),
                    'spring_energy_mJ': ('spring_energy_mJ', 'spring energy', 'mJ')}
INTERVALS = {50: ('q25', 'q75'), 80: ('q10', 'q90')}


@dataclass(frozen=True)
class StrikeForecast:
    strike: RealStrike
    samples: dict           # metric -> ndarray (N,), NaN where a drawn robot did not strike
    not_struck: int
    climatology: dict       # metric -> the group's training values (the spread's)
    day_seen: bool = False  # forecast from its recording day's assembly, which the spread knows

    def measured(self, metric: str) -> Optional[float]:
        return getattr(self.strike, metric)     # a RealStrike's measured value, or None


def strike_rng(seed: int, index: int) -> np.random.Generator:
    """The draws of the index-th strike: the same for a seed whatever else is forecast."""
    return np.random.default_rng([seed, index])


def forecast_strikes(scenes: dict[str, Scene], strikes: Sequence[RealStrike], n: int,
                     seed: int, mapper: Callable,
                     spreads: Optional[dict[str, Spread]] = None) -> list[StrikeForecast]:
    """Every strike forecast from N robots of its group's spread (``spreads``, default each
    scene's own); all simulations go through ``mapper`` at once."""
    spreads = spreads or {g: scene_spread(scene) for g, scene in scenes.items()}
    tasks, factors = [], []
    for i, strike in enumerate(strikes):
        draws = spreads[strike.group].draw(n, strike_rng(seed, i), strike.contact_angle_deg,
                                           strike.recording_day)
        tasks += [(scenes[strike.group], strike, False, values) for values in draws.values]
        factors.append(draws.factors)
    simulated = mapper(simulate_task, tasks)
    out = []
    for i, strike in enumerate(strikes):
        sims = simulated[i * n:(i + 1) * n]
        samples = {}
        for metric in FORECAST_METRICS:
            values = np.array([getattr(s, metric) if s.status == 'strike' else math.nan
                               for s in sims])
            samples[metric] = values * factors[i].get(metric, 1.0)
        spread = spreads[strike.group]
        out.append(StrikeForecast(strike, samples, sum(s.status != 'strike' for s in sims),
                                  spread.climatology, spread.knows_day(strike.recording_day)))
    return out


def prediction_rows(forecasts: Sequence[StrikeForecast]) -> list[dict]:
    """predictions.csv: trial, group, whether its day was seen, and per metric its measured
    value and q05..q95."""
    rows = []
    for f in forecasts:
        row = {'trial': f.strike.trial, 'group': f.strike.group, 'day_seen': f.day_seen}
        for metric, (stem, _, _) in FORECAST_METRICS.items():
            measured = f.measured(metric)
            row[f'{stem}_measured'] = math.nan if measured is None else measured
            row.update({f'{stem}_{q}': v for q, v in quantiles(f.samples[metric]).items()})
        row['robots_not_struck'] = f.not_struck
        rows.append(row)
    return rows


def scores(forecasts: Sequence[StrikeForecast]) -> dict:
    """Per metric, per group and pooled ('all'): strikes, coverage of the 50 % and 80 %
    intervals, mean CRPS of the forecast and of the climatology (each forecast's own), their
    ratio, the PITs with their histogram (10 bins) and the median |relative error| of q50."""
    out = {}
    for metric in FORECAST_METRICS:
        per_strike = []
        for f in forecasts:
            y = f.measured(metric)
            samples = f.samples[metric]
            if y is None or not np.isfinite(samples).any():
                continue
            q = quantiles(samples)
            clim = np.asarray(f.climatology.get(metric, ()), float)
            per_strike.append({
                'group': f.strike.group,
                'in50': q[INTERVALS[50][0]] <= y <= q[INTERVALS[50][1]],
                'in80': q[INTERVALS[80][0]] <= y <= q[INTERVALS[80][1]],
                'crps': crps(samples, y),
                'crps_climatology': crps(clim, y) if clim.size else math.nan,
                'pit': pit(samples, y),
                'median_error': q['q50'] / y - 1.0})
        groups = sorted({s['group'] for s in per_strike})
        out[metric] = {g: _summary([s for s in per_strike if s['group'] == g])
                       for g in groups}
        out[metric]['all'] = _summary(per_strike)
    return out


def _summary(rows: list[dict]) -> dict:
    if not rows:
        return {'strikes': 0}
    forecast = float(np.mean([r['crps'] for r in rows]))
    clim = float(np.mean([r['crps_climatology'] for r in rows]))
    pits = np.array([r['pit'] for r in rows])
    return {'strikes': len(rows),
            'coverage_50': float(np.mean([r['in50'] for r in rows])),
            'coverage_80': float(np.mean([r['in80'] for r in rows])),
            'crps': forecast, 'crps_climatology': clim,
            'crps_ratio': forecast / clim if clim > 0 else math.nan,
            'pit_histogram': np.histogram(pits, bins=10, range=(0.0, 1.0))[0].tolist(),
            'pits': pits.tolist(),
            'median_abs_error_q50': float(np.median(np.abs([r['median_error']
                                                             for r in rows])))}


def left_out_days(scenes: dict[str, Scene], latents: Sequence, param, n: int, seed: int,
                  mapper: Callable) -> list[StrikeForecast]:
    """Every strike forecast by the spread fitted without its recording day (its own latent,
    and its day's in the mixed model, discrepancy and climatology, left out); the scenes'
    identified parameters stay as they are, fitted to every day. ``latents``: each strike's
    own (spread_fit.strike_latents)."""
    return _left_out(scenes, latents, param, n, seed, mapper,
                     [x.strike.recording_day for x in latents])


def left_out_strikes(scenes: dict[str, Scene], latents: Sequence, param, n: int, seed: int,
                     mapper: Callable) -> list[StrikeForecast]:
    """Every strike forecast by the spread fitted without it: a later strike of a day the
    spread has seen, forecast from that day's other strikes (a day of one strike becomes a new
    day). As left_out_days, the scenes' identified parameters stay fitted to every strike."""
    return _left_out(scenes, latents, param, n, seed, mapper, list(range(len(latents))))


def _left_out(scenes: dict[str, Scene], latents: Sequence, param, n: int, seed: int,
              mapper: Callable, units: list) -> list[StrikeForecast]:
    """Each strike forecast by the spread refitted without the strikes of its unit
    (``units``: one per latent; the strikes of a unit are left out together)."""
    from .spread_fit import spreads_from
    out: list = [None] * len(latents)
    for unit in dict.fromkeys(units):
        at = [i for i, u in enumerate(units) if u == unit]
        kept = [x for x, u in zip(latents, units) if u != unit]
        left = [latents[i].strike for i in at]
        spreads, _ = spreads_from(kept, {g: scenes[g] for g in {s.group for s in left}}, param)
        for i, f in zip(at, forecast_strikes(scenes, left, n, seed, mapper, spreads)):
            out[i] = f
    return out



__all__ = ['FORECAST_METRICS', 'INTERVALS', 'StrikeForecast', 'forecast_strikes',
           'left_out_days', 'left_out_strikes', 'prediction_rows', 'scores', 'strike_rng']
