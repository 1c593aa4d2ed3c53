"""A real strike simulated at its own conditions, and how far the two are apart.

`simulate_strike` sets a scene to one strike's guide distance, contact angle and measured pull
speed, runs it, and reports what the lab measures of a strike: peak tip speed, the lab's spring
energy (mantis_sim.results.lab_spring_energy_mJ of the deepest body turn), peak body and arm
speeds, and the motion around phase IV on a time grid. `error_table` and `slopes` compare many
of them with their real counterparts: per strike, per group, and the effects a design study
varies (least squares with one intercept per recording day where asked, with standard
errors).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

from mantis_sim.model import SimulationError
from mantis_sim.parameters import ParameterError
from mantis_sim.results import lab_spring_energy_mJ, simulate
from mantis_sim.scene import Scene

from .strikes import RealStrike, StrikeSeries

# Where the motion is compared, from the start of phase IV (s): the strike of air lasts ~5 ms,
# that of water ~20 ms; the grid resolves the arm's fastest swing (~0.2 ms per radian).
SERIES_WINDOW_S = {'air': (-1.0e-3, 6.0e-3), 'water': (-2.0e-3, 22.0e-3)}
SERIES_STEP_S = {'air': 0.2e-3, 'water': 0.5e-3}
# Where the arm sits on the latch: the latched arm angle is the contact angle + this offset.
LATCH_KEY = 'geometry.latch_offset_deg'


def strike_values(strike: RealStrike) -> dict:
    """The scene keys through which a strike's conditions are set, with their values."""
    return {'geometry.d_t_mm': strike.d_t_mm,
            'geometry.contact_angle_deg': strike.contact_angle_deg,
            'drive.pull_speed_mm_per_s': strike.pull_mm_per_s}


def strike_overrides(strike: RealStrike) -> list[str]:
    """strike_values as `--set` assignments."""
    return [f'{key}={value!r}' for key, value in strike_values(strike).items()]


def seat_values(strike: RealStrike) -> dict:
    """The scene value that latches the simulated arm where the strike's tracks show it at
    overcentering (`RealStrike.seat_deg`): with the pivot's hold of the identified scenes the
    arm is still there at overcentering. {} for a strike without a seat."""
    if strike.seat_deg is None:
        return {}
    return {LATCH_KEY: strike.seat_deg - strike.contact_angle_deg}


def series_grid(medium: str) -> np.ndarray:
    start, stop = SERIES_WINDOW_S[medium]
    step = SERIES_STEP_S[medium]
    return np.arange(start, stop + 0.5 * step, step)


@dataclass
class SimulatedStrike:
    trial: str
    status: str                       # 'strike', 'no strike' or 'failed'
    reason: str
    peak_tip_speed_mps: float = math.nan
    spring_energy_mJ: float = math.nan
    peak_body_speed_radps: float = math.nan
    peak_arm_speed_radps: float = math.nan
    series: Optional[StrikeSeries] = None
    wall_s: float = 0.0


def simulate_strike(scene: Scene, strike: RealStrike, series: bool = True,
                    values: Optional[dict] = None) -> SimulatedStrike:
    """One strike at its own conditions (module docstring), with ``values`` ({key: value}, as a
    fit or a day's state sets them) set together with them. Never raises for a strike the model
    cannot simulate: its status says why."""
    settings = {**strike_values(strike), **(values or {})}
    if series:      # simulate through the whole window that is compared
        settings['integration.post_peak_ms'] = SERIES_WINDOW_S[strike.medium][1] * 1e3
    try:
        at_conditions = scene.with_values(settings)
    except ParameterError as exc:   # e.g. a latch offset this strike's angle cannot take
        return SimulatedStrike(strike.trial, 'failed', f'at its conditions: {exc}')
    try:
        result = simulate(at_conditions, dense=series)
    except (SimulationError, ArithmeticError) as exc:
        return SimulatedStrike(strike.trial, 'failed', f'{type(exc).__name__}: {exc}')
    m = result.metrics
    if not m['strike_reached']:
        return SimulatedStrike(strike.trial, 'no strike', m['reason'], wall_s=m['wall_time_s'])
    out = SimulatedStrike(
        strike.trial, 'strike', '', m['peak_tip_speed_mps'],
        lab_spring_energy_mJ(m['deepest_body_angle_rad']),
        m['peak_body_speed_in_strike_radps'] or math.nan, m['peak_arm_speed_radps'],
        wall_s=m['wall_time_s'])
    if series:
        out.series = _sampled_series(result, strike.medium)
    return out


def _sampled_series(result, medium: str) -> StrikeSeries:
    """theta1, theta3 and tendon force on the medium's grid around phase IV."""
    t_iv_ms = result.metrics['phase_start_s']['IV'] * 1e3
    grid = series_grid(medium)
    times_ms = t_iv_ms + grid * 1e3
    states, forces = result.states_and_forces_at(times_ms)
    return StrikeSeries(grid, states[:, 0], states[:, 1], forces)


def real_on_grid(series: StrikeSeries, medium: str) -> StrikeSeries:
    """A recorded series interpolated onto the medium's grid (NaN where it does not reach)."""
    grid = series_grid(medium)

    def at(values):
        if values is None:
            return None
        return np.interp(grid, series.t_s, values, left=np.nan, right=np.nan)
    return StrikeSeries(grid, at(series.theta1_rad), at(series.theta3_rad),
                        at(series.tendon_force_N))


# --- comparison ----------------------------------------------------------------------------------
COMPARED = (('peak_tip_speed_mps', 'peak tip speed', 'm/s'),
            ('spring_energy_mJ', 'spring energy', 'mJ'),
            ('peak_body_speed_radps', 'peak body speed', 'rad/s'),
            ('peak_arm_speed_radps', 'peak arm speed', 'rad/s'))


