"""The spread of each group's strikes, fitted to the training strikes (`mantis identify
--spread`), written into each group's scene (mantis_sim.spread reads it).

1. **Each strike's own latent.** The value of the latent key (where the arm sits on the latch)
   that brings the strike's simulated tip speed and spring energy closest to its measured
   ones, the scene otherwise held (Gauss-Newton, day_state.DayStateFit with each strike its
   own unit).
2. **Days and strikes.** A linear mixed model over those values (statsmodels MixedLM,
   restricted maximum likelihood): a mean per group; a random intercept per recording day of
   the group, the day's assembly; and the strikes' scatter within a day. The two variances
   are shared by the groups (a group has two to eight days: too few for its own). REML, since
   with so few days maximum likelihood would shrink the day variance by about 1/days. A
   strike's latent is an estimate: its own uncertainty is left inside the within-day scatter,
   which makes the spread wider, not narrower. Each training day's assembly is kept too, as
   the model predicts it from the day's strikes (the random intercept's conditional mean and
   standard deviation): a later strike of a day already seen is forecast from its day.
3. **The discrepancy.** At its own latent each strike still misses in tip speed and in spring
   energy (one key cannot match both): measured / simulated - 1. A mixed model of the same
   form gives its mean (the bias, with its standard error) and its scatter between days and
   within them, which a new strike's discrepancy has both of. One for all groups: with two to
   eight days a group's own mean is mostly its days' noise (left out a day at a time, such
   means made the forecasts worse).
4. **The identified parameters.** Their standard errors and correlations from the scene's
   provenance (`mantis identify`), for the keys that apply to the group.

The spread is fitted to all the training strikes of a group at once, never to one strike.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
import math
import warnings

import numpy as np

from mantis_sim.scene import Scene
from mantis_sim.spread import METRICS, Discrepancy, Latent, ParameterSpread, Spread

from .day_state import DayStateFit
from .fidelity import LATCH_KEY, SimulatedStrike
from .identify import (
    FreeParameter,
    IdentificationError,
    Weights,
    parse_free_parameter,
    simulate_task,
    split_label,
)
from .strikes import RealStrike

DEFAULT_LATENT = f'{LATCH_KEY}=-5:12'
# the latent answers to the lab's two values of a strike; the peak body and arm speeds and the
# recorded motion are the identification's business
LATENT_WEIGHTS = Weights(tip_speed=1.0, spring_energy=1.0, body_speed=0.0, arm_speed=0.0,
                         series=0.0)


@dataclass(frozen=True)
class StrikeLatent:
    strike: RealStrike
    value: float
    std_error: float
    at_bound: bool
    simulated: SimulatedStrike          # the strike at its own latent

    def correction(self, metric: str) -> float:
        """measured / simulated - 1 at the strike's own latent: the discrepancy's sample."""
        measured = getattr(self.strike, metric)
        predicted = getattr(self.simulated, metric)
        if measured is None or not (math.isfinite(predicted) and predicted > 0):
            return math.nan
        return measured / predicted - 1.0


@dataclass(frozen=True)
class LatentModel:
    """The mixed model's estimates (units of the latent key)."""
    key: str
    means: dict                 # group -> (mean, standard error)
    day_sd: float
    day_sd_std_error: float
    strike_sd: float
    days: int
    strikes: int
    #: group -> {recording day: (its assembly's offset from the group's mean, the standard
    #: deviation of the day's level, mean + offset)}: the day's random intercept as the mixed
    #: model predicts it from the day's strikes (the BLUP, _day_levels)
    day_effects: dict = field(default_factory=dict)

    @property
    def day_dof(self) -> int:
        """The day variance's degrees of freedom: days less the group means."""
        return max(self.days - len(self.means), 1)

    @property
    def strike_dof(self) -> int:
        """The within-day variance's degrees of freedom: strikes less days."""
        return max(self.strikes - self.days, 1)

    @property
    def strike_sd_std_error(self) -> float:
        """As for a sample standard deviation on strike_dof (statsmodels reports no standard
        error of the scale)."""
        return self.strike_sd / math.sqrt(2.0 * self.strike_dof)


