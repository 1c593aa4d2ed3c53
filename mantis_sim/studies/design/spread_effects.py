"""Design effects with the interval the data leave them, and how many strikes a lab needs to
see each, from the scenes' spread (mantis_sim.spread).

An effect is the change of a metric's mean strike per unit of a design key, between two
designs of one scene. Its interval comes from nested draws:

- M robot models (Spread.one_model): the identified parameters, the latent's mean and day
  scatter and the discrepancy's bias, each drawn once per model;
- for each model, N robots at the low and at the high design, the same robots at both (the
  same draws of where the arm sits, its day and its scatter): the effect under that model is
  the difference of the two designs' mean strikes over the step.

The effect's quantiles over the M models are its interval. A lab that strikes n times at each
of the two designs sees the effect (two-sided test at the 5 % level, 80 % power) when
n >= 2 (z_0.975 + z_0.8)^2 sd^2 / delta^2, with sd the scatter of one strike at a design under
one model (days, strikes, the discrepancy's scatter) and delta the median effect times the
step.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math

import numpy as np

from mantis_sim.robots import scene_spread, simulate_robot
from mantis_sim.scene import Scene

Z_TWO_SIDED_5_PERCENT = 1.959964
Z_POWER_80_PERCENT = 0.841621


@dataclass(frozen=True)
class EffectSpec:
    name: str
    scene: str          # the group scene whose robot it is
    key: str            # the design key varied
    low: float
    high: float
    metric: str         # a forecast.DESIGN_METRICS key
    unit: str


@dataclass(frozen=True)
class DesignEffect:
    spec: EffectSpec
    median: float           # per unit of the key, in `unit`
    q10: float
    q90: float
    strike_sd: float        # one strike's scatter at the low design, in the metric's unit
    strikes_needed: float   # per design, to see the median effect over the step (inf: never)
    models: int
    robots: int

    @property
    def exceeds_spread(self) -> bool:
        """Whether the designs' difference in mean exceeds one strike's scatter."""
        return abs(self.median * (self.spec.high - self.spec.low)) > self.strike_sd


#: The effects a design study of this robot varies (fidelity.EFFECT_SLOPES measures them on
#: the real strikes), each at the identified air_23mm robot, about the lab's usual conditions.
#: The guide distance is varied within the 23 mm robot: its pivot's hold stays the 23 mm
#: guide's (the 19 mm robot holds about 4 times longer; docs/fidelity.md).
EFFECTS = (
    EffectSpec('spring energy per mm of guide distance', 'air_23mm', 'geometry.d_t_mm', 21.0,
               23.0, 'spring_energy_mJ', 'mJ/mm'),
    EffectSpec('peak tip speed per mm/s of pull speed', 'air_23mm',
               'drive.pull_speed_mm_per_s', 0.5, 2.3, 'peak_tip_speed_mps', 'm/s per mm/s'),
    EffectSpec('peak tip speed per degree of contact angle', 'air_23mm',
               'geometry.contact_angle_deg', 2.5, 4.0, 'peak_tip_speed_mps', 'm/s/deg'),
    EffectSpec('peak tip speed per mm of guide distance', 'air_23mm', 'geometry.d_t_mm', 21.0,
               23.0, 'peak_tip_speed_mps', 'm/s/mm'),
)


def strikes_needed(effect_per_step: float, strike_sd: float) -> float:
    """Strikes per design to see a difference of ``effect_per_step`` between two designs."""
    if effect_per_step == 0 or not math.isfinite(effect_per_step):
        return math.inf
    z = Z_TWO_SIDED_5_PERCENT + Z_POWER_80_PERCENT
    return math.ceil(2.0 * z * z * strike_sd ** 2 / effect_per_step ** 2)


def design_effect(scene: Scene, spec: EffectSpec, models: int, robots: int, seed: int,
                  mapper: Callable) -> DesignEffect:
    """The effect of module docstring, with M = ``models`` and N = ``robots``."""
    spread = scene_spread(scene)
    rng = np.random.default_rng(seed)
    designs = [scene.with_values({spec.key: value}) for value in (spec.low, spec.high)]
    tasks, factors = [], []
    for k in range(models):
        model = spread.one_model(rng)
        for design in designs:      # the same robots at both designs
            draws = model.draw(robots, np.random.default_rng([seed, k]),
                               design.geometry.contact_angle_deg)
            tasks += [(design, values) for values in draws.values]
            factors.append(draws.factors.get(spec.metric, np.ones(robots)))
    results = mapper(simulate_robot, tasks)
    values = np.array([r.get(spec.metric, math.nan) for r in results], float)
    values = values.reshape(models, 2, robots) * np.array(factors).reshape(models, 2, robots)
    means = np.nanmean(values, axis=2)
    effects = (means[:, 1] - means[:, 0]) / (spec.high - spec.low)
    strike_sd = float(np.sqrt(np.nanmean(np.nanvar(values[:, 0, :], axis=1, ddof=1))))
    q10, median, q90 = (float(v) for v in np.quantile(effects, [0.1, 0.5, 0.9]))
    return DesignEffect(spec, median, q10, q90, strike_sd,
                        strikes_needed(median * (spec.high - spec.low), strike_sd),
                        models, robots)


__all__ = ['EFFECTS', 'DesignEffect', 'EffectSpec', 'design_effect', 'strikes_needed']
