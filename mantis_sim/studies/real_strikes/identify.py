"""System identification: the scene parameters you name, fitted to real strikes.

Every strike is simulated at its own conditions (fidelity.simulate_strike) with the scene of its
group (air_19mm, air_23mm, water_23mm: a parameter may be free for all groups or for some, as
`contact.hold_lever_mm@air_19mm`), and the residuals are, per strike:
- relative errors of peak tip speed and spring energy (the lab's values), and, with a lower
  weight, of the peak body and arm speeds;
- where the strike's motion was recorded, the body's and the arm's turn from the start of phase
  IV (theta1(t) - theta1(0), theta3(t) - theta3(0)) on a time grid through the strike, scaled so
  that a whole series weighs as much as one summary value.
scipy's least_squares (trust region, within bounds) minimises their sum of squares, or of a
robust loss of them (Loss: soft_l1, cauchy, huber, which weigh a strike far from the model
less, as a strike of a day whose robot was assembled differently is); its Jacobian is taken by
forward differences, all perturbed parameter sets simulated at once on the sweep's workers (a
local Dask cluster on this machine's cores, or a cluster given by address). The standard errors
and correlations come from that Jacobian at the solution (Gauss-Newton covariance, scaled by
the residual variance, with the robust loss's weights at the solution); a correlation above
CORRELATION_WARNING says the data cannot separate those two parameters.

Cross-validation leaves out one recording day at a time: fitted on the other days (starting
from the full fit), it predicts the left-out day's strikes; those errors, not the fitted ones,
say how the model does on strikes it has not seen.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, fields
import datetime
import math
import time
from typing import Optional

import numpy as np

from mantis_sim.errors import InputError
from mantis_sim.model import kinetic_lever
from mantis_sim.parameters import SECTIONS
from mantis_sim.scene import Scene

from .fidelity import SimulatedStrike, real_on_grid, seat_values, simulate_strike
from .strikes import RealStrike

CORRELATION_WARNING = 0.9
FAILED_RESIDUAL = 1.0           # each residual of a strike the model cannot simulate
SERIES_SCALE_RAD = {'theta1': 0.05, 'theta3': 0.5}


class IdentificationError(InputError):
    """The identification cannot start as asked (names the parameter, group or strike)."""


@dataclass(frozen=True)
class Weights:
    tip_speed: float = 1.0
    spring_energy: float = 1.0
    body_speed: float = 0.3
    arm_speed: float = 0.3
    # The recorded motion is the authors' processed angles (their smoothing is not published):
    # at this weight a whole series counts about as much as the summary values of its strike
    # where the model stands today (at 0.3 the time course, which no parameter here can match
    # closely, outweighs the lab's values thirty times over).
    series: float = 0.05

    @classmethod
    def parse(cls, items: Sequence[str]) -> Weights:
        """Weights from 'name=value' items (the rest at their defaults)."""
        known = {f.name for f in fields(cls)}
        values = {}
        for item in items:
            name, sep, text = item.partition('=')
            if not sep or name not in known:
                raise IdentificationError(
                    f'--weight {item}: expected NAME=VALUE with NAME one of '
                    f'{", ".join(sorted(known))}')
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not value >= 0.0 or math.isinf(value):
                raise IdentificationError(f'--weight {item}: the weight must be a finite '
                                          f'number >= 0')
            values[name] = value
        return cls(**values)


@dataclass(frozen=True)
class Loss:
    """How residuals count: 'linear' (least squares) or one of scipy's robust losses, rho(z)
    of z = (r / scale)^2, for which a residual beyond `scale` counts less than its square.
    Each residual row counts by itself, in the units of the weighted residuals: a relative error
    times its weight (a tip speed 5 % off at weight 1 is 0.05). A strike the model cannot
    simulate has residuals of FAILED_RESIDUAL, which a robust loss counts little more than a
    large miss."""

    name: str = 'linear'
    scale: float = 1.0

    NAMES = ('linear', 'soft_l1', 'huber', 'cauchy')

    def __post_init__(self):
        if self.name not in self.NAMES:
            raise IdentificationError(f'loss {self.name!r}: must be one of '
                                      f'{", ".join(self.NAMES)}')

    @classmethod
    def parse(cls, text: str) -> Loss:
        """'linear' or 'NAME:SCALE', as --loss takes it (SCALE in weighted-residual units)."""
        name, sep, scale_text = text.partition(':')
        if name not in cls.NAMES:
            raise IdentificationError(f'--loss {text}: NAME must be one of '
                                      f'{", ".join(cls.NAMES)}')
        if name == 'linear':
            if sep:
                raise IdentificationError(f'--loss {text}: least squares (linear) takes no '
                                          f'SCALE')
            return cls()
        try:
            scale = float(scale_text)
        except ValueError:
            scale = math.nan
        if not (scale > 0.0 and math.isfinite(scale)):
            raise IdentificationError(f'--loss {text}: a robust loss needs SCALE, a finite '
                                      f'number > 0 (a relative error at weight 1: 0.05 = 5 %)')
        return cls(name, scale)

    @property
    def label(self) -> str:
        return self.name if self.name == 'linear' else f'{self.name}:{self.scale:g}'

    def cost(self, residual: np.ndarray) -> float:
        """What the fit minimises: 0.5 scale^2 sum(rho(z)) (0.5 sum(r^2) when linear)."""
        rho, _ = _RHO[self.name]
        return float(0.5 * self.scale ** 2 * np.sum(rho((residual / self.scale) ** 2)))

    def row_weights(self, residual: np.ndarray) -> np.ndarray:
        """sqrt(rho'(z)) per residual: the weights of the least-squares problem that has the
        same step at this point (iteratively reweighted least squares)."""
        _, slope = _RHO[self.name]
        return np.sqrt(slope((residual / self.scale) ** 2))


# scipy.optimize.least_squares' losses: rho(z) and rho'(z), z = (residual / scale)^2
_RHO = {
    'linear': (lambda z: z, np.ones_like),
    'soft_l1': (lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0), lambda z: 1.0 / np.sqrt(1.0 + z)),
    'huber': (lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0),
              lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))),
    'cauchy': (np.log1p, lambda z: 1.0 / (1.0 + z)),
}


@dataclass(frozen=True)
class FreeParameter:
    """A scene key set free, for every group or only for the named ones, within bounds; with a
    recording day, only for that day's strikes (a day's state: a nuisance parameter, kept in
    the provenance, not in the scene)."""

    key: str
    lower: float
    upper: float
    groups: Optional[tuple] = None
    day: Optional[str] = None

    @property
    def label(self) -> str:
        label = self.key if self.groups is None else f'{self.key}@{"+".join(self.groups)}'
        return label if self.day is None else f'{label}#{self.day}'

    def applies_to(self, group: str) -> bool:
        return self.groups is None or group in self.groups

    def applies_to_strike(self, strike: RealStrike) -> bool:
        return self.applies_to(strike.group) and self.day in (None, strike.recording_day)


def per_day_parameters(param: FreeParameter, strikes: Sequence[RealStrike]) -> list:
    """One copy of ``param`` for each (group, recording day) of the strikes it applies to."""
    days = sorted({(s.group, s.recording_day) for s in strikes if param.applies_to(s.group)})
    undated = sorted({s.trial for s in strikes if param.applies_to(s.group)
                      and not s.recording_day})
    if undated:
        raise IdentificationError(f'--per-day {param.label}: strikes without a recording_day '
                                  f'({", ".join(undated[:5])})')
    return [FreeParameter(param.key, param.lower, param.upper, (group,), day)
            for group, day in days]


def split_label(label: str) -> tuple[str, Optional[tuple]]:
    """'section.key[@group[+group]]' (FreeParameter.label) -> (key, groups or None: all)."""
    key, _, group_text = label.partition('@')
    return key, tuple(g for g in group_text.split('+') if g) or None


def parse_free_parameter(text: str, scenes: dict[str, Scene],
                         option: str = '--fit') -> FreeParameter:
    """'section.key[@group[+group]][=LO:HI]' -> FreeParameter; bounds default to the key's
    valid range. Refuses unknown keys, groups, and bounds outside the valid range."""
    spec, _, bounds = text.partition('=')
    key, groups = split_label(spec.strip())
    section, _, name = key.partition('.')
    cls = SECTIONS.get(section)
    meta = None
    if cls is not None:
        meta = next((f.metadata for f in cls.__dataclass_fields__.values() if f.name == name),
                    None)
    if meta is None or meta.get('choices') is not None or meta.get('lo') is None:
        raise IdentificationError(f'{option} {text}: {key!r} is not a numeric scene parameter '
                                  f'(see `mantis scenes --params`)')
    unknown = [g for g in groups or () if g not in scenes]
    if unknown:
        raise IdentificationError(f'{option} {text}: no strikes of group(s) {", ".join(unknown)} '
                                  f'(groups here: {", ".join(sorted(scenes))})')
    lo, hi = float(meta['lo']), float(meta['hi'])
    if bounds:
        try:
            lo_text, hi_text = bounds.split(':')
            lo, hi = float(lo_text), float(hi_text)
        except ValueError:
            raise IdentificationError(f'{option} {text}: bounds must be LO:HI') from None
        if not (meta['lo'] <= lo < hi <= meta['hi']):
            raise IdentificationError(f'{option} {text}: bounds {lo:g}:{hi:g} must lie within '
                                      f'the valid range [{meta["lo"]:g}, {meta["hi"]:g}] '
                                      f'{meta["unit"]} with LO < HI')
    return FreeParameter(key, lo, hi, groups)


@dataclass
class Identification:
    parameters: list[FreeParameter]
    values: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    initial: np.ndarray
    cost: float
    residual_count: int
    evaluations: int
    wall_s: float
    strikes: list[RealStrike]
    simulated: list[SimulatedStrike]
    message: str
    jacobian: Optional[np.ndarray] = None       # at the solution, residuals x parameters
    residual: Optional[np.ndarray] = None
    row_strike: Optional[np.ndarray] = None     # the strike of each residual
    loss: Loss = Loss()
    at_seat: bool = False       # each strike's arm latched at its tracked seat (StrikeModel)
    started: str = field(default_factory=lambda: datetime.datetime.now(
        datetime.UTC).isoformat(timespec='seconds'))

    def at_bounds(self) -> list[str]:
        """Parameters the fit left within 1 % of the range at one of its bounds: the data want
        them further out than allowed, and their standard errors do not mean much."""
        return [p.label for p, v in zip(self.parameters, self.values)
                if min(v - p.lower, p.upper - v) <= 0.01 * (p.upper - p.lower)]

    def value_map(self) -> dict[str, float]:
        return {p.label: float(v) for p, v in zip(self.parameters, self.values)}

    def inseparable_pairs(self) -> list[tuple[str, str, float]]:
        """Pairs of parameters the data cannot tell apart (|correlation| > the warning)."""
        out = []
        n = len(self.parameters)
        for i in range(n):
            for j in range(i + 1, n):
                rho = self.correlation[i, j]
                if math.isfinite(rho) and abs(rho) > CORRELATION_WARNING:
                    out.append((self.parameters[i].label, self.parameters[j].label, float(rho)))
        return out


def values_for_strike(params: Sequence[FreeParameter], values, strike: RealStrike) -> dict:
    """{key: value} of every free parameter that applies to the strike (its group, its day)."""
    return {p.key: float(v) for p, v in zip(params, values) if p.applies_to_strike(strike)}


def task_values(strike: RealStrike, values: dict, at_seat: bool) -> dict:
    """What a simulation of the strike sets beside its conditions: ``values`` (a fit's, a
    day's), over the strike's tracked seat where ``at_seat`` (fidelity.seat_values)."""
    return {**(seat_values(strike) if at_seat else {}), **values}


def strike_residuals(strike: RealStrike, sim: SimulatedStrike, weights: Weights) -> np.ndarray:
    """This strike's residuals (module docstring); a fixed count per strike."""
    summary = ((strike.peak_tip_speed_mps, sim.peak_tip_speed_mps, weights.tip_speed),
               (strike.spring_energy_mJ, sim.spring_energy_mJ, weights.spring_energy),
               (strike.peak_body_speed_radps, sim.peak_body_speed_radps, weights.body_speed),
               (strike.peak_arm_speed_radps, sim.peak_arm_speed_radps, weights.arm_speed))
    out = []
    for measured, predicted, weight in summary:
        if measured is None or weight == 0:
            continue
        out.append(weight * (predicted / measured - 1.0) if math.isfinite(predicted)
                   else FAILED_RESIDUAL)
    if strike.series is not None and weights.series > 0:
        real = real_on_grid(strike.series, strike.medium)
        n = real.t_s.size
        for name in ('theta1', 'theta3'):
            measured = getattr(real, f'{name}_rad')
            measured = measured - measured[np.argmin(np.abs(real.t_s))]
            if sim.series is None:
                out.extend([FAILED_RESIDUAL] * n)
                continue
            predicted = getattr(sim.series, f'{name}_rad')
            predicted = predicted - predicted[np.argmin(np.abs(sim.series.t_s))]
            diff = (predicted - measured) / SERIES_SCALE_RAD[name]
            diff = np.where(np.isfinite(measured), diff, 0.0)
            diff = np.where(np.isfinite(diff), diff, FAILED_RESIDUAL)
            out.extend(weights.series * diff / math.sqrt(n))
    return np.asarray(out, dtype=float)


def simulate_task(task) -> SimulatedStrike:
    """(scene, strike, with its series?, {key: value}) -> simulate_strike: the strike at its
    own conditions with those values set together (a latch offset is checked against the
    strike's own contact angle). A task for the workers."""
    scene, strike, series, values = task
    return simulate_strike(scene, strike, series=series, values=values)


class StrikeModel:
    """Simulates the strikes for parameter sets, many at once, through ``mapper``
    (mapper(function, tasks) -> results in order: serial, or on a Dask cluster). With
    ``at_seat`` each strike that has a tracked seat is simulated with its arm latched there
    (fidelity.seat_values), the free parameters set beside."""

    def __init__(self, scenes: dict[str, Scene], strikes: list[RealStrike],
                 params: list[FreeParameter], weights: Weights, mapper: Callable,
                 at_seat: bool = False):
        missing = sorted({s.group for s in strikes} - set(scenes))
        if missing:
            raise IdentificationError(f'no scene for the strikes of group(s) '
                                      f'{", ".join(missing)}')
        self.scenes, self.strikes, self.params = scenes, strikes, params
        self.weights, self.mapper, self.at_seat = weights, mapper, at_seat
        self.evaluations = 0

    def of(self, strikes: list[RealStrike],
           params: Optional[list[FreeParameter]] = None) -> StrikeModel:
        """The same model for other strikes (and free parameters), e.g. a left-out day's."""
        return StrikeModel(self.scenes, strikes, self.params if params is None else params,
                           self.weights, self.mapper, self.at_seat)

    def simulate(self, value_sets: list[np.ndarray]) -> list[list[SimulatedStrike]]:
        tasks = []
        for values in value_sets:
            tasks.extend((self.scenes[s.group], s, s.series is not None,
                          task_values(s, values_for_strike(self.params, values, s),
                                      self.at_seat))
                         for s in self.strikes)
        results = self.mapper(simulate_task, tasks)
        self.evaluations += len(value_sets)
        n = len(self.strikes)
        return [results[k * n:(k + 1) * n] for k in range(len(value_sets))]

    def residuals(self, value_sets: list[np.ndarray]) -> list[np.ndarray]:
        out = []
        for sims in self.simulate(value_sets):
            parts = [strike_residuals(strike, sim, self.weights)
                     for strike, sim in zip(self.strikes, sims)]
            # which strike each residual belongs to (a fixed count per strike)
            self.row_strike = np.repeat(np.arange(len(parts)), [p.size for p in parts])
            out.append(np.concatenate(parts))
        return out


def identify(model: StrikeModel, initial: Optional[Sequence[float]] = None,
             max_iterations: int = 8, relative_step: float = 0.02,
             log: Callable[[str], None] = lambda _: None,
             loss: Loss = Loss()) -> Identification:
    """Least-squares fit of model.params (module docstring), under ``loss``."""
    from scipy.optimize import least_squares
    params = model.params
    lower = np.array([p.lower for p in params])
    upper = np.array([p.upper for p in params])
    x0 = np.array(initial if initial is not None else
                  [default_value(model.scenes, p) for p in params], dtype=float)
    x0 = np.clip(x0, lower, upper)
    started = time.monotonic()
    cache: dict[bytes, np.ndarray] = {}
    last_jacobian: dict[bytes, np.ndarray] = {}      # the last one, by the point it is at

    def steps(x):
        step = relative_step * np.maximum(np.abs(x), 0.05 * (upper - lower))
        # step inwards at an upper bound
        return np.where(x + step > upper, -step, step)

    def fun(x):
        key = x.tobytes()
        if key not in cache:
            cache[key] = model.residuals([x])[0]
            log(f'cost {loss.cost(cache[key]):.5g} at '
                + ', '.join(f'{p.label}={v:.4g}' for p, v in zip(params, x)))
        return cache[key]

    def jac(x):
        h = steps(x)
        sets = [x] if x.tobytes() not in cache else []
        sets += [x + np.eye(len(x))[i] * h[i] for i in range(len(x))]
        results = model.residuals(sets)
        if x.tobytes() not in cache:
            cache[x.tobytes()] = results.pop(0)
        base = cache[x.tobytes()]
        jacobian = np.column_stack([(r - base) / h[i] for i, r in enumerate(results)])
        last_jacobian.clear()
        last_jacobian[x.tobytes()] = jacobian
        return jacobian

    scale = np.maximum(np.abs(x0), 0.05 * (upper - lower))
    solution = least_squares(fun, x0, jac=jac, bounds=(lower, upper), x_scale=scale,
                             max_nfev=max_iterations, method='trf', loss=loss.name,
                             f_scale=loss.scale)
    x = solution.x
    # at the solution itself: the optimiser may stop on a step it accepted after its last one
    jacobian = last_jacobian.get(x.tobytes())
    if jacobian is None:
        jacobian = jac(x)
    residual = fun(x)
    weights = loss.row_weights(residual)
    std_errors, correlation = _uncertainty(jacobian * weights[:, None], residual * weights,
                                           len(x))
    simulated = model.simulate([x])[0]
    return Identification(list(params), x, std_errors, correlation, x0,
                          float(solution.cost), residual.size, model.evaluations,
                          time.monotonic() - started, model.strikes, simulated,
                          solution.message, jacobian, residual, model.row_strike.copy(),
                          loss=loss, at_seat=model.at_seat)


def _uncertainty(jacobian: np.ndarray, residual: np.ndarray, n: int):
    """Standard errors and correlations from the Gauss-Newton covariance."""
    dof = max(residual.size - n, 1)
    variance = float(residual @ residual) / dof
    covariance = variance * np.linalg.pinv(jacobian.T @ jacobian)
    std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    with np.errstate(invalid='ignore', divide='ignore'):
        correlation = covariance / np.outer(std, std)
    return std, correlation


def default_value(scenes: dict[str, Scene], p: FreeParameter) -> float:
    """Where a fit of ``p`` starts: the value the model uses in the first group it applies to."""
    group = next(g for g in sorted(scenes) if p.applies_to(g))
    return scene_value(scenes[group], p.key)


# Optional keys a scene may leave unset, and the value the model then uses.
_WHEN_UNSET = {'hinge.kinetic_friction_lever_mm': kinetic_lever}


def scene_value(scene: Scene, key: str) -> float:
    """The value the model uses for a numeric key of the scene, also where an optional key is
    left unset (hinge.kinetic_friction_lever_mm: the ratio x the static lever)."""
    section, _, name = key.partition('.')
    value = getattr(getattr(scene, section), name)
    if value is None:
        if key not in _WHEN_UNSET:
            raise IdentificationError(f'{key} is unset in scene {scene.name} and has no value '
                                      f'to start a fit from: set it in the scene')
        value = _WHEN_UNSET[key](scene)
    return float(value)


@dataclass
class FoldResult:
    left_out: str
    strikes: list[RealStrike]
    simulated: list[SimulatedStrike]
    values: np.ndarray


def cross_validate_one_step(model: StrikeModel, fit: Identification,
                            log: Callable[[str], None] = lambda _: None) -> list[FoldResult]:
    """Leave one recording day out at a time, each fit to the other days taken as one
    Gauss-Newton step from the full fit (with the full fit's Jacobian restricted to the other
    days' residuals), within the bounds; the left-out day's strikes are then simulated with it.
    The usual linearised leave-out: one simulation of the left-out strikes per day, where a
    refit (cross_validate) costs a whole identification per day."""
    days = _days(model)
    lower = np.array([p.lower for p in fit.parameters])
    upper = np.array([p.upper for p in fit.parameters])
    folds = []
    for day in days:
        keep = np.array([model.strikes[i].recording_day != day for i in fit.row_strike])
        weights = fit.loss.row_weights(fit.residual[keep])
        j, r = fit.jacobian[keep] * weights[:, None], fit.residual[keep] * weights
        step = -np.linalg.pinv(j.T @ j) @ (j.T @ r)
        values = _without_the_day(model, np.clip(fit.values + step, lower, upper), day)
        test = [s for s in model.strikes if s.recording_day == day]
        predicted = model.of(test).simulate([values])[0]
        log(f'left out {day}: {len(test)} strikes')
        folds.append(FoldResult(day, test, predicted, values))
    return folds


def _without_the_day(model: StrikeModel, values: np.ndarray, day: str) -> np.ndarray:
    """The values with the left-out day's own parameters (--per-day) at the scene's value: a
    day the fit has not seen is predicted as the scene stands for any day."""
    values = values.copy()
    for i, p in enumerate(model.params):
        if p.day == day:
            values[i] = default_value(model.scenes, p)
    return values


def _days(model: StrikeModel) -> list[str]:
    days = sorted({s.recording_day for s in model.strikes})
    if len(days) < 2:
        raise IdentificationError('cross-validation needs strikes of at least two recording '
                                  'days (the recording_day column)')
    return days


def cross_validate(model: StrikeModel, fitted: np.ndarray, max_iterations: int = 3,
                   log: Callable[[str], None] = lambda _: None,
                   loss: Loss = Loss()) -> list[FoldResult]:
    """Leave one recording day out at a time, refitted on the other days from the full fit."""
    days = _days(model)
    folds = []
    for day in days:
        train = [s for s in model.strikes if s.recording_day != day]
        test = [s for s in model.strikes if s.recording_day == day]
        train_groups = {s.group for s in train}
        free = [p for p in model.params if (p.groups is None or set(p.groups) & train_groups)
                and p.day != day]
        fixed = [(p, v) for p, v in zip(model.params, fitted) if p not in free]
        sub = model.of(train, free)
        start = [v for p, v in zip(model.params, fitted) if p in free]
        fit = identify(sub, start, max_iterations=max_iterations, loss=loss)
        values = dict(zip(free, fit.values))
        values.update(dict(fixed))
        full = _without_the_day(model, np.array([values[p] for p in model.params]), day)
        predicted = model.of(test).simulate([full])[0]
        log(f'left out {day}: {len(test)} strikes')
        folds.append(FoldResult(day, test, predicted, full))
    return folds


__all__ = ['CORRELATION_WARNING', 'FoldResult', 'FreeParameter', 'Identification',
           'IdentificationError', 'Loss', 'StrikeModel', 'Weights', 'cross_validate',
           'cross_validate_one_step', 'default_value', 'identify', 'scene_value', 'simulate_task',
           'parse_free_parameter', 'per_day_parameters', 'strike_residuals', 'task_values',
           'values_for_strike']


def error_summary(strikes: list[RealStrike], simulated: list[SimulatedStrike]) -> dict:
    """Per group: strikes and median |relative error| of peak tip speed and spring energy."""
    from .fidelity import error_rows, group_summary
    rows = error_rows(strikes, simulated)
    speed = group_summary(rows, 'peak_tip_speed_mps')
    energy = group_summary(rows, 'spring_energy_mJ')
    return {g: {'strikes': speed[g]['strikes'],
                'tip_speed_median_abs_error': round(speed[g]['median_abs_error'], 4),
                'spring_energy_median_abs_error': round(energy[g]['median_abs_error'], 4)}
            for g in speed}


def calibrated_scene(base: dict, fit: Identification, group: str,
                     folds: Optional[list[FoldResult]] = None,
                     sources: Sequence[str] = (),
                     cv_method: str = 'leave one recording day out',
                     weights: Optional[Weights] = None) -> dict:
    """A scene file's content (``base``: the group's scene file as a mapping) with the fitted
    values that apply to the group and their provenance: which strikes, when, the residuals,
    each parameter's standard error and the correlations. Where ``base`` was itself identified
    and keeps parameters this fit held, that fit stays on record as an earlier stage. A spread
    in ``base`` was fitted about the parameters this fit replaces: it is dropped (`mantis
    identify --spread` fits it again)."""
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    earlier = doc.pop('provenance', None) or {}
    doc.pop('spread', None)
    labels = [p.label for p in fit.parameters if p.day is None]
    parameters, day_states = {}, {}
    for p, value, std, start in zip(fit.parameters, fit.values, fit.std_errors, fit.initial):
        entry = {'value': float(f'{value:.6g}'), 'std_error': float(f'{std:.3g}'),
                 'bounds': [p.lower, p.upper], 'start': float(f'{start:.6g}')}
        if p.label in fit.at_bounds():
            entry['at_bound'] = True
        if p.day is not None:           # a day's state: on record, the scene keeps its value
            if p.applies_to(group):
                day_states[p.label] = entry
            continue
        if p.applies_to(group):
            section, _, name = p.key.partition('.')
            doc.setdefault(section, {})[name] = entry['value']
        else:
            entry['applies_to'] = list(p.groups or ())
        parameters[p.label] = entry
    held, stages = _held_from_earlier_stages(earlier, parameters)
    index = [i for i, p in enumerate(fit.parameters) if p.day is None]
    correlation = {a: {b: float(f'{fit.correlation[i, j]:.3f}') for j, b in zip(index, labels)
                       if j != i} for i, a in zip(index, labels)}
    provenance = {
        'identified_by': 'mantis identify',
        'date': fit.started,
        'strikes': len(fit.strikes),
        'recording_days': sorted({s.recording_day for s in fit.strikes if s.recording_day}),
        'trials': [s.trial for s in fit.strikes],
        'sources': sorted(set(sources)),
        'parameters': {**held, **parameters},
        'correlation': correlation,
        'inseparable': [f'{a} ~ {b} (correlation {rho:+.2f})'
                        for a, b, rho in fit.inseparable_pairs()],
        'weights': asdict(weights or Weights()),
        'loss': fit.loss.label,
        **({'at_seat': 'each strike\'s arm latched at its tracked seat (mantis identify '
                       '--at-seat)'} if fit.at_seat else {}),
        'cost': float(f'{fit.cost:.5g}'),
        'fitted_errors': error_summary(fit.strikes, fit.simulated),
        'optimiser': fit.message,
    }
    if folds:
        provenance['cross_validated_errors'] = error_summary(
            [s for f in folds for s in f.strikes], [s for f in folds for s in f.simulated])
        provenance['cross_validation'] = cv_method
        provenance['cross_validation_by_day'] = {
            f.left_out: error_summary(f.strikes, f.simulated) for f in folds}
    if day_states:
        provenance['day_states'] = day_states
    if stages:
        provenance['earlier_stages'] = stages
    doc['provenance'] = provenance
    return doc


STAGE_KEYS = ('date', 'strikes', 'weights', 'loss', 'at_seat', 'cost', 'fitted_errors',
              'cross_validated_errors', 'cross_validation', 'optimiser', 'day_states')


def _same_parameter(label: str, other: str) -> bool:
    """Whether two labels (FreeParameter.label) set one key for a group in common."""
    (key, groups), (other_key, other_groups) = split_label(label), split_label(other)
    if key != other_key:
        return False
    return groups is None or other_groups is None or bool(set(groups) & set(other_groups))


def _held_from_earlier_stages(earlier: dict, refitted: dict) -> tuple[dict, list]:
    """(the parameters an earlier identification fitted that this one held, each marked with
    its stage, 1 the first; the record of those earlier fits), or ({}, []) if it held none."""
    if earlier.get('identified_by') != 'mantis identify':
        return {}, []
    stages = list(earlier.get('earlier_stages') or [])
    previous = len(stages) + 1
    entries = earlier.get('parameters') or {}
    held = {label: {**entry, 'held_from_stage': entry.get('held_from_stage', previous)}
            for label, entry in entries.items()
            if not any(_same_parameter(label, other) for other in refitted)}
    if not held:
        return {}, []
    record = {key: earlier[key] for key in STAGE_KEYS if key in earlier}
    record.setdefault('weights', asdict(Weights()))
    fitted_there = sorted(label for label, entry in entries.items()
                          if 'held_from_stage' not in entry)
    stages.append({'stage': previous, 'parameters': fitted_there, **record})
    return held, stages


__all__ += ['calibrated_scene', 'error_summary']
