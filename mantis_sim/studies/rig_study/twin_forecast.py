"""The twin's forecast of each trial of a study, at the trial's conditions, and of the day's
later trials from its earlier ones.

For each combination of conditions the study runs, an ensemble of N robots is simulated once:
everything the scene's spread draws (its identified parameters, the discrepancy's factors), but
the latent (where the arm sits on the latch) laid out over its whole range instead of drawn:
one robot at each end of the range and N - 2 evenly between. A forecast is then a weighting of
those robots (importance weights: the density of the latent at each robot's value), so that
any belief about the latent is a forecast without simulating again:

- a new day's strike: the spread's own predictive (its mean, the days' and the strikes'
  scatter, each drawn within its uncertainty); a draw beyond the range sits at its end, as the
  simulated rig's robots do, so the end robots carry that mass;
- a strike of a day with earlier strikes: the day's level (its assembly) is inferred from what
  those strikes measured, on a grid (the prior: a new day's level; the likelihood of each
  earlier strike: the ensemble at its conditions, kernel-smoothed by MEASUREMENT_FLOOR at
  least), and the strike's latent is
  the day's level plus the within-day scatter. The day is read from the work done loading the
  spring, measured on every trial by the load cell and the stage, and the quantity the latch's
  seat moves most (docs/study.md).

A forecast is of what the rig measures: the peak force as the load cell's amplifier passes it,
and each value moved and spread by the rig's measuring chain (quantities.MEASUREMENT: the
real rig's, or the simulated rig's, as its supervisor's backend says). Its
quantiles, its PIT for a measured value and its 95 % interval come from the weighted ensemble;
robots that did not strike are left out of it.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
import math
from typing import Optional

import numpy as np

from mantis_sim.model import SimulationError
from mantis_sim.parameters import ParameterError
from mantis_sim.results import simulate
from mantis_sim.robots import scene_spread
from mantis_sim.scene import Scene
from mantis_sim.sensors import first_order_lowpass
from mantis_sim.spread import QUANTILE_LEVELS, quantile_label
from mantis_sim.studies.rig_study.quantities import QUANTITIES, RIG_ERROR
from mantis_sim.trial_conditions import conditions_of_scene, scene_for_conditions
from mantis_sim.world import SETTLE_AFTER_PEAK_MS

#: The quantity the day's level is read from (see the module docstring).
DAY_QUANTITY = 'loading_work_mJ'
#: The spread's discrepancy factor that each quantity carries (the others are the physics').
DISCREPANCY_OF = {'peak_tip_speed_mps': 'peak_tip_speed_mps',
                  'max_spring_energy_mJ': 'spring_energy_mJ'}
#: Draws of the spread's own uncertainty (mean, day and strike scatter) in its predictive.
PREDICTIVE_DRAWS = 400
DAY_GRID = 161
#: The relative error of the day's quantity as the rig measures it (the kernel's least width).
MEASUREMENT_FLOOR = 0.02
INTERVAL_95 = (0.025, 0.975)
#: The load cell's sample rate (the rig's DAQ default, its load-cell node's).
LOADCELL_RATE_HZ = 20_000.0
FILTER_LEAD_MS = 5.0
#: The ensembles' integrator: the fast engine (the compiled Radau IIA), a quarter of LSODA's
#: cost a robot; on air_23mm_rig its quantities agree with LSODA's to 1e-6 and the load-cell
#: peak to 0.05 % (docs/study.md).
ENSEMBLE_SOLVER = 'fast'
#: How long each robot is simulated past its peak tip speed: the tendon's tension peaks some
#: milliseconds after the tip does (the arm's recoil), and the rig's load cell sees that peak
#: (its world runs this long past the peak before it holds the pose). Stopped at the tip's peak,
#: the ensembles' peak force was 8-14 % below the rig's.
AFTER_PEAK_MS = SETTLE_AFTER_PEAK_MS


def robot_quantities(task) -> dict:
    """(scene, {key: value}, slack force N, the load cell's sample phase in [0, 1)) -> the
    study's quantities for one robot, NaN where it did not strike. The loading is timed and
    counted from the first tension at the supervisor's slack force (the rig's pull starts
    there), to the unlatching."""
    scene, values, slack_force_N, phase = task
    nan = dict.fromkeys(QUANTITIES, math.nan)
    try:
        result = simulate(scene.with_values(values))
    except (SimulationError, ParameterError, ArithmeticError):
        return nan
    m, tr = result.metrics, result.trajectory
    if not m['strike_reached']:
        return nan
    unlatch_ms = m['phase_start_s']['II'] * 1e3
    taut = np.flatnonzero(tr.tendon_force_N >= slack_force_N)
    start_ms = float(tr.t_ms[taut[0]]) if taut.size else 0.0
    work = np.interp([start_ms, unlatch_ms], tr.t_ms, tr.drive_work_mJ)
    return {'peak_tendon_force_N': load_cell_peak_N(scene, tr.t_ms, tr.tendon_force_N,
                                                    unlatch_ms, phase),
            'loading_work_mJ': float(work[1] - work[0]),
            'release_time_s': (unlatch_ms - start_ms) * 1e-3,
            'peak_tip_speed_mps': m['peak_tip_speed_mps'],
            'max_spring_energy_mJ': m['max_spring_energy_mJ']}


def load_cell_peak_N(scene: Scene, t_ms: np.ndarray, tension_N: np.ndarray,
                     strike_ms: float, phase: float = 0.0) -> float:
    """The peak of the tension as the load cell reads it: sampled at LOADCELL_RATE_HZ and
    low-passed by its amplifier where the scene simulates the load cell's dynamics (the
    strike's spike lasts about a millisecond: the amplifier takes a share of it off). Where
    the samples fall on the spike (``phase``, a share of the sample period: a rig's strike
    starts at no particular sample) moves the reading by up to 5 %. The filter runs from
    FILTER_LEAD_MS before the unlatching (``strike_ms``), settled there: its time constant is
    a fraction of a millisecond, and the slow loading before passes it whole."""
    if not scene.has('loadcell_dynamics'):
        return float(np.max(tension_N))
    before = tension_N[t_ms < strike_ms - FILTER_LEAD_MS]
    step_ms = 1e3 / LOADCELL_RATE_HZ
    grid = np.arange(max(t_ms[0], strike_ms - FILTER_LEAD_MS) + phase * step_ms, t_ms[-1],
                     step_ms)
    force = np.interp(grid, t_ms, tension_N)
    pole = math.exp(-2.0 * math.pi * scene.loadcell.bandwidth_hz / LOADCELL_RATE_HZ)
    peak = float(np.max(first_order_lowpass(force, pole, float(force[0])))) if grid.size \
        else -math.inf
    return max(peak, float(np.max(before)) if before.size else -math.inf)


@dataclass(frozen=True)
class Ensemble:
    """N robots of one combination of conditions: their latent values (None without a latent)
    and each quantity's simulated value (times its discrepancy factor)."""
    conditions: dict
    latent: Optional[np.ndarray]
    lower: float
    upper: float
    values: dict            # quantity -> ndarray (N,)

    @property
    def robots(self) -> int:
        return len(next(iter(self.values.values())))


