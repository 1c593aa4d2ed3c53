"""A study's plan: YAML read and checked, and the order its trials run in.

```yaml
scene: air_23mm_rig          # the twin's scene that forecasts every trial (it needs a spread)
factors:                     # trial conditions of the supervisor, each with its levels
  d_t_mm: [19, 25]
  pull_speed_mm_s: [1.0, 2.3]
repeats: 4                   # trials per combination of levels; or `auto` (then smallest_effect)
order: random                # random (seeded) | as-listed | split-plot
seed: 5
fixed: {contact_angle_deg: 3.0}          # other conditions, the same for every trial
# hard_to_change: d_t_mm     # split-plot: the factor changed by hand (default d_t_mm)
# smallest_effect: {peak_tip_speed_mps: 0.5}   # repeats: auto resolves this difference
# robots: 200                # the twin's robots per combination (its forecast ensemble)
# video: true                # the simulated rig films each trial; its tip speed from the film
```

Orders:
- ``as-listed``: the combinations in the order the levels are listed (the first factor
  slowest), each combination's repeats one after the other.
- ``random``: every trial shuffled (seeded): no factor follows the day's drift.
- ``split-plot``: one block per level of the hard-to-change factor, in a seeded random order,
  so that it changes as few times as the design allows (levels - 1); within a block the other
  factors' trials are shuffled. A trial that aborts is repeated at the end of its block.

A plan that cannot run is refused with every mistake named, one line each.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
import itertools
import math
from pathlib import Path
from typing import Optional

import numpy as np
import yaml

from mantis_sim.errors import InputError
from mantis_sim.trial_conditions import CONDITION_KEYS  # what a plan may vary or fix

ORDERS = ('random', 'as-listed', 'split-plot')
PLAN_KEYS = ('scene', 'factors', 'repeats', 'order', 'seed', 'fixed', 'hard_to_change',
             'smallest_effect', 'robots', 'description', 'video')
DEFAULT_ROBOTS = 200
DEFAULT_HARD_TO_CHANGE = 'd_t_mm'
MAX_TRIALS = 10_000


class PlanError(InputError):
    """A plan that cannot run; the message names each mistake, one line each."""


@dataclass(frozen=True)
class PlannedTrial:
    """One trial of the plan: its number in the plan (1-based, before ordering), its block in
    the run order, and its conditions (factor levels and fixed conditions)."""
    trial: int
    block: int
    conditions: dict


@dataclass(frozen=True)
class StudyPlan:
    scene: str
    factors: dict                   # name -> tuple of levels, in the plan's order
    repeats: Optional[int]          # None: auto (resolved from the twin's spread)
    order: str = 'random'
    seed: int = 0
    fixed: dict = field(default_factory=dict)
    hard_to_change: Optional[str] = None
    smallest_effect: dict = field(default_factory=dict)    # quantity -> difference to resolve
    robots: int = DEFAULT_ROBOTS
    description: str = ''
    #: the simulated rig films each trial (the supervisor's ``video``), and the study takes the
    #: tip speed and spring energy from the film's tracks instead of the bag's marker frames
    video: bool = False

    @property
    def cells(self) -> list[dict]:
        """Every combination of the factors' levels (the first factor slowest)."""
        names = list(self.factors)
        return [dict(zip(names, levels))
                for levels in itertools.product(*(self.factors[n] for n in names))]

    def conditions_of(self, cell: Mapping) -> dict:
        return {**self.fixed, **cell}

    def with_repeats(self, repeats: int) -> StudyPlan:
        return replace(self, repeats=int(repeats))

    def trials(self) -> list[PlannedTrial]:
        """The trials in run order (the plan's repeats must be resolved)."""
        if self.repeats is None:
            raise PlanError('the plan\'s repeats are `auto`: resolve them from the twin first')
        numbered = [(cell, k) for cell in self.cells for k in range(self.repeats)]
        planned = [PlannedTrial(i + 1, 1, self.conditions_of(cell))
                   for i, (cell, _) in enumerate(numbered)]
        rng = np.random.default_rng(self.seed)
        if self.order == 'as-listed':
            return planned
        if self.order == 'random':
            return [planned[i] for i in rng.permutation(len(planned))]
        factor = self.hard_to_change
        levels = [self.factors[factor][i] for i in rng.permutation(len(self.factors[factor]))]
        ordered = []
        for block, level in enumerate(levels, start=1):
            members = [t for t in planned if t.conditions[factor] == level]
            ordered += [replace(members[i], block=block) for i in rng.permutation(len(members))]
        return ordered

    def to_mapping(self) -> dict:
        """The plan as YAML holds it (load_plan reads it back the same)."""
        out = {'scene': self.scene, 'factors': {k: list(v) for k, v in self.factors.items()},
               'repeats': 'auto' if self.repeats is None else self.repeats,
               'order': self.order, 'seed': self.seed}
        if self.fixed:
            out['fixed'] = dict(self.fixed)
        if self.order == 'split-plot':
            out['hard_to_change'] = self.hard_to_change
        if self.smallest_effect:
            out['smallest_effect'] = dict(self.smallest_effect)
        out['robots'] = self.robots
        if self.description:
            out['description'] = self.description
        if self.video:
            out['video'] = True
        return out


