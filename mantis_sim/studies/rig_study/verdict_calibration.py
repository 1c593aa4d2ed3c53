"""How far a study's verdicts hold where the truth is known: the simulated rig, whose robots the
twin draws from the same scene and spread that forecast them.

Three tallies over many finished studies:

- **effects**: each measured effect inside the twin's 95 % forecast of it (effects.py);
- **trials**: each measured value inside its forecast's central 50 % and 95 % (its PIT within
  [0.25, 0.75] and [0.025, 0.975]);
- **the measuring chain**: each measured value against the true value of the robot the rig
  built for that trial (its conditions and its seat on the latch, as the simulated world
  reports them): the relative bias and scatter of what the load cell, the stage, the camera and
  the analysis make of the truth. A forecast of what the simulated rig measures carries them
  (quantities.SIMULATED_RIG_ERROR).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
import math

import numpy as np

from mantis_sim.scene import Scene
from mantis_sim.studies.rig_study.quantities import QUANTITIES
from mantis_sim.studies.rig_study.twin_forecast import (
    AFTER_PEAK_MS,
    ENSEMBLE_SOLVER,
    robot_quantities,
)
from mantis_sim.trial_conditions import scene_for_conditions

CENTRAL_50 = (0.25, 0.75)
CENTRAL_95 = (0.025, 0.975)


@dataclass(frozen=True)
class Coverage:
    """How many of ``n`` values fell inside an interval."""
    inside: int
    n: int

    @property
    def share(self) -> float:
        return self.inside / self.n if self.n else math.nan

    def __add__(self, other: Coverage) -> Coverage:
        return Coverage(self.inside + other.inside, self.n + other.n)

    def text(self) -> str:
        return f'{self.inside} of {self.n} ({100 * self.share:.0f} %)' if self.n else 'none'


def trial_coverage(rows: Iterable[Mapping], quantity: str,
                   interval: tuple[float, float]) -> Coverage:
    """The rows' measured ``quantity`` inside the forecast's central ``interval`` (by PIT)."""
    pits = [r.get(f'{quantity}_pit') for r in rows]
    pits = [float(p) for p in pits if _finite(p)]
    return Coverage(sum(interval[0] <= p <= interval[1] for p in pits), len(pits))


def effect_coverage(effects: Iterable[Mapping], quantity: str | None = None) -> Coverage:
    """The measured effects (effects.csv rows) inside the twin's 95 % forecast of them."""
    rows = [e for e in effects if quantity is None or e['quantity'] == quantity]
    rows = [e for e in rows if all(_finite(e.get(k)) for k in
                                   ('measured', 'twin_low_95', 'twin_high_95'))]
    inside = sum(float(e['twin_low_95']) <= float(e['measured']) <= float(e['twin_high_95'])
                 for e in rows)
    return Coverage(inside, len(rows))


def true_quantities(scene: Scene, conditions: Mapping, seat_deg: float,
                    slack_force_N: float) -> dict:
    """The study's quantities of the robot the simulated rig built: the scene at the trial's
    conditions with the arm seated at ``seat_deg`` on the latch (geometry.latch_offset_deg),
    integrated as the forecasts' ensembles are. The load cell's sample phase is taken at the
    middle of a sample period (past the strike it moves the peak by under 0.3 %)."""
    robot = scene_for_conditions(scene, conditions).with_values(
        {'geometry.latch_offset_deg': float(seat_deg), 'integration.solver': ENSEMBLE_SOLVER,
         'integration.post_peak_ms': AFTER_PEAK_MS})
    return robot_quantities((robot, {}, slack_force_N, 0.5))


def chain_errors(pairs: Iterable[tuple[Mapping, Mapping]]) -> dict:
    """quantity -> (relative bias, relative sd, n) of measured against true values, from
    (measured row, true quantities) pairs."""
    pairs = list(pairs)
    out = {}
    for name in QUANTITIES:
        ratios = np.array([float(m[name]) / t[name] - 1.0 for m, t in pairs
                           if _finite(m.get(name)) and _finite(t.get(name)) and t[name] != 0])
        out[name] = ((float(ratios.mean()), float(ratios.std(ddof=1)), ratios.size)
                     if ratios.size > 1 else (math.nan, math.nan, ratios.size))
    return out


def _finite(value) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


__all__ = ['CENTRAL_50', 'CENTRAL_95', 'Coverage', 'chain_errors', 'effect_coverage',
           'trial_coverage', 'true_quantities']
