"""The robot's spread: how far strikes of one design scatter, and how sure the model is.

A scene's `spread` section (written by `mantis identify --spread`,
studies/real_strikes/spread_fit.py) describes what differs between simulated robots of one
design, each part drawn on its own:

- **the latent**: where the arm sits on the latch (`geometry.latch_offset_deg`), which the
  recorded conditions do not fix. A strike's value is the group's mean, plus its day's
  assembly, plus its own scatter within the day, each normal (a mixed model over the training
  strikes' own values). The mean is drawn within its standard error, and the day's standard
  deviation from its own uncertainty (a scaled inverse chi-square on the days' degrees of
  freedom: with a handful of days, a new day may lie further out than the fitted value says),
  as is the within-day one (on the strikes' less the days').
  A strike of a recording day the fit has seen takes that day's assembly as the mixed model
  predicts it from the day's strikes (`days`: its offset from the mean, and the standard
  deviation of the day's level, mean + offset), not a new day's draw.
  A draw beyond the latch's range sits at its end: an arm cannot sit beyond the latch.
- **the identified parameters**: multivariate normal about the scene's values, from their
  standard errors and correlations; draws outside a parameter's bounds are clipped to them.
- **the discrepancy**: what the physics misses, per metric, a relative error: its bias (drawn
  within its standard error) and its scatter, normal.

The first two go through the simulator, so a design nobody built scatters as its physics
says; the discrepancy multiplies the simulated metric. The section also keeps the group's
measured values (`climatology`), the forecast that quotes the lab's past strikes, against
which a spread is judged.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
import math
from typing import Optional

import numpy as np

from .parameters import SECTIONS, ParameterError, describe

#: The metrics a discrepancy and a climatology are kept for, as a strike report names them.
METRICS = ('peak_tip_speed_mps', 'spring_energy_mJ')
#: Robots a spread draws by default: the fewest whose quantiles move by under 5 % of the 80 %
#: interval's width from seed to seed (docs/spread_benchmark.md, "What N costs").
DEFAULT_ROBOTS = 400
#: The quantile levels reported for a spread: q05, q10, ... q95.
QUANTILE_LEVELS = tuple(round(0.05 * k, 2) for k in range(1, 20))


def quantile_label(level: float) -> str:
    return f'q{round(100 * level):02d}'


def _scatter_sds(sd: float, dof: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """N draws of a fitted standard deviation from its uncertainty: a scaled inverse chi-square
    on its degrees of freedom (the fitted value itself where they are infinite)."""
    if not math.isfinite(dof):
        return np.full(n, sd)
    return sd * np.sqrt(dof / rng.chisquare(dof, n))


@dataclass(frozen=True)
class Latent:
    """A strike's own value of a scene key: mean + day + strike, each normal (units of key)."""
    key: str
    mean: float
    mean_std_error: float
    day_sd: float
    strike_sd: float
    lower: float        # the draws' range (the key's valid values for the scene's geometry)
    upper: float
    day_dof: float = math.inf   # the degrees of freedom of the day variance (days - groups)
    strike_dof: float = math.inf    # those of the within-day variance (strikes - days)
    #: recording day -> (its assembly's offset from the mean, the sd of its level, mean +
    #: offset, the mean's own error included), for the days the fit has seen
    days: Mapping[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class ParameterSpread:
    """The identified parameters' joint normal uncertainty (values in their keys' units)."""
    keys: tuple
    values: np.ndarray
    covariance: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


@dataclass(frozen=True)
class Discrepancy:
    """What the physics misses in a metric, relative: measured = simulated * (1 + bias + e),
    e normal with standard deviation sd."""
    metric: str
    bias: float
    bias_std_error: float
    sd: float


@dataclass(frozen=True)
class Draws:
    """N robots drawn from a spread: their scene values and each metric's discrepancy factor."""
    values: list            # [{key: value}] one per robot
    factors: dict           # metric -> ndarray (N,) to multiply the simulated metric by


@dataclass(frozen=True)
class Spread:
    latent: Optional[Latent]
    parameters: Optional[ParameterSpread]
    discrepancy: tuple
    climatology: dict       # metric -> tuple of the group's measured values
    provenance: dict

    def draw(self, n: int, rng: np.random.Generator, contact_angle_deg: float = 0.0,
             day: Optional[str] = None) -> Draws:
        """N robots. ``contact_angle_deg``: the design's, which bounds the latched arm angle
        (contact angle + latch offset in [0, 15] degrees) when the latent is that offset.
        ``day``: the recording day the strikes belong to; one the spread has seen gives them
        its assembly, any other a new day's."""
        if n < 1:
            raise ParameterError(f'a spread needs at least one robot, got {n}')
        values = [{} for _ in range(n)]
        if self.parameters is not None:
            for row, draw in zip(values, self._parameter_draws(n, rng)):
                row.update(zip(self.parameters.keys, map(float, draw)))
        if self.latent is not None:
            for row, value in zip(values, self._latent_draws(n, rng, contact_angle_deg, day)):
                row[self.latent.key] = float(value)
        factors = {}
        for d in self.discrepancy:
            bias = rng.normal(d.bias, d.bias_std_error, n)
            factors[d.metric] = 1.0 + bias + rng.normal(0.0, d.sd, n)
        return Draws(values, factors)

    def knows_day(self, day: Optional[str]) -> bool:
        """Whether the fit has seen recording day ``day`` (its strikes then draw its assembly)."""
        return self.latent is not None and day in self.latent.days

    def one_model(self, rng: np.random.Generator) -> Spread:
        """This spread with what the data leave uncertain drawn once: the parameters, the
        latent's mean and day scatter, the discrepancy's bias. What remains is how strikes of
        one robot model scatter (days, strikes, the discrepancy's scatter): averaged over its
        draws, a design's mean under one model; over many such models, how sure that mean is."""
        parameters = latent = None
        if self.parameters is not None:
            p = self.parameters
            fixed = self._parameter_draws(1, rng)[0]
            parameters = ParameterSpread(p.keys, fixed, np.zeros_like(p.covariance), p.lower,
                                         p.upper)
        if self.latent is not None:
            lat = self.latent
            day_sd = float(_scatter_sds(lat.day_sd, lat.day_dof, 1, rng)[0])
            mean = float(rng.normal(lat.mean, lat.mean_std_error))
            strike_sd = float(_scatter_sds(lat.strike_sd, lat.strike_dof, 1, rng)[0])
            latent = replace(lat, mean=mean, mean_std_error=0.0, day_sd=day_sd,
                             strike_sd=strike_sd, day_dof=math.inf, strike_dof=math.inf)
        discrepancy = tuple(replace(d, bias=float(rng.normal(d.bias, d.bias_std_error)),
                                    bias_std_error=0.0) for d in self.discrepancy)
        return replace(self, latent=latent, parameters=parameters, discrepancy=discrepancy)

    def _parameter_draws(self, n: int, rng: np.random.Generator) -> np.ndarray:
        p = self.parameters
        if not p.covariance.any():
            return np.clip(np.tile(p.values, (n, 1)), p.lower, p.upper)
        draws = rng.multivariate_normal(p.values, p.covariance, n, method='eigh')
        return np.clip(draws, p.lower, p.upper)

    def latent_range(self, contact_angle_deg: float) -> tuple[float, float]:
        """Where the latent may lie for a design of this contact angle: its range, and for the
        latch offset the latched arm within [0, 15] degrees."""
        lat = self.latent
        lower, upper = lat.lower, lat.upper
        if lat.key == 'geometry.latch_offset_deg':
            lower = max(lower, -contact_angle_deg)
            upper = min(upper, 15.0 - contact_angle_deg)
        if not lower < upper:
            raise ParameterError(f'{lat.key}: no value lies in [{lower:g}, {upper:g}] for a '
                                 f'contact angle of {contact_angle_deg:g} degrees')
        return lower, upper

    def _latent_draws(self, n: int, rng: np.random.Generator, contact_angle_deg: float,
                      day: Optional[str] = None) -> np.ndarray:
        lat = self.latent
        lower, upper = self.latent_range(contact_angle_deg)
        if self.knows_day(day):
            offset, level_sd = lat.days[day]
            level = rng.normal(lat.mean + offset, level_sd, n)
        else:
            level = (rng.normal(lat.mean, lat.mean_std_error, n)
                     + rng.normal(0.0, 1.0, n) * _scatter_sds(lat.day_sd, lat.day_dof, n, rng))
        strike = rng.normal(0.0, 1.0, n) * _scatter_sds(lat.strike_sd, lat.strike_dof, n, rng)
        return np.clip(level + strike, lower, upper)

    def to_mapping(self) -> dict:
        """The scene file's `spread` section (from_mapping reads it back)."""
        out: dict = {}
        if self.latent is not None:
            lat = self.latent
            out['latent'] = {'key': lat.key, 'mean': _sig(lat.mean),
                             'mean_std_error': _sig(lat.mean_std_error),
                             'day_sd': _sig(lat.day_sd), 'strike_sd': _sig(lat.strike_sd),
                             'range': [_sig(lat.lower), _sig(lat.upper)],
                             'day_dof': _sig(lat.day_dof), 'strike_dof': _sig(lat.strike_dof)}
            if lat.days:
                out['latent']['days'] = {day: {'offset': _sig(effect), 'sd': _sig(sd)}
                                         for day, (effect, sd) in lat.days.items()}
        if self.parameters is not None:
            p = self.parameters
            sd = np.sqrt(np.diag(p.covariance))
            scale = np.where(sd > 0, sd, 1.0)
            corr = p.covariance / np.outer(scale, scale)
            np.fill_diagonal(corr, 1.0)
            out['parameters'] = {
                key: {'value': _sig(v), 'std_error': _sig(s), 'bounds': [_sig(lo), _sig(hi)]}
                for key, v, s, lo, hi in zip(p.keys, p.values, sd, p.lower, p.upper)}
            pairs = {a: {b: round(float(corr[i, j]), 4) for j, b in enumerate(p.keys)
                         if j != i and corr[i, j] != 0} for i, a in enumerate(p.keys)}
            out['correlation'] = {a: row for a, row in pairs.items() if row}
        out['discrepancy'] = {d.metric: {'bias': _sig(d.bias),
                                         'bias_std_error': _sig(d.bias_std_error),
                                         'sd': _sig(d.sd)} for d in self.discrepancy}
        out['climatology'] = {m: [_sig(v) for v in values]
                              for m, values in self.climatology.items()}
        out['provenance'] = self.provenance
        return out

    @classmethod
    def from_mapping(cls, data, where: str) -> Spread:
        """A scene file's `spread` section; a malformed one is refused (ParameterError) naming
        ``where`` and the field."""
        data = _mapping(data, where, 'spread')
        unknown = set(data) - {'latent', 'parameters', 'correlation', 'discrepancy',
                               'climatology', 'provenance'}
        if unknown:
            raise ParameterError(f'{where}: spread: unknown key(s) '
                                 f'{", ".join(sorted(map(str, unknown)))}')
        return cls(_latent(data.get('latent'), where), _parameters(data, where),
                   _discrepancy(_mapping(data.get('discrepancy'), where, 'discrepancy'), where),
                   _climatology(_mapping(data.get('climatology'), where, 'climatology'), where),
                   _mapping(data.get('provenance'), where, 'provenance'))

def _sig(value) -> float:
    """A float to 6 significant digits: what a scene file needs, readably."""
    return float(f'{float(value):.6g}')


def _number(value, where: str, name: str, minimum: Optional[float] = None) -> float:
    if isinstance(value, bool):
        raise ParameterError(f'{where}: spread: {name} = {value!r} is not a number')
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f'{where}: spread: {name} = {value!r} is not a number') from None
    if not math.isfinite(number) or (minimum is not None and number < minimum):
        bound = '' if minimum is None else f' >= {minimum:g}'
        raise ParameterError(f'{where}: spread: {name} = {value!r} must be a finite number{bound}')
    return number


