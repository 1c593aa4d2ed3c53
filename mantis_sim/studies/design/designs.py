"""Designs for a study: ranges of scene parameters, as a grid or a Latin hypercube, and the
simulated strike of each design as one row of results.

A design is a scene with some of its parameters set (``{'geometry.d_t_mm': 21.0, ...}``). Its
row holds every input, the metrics of `mantis sim --json` (nested ones flattened:
``phase_start_s.IV``), the solver and tolerance, the integration's wall time (``wall_time_s``,
as `mantis sim` reports it) and the whole design's (``design_time_s``: the scene, the
simulation and its metrics), and a status:
``ok``, ``no strike`` (the pull never released the arm) or ``failed`` (the simulation raised),
with the reason. With a spread (``spread_robots`` N > 0), the row also holds the quantiles
q05..q95 of SPREAD_METRICS over N robots drawn from the scene's spread at the design
(``peak_tip_speed_mps_q05``, ...), the same draws for every design of a seed (mantis_sim.robots).
Nothing here knows where the designs run (mantis_sim.studies.design.sweep does).
"""
from __future__ import annotations

from dataclasses import dataclass
import functools
import hashlib
import itertools
import json
import math
import time

import numpy as np

from mantis_sim.errors import InputError
from mantis_sim.model import SimulationError
from mantis_sim.parameters import ParameterError
from mantis_sim.results import JSON_KEYS, simulate
from mantis_sim.robots import design_spread
from mantis_sim.scene import Scene, load_scene
from mantis_sim.spread import quantiles
from mantis_sim.studies.shared.blas import one_blas_thread

STATUS_OK, STATUS_NO_STRIKE, STATUS_FAILED = 'ok', 'no strike', 'failed'
ID_COLUMN = 'design_id'
METRIC_KEYS = tuple(k for k in JSON_KEYS if k not in ('effects', 'solver', 'rtol',
                                                      'wall_time_s', 'status', 'reason'))
#: The metrics a sweep with a spread gives the quantiles of (mantis_sim.robots.DESIGN_METRICS).
SPREAD_METRICS = ('peak_tip_speed_mps', 'spring_energy_mJ', 'max_spring_energy_mJ',
                  'peak_tendon_force_N')
SPREAD_ROBOTS_COLUMN = 'spread_robots'
EXTRA_METRICS = ('peak_time_s', 'peak_arm_speed_radps', 'peak_body_speed_in_strike_radps',
                 'arm_kinetic_energy_share_at_peak', 'tendon_work_phase_IV_mJ')


class DesignError(InputError):
    """A range or a design that cannot be simulated (names the key and why)."""


@dataclass(frozen=True)
class Range:
    key: str
    low: float
    high: float
    n: int | None = None          # grid points; None with --sample

    def values(self) -> np.ndarray:
        return np.linspace(self.low, self.high, self.n)


def parse_range(text: str, need_n: bool = True) -> Range:
    """``KEY=LO:HI:N`` (or ``KEY=LO:HI`` for a Latin hypercube)."""
    key, sep, spec = text.partition('=')
    parts = spec.split(':')
    if not sep or not key.strip() or len(parts) not in (2, 3):
        raise DesignError(f'--vary {text!r}: expected KEY=LO:HI:N (for a grid) or KEY=LO:HI '
                          f'(with --sample), e.g. geometry.d_t_mm=19:25:7')
    try:
        low, high = float(parts[0]), float(parts[1])
        n = int(parts[2]) if len(parts) == 3 else None
    except ValueError:
        raise DesignError(f'--vary {text!r}: LO and HI must be numbers and N a whole '
                          f'number') from None
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise DesignError(f'--vary {text!r}: need finite LO <= HI')
    if need_n and (n is None or n < 1):
        raise DesignError(f'--vary {text!r}: a grid needs N >= 1 points (KEY=LO:HI:N)')
    if n is not None and n < 1:
        raise DesignError(f'--vary {text!r}: N must be >= 1')
    return Range(key.strip(), low, high, n)


def check_ranges(scene: Scene, ranges: list[Range]) -> None:
    """Refuse, before any work, a key the scene does not have, a non-numeric one, a key given
    twice, or an end of a range outside the parameter's valid range (DesignError)."""
    seen = set()
    for r in ranges:
        if r.key in seen:
            raise DesignError(f'--vary {r.key}: given twice')
        seen.add(r.key)
    for i, r in enumerate(ranges):
        others = ranges[:i] + ranges[i + 1:]
        for end in (r.low, r.high):
            # an end is refused only if no end of the other ranges makes it a valid design
            # (keys that constrain each other, as contact angle and latch offset, vary together)
            error = None
            for combo in itertools.product(*((o.low, o.high) for o in others)):
                values = {**dict(zip((o.key for o in others), combo)), r.key: end}
                try:
                    varied = scene.with_overrides([f'{k}={v!r}' for k, v in values.items()])
                    break
                except ParameterError as exc:
                    error = error or exc
            else:
                raise DesignError(f'--vary {r.key}={r.low:g}:{r.high:g}: {error}')
            if not isinstance(_lookup(varied, r.key), (int, float)):
                raise DesignError(f'--vary {r.key}: not a numeric parameter')


