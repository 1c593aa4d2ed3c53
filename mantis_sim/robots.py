"""N robots of one design, drawn from its scene's spread (mantis_sim.spread) and simulated:
what `mantis sim --spread` and `mantis sweep --spread` report, each metric's samples and
quantiles."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math

import numpy as np

from .model import SimulationError
from .parameters import ParameterError
from .results import lab_spring_energy_mJ, simulate
from .scene import Scene
from .spread import Spread, quantiles


def scene_spread(scene: Scene) -> Spread:
    if scene.spread is None:
        raise ParameterError(f'scene {scene.name} has no spread: fit one with `mantis identify '
                         f'--spread` (docs/spread.md)')
    return scene.spread


#: What `mantis sim --spread` gives the quantiles of: metric -> (short label, label, unit).
#: The lab's spring energy and the peak tip speed carry the discrepancy; the rest are the
#: physics' own.
DESIGN_METRICS = {
    'peak_tip_speed_mps': ('tip speed', 'peak tip speed', 'm/s'),
    'spring_energy_mJ': ('energy, lab', 'spring energy, the lab\'s (deepest body turn)', 'mJ'),
    'max_spring_energy_mJ': ('energy, most', 'spring energy, the model\'s most', 'mJ'),
    'peak_tendon_force_N': ('tendon force', 'peak tendon force', 'N'),
    'phase_start_s.IV': ('IV start', 'phase IV start', 's'),
    'phase_duration_s.III': ('III lasts', 'phase III duration', 's'),
    'phase_duration_s.IV': ('IV lasts', 'phase IV duration', 's'),
}


@dataclass(frozen=True)
class DesignSpread:
    """N robots of one design: each metric's samples (NaN where a robot did not strike)."""
    samples: dict
    robots: int
    not_struck: int
    reasons: tuple          # why robots did not strike (distinct reasons)

    def quantiles(self) -> dict:
        return {metric: quantiles(values) for metric, values in self.samples.items()}


def simulate_robot(task) -> dict:
    """(scene, {key: value}) -> the design metrics of one drawn robot, or {'reason': ...}
    where it did not strike. A task for the workers."""
    scene, values = task
    try:
        m = simulate(scene.with_values(values)).metrics
    except (SimulationError, ParameterError, ArithmeticError) as exc:
        return {'reason': f'{type(exc).__name__}: {exc}'}
    if not m['strike_reached']:
        return {'reason': m['reason']}
    out = {'peak_tip_speed_mps': m['peak_tip_speed_mps'],
           'spring_energy_mJ': lab_spring_energy_mJ(m['deepest_body_angle_rad']),
           'max_spring_energy_mJ': m['max_spring_energy_mJ'],
           'peak_tendon_force_N': m['peak_tendon_force_N']}
    for metric in DESIGN_METRICS:
        key, _, phase = metric.partition('.')
        if phase:
            out[metric] = m[key][phase]
    return out


def design_spread(scene: Scene, n: int, seed: int, mapper: Callable,
                  day: str | None = None) -> DesignSpread:
    """N robots of the scene's design drawn from its spread, simulated through ``mapper``; of
    recording day ``day``'s assembly if given (one the spread has seen)."""
    spread = scene_spread(scene)
    if day is not None and not spread.knows_day(day):
        known = ', '.join(sorted(spread.latent.days)) if spread.latent is not None else ''
        raise ParameterError(f'the spread of scene {scene.name} has not seen recording day '
                             f'{day} (it knows: {known or "none"})')
    draws = spread.draw(n, np.random.default_rng(seed), scene.geometry.contact_angle_deg, day)
    results = mapper(simulate_robot, [(scene, values) for values in draws.values])
    samples = {}
    for metric in DESIGN_METRICS:
        values = np.array([r.get(metric, math.nan) for r in results], dtype=float)
        samples[metric] = values * draws.factors.get(metric, 1.0)
    reasons = tuple(sorted({r['reason'] for r in results if 'reason' in r}))
    return DesignSpread(samples, n, sum('reason' in r for r in results), reasons)


class SessionRobots:
    """The robots of one simulated session on the rig, one day's: ``robots(n)`` is the scene
    of the n-th latching. What the spread leaves uncertain (the parameters, the latent's mean
    and day scatter: Spread.one_model) and the day's assembly are drawn once from the seed;
    where the arm sits is drawn anew at each latching, about the day's level, so that a
    session varies as a real one does. The discrepancy is the statistics of measured values,
    not physics: a session's sensors measure the physics as it is."""

    def __init__(self, scene: Scene, seed: int):
        self.scene, self.seed = scene, seed
        rng = np.random.default_rng(seed)
        model = scene_spread(scene).one_model(rng)
        self._model = model
        self._fixed = ({} if model.parameters is None
                       else dict(zip(model.parameters.keys, map(float, model.parameters.values))))
        lat = model.latent
        self._day_level = None if lat is None else float(rng.normal(lat.mean, lat.day_sd))

    def __call__(self, latching: int, base: Scene | None = None) -> Scene:
        """The robot of the n-th latching, drawn about ``base`` (default: the session's scene),
        e.g. the scene at a trial's conditions (mantis_sim.trial_conditions): the same draw for the
        same latching whatever the base, kept within the latent's range for the base's
        contact angle."""
        base = self.scene if base is None else base
        values = dict(self._fixed)
        lat = self._model.latent
        if lat is not None:
            rng = np.random.default_rng([self.seed, latching])
            lower, upper = self._model.latent_range(base.geometry.contact_angle_deg)
            values[lat.key] = float(np.clip(self._day_level + rng.normal(0.0, lat.strike_sd),
                                            lower, upper))
        return base.with_values(values) if values else base


__all__ = ['DESIGN_METRICS', 'DesignSpread', 'SessionRobots', 'design_spread', 'scene_spread',
           'simulate_robot']