def strike_latents(scenes: dict[str, Scene], strikes: Sequence[RealStrike],
                   param: FreeParameter, mapper: Callable, iterations: int = 8,
                   log: Callable[[str], None] = lambda _: None) -> list[StrikeLatent]:
    """Each strike's own value of ``param`` (module docstring, 1), and the strike there."""
    own = [replace(s, recording_day=s.trial) for s in strikes]     # each strike its own unit
    fit = DayStateFit(scenes, own, param, LATENT_WEIGHTS, mapper)
    states = {state.day: state for state in fit.fit(iterations, log=log)}
    fitted = [s for s in strikes if s.trial in states]
    sims = mapper(simulate_task, [(scenes[s.group], s, False,
                                   {param.key: states[s.trial].value}) for s in fitted])
    return [StrikeLatent(s, states[s.trial].value, states[s.trial].std_error,
                         states[s.trial].at_bound, sim) for s, sim in zip(fitted, sims)]


def latent_model(latents: Sequence[StrikeLatent], key: str) -> LatentModel:
    """The mixed model of module docstring, 2, over the strikes that struck."""
    used = [x for x in latents if x.simulated.status == 'strike']
    groups = sorted({x.strike.group for x in used})
    if len(used) < 3 or len({(x.strike.group, x.strike.recording_day) for x in used}) < 2:
        raise IdentificationError(f'the spread needs strikes of at least two recording '
                                  f'days; got {len(used)} strikes')
    y = np.array([x.value for x in used])
    exog = np.array([[x.strike.group == g for g in groups] for x in used], dtype=float)
    units = [f'{x.strike.group}#{x.strike.recording_day}' for x in used]
    fit = _mixed_model(y, exog, units)
    strike_sd = math.sqrt(fit.strike_var)
    # REML ends the day variance at its bound, zero, only to within its optimiser's tolerance:
    # a day scatter under 3 % of the strikes' is taken as none
    day_sd = math.sqrt(fit.day_var) if fit.day_var > 1e-3 * fit.strike_var else 0.0
    means = {g: (float(m), float(se)) for g, m, se in zip(groups, fit.means, fit.mean_std_errors)}
    return LatentModel(
        key, means, day_sd, _sd_std_error(day_sd, fit.day_var_std_error), strike_sd,
        len(set(units)), len(used), _day_levels(used, fit, means, day_sd > 0))


def _day_levels(used: Sequence[StrikeLatent], fit: _MixedFit, means: dict,
                has_days: bool) -> dict:
    """group -> {day: (offset, sd)}: each day's random intercept predicted from its m strikes
    (its conditional mean and sd), and the sd of the day's level, mean + offset. The mean's
    own error enters that level only by the share the day's strikes do not pin,
    1 - day_var / (day_var + strike_var / m): a day of several strikes sits where they do
    whatever the group's mean. Without a day variance every day sits at the mean."""
    out: dict = {}
    counts = Counter((x.strike.group, x.strike.recording_day) for x in used)
    for (group, day), m in counts.items():
        mean_se = means[group][1]
        if not has_days:
            out.setdefault(group, {})[day] = (0.0, mean_se)
            continue
        offset, offset_sd = fit.unit_effects[f'{group}#{day}']
        unpinned = 1.0 - fit.day_var / (fit.day_var + fit.strike_var / m)
        out.setdefault(group, {})[day] = (offset, math.hypot(offset_sd, unpinned * mean_se))
    return out


@dataclass(frozen=True)
class _MixedFit:
    means: np.ndarray               # the fixed effects
    mean_std_errors: np.ndarray
    day_var: float                  # the random intercept's variance
    day_var_std_error: float        # NaN where statsmodels gives none (the variance at zero)
    strike_var: float               # the residual variance
    unit_effects: dict              # unit -> (its random intercept's conditional mean, sd)


