"""Each factor's effect on each quantity: measured from the study's strikes with its 95 %
interval, beside the twin's forecast of the same effect, and the repeats that would resolve it.

The measured effect of a factor's level is its difference from the factor's first level, from
a main-effects least-squares fit over every strike (a dummy per level of every factor besides
its first): on a balanced plan that is the difference of the two levels' means, and strikes
lost to aborts leave it unbiased. Its 95 % interval is Student's t on the fit's residual
degrees of freedom. The twin's effect is its forecast of what that same fit of the study's own
strikes will give (effect_forecast: this day's robot as the study's strikes tell it, the
study's repeats, the measurement's error): the median and the 2.5-97.5 % of its replays.

A difference delta is seen (two-sided test at the 5 % level, 80 % power) with
n >= 2 (z_0.975 + z_0.8)^2 sd^2 / delta^2 strikes at each level
(mantis_sim.studies.design.spread_effects.strikes_needed); a level of a factor gathers
(combinations / levels) strikes per repeat. An effect left unresolved by as many repeats as
that asks for was the 20 % that such a study misses: one more repeat at least is advised, never
none.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math

import numpy as np

from mantis_sim.studies.design.spread_effects import strikes_needed
from mantis_sim.studies.rig_study.twin_forecast import StudyForecaster

from .effect_forecast import replay_values, replayed_effects
from .plan import CONDITION_KEYS, StudyPlan
from .quantities import QUANTITIES

MIN_REPEATS = 2


@dataclass(frozen=True)
class Effect:
    factor: str
    level: object
    reference: object           # the factor's first level
    quantity: str
    measured: float             # level minus reference, in the quantity's unit
    low: float                  # its 95 % interval (NaN where the strikes cannot give one)
    high: float
    strikes: int                # strikes of the quantity the fit used
    residual_sd: float
    twin: float                 # the twin's forecast of the same difference
    twin_low: float
    twin_high: float
    more_repeats: float         # repeats beyond those run that would resolve it (0: resolved,
    #                             at least 1 otherwise; inf: no difference to resolve is
    #                             forecast or planned)

    @property
    def resolved(self) -> bool:
        return math.isfinite(self.low) and (self.low > 0 or self.high < 0)

    @property
    def twin_inside(self) -> bool:
        """Whether the measured effect lies in the twin's 95 % forecast of it (the twin right
        about it, as far as this study can tell)."""
        return math.isfinite(self.measured) and self.twin_low <= self.measured <= self.twin_high


def _design_matrix(plan: StudyPlan, rows: Sequence[Mapping]) -> tuple[np.ndarray, list]:
    columns, names = [np.ones(len(rows))], []
    for factor, levels in plan.factors.items():
        for level in levels[1:]:
            columns.append(np.array([_same(row[factor], level) for row in rows], float))
            names.append((factor, level))
    return np.column_stack(columns), names


def _same(a, b) -> bool:
    if isinstance(b, str):
        return str(a) == b
    try:
        return abs(float(a) - float(b)) < 1e-9
    except (TypeError, ValueError):
        return False


def measured_effects(plan: StudyPlan, rows: Sequence[Mapping], quantity: str) -> dict:
    """(factor, level) -> (effect, 95 % low, high, strikes, residual sd) from the rows that
    measured ``quantity``."""
    rows = [r for r in rows if r.get(quantity) is not None and math.isfinite(r[quantity])]
    x, names = _design_matrix(plan, rows)
    out = {name: (math.nan, math.nan, math.nan, len(rows), math.nan) for name in names}
    if not rows:
        return out
    y = np.array([r[quantity] for r in rows], float)
    coef, _, rank, _ = np.linalg.lstsq(x, y, rcond=None)
    dof = len(rows) - rank
    if rank < x.shape[1]:       # a level without strikes: its effect is not identified
        return out
    residual = y - x @ coef
    sd = math.sqrt(float(residual @ residual) / dof) if dof > 0 else math.nan
    cov = np.linalg.pinv(x.T @ x) * sd ** 2 if dof > 0 else None
    from scipy import stats  # here: a study's runner imports this module, its report uses t
    t = stats.t.ppf(0.975, dof) if dof > 0 else math.nan
    for k, name in enumerate(names, start=1):
        if cov is None:
            out[name] = (float(coef[k]), math.nan, math.nan, len(rows), sd)
        else:
            half = t * math.sqrt(cov[k, k])
            out[name] = (float(coef[k]), float(coef[k] - half), float(coef[k] + half),
                         len(rows), sd)
    return out


def twin_effects(plan: StudyPlan, forecaster: StudyForecaster, quantity: str,
                 rows: Sequence[Mapping], conditions_of: Callable = None,
                 seed: int = 0) -> dict:
    """(factor, level) -> (effect, 2.5 %, 97.5 %): the twin's forecast of what the fit of
    ``rows`` (the study's strikes, each at its conditions and day) will measure
    (effect_forecast)."""
    conditions_of = conditions_of or row_conditions
    x, names = _design_matrix(plan, rows)
    values = replay_values(forecaster, rows, quantity, conditions_of, seed=seed)
    effects = replayed_effects(x, values)
    out = {}
    for k, name in enumerate(names, start=1):
        low, mid, high = np.nanquantile(effects[:, k], [0.025, 0.5, 0.975])
        out[name] = (float(mid), float(low), float(high))
    return out


def row_conditions(row: Mapping) -> dict:
    """The conditions a row records (the forecaster takes the scene's for any it leaves out)."""
    return {k: row[k] for k in CONDITION_KEYS if row.get(k) is not None}


def _weighted_mean(v: np.ndarray, w: np.ndarray) -> float:
    ok = np.isfinite(v)
    return float(np.sum(v[ok] * w[ok]) / np.sum(w[ok])) if np.sum(w[ok]) > 0 else math.nan


def study_effects(plan: StudyPlan, rows: Sequence[Mapping], forecaster: StudyForecaster,
                  repeats_run: int, planned: Sequence[Mapping] = (),
                  conditions_of: Callable = None) -> list[Effect]:
    """Every factor level's effect on every quantity some row measured (``rows``: the done
    ones). The twin forecasts the fit of the rows that measured it, or, where they cannot
    give every effect yet, of the ``planned`` rows (the whole record)."""
    cells_per_level = {f: len(plan.cells) / len(levels) for f, levels in plan.factors.items()}
    effects = []
    for quantity in QUANTITIES:
        if not any(r.get(quantity) is not None and math.isfinite(r[quantity]) for r in rows):
            continue
        measured = measured_effects(plan, rows, quantity)
        fitted = [r for r in rows if _finite(r.get(quantity))]
        if not _identified(plan, fitted) and _identified(plan, planned):
            fitted = list(planned)
        twin = twin_effects(plan, forecaster, quantity, fitted, conditions_of)
        for (factor, level), (value, low, high, strikes, sd) in measured.items():
            t, t_low, t_high = twin[(factor, level)]
            effect = Effect(factor, level, plan.factors[factor][0], quantity, value, low, high,
                            strikes, sd, t, t_low, t_high, 0.0)
            if not effect.resolved:
                delta = plan.smallest_effect.get(quantity) or _forecast_difference(effect)
                effect = _with_more_repeats(effect, delta, cells_per_level[factor], repeats_run)
            effects.append(effect)
    return effects


def _identified(plan: StudyPlan, rows: Sequence[Mapping]) -> bool:
    if not rows:
        return False
    x, _ = _design_matrix(plan, rows)
    return int(np.linalg.matrix_rank(x)) == x.shape[1]


def _finite(value) -> bool:
    return value is not None and isinstance(value, (int, float)) and math.isfinite(value)


def _forecast_difference(effect: Effect) -> float | None:
    """The difference to resolve when the plan names none: the twin's, where it is at least a
    tenth of one strike's scatter."""
    t = effect.twin
    if not math.isfinite(t) or t == 0.0:
        return None
    if math.isfinite(effect.residual_sd) and abs(t) < 0.1 * effect.residual_sd:
        return None
    return abs(t)


def _with_more_repeats(effect: Effect, delta, cells_per_level: float,
                       repeats_run: int) -> Effect:
    from dataclasses import replace
    if not delta:
        return replace(effect, more_repeats=math.inf)
    if not math.isfinite(effect.residual_sd):
        return replace(effect, more_repeats=math.nan)
    needed = strikes_needed(delta, effect.residual_sd)
    if not math.isfinite(needed):
        return replace(effect, more_repeats=math.inf)
    return replace(effect, more_repeats=float(max(1, math.ceil(needed / cells_per_level)
                                                  - repeats_run)))


def auto_repeats(plan: StudyPlan, forecaster: StudyForecaster) -> int:
    """The repeats that resolve the plan's smallest effects (80 % power, 5 % level), from the
    twin's scatter of one strike within a day (at the latent's mean level), at the worst
    combination of conditions; at least MIN_REPEATS."""
    repeats = MIN_REPEATS
    belief = forecaster.belief
    for quantity, delta in plan.smallest_effect.items():
        sd = 0.0
        for cell in plan.cells:
            ensemble = forecaster.ensemble(plan.conditions_of(cell))
            if belief.latent is not None:
                weights = belief.within_day_weights(ensemble, np.array([belief.latent.mean]))[0]
            else:
                weights = belief.new_day_weights(ensemble)
            v = ensemble.values[quantity]
            ok = np.isfinite(v)
            mean = _weighted_mean(v, weights)
            sd = max(sd, math.sqrt(float(np.sum(weights[ok] * (v[ok] - mean) ** 2)
                                         / np.sum(weights[ok]))))
        needed = strikes_needed(delta, sd)
        for levels in plan.factors.values():
            per_level = len(plan.cells) / len(levels)
            repeats = max(repeats, math.ceil(needed / per_level))
    return int(repeats)


__all__ = ['Effect', 'auto_repeats', 'measured_effects', 'study_effects', 'twin_effects']