def error_rows(strikes: list[RealStrike], simulated: list[SimulatedStrike]) -> list[dict]:
    """One row per strike: conditions, real and simulated values, relative errors."""
    rows = []
    for real, sim in zip(strikes, simulated):
        row = {'trial': real.trial, 'recording_day': real.recording_day, 'group': real.group,
               'd_t_mm': real.d_t_mm, 'contact_angle_deg': real.contact_angle_deg,
               'pull_mm_per_s': real.pull_mm_per_s, 'seat_deg': real.seat_deg,
               'status': sim.status, 'reason': sim.reason}
        for key, _, _ in COMPARED:
            measured, predicted = getattr(real, key), getattr(sim, key)
            row[f'real_{key}'] = measured
            row[f'sim_{key}'] = predicted
            row[f'error_{key}'] = (predicted / measured - 1.0
                                   if measured and math.isfinite(predicted) else math.nan)
        rows.append(row)
    return rows


def group_summary(rows: list[dict], key: str) -> dict[str, dict]:
    """Per group: strikes, median error and median |error| of one compared value."""
    out = {}
    for group in sorted({r['group'] for r in rows}):
        errors = np.array([r[f'error_{key}'] for r in rows if r['group'] == group], dtype=float)
        errors = errors[np.isfinite(errors)]
        out[group] = {'strikes': int(errors.size),
                      'median_error': float(np.median(errors)) if errors.size else math.nan,
                      'median_abs_error': float(np.median(np.abs(errors)))
                      if errors.size else math.nan}
    return out


@dataclass(frozen=True)
class Slope:
    value: float
    std_error: float
    strikes: int


def fit_slope(x: np.ndarray, y: np.ndarray, days: Optional[list[str]] = None) -> Slope:
    """Least-squares slope of y on x, with one intercept per recording day when ``days`` is
    given (the effect within days), and its standard error."""
    return fit_slopes([x], y, days)[0]


def fit_slopes(xs: Sequence, y: np.ndarray, days: Optional[list[str]] = None) -> list[Slope]:
    """fit_slope of y on several x at once: each one's slope with the others held (and one
    intercept per recording day when ``days`` is given). Strikes with any value missing are
    left out; where the data cannot separate the columns every slope is NaN."""
    xs = [np.asarray(x, float) for x in xs]
    y = np.asarray(y, float)
    keep = np.isfinite(y) & np.logical_and.reduce([np.isfinite(x) for x in xs])
    xs, y = [x[keep] for x in xs], y[keep]
    if days is None:
        columns = [np.ones_like(y)]
    else:
        kept_days = [d for d, k in zip(days, keep) if k]
        columns = [np.array([d == day for d in kept_days], float)
                   for day in sorted(set(kept_days))]
    design = np.column_stack([*xs, *columns])
    coef, _, rank, _ = np.linalg.lstsq(design, y, rcond=None)
    dof = len(y) - rank
    if dof <= 0 or rank < design.shape[1]:
        return [Slope(math.nan, math.nan, len(y)) for _ in xs]
    residual = y - design @ coef
    covariance = residual @ residual / dof * np.linalg.pinv(design.T @ design)
    return [Slope(float(coef[i]), float(math.sqrt(covariance[i, i])), len(y))
            for i in range(len(xs))]


# The effects a design study varies (issue 24): (name, y key, x key, rows kept, within days?)
EFFECT_SLOPES = (
    ('spring energy per mm of guide distance (air)', 'spring_energy_mJ', 'd_t_mm',
     lambda r: r['group'].startswith('air'), False, 'mJ/mm'),
    ('peak tip speed per mm/s of pull speed (air 23 mm, within days)', 'peak_tip_speed_mps',
     'pull_mm_per_s', lambda r: r['group'] == 'air_23mm', True, 'm/s per mm/s'),
    ('peak tip speed per degree of contact angle (air 23 mm, within days)',
     'peak_tip_speed_mps', 'contact_angle_deg', lambda r: r['group'] == 'air_23mm', True,
     'm/s/deg'),
    ('peak tip speed per mm of guide distance (air)', 'peak_tip_speed_mps', 'd_t_mm',
     lambda r: r['group'].startswith('air'), False, 'm/s/mm'),
)


def effect_slopes(rows: list[dict]) -> list[dict]:
    """The four effects, fitted the same way to the real and to the simulated strikes."""
    out = []
    for name, y_key, x_key, keep, within_days, unit in EFFECT_SLOPES:
        chosen = [r for r in rows if keep(r) and r['status'] == 'strike']
        days = [r['recording_day'] for r in chosen] if within_days else None
        x = np.array([r[x_key] for r in chosen], float)
        real = fit_slope(x, np.array([r[f'real_{y_key}'] for r in chosen], float), days)
        sim = fit_slope(x, np.array([r[f'sim_{y_key}'] for r in chosen], float), days)
        agrees = (math.isfinite(real.value) and math.isfinite(sim.value)
                  and abs(sim.value - real.value) <= 2.0 * real.std_error)
        out.append({'effect': name, 'unit': unit, 'strikes': real.strikes,
                    'real': real.value, 'real_std_error': real.std_error, 'sim': sim.value,
                    'within_two_std_errors': agrees})
    return out


__all__ = ['COMPARED', 'EFFECT_SLOPES', 'LATCH_KEY', 'SimulatedStrike', 'Slope',
           'effect_slopes', 'error_rows', 'fit_slope', 'fit_slopes', 'group_summary',
           'real_on_grid', 'seat_values', 'series_grid', 'simulate_strike', 'strike_overrides',
           'strike_values']