def _mixed_model(y: np.ndarray, exog: np.ndarray, units: list) -> _MixedFit:
    """statsmodels' MixedLM of y on exog with a random intercept per unit, fitted by REML.
    (statsmodels, a slow import, is loaded here, not by every `mantis` command.) Where the
    days agree within their strikes' scatter the day variance ends at zero, and statsmodels
    warns on its way there and in its standard errors: an answer here, not a failure; a
    result that is not finite is."""
    from statsmodels.regression.mixed_linear_model import MixedLM
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')     # ConvergenceWarning, SingularMatrixWarning, ...
        result = MixedLM(y, exog, groups=units).fit(reml=True)
        effects = {unit: (float(np.ravel(mean)[0]),
                          math.sqrt(max(float(np.ravel(result.random_effects_cov[unit])[0]),
                                        0.0)))
                   for unit, mean in result.random_effects.items()}
        fit = _MixedFit(np.ravel(result.fe_params), np.ravel(result.bse_fe),
                        float(result.cov_re[0, 0]), float(np.ravel(result.bse_re)[0]),
                        float(result.scale), effects)
    estimates = np.concatenate([fit.means, fit.mean_std_errors, [fit.day_var, fit.strike_var]])
    if not np.isfinite(estimates).all():
        raise IdentificationError(f'the mixed model over {len(y)} strikes of '
                                  f'{len(set(units))} days did not converge to finite '
                                  f'estimates')
    return fit


def _sd_std_error(sd: float, variance_std_error: float) -> float:
    """The standard error of a standard deviation from its variance's (delta method); NaN
    where the variance ended at zero, its bound, where no such error means anything."""
    if sd > 0:
        return variance_std_error / (2.0 * sd)
    return math.nan


def discrepancies(latents: Sequence[StrikeLatent]) -> tuple:
    """The Discrepancy of each metric (module docstring, 3), the same for every group."""
    used = [x for x in latents if x.simulated.status == 'strike']
    out = []
    for metric in METRICS:
        rows = [(x.correction(metric), f'{x.strike.group}#{x.strike.recording_day}')
                for x in used]
        rows = [(c, unit) for c, unit in rows if math.isfinite(c)]
        y = np.array([c for c, _ in rows])
        if y.size and np.ptp(y) == 0:       # the physics matches every strike alike
            out.append(Discrepancy(metric, float(y[0]), 0.0, 0.0))
            continue
        fit = _mixed_model(y, np.ones((y.size, 1)), [u for _, u in rows])
        out.append(Discrepancy(metric, float(fit.means[0]), float(fit.mean_std_errors[0]),
                               math.sqrt(max(fit.day_var, 0.0) + fit.strike_var)))
    return tuple(out)


def parameter_spread(scene: Scene, group: str) -> ParameterSpread | None:
    """The identified parameters that apply to ``group``, from the scene's provenance: values,
    standard errors, bounds and correlations (pairs the provenance does not correlate, e.g.
    of different stages, are taken as independent)."""
    prov = scene.provenance or {}
    entries = {}
    for label, entry in (prov.get('parameters') or {}).items():
        key, groups = split_label(label)
        if groups is None or group in groups:
            entries[key] = (label, entry)
    if not entries:
        return None
    keys = tuple(entries)
    values = np.array([float(entries[k][1]['value']) for k in keys])
    sd = np.array([float(entries[k][1]['std_error']) for k in keys])
    bounds = np.array([entries[k][1].get('bounds', [-math.inf, math.inf]) for k in keys], float)
    corr = np.eye(len(keys))
    table = prov.get('correlation') or {}
    for i, a in enumerate(keys):
        for j, b in enumerate(keys):
            rho = (table.get(entries[a][0]) or {}).get(entries[b][0])
            if i != j and rho is not None:
                corr[i, j] = float(rho)
    corr = _nearest_correlation(0.5 * (corr + corr.T))
    return ParameterSpread(keys, values, corr * np.outer(sd, sd), bounds[:, 0], bounds[:, 1])