def load_plan(path, check_condition: Optional[Callable] = None) -> StudyPlan:
    """The plan in YAML file ``path``. ``check_condition(name, value)`` may raise an InputError
    for a value the rig refuses (its ranges); every mistake found is named in the PlanError."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise PlanError(f'{path}: cannot read the plan: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise PlanError(f'{path}: not YAML: {str(exc).splitlines()[0]}') from None
    return plan_from_mapping(data, str(path), check_condition)


def plan_from_mapping(data, where: str,
                      check_condition: Optional[Callable] = None) -> StudyPlan:
    problems: list[str] = []
    if not isinstance(data, dict):
        raise PlanError(f'{where}: a plan is a mapping of scene, factors, repeats, order, ...; '
                        f'got {type(data).__name__}')
    for key in data:
        if key not in PLAN_KEYS:
            problems.append(f'unknown key {key!r} (known: {", ".join(PLAN_KEYS)})')
    scene = data.get('scene')
    if not isinstance(scene, str) or not scene:
        problems.append('scene: the name or path of the twin\'s scene is required')
    factors = _factors(data.get('factors'), problems, check_condition)
    fixed = _fixed(data.get('fixed') or {}, factors, problems, check_condition)
    repeats = _repeats(data.get('repeats'), problems)
    order = data.get('order', 'random')
    if order not in ORDERS:
        problems.append(f'order: {order!r} is not one of {", ".join(ORDERS)}')
    seed = data.get('seed', 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        problems.append(f'seed: {seed!r} is not a whole number in [0, 2^32)')
    hard = data.get('hard_to_change')
    if order == 'split-plot':
        hard = hard or DEFAULT_HARD_TO_CHANGE
        if factors and hard not in factors:
            problems.append(f'hard_to_change: {hard!r} is not one of the factors '
                            f'({", ".join(factors)}); a split-plot order blocks on one of them')
    elif hard is not None:
        problems.append(f'hard_to_change: only a split-plot order has one (order is {order})')
    smallest = _smallest_effect(data.get('smallest_effect'), repeats, problems)
    robots = data.get('robots', DEFAULT_ROBOTS)
    if isinstance(robots, bool) or not isinstance(robots, int) or not 20 <= robots <= 5000:
        problems.append(f'robots: {robots!r} is not a whole number in [20, 5000]')
    description = data.get('description', '')
    if not isinstance(description, str):
        problems.append('description: must be text')
    video = data.get('video', False)
    if not isinstance(video, bool):
        problems.append(f'video: {video!r} is not true or false (true: the simulated rig films '
                        f'each trial and its tip speed comes from the film)')
    if factors and isinstance(repeats, int):
        total = math.prod(len(v) for v in factors.values()) * repeats
        if total > MAX_TRIALS:
            problems.append(f'{total} trials planned; at most {MAX_TRIALS}')
    if problems:
        raise PlanError(f'{where}: the plan cannot run:\n  ' + '\n  '.join(problems))
    return StudyPlan(scene=scene, factors=factors, repeats=repeats, order=order, seed=seed,
                     fixed=fixed, hard_to_change=hard if order == 'split-plot' else None,
                     smallest_effect=smallest, robots=robots, description=description,
                     video=video is True)


def _level(name: str, value, problems: list, check_condition) -> Optional[object]:
    if name == 'medium':
        if not isinstance(value, str):
            problems.append(f'{name}: level {value!r} is not a medium\'s name')
            return None
    elif isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        problems.append(f'{name}: level {value!r} is not a number')
        return None
    else:
        value = float(value)
    if check_condition is not None:
        try:
            check_condition(name, value)
        except InputError as exc:
            problems.append(f'{name}: {exc}')
            return None
    return value


def _factors(raw, problems: list, check_condition) -> dict:
    if not isinstance(raw, dict) or not raw:
        problems.append(f'factors: a mapping of trial conditions ({", ".join(CONDITION_KEYS)}) '
                        f'to their levels is required')
        return {}
    factors = {}
    for name, levels in raw.items():
        if name not in CONDITION_KEYS:
            problems.append(f'factors: {name!r} is not a trial condition (one of '
                            f'{", ".join(CONDITION_KEYS)})')
            continue
        if not isinstance(levels, list) or not levels:
            problems.append(f'factors: {name}: a list of its levels is required, got {levels!r}')
            continue
        checked = [_level(name, v, problems, check_condition) for v in levels]
        if any(v is None for v in checked):
            continue
        if len(set(checked)) != len(checked):
            problems.append(f'factors: {name}: a level is listed twice ({levels})')
            continue
        factors[name] = tuple(checked)
    return factors


def _fixed(raw, factors: dict, problems: list, check_condition) -> dict:
    if not isinstance(raw, dict):
        problems.append(f'fixed: a mapping of trial conditions to values, got {raw!r}')
        return {}
    fixed = {}
    for name, value in raw.items():
        if name not in CONDITION_KEYS:
            problems.append(f'fixed: {name!r} is not a trial condition (one of '
                            f'{", ".join(CONDITION_KEYS)})')
        elif name in factors:
            problems.append(f'fixed: {name} is also a factor')
        else:
            checked = _level(name, value, problems, check_condition)
            if checked is not None:
                fixed[name] = checked
    return fixed


def _repeats(raw, problems: list) -> Optional[int]:
    if raw == 'auto':
        return None
    if isinstance(raw, bool) or not isinstance(raw, int) or not 1 <= raw <= 1000:
        problems.append(f'repeats: {raw!r} is neither a whole number in [1, 1000] nor `auto`')
        return 1
    return raw


def _smallest_effect(raw, repeats, problems: list) -> dict:
    if raw is None:
        if repeats is None:
            problems.append('smallest_effect: `repeats: auto` needs the smallest difference the '
                            'study must resolve, e.g. {peak_tip_speed_mps: 0.5}')
        return {}
    if not isinstance(raw, dict) or not raw:
        problems.append(f'smallest_effect: a mapping of quantity to difference, got {raw!r}')
        return {}
    from .quantities import QUANTITIES
    out = {}
    for name, value in raw.items():
        if name not in QUANTITIES:
            problems.append(f'smallest_effect: {name!r} is not a measured quantity (one of '
                            f'{", ".join(QUANTITIES)})')
        elif isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not (math.isfinite(value) and value > 0):
            problems.append(f'smallest_effect: {name} = {value!r} must be a number > 0 '
                            f'({QUANTITIES[name].unit})')
        else:
            out[name] = float(value)
    return out


__all__ = ['CONDITION_KEYS', 'ORDERS', 'PlanError', 'PlannedTrial', 'StudyPlan', 'load_plan',
           'plan_from_mapping']