def _mapping(value, where: str, name: str) -> dict:
    """``value`` as a mapping ({} if absent); anything else is refused, naming ``name``."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ParameterError(f'{where}: spread: {name} must be a mapping, got '
                             f'{type(value).__name__} {value!r}')
    return value


def _span(value, where: str, name: str) -> tuple[float, float]:
    """[low, high] with low < high (either may be infinite)."""
    if value is None:
        return -math.inf, math.inf
    if not (isinstance(value, (list, tuple)) and len(value) == 2):
        raise ParameterError(f'{where}: spread: {name} = {value!r} is not [low, high]')
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ParameterError(f'{where}: spread: {name} = {value!r} is not [low, high] in '
                             f'numbers') from None
    if not low < high:
        raise ParameterError(f'{where}: spread: {name} = {value!r}: need low < high')
    return low, high


def _scene_key(value, where: str, name: str) -> str:
    """A numeric scene key section.name, as a scene file's sections define it."""
    section, _, field = str(value).partition('.')
    known = {key for key, default, _, _ in describe(section)} if section in SECTIONS else set()
    if not isinstance(value, str) or value not in known:
        raise ParameterError(f'{where}: spread: {name} {value!r} is not a scene key '
                             f'(section.name, e.g. geometry.latch_offset_deg)')
    return value