def _nearest_correlation(corr: np.ndarray) -> np.ndarray:
    """Rounded correlations can leave a matrix slightly indefinite: clip its eigenvalues."""
    w, v = np.linalg.eigh(corr)
    if w.min() >= 0:
        return corr
    fixed = (v * np.clip(w, 1e-9, None)) @ v.T
    d = np.sqrt(np.diag(fixed))
    return fixed / np.outer(d, d)


def climatology(strikes: Sequence[RealStrike], group: str) -> dict:
    """The group's measured values: the forecast that quotes the lab's past strikes."""
    out = {}
    for metric in METRICS:
        out[metric] = tuple(float(getattr(s, metric)) for s in strikes
                            if s.group == group and getattr(s, metric) is not None)
    return out


def fit_spreads(scenes: dict[str, Scene], strikes: Sequence[RealStrike], mapper: Callable,
                latent: str = DEFAULT_LATENT, iterations: int = 8, sources: Sequence[str] = (),
                log: Callable[[str], None] = lambda _: None) -> tuple[dict, list, LatentModel]:
    """group -> Spread for every group among the strikes, with the strikes' own latents and
    the mixed model they gave."""
    param = latent_parameter(scenes, latent)
    log(f'spread: each strike\'s own {param.key} ({len(strikes)} strikes)')
    latents = strike_latents(scenes, strikes, param, mapper, iterations, log)
    spreads, model = spreads_from(latents, scenes, param, sources)
    return spreads, latents, model


def latent_parameter(scenes: dict[str, Scene], latent: str = DEFAULT_LATENT) -> FreeParameter:
    """'key=LO:HI' -> the latent's FreeParameter (its bounds are the draws' range)."""
    return parse_free_parameter(latent, scenes, option='--spread-latent')


def spreads_from(latents: Sequence[StrikeLatent], scenes: dict[str, Scene],
                 param: FreeParameter, sources: Sequence[str] = ()) -> tuple[dict, LatentModel]:
    """group -> Spread from the strikes' own latents (module docstring, 2-4): the scenes'
    groups each need struck strikes among them."""
    model = latent_model(latents, param.key)
    errors = discrepancies(latents)
    missing = sorted(set(scenes) - set(model.means))
    if missing:
        raise IdentificationError(f'no strike of {", ".join(missing)} struck at its own '
                                  f'latent: no spread for it')
    strikes = [x.strike for x in latents]
    provenance = {
        'fitted_by': 'mantis identify --spread',
        'date': datetime.now(UTC).isoformat(timespec='seconds'),
        'strikes': model.strikes, 'recording_days': model.days,
        'sources': list(sources),
        'method': 'each strike\'s own latent (Gauss-Newton on its tip speed and spring energy); '
                  'a linear mixed model over them (statsmodels MixedLM, REML: a mean per '
                  'group, a random intercept per recording day, the scatter within days); '
                  'the relative discrepancy at each strike\'s own latent',
        'latent_std_errors': {'day_sd': model.day_sd_std_error,
                              'strike_sd': model.strike_sd_std_error},
        'at_bound': sorted(x.strike.trial for x in latents if x.at_bound),
        'not_struck': sorted(x.strike.trial for x in latents
                             if x.simulated.status != 'strike'),
    }
    spreads = {}
    for group, scene in scenes.items():
        mean, mean_se = model.means[group]
        spreads[group] = Spread(
            Latent(param.key, mean, mean_se, model.day_sd, model.strike_sd, param.lower,
                   param.upper, model.day_dof, model.strike_dof,
                   model.day_effects.get(group, {})),
            parameter_spread(scene, group), errors, climatology(strikes, group),
            {**provenance, 'group_strikes': sum(s.group == group for s in strikes)})
    return spreads, model


__all__ = ['DEFAULT_LATENT', 'LatentModel', 'StrikeLatent', 'climatology', 'discrepancies',
           'fit_spreads', 'latent_model', 'latent_parameter', 'parameter_spread', 'spreads_from',
           'strike_latents']