def latent_layout(n: int, lower: float, upper: float) -> np.ndarray:
    """One robot at each end of the range and n - 2 at the midpoints of equal parts between."""
    inner = lower + (np.arange(n - 2) + 0.5) / (n - 2) * (upper - lower)
    return np.concatenate([[lower], inner, [upper]])


def simulate_ensemble(scene: Scene, conditions: Mapping, robots: int, seed: int,
                      mapper: Callable = map, slack_force_N: float = 0.2) -> Ensemble:
    """The ensemble of ``robots`` robots at ``conditions`` (the same draws for a seed at every
    combination of conditions, so that their differences are the conditions'). Integrated by
    ENSEMBLE_SOLVER whatever the scene's solver (the same model and tolerance), each past its
    peak tip speed by AFTER_PEAK_MS. The ensemble's conditions are all of CONDITION_KEYS: those
    given, the scene's for the rest."""
    at_conditions = scene_for_conditions(scene, conditions)
    design = at_conditions.with_values({'integration.solver': ENSEMBLE_SOLVER,
                                        'integration.post_peak_ms': AFTER_PEAK_MS})
    spread = scene_spread(design)
    draws = spread.draw(robots, np.random.default_rng(seed), design.geometry.contact_angle_deg)
    latent, lower, upper = None, math.nan, math.nan
    if spread.latent is not None:
        lower, upper = spread.latent_range(design.geometry.contact_angle_deg)
        latent = latent_layout(robots, lower, upper)
        for row, value in zip(draws.values, latent):
            row[spread.latent.key] = float(value)
    phases = np.random.default_rng([seed, 3]).uniform(0.0, 1.0, robots)
    results = list(mapper(robot_quantities, [(design, values, slack_force_N, float(phase))
                                             for values, phase in zip(draws.values, phases)]))
    values = {}
    for name in QUANTITIES:
        simulated = np.array([r[name] for r in results], float)
        factor = draws.factors.get(DISCREPANCY_OF.get(name, ''), 1.0)
        values[name] = simulated * factor
    return Ensemble(conditions_of_scene(at_conditions), latent, lower, upper, values)