def _latent(data, where: str) -> Optional[Latent]:
    if data is None:
        return None
    data = _mapping(data, where, 'latent')
    if 'key' not in data:
        raise ParameterError(f'{where}: spread: latent must be a mapping with key, mean, '
                             f'mean_std_error, day_sd, strike_sd and range')
    lower, upper = _span(data.get('range'), where, 'latent range')
    return Latent(_scene_key(data['key'], where, 'latent key'),
                  _number(data.get('mean'), where, 'latent mean'),
                  _number(data.get('mean_std_error', 0.0), where, 'latent mean_std_error', 0.0),
                  _number(data.get('day_sd'), where, 'latent day_sd', 0.0),
                  _number(data.get('strike_sd'), where, 'latent strike_sd', 0.0), lower, upper,
                  _dof(data.get('day_dof'), where, 'latent day_dof'),
                  _dof(data.get('strike_dof'), where, 'latent strike_dof'),
                  _days(_mapping(data.get('days'), where, 'latent days'), where))


def _dof(value, where: str, name: str) -> float:
    """Degrees of freedom: absent or .inf for a scatter taken as known."""
    return math.inf if value is None or value == math.inf else _number(value, where, name, 1.0)


def _days(data: dict, where: str) -> dict:
    """latent.days: {recording day: {offset, sd}} (degrees, or the latent key's units)."""
    out = {}
    for day, entry in data.items():
        if not isinstance(day, str):        # unquoted, 011620 would be read as octal 5008
            raise ParameterError(f'{where}: spread: latent days: the recording day {day!r} '
                                 f'must be a string (quote it)')
        entry = _mapping(entry, where, f'latent days {day}')
        if set(entry) != {'offset', 'sd'}:
            raise ParameterError(f'{where}: spread: latent days {day} must be a mapping with '
                                 f'offset and sd, got {entry!r}')
        out[day] = (_number(entry['offset'], where, f'latent days {day} offset'),
                    _number(entry['sd'], where, f'latent days {day} sd', 0.0))
    return out


