"""A recording day's own state: one scene key fitted to each day's strikes, the rest of the
identified robot held, and what that buys, by leaving one strike out within days.

Strikes of one day share the robot's assembly, and days differ by up to 5 m/s at the same
conditions (docs/fidelity.md). The shipped scenes stand for the robot across days; a lab that
has struck a few times today can set today's value of the key that differs by day from those
strikes and simulate today's robot. By default that is where the arm sits on the latch
(`geometry.latch_offset_deg`): fitted to a day's peaks alone, it follows the arm angle the
tracks show at overcentering. The pivot's hold (`hinge.friction_lever_mm`) is the other
candidate, and does worse (docs/fidelity.md).

Each day's value is fitted by Gauss-Newton on its strikes' residuals (identify.strike_residuals,
the identification's weights), all days at once on the sweep's workers. Leaving one strike out,
its day's value is one Gauss-Newton step from the scene's value on the day's other strikes, and
the strike is then simulated with it: the error it has there is what a day's state predicts.

When the key is the pivot's hold, the braking of the arm's swing stays the scene's (its
kinetic lever is pinned): what varies by day holds the arm; what brakes it is the robot's.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math

import numpy as np

from mantis_sim.model import kinetic_lever
from mantis_sim.scene import Scene

from .fidelity import LATCH_KEY, SimulatedStrike, error_rows, group_summary
from .identify import (
    FreeParameter,
    Weights,
    scene_value,
    simulate_task,
    strike_residuals,
    task_values,
)
from .strikes import RealStrike

HOLD_KEY = 'hinge.friction_lever_mm'
# the latched arm angle, contact angle + offset, must lie in [0, 15] degrees: a strike whose
# angle cannot take an offset counts as failed at it
DEFAULT_DAY_KEY = f'{LATCH_KEY}=-5:12'
RELATIVE_STEP = 0.02


@dataclass(frozen=True)
class DayState:
    group: str
    day: str
    value: float
    std_error: float
    strikes: int
    at_bound: bool
    failed: tuple = ()          # 'trial: reason' of the day's strikes that failed at its value


@dataclass(frozen=True)
class LeftOut:
    """One strike predicted with the scene as it is and with its day's value from the day's
    other strikes."""
    strike: RealStrike
    value: float
    shared: SimulatedStrike
    own_day: SimulatedStrike


def day_values(scene: Scene, key: str, value: float, hold_braking: bool = True) -> dict:
    """{key: value} for the day; when the key is the hold, the braking stays the scene's
    (unless not ``hold_braking``: then it follows the hold, mu_k/mu_s fixed)."""
    values = {key: value}
    if hold_braking and key == HOLD_KEY and scene.has('pivot_friction'):
        values['hinge.kinetic_friction_lever_mm'] = min(kinetic_lever(scene), value)
    return values


def day_scene(scene: Scene, key: str, value: float, hold_braking: bool = True) -> Scene:
    """The scene with the day's value of key (day_values)."""
    return scene.with_values(day_values(scene, key, value, hold_braking))