class LatentBelief:
    """The spread's latent as the forecasts weigh it: a new day's predictive, and the
    within-day scatter about a day's level (each a mixture over the spread's own uncertainty)."""

    def __init__(self, scene: Scene, seed: int):
        spread = scene_spread(scene)
        self.latent = spread.latent
        rng = np.random.default_rng([seed, 7])
        self._models = [spread.one_model(rng).latent for _ in range(PREDICTIVE_DRAWS)] \
            if self.latent is not None else []

    def new_day_weights(self, ensemble: Ensemble) -> np.ndarray:
        if ensemble.latent is None:
            return _uniform(ensemble.robots)
        parts = [_clipped_normal_weights(ensemble, lat.mean,
                                         math.hypot(lat.day_sd, lat.strike_sd))
                 for lat in self._models]
        return _normalised(np.mean(parts, axis=0))

    def level_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(levels, prior weight of each) of a day's level: a new day's."""
        lat = self.latent
        spread_sd = max(math.hypot(lat.day_sd, lat.mean_std_error), 1e-6)
        levels = np.linspace(lat.mean - 5 * spread_sd, lat.mean + 5 * spread_sd, DAY_GRID)
        prior = np.mean([_normal_pdf(levels, m.mean, max(m.day_sd, 1e-9)) for m in self._models],
                        axis=0)
        return levels, _normalised(prior)

    def strike_sds(self) -> np.ndarray:
        """The within-day scatter of a strike about its day's level, one per model drawn."""
        return np.array([m.strike_sd for m in self._models])

    def within_day_weights(self, ensemble: Ensemble, levels: np.ndarray) -> np.ndarray:
        """(levels, robots): each row the weights of the ensemble given the day's level."""
        sds = np.array([m.strike_sd for m in self._models])
        rows = [np.mean([_clipped_normal_weights(ensemble, level, sd) for sd in sds[::20]],
                        axis=0) for level in levels]
        return np.array([_normalised(r) for r in rows])


