"""A trial's measured values set against its forecast: each quantity's quantiles (q05..q95),
its PIT, and a flag where it falls outside the forecast's central 95 %, with the likely cause
in words."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math

from mantis_sim.spread import QUANTILE_LEVELS, quantile_label
from mantis_sim.studies.rig_study.twin_forecast import INTERVAL_95, Forecast

from .quantities import QUANTITIES

QUANTILE_LABELS = tuple(quantile_label(q) for q in QUANTILE_LEVELS)


def forecast_columns(name: str) -> list[str]:
    """A quantity's forecast columns in a study's table: its quantiles, its PIT, its flag."""
    return [f'{name}_{label}' for label in QUANTILE_LABELS] + [f'{name}_pit', f'{name}_flag']


@dataclass(frozen=True)
class Judgement:
    values: dict            # column -> value: quantiles, PIT and flag of each quantity
    flagged: tuple          # quantities outside their 95 % interval
    cause: str              # the likely causes, in words ('' when none is flagged)


def judge(forecast: Forecast, measured: Mapping) -> Judgement:
    """Every quantity's forecast columns; a measured value (``measured[name]``, None or NaN if
    not measured) gets its PIT and flag."""
    values, flagged, causes = {}, [], []
    for name, quantity in QUANTITIES.items():
        for label, q in forecast.quantiles(name).items():
            values[f'{name}_{label}'] = q
        value = measured.get(name)
        value = math.nan if value is None else float(value)
        pit = forecast.pit(name, value)
        values[f'{name}_pit'] = pit
        outside = math.isfinite(pit) and not INTERVAL_95[0] <= pit <= INTERVAL_95[1]
        values[f'{name}_flag'] = ('' if not math.isfinite(pit)
                                  else 'outside' if outside else 'inside')
        if outside:
            lo, hi = forecast.quantile(name, INTERVAL_95)
            side, cause = (('below', quantity.low_cause) if pit < 0.5
                           else ('above', quantity.high_cause))
            flagged.append(name)
            causes.append(f'{quantity.label} {value:.4g} {quantity.unit} {side} its 95 % '
                          f'interval {lo:.4g}-{hi:.4g}: {cause}')
    return Judgement(values, tuple(flagged), '; '.join(causes))


__all__ = ['Judgement', 'QUANTILE_LABELS', 'forecast_columns', 'judge']