class DayStateFit:
    """Fits ``param`` per (group, recording day) with the scenes otherwise held; simulations
    go through ``mapper`` (mapper(function, tasks) -> results in order). With ``at_seat``
    each strike's arm is latched at its tracked seat (fidelity.seat_values), as
    identify.StrikeModel does."""

    def __init__(self, scenes: dict[str, Scene], strikes: list[RealStrike],
                 param: FreeParameter, weights: Weights, mapper: Callable,
                 hold_braking: bool = True, at_seat: bool = False):
        self.scenes, self.param, self.weights, self.mapper = scenes, param, weights, mapper
        self.hold_braking, self.at_seat = hold_braking, at_seat
        self.strikes = [s for s in strikes if s.recording_day and param.applies_to(s.group)
                        and s.group in scenes]
        # from the scene's value, within the bounds asked for
        self.start = {g: min(max(scene_value(s, param.key), param.lower), param.upper)
                      for g, s in scenes.items()}

    def _simulate(self, pairs: list[tuple[RealStrike, float]]) -> list[SimulatedStrike]:
        tasks = [(self.scenes[s.group], s, s.series is not None,
                  task_values(s, day_values(self.scenes[s.group], self.param.key, v,
                                            self.hold_braking), self.at_seat))
                 for s, v in pairs]
        return self.mapper(simulate_task, tasks)

    def _scale(self, value: float) -> float:
        p = self.param
        return max(abs(value), 0.05 * (p.upper - p.lower))

    def _step(self, value: float) -> float:
        h = RELATIVE_STEP * self._scale(value)
        return -h if value + h > self.param.upper else h

    def _jacobians(self, groups: dict, value: dict) -> dict:
        """For each set of strikes in ``groups`` (name -> strikes), at its value: (residuals,
        their derivative by the key), both sets of simulations at once."""
        names = list(groups)
        steps = {d: self._step(value[d]) for d in names}
        pairs = [(s, value[d]) for d in names for s in groups[d]]
        pairs += [(s, value[d] + steps[d]) for d in names for s in groups[d]]
        sims = self._simulate(pairs)
        res = [strike_residuals(s, m, self.weights) for (s, _), m in zip(pairs, sims)]
        n, k, out = len(pairs) // 2, 0, {}
        for d in names:
            count = len(groups[d])
            r = np.concatenate(res[k:k + count])
            out[d] = (r, (np.concatenate(res[n + k:n + k + count]) - r) / steps[d],
                      sims[k:k + count])
            k += count
        return out

    def fit(self, iterations: int = 5,
            log: Callable[[str], None] = lambda _: None) -> list[DayState]:
        """Each (group, day)'s own value, all days at once. A step that raises a day's cost is
        halved back towards its best value; the fit stops when no day moves by more than 1e-4
        of its value (or of a hundredth of the bounds' width, if more)."""
        p = self.param
        members: dict = {}
        for s in self.strikes:
            members.setdefault((s.group, s.recording_day), []).append(s)
        value = {d: self.start[d[0]] for d in members}
        best: dict = {}         # day -> (cost, value, residuals, derivative, simulations)
        for iteration in range(iterations + 1):
            for d, (r, j, sims) in self._jacobians(members, value).items():
                if d not in best or float(r @ r) <= best[d][0]:
                    best[d] = (float(r @ r), value[d], r, j, sims)
            if iteration == iterations:
                break
            new = {}
            for d in members:
                _, at, r, j, _ = best[d]
                # from the best value on: its Gauss-Newton step, or back towards it if the last
                # step from it raised the cost
                new[d] = (_gauss_newton(at, r, j, p) if value[d] == at
                          else 0.5 * (value[d] + at))
            most = max(members, key=lambda d: abs(new[d] - value[d]) / self._scale(value[d]))
            moved = abs(new[most] - value[most])
            log(f'day states: iteration {iteration + 1} of {iterations}, largest move '
                f'{moved:.3g} ({most[0]} {most[1]})')
            if moved <= 1e-4 * max(abs(value[most]), 0.01 * (p.upper - p.lower)):
                break
            value = new
        out = []
        for d in sorted(members):
            _, at, r, j, sims = best[d]
            failed = tuple(f'{m.trial}: {m.reason}' for m in sims if m.status != 'strike')
            jj = float(j @ j)
            std = math.sqrt(float(r @ r) / max(r.size - 1, 1) / jj) if jj > 0 else math.inf
            at_bound = min(at - p.lower, p.upper - at) <= 1e-3 * (p.upper - p.lower)
            out.append(DayState(d[0], d[1], at, std, len(members[d]), at_bound, failed))
        return out

    def leave_one_out(self) -> list[LeftOut]:
        """Every strike of a day with at least two in its group, predicted with the scene's
        value and with its day's value from the day's other strikes: one Gauss-Newton step from
        the scene's value (a one-step estimate, not fit's iterations), then simulated."""
        strikes = self.strikes
        at_start = self._jacobians({i: [s] for i, s in enumerate(strikes)},
                                   {i: self.start[s.group] for i, s in enumerate(strikes)})
        chosen = []
        for i, s in enumerate(strikes):
            others = [k for k, o in enumerate(strikes) if k != i and o.group == s.group
                      and o.recording_day == s.recording_day]
            if others:
                value = _gauss_newton(self.start[s.group],
                                      np.concatenate([at_start[k][0] for k in others]),
                                      np.concatenate([at_start[k][1] for k in others]),
                                      self.param)
                chosen.append((i, value))
        predicted = self._simulate([(strikes[i], v) for i, v in chosen])
        return [LeftOut(strikes[i], v, at_start[i][2][0], m)
                for (i, v), m in zip(chosen, predicted)]


def _gauss_newton(value: float, r: np.ndarray, j: np.ndarray, param: FreeParameter) -> float:
    jj = float(j @ j)
    if not jj > 0 or not math.isfinite(jj):
        return value
    return float(np.clip(value - float(j @ r) / jj, param.lower, param.upper))


def left_out_summary(left_out: list[LeftOut]) -> dict[str, dict]:
    """Per group: strikes predicted, and the median |error| of tip speed and spring energy with
    the scene's value (`shared`) and with the day's own (`own_day`)."""
    strikes = [x.strike for x in left_out]
    rows = {which: error_rows(strikes, [getattr(x, which) for x in left_out])
            for which in ('shared', 'own_day')}
    out = {}
    for group in sorted({s.group for s in strikes}):
        entry = {'strikes': sum(s.group == group for s in strikes)}
        for label, key in (('tip_speed', 'peak_tip_speed_mps'),
                           ('spring_energy', 'spring_energy_mJ')):
            for which, table in rows.items():
                entry[f'{label}_{which}'] = group_summary(table, key)[group]['median_abs_error']
        out[group] = entry
    return out


__all__ = ['DEFAULT_DAY_KEY', 'HOLD_KEY', 'LATCH_KEY', 'DayState', 'DayStateFit', 'LeftOut',
           'day_scene', 'day_values', 'left_out_summary']