@dataclass(frozen=True)
class Forecast:
    """A weighted ensemble: each quantity's values and the weights of the robots."""
    values: dict
    weights: np.ndarray
    day_strikes: int        # earlier strikes of the day it was conditioned on
    measurement: Mapping = field(default_factory=lambda: RIG_ERROR)

    def _finite(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """The forecast of what the rig measures: each robot's value moved and spread by the
        rig's measuring chain (relative), robots that struck."""
        v = self.values[name]
        ok = np.isfinite(v) & (self.weights > 0)
        v, w = v[ok], self.weights[ok]
        error = self.measurement.get(name)
        if error is not None and v.size:
            e = np.asarray(error.points)
            v = (v[:, None] * (1.0 + e[None, :])).ravel()
            w = np.repeat(w / e.size, e.size)
        return v, w

    def quantile(self, name: str, levels: Sequence[float]) -> np.ndarray:
        v, w = self._finite(name)
        if v.size == 0 or w.sum() <= 0:
            return np.full(len(levels), math.nan)
        order = np.argsort(v)
        v, w = v[order], w[order] / w.sum()
        cdf = np.cumsum(w) - 0.5 * w
        return np.interp(levels, cdf, v)

    def quantiles(self, name: str) -> dict:
        return dict(zip((quantile_label(q) for q in QUANTILE_LEVELS),
                        map(float, self.quantile(name, QUANTILE_LEVELS))))

    def pit(self, name: str, measured: float) -> float:
        v, w = self._finite(name)
        if v.size == 0 or not math.isfinite(measured):
            return math.nan
        w = w / w.sum()
        return float(w[v < measured].sum() + 0.5 * w[v == measured].sum())

    def mean_sd(self, name: str) -> tuple[float, float]:
        v, w = self._finite(name)
        if v.size == 0:
            return math.nan, math.nan
        w = w / w.sum()
        mean = float(np.sum(w * v))
        return mean, float(math.sqrt(max(np.sum(w * (v - mean) ** 2), 0.0)))


class MissingEnsemble(ParameterError):
    """No ensemble was simulated at a trial's conditions (its ``conditions``: all of them)."""

    def __init__(self, conditions: dict):
        super().__init__(f'no forecast ensemble at the conditions {conditions}')
        self.conditions = conditions


class StudyForecaster:
    """Forecasts of a study's trials from one ensemble per combination of conditions."""

    def __init__(self, scene: Scene, ensembles: Sequence[Ensemble], seed: int,
                 measurement: Mapping = RIG_ERROR):
        self.scene = scene
        self.measurement = measurement      # quantity -> MeasurementError of the rig's chain
        self.belief = LatentBelief(scene, seed)
        self._ensembles: dict = {}
        for ensemble in ensembles:
            self.add(ensemble)
        self._within: dict = {}
        self._levels = self._prior = None
        if self.belief.latent is not None:
            self._levels, self._prior = self.belief.level_grid()

    def conditions(self, conditions: Mapping) -> dict:
        """All of a trial's conditions (CONDITION_KEYS): those given, the scene's for the rest."""
        return conditions_of_scene(scene_for_conditions(self.scene, conditions))

    def add(self, ensemble: Ensemble) -> None:
        self._ensembles[conditions_key(self.conditions(ensemble.conditions))] = ensemble

    def has(self, conditions: Mapping) -> bool:
        return conditions_key(self.conditions(conditions)) in self._ensembles

    def ensemble(self, conditions: Mapping) -> Ensemble:
        """The ensemble simulated at exactly these conditions (those given, the scene's for
        the rest): a trial is forecast at the conditions it ran at, whoever set them.
        MissingEnsemble where none was."""
        full = self.conditions(conditions)
        found = self._ensembles.get(conditions_key(full))
        if found is None:
            raise MissingEnsemble(full)
        return found

    def _within_day(self, conditions: Mapping) -> np.ndarray:
        key = conditions_key(self.conditions(conditions))
        if key not in self._within:
            self._within[key] = self.belief.within_day_weights(self.ensemble(conditions),
                                                               self._levels)
        return self._within[key]

    def forecast(self, conditions: Mapping,
                 earlier: Sequence[tuple[Mapping, float]] = ()) -> Forecast:
        """The forecast of a trial at ``conditions``, given the day's ``earlier`` strikes:
        (their conditions, their measured DAY_QUANTITY) each."""
        ensemble = self.ensemble(conditions)
        earlier = [(c, m) for c, m in earlier if m is not None and math.isfinite(m)]
        if self._levels is None or not earlier:
            return Forecast(ensemble.values, self.belief.new_day_weights(ensemble), 0,
                            self.measurement)
        posterior = self.day_posterior(earlier)
        weights = _normalised(posterior @ self._within_day(conditions))
        return Forecast(ensemble.values, weights, len(earlier), self.measurement)

    def day_posterior(self, earlier: Sequence[tuple[Mapping, float]]) -> np.ndarray:
        log_post = np.log(np.maximum(self._prior, 1e-300))
        for conditions, measured in earlier:
            ensemble = self.ensemble(conditions)
            y = ensemble.values[DAY_QUANTITY]
            ok = np.isfinite(y)
            within = self._within_day(conditions)[:, ok]
            kernel = _normal_pdf(measured, y[ok], _bandwidth(y[ok]))
            log_post += np.log(np.maximum(within @ kernel, 1e-300))
        log_post -= log_post.max()
        return _normalised(np.exp(log_post))

    def day_level(self, earlier) -> tuple[float, float]:
        """The day's level (mean, sd) the earlier strikes say, in the latent's unit."""
        post = self.day_posterior(earlier) if earlier else self._prior
        mean = float(np.sum(post * self._levels))
        return mean, float(math.sqrt(np.sum(post * (self._levels - mean) ** 2)))

    def level_draws(self, strikes: Sequence[tuple[Mapping, float]], n: int,
                    rng: np.random.Generator) -> np.ndarray:
        """n draws of the day's level given its ``strikes`` (the prior without any), each
        spread evenly within its grid step."""
        post = self.day_posterior(strikes) if strikes else self._prior
        step = self._levels[1] - self._levels[0]
        picks = rng.choice(self._levels, size=n, p=post)
        return picks + rng.uniform(-0.5 * step, 0.5 * step, n)


def conditions_key(conditions: Mapping) -> tuple:
    """A hashable key of a set of conditions: numbers rounded to 9 decimals (19 and 19.0
    alike), names as text."""
    return tuple(sorted((k, _norm(v)) for k, v in conditions.items()))


def _norm(value):
    return round(float(value), 9) if isinstance(value, (int, float)) else str(value)


def _uniform(n: int) -> np.ndarray:
    return np.full(n, 1.0 / n)


def _normalised(w: np.ndarray) -> np.ndarray:
    total = float(np.sum(w))
    return w / total if total > 0 else _uniform(len(w))


def _normal_pdf(x, mean, sd):
    z = (np.asarray(x, float) - mean) / sd
    return np.exp(-0.5 * z * z) / (sd * math.sqrt(2 * math.pi))


def _normal_cdf(x, mean, sd) -> float:
    return 0.5 * math.erfc(-(x - mean) / (sd * math.sqrt(2)))


def _clipped_normal_weights(ensemble: Ensemble, mean: float, sd: float) -> np.ndarray:
    """Weights of the laid-out robots for latent = clip(normal(mean, sd)): the density times
    the spacing inside, the mass beyond each end on the end's robot."""
    x, lower, upper = ensemble.latent, ensemble.lower, ensemble.upper
    sd = max(sd, 1e-9)
    spacing = (upper - lower) / (len(x) - 2)
    w = _normal_pdf(x, mean, sd) * spacing
    w[0] = _normal_cdf(lower, mean, sd)
    w[-1] = 1.0 - _normal_cdf(upper, mean, sd)
    return w


def _bandwidth(y: np.ndarray) -> float:
    """The kernel that turns the ensemble's values (in the order of their latent) into a
    density: twice the median step between neighbouring robots, and at least
    MEASUREMENT_FLOOR of the values' size (what the load cell and the stage themselves miss)."""
    steps = np.abs(np.diff(y))
    step = float(np.median(steps)) if steps.size else 0.0
    return max(2.0 * step, MEASUREMENT_FLOOR * float(np.median(np.abs(y))), 1e-12)


__all__ = ['DAY_QUANTITY', 'Ensemble', 'Forecast', 'INTERVAL_95', 'LatentBelief',
           'MissingEnsemble', 'StudyForecaster', 'conditions_key', 'latent_layout',
           'robot_quantities', 'simulate_ensemble']