def _parameters(data: dict, where: str) -> Optional[ParameterSpread]:
    params = _mapping(data.get('parameters'), where, 'parameters')
    if not params:
        return None
    keys = tuple(_scene_key(k, where, 'parameter') for k in params)
    entries = {k: _mapping(params[k], where, f'parameter {k}') for k in keys}
    values = np.array([_number(entries[k].get('value'), where, f'{k} value') for k in keys])
    sd = np.array([_number(entries[k].get('std_error'), where, f'{k} std_error', 0.0)
                   for k in keys])
    bounds = np.array([_span(entries[k].get('bounds'), where, f'{k} bounds') for k in keys])
    corr = np.eye(len(keys))
    table = _mapping(data.get('correlation'), where, 'correlation')
    for a, row in table.items():
        for b, rho in _mapping(row, where, f'correlation of {a}').items():
            if a not in keys or b not in keys or a == b:
                raise ParameterError(f'{where}: spread: correlation of {a} with {b}: both '
                                     f'must be distinct parameters of the spread')
            corr[keys.index(a), keys.index(b)] = _number(rho, where, f'correlation {a}, {b}')
    if not np.allclose(corr, corr.T) or np.abs(corr).max() > 1.0:
        raise ParameterError(f'{where}: spread: correlation must be symmetric, each within '
                             f'[-1, 1]')
    covariance = corr * np.outer(sd, sd)
    if np.linalg.eigvalsh(covariance).min() < -1e-9 * max(float(sd.max()) ** 2, 1e-300):
        raise ParameterError(f'{where}: spread: the parameters\' correlation is not positive '
                             f'semi-definite')
    return ParameterSpread(keys, values, covariance, bounds[:, 0], bounds[:, 1])