def _lookup(scene: Scene, key: str):
    section, _, name = key.partition('.')
    return getattr(getattr(scene, section), name)


def grid(ranges: list[Range]) -> list[dict]:
    return [dict(zip([r.key for r in ranges], (float(v) for v in combo)))
            for combo in itertools.product(*(r.values() for r in ranges))]


def latin_hypercube(ranges: list[Range], n: int, seed: int = 0) -> list[dict]:
    """n designs, each range cut into n strata and every stratum used once (scipy's qmc)."""
    from scipy.stats import qmc
    if n < 1:
        raise DesignError(f'--sample {n}: need at least one design')
    unit = qmc.LatinHypercube(d=len(ranges), seed=seed).random(n)
    lows = np.array([r.low for r in ranges])
    spans = np.array([r.high - r.low for r in ranges])
    return [dict(zip([r.key for r in ranges], (float(v) for v in lows + spans * u)))
            for u in unit]


def design_id(values: dict) -> str:
    """Stable across runs and machines: the sorted inputs, floats in their exact repr."""
    text = json.dumps({k: repr(float(v)) for k, v in sorted(values.items())})
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def run_design(scene: Scene, values: dict, spread_robots: int = 0,
               spread_seed: int = 1) -> dict:
    """The row of one design (module docstring). Never raises for a design that fails."""
    row = _run_nominal(scene, values)
    if spread_robots and row['status'] != STATUS_FAILED:
        started = time.perf_counter()
        row.update(spread_columns(scene.with_values(values), spread_robots, spread_seed))
        row['design_time_s'] += time.perf_counter() - started
    return row


def spread_columns(design: Scene, robots: int, seed: int) -> dict:
    """The quantiles of SPREAD_METRICS over the design's drawn robots, as row columns."""
    run = design_spread(design, robots, seed, lambda f, items: [f(item) for item in items])
    out = {SPREAD_ROBOTS_COLUMN: robots, 'spread_seed': seed, 'spread_not_struck': run.not_struck}
    for metric in SPREAD_METRICS:
        out.update({f'{metric}_{q}': v for q, v in quantiles(run.samples[metric]).items()})
    return out


def _run_nominal(scene: Scene, values: dict) -> dict:
    row = {ID_COLUMN: design_id(values), **values}
    started = time.perf_counter()
    try:
        result = simulate(scene.with_values(values))
    except (SimulationError, InputError, ArithmeticError, ValueError) as exc:
        row.update(status=STATUS_FAILED, reason=f'{type(exc).__name__}: {exc}',
                   wall_time_s=time.perf_counter() - started,
                   design_time_s=time.perf_counter() - started)
        return row
    metrics = result.metrics
    row.update(_flatten({k: metrics[k] for k in METRIC_KEYS + EXTRA_METRICS}))
    row.update(solver=metrics['solver'], rtol=float(metrics['rtol']),
               wall_time_s=float(metrics['wall_time_s']))
    if metrics['strike_reached']:
        row.update(status=STATUS_OK, reason='')
    else:
        row.update(status=STATUS_NO_STRIKE, reason=metrics['reason'])
    row['design_time_s'] = time.perf_counter() - started
    return row


def run_chunk(scene_name: str, overrides: list, chunk: list[dict], spread_robots: int = 0,
              spread_seed: int = 1) -> list[dict]:
    """Rows of several designs of one scene: what a worker runs (the scene loaded once, BLAS
    on one thread as on any worker: mantis_sim.studies.shared.blas)."""
    one_blas_thread()
    scene = _loaded(scene_name, tuple(overrides))
    return [run_design(scene, values, spread_robots, spread_seed) for values in chunk]


@functools.lru_cache(maxsize=8)
def _loaded(scene_name: str, overrides: tuple) -> Scene:
    """The scene a worker's chunks share: loaded (its YAML read and checked) once."""
    return load_scene(scene_name, list(overrides))


def _flatten(metrics: dict) -> dict:
    out = {}
    for key, value in metrics.items():
        if isinstance(value, dict):
            for sub, v in value.items():
                out[f'{key}.{sub}'] = None if v is None else float(v)
        else:
            out[key] = None if value is None else float(value)
    return out


__all__ = ['DesignError', 'Range', 'check_ranges', 'design_id', 'grid', 'latin_hypercube',
           'parse_range', 'run_chunk', 'run_design', 'spread_columns', 'ID_COLUMN',
           'SPREAD_METRICS', 'SPREAD_ROBOTS_COLUMN', 'STATUS_OK',
           'STATUS_NO_STRIKE', 'STATUS_FAILED']