def _discrepancy(data: dict, where: str) -> tuple:
    out = []
    for metric, entry in data.items():
        if metric not in METRICS:
            raise ParameterError(f'{where}: spread: discrepancy of {metric!r}: known metrics '
                                 f'are {", ".join(METRICS)}')
        entry = _mapping(entry, where, f'discrepancy of {metric}')
        out.append(Discrepancy(metric, _number(entry.get('bias', 0.0), where, 'bias'),
                               _number(entry.get('bias_std_error', 0.0), where,
                                       'bias_std_error', 0.0),
                               _number(entry.get('sd'), where, f'{metric} sd', 0.0)))
    return tuple(out)


def _climatology(data: dict, where: str) -> dict:
    out = {}
    for metric, values in data.items():
        if metric not in METRICS:
            raise ParameterError(f'{where}: spread: climatology of {metric!r}: known metrics '
                                 f'are {", ".join(METRICS)}')
        if not isinstance(values, (list, tuple)):
            raise ParameterError(f'{where}: spread: climatology of {metric} must be a list of '
                                 f'measured values, got {values!r}')
        out[metric] = tuple(_number(v, where, f'climatology {metric}') for v in values)
    return out


def quantiles(samples: np.ndarray) -> dict:
    """{'q05': ..., ..., 'q95': ...} of the finite samples (NaN if none)."""
    finite = np.asarray(samples, float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return {quantile_label(q): math.nan for q in QUANTILE_LEVELS}
    return {quantile_label(q): float(v)
            for q, v in zip(QUANTILE_LEVELS, np.quantile(finite, QUANTILE_LEVELS))}


def crps(samples: np.ndarray, observed: float) -> float:
    """The continuous ranked probability score of an ensemble forecast for one observation
    (in the observation's units; lower is better): E|X - y| - E|X - X'| / 2."""
    x = np.sort(np.asarray(samples, float)[np.isfinite(samples)])
    n = x.size
    if n == 0 or not math.isfinite(observed):
        return math.nan
    # E|X - X'| from the sorted sample in O(n): sum_i (2i - n - 1) x_i * 2 / n^2
    spread_term = float(np.sum((2 * np.arange(1, n + 1) - n - 1) * x)) * 2.0 / n ** 2
    return float(np.mean(np.abs(x - observed))) - 0.5 * spread_term


def pit(samples: np.ndarray, observed: float) -> float:
    """Where the observation falls in the forecast: the fraction of the ensemble below it
    (ties counted half)."""
    x = np.asarray(samples, float)
    x = x[np.isfinite(x)]
    if x.size == 0 or not math.isfinite(observed):
        return math.nan
    return float((np.sum(x < observed) + 0.5 * np.sum(x == observed)) / x.size)


__all__ = ['DEFAULT_ROBOTS', 'METRICS', 'QUANTILE_LEVELS', 'Discrepancy', 'Draws', 'Latent',
           'ParameterSpread', 'Spread', 'crps', 'pit', 'quantile_label', 'quantiles']
