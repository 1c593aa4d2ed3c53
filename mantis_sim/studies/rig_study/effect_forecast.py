"""The twin's forecast of the effects a study measures: what this study's least-squares fit will
give, not the mean effect over every robot the spread can draw.

A study measures one day's robot: the day's level of where the arm sits on the latch (its
assembly), each strike scattered about it. Where the model is not linear in that seat, an
effect differs from day to day: on `air_23mm_rig` the contact angle's effect on the tip speed
is -0.05 m/s for a day seated near its mean and -0.7 m/s averaged over all days (a day seated
low has its arm pressed to 0 degrees at the smaller angle). So the forecast replays the study:

1. the day's level is drawn from what the study's own strikes say of it (its posterior from
   their loading work, StudyForecaster.day_posterior; a new day's prior before any strike), a
   level per recording day, and the within-day scatter from the spread's uncertainty;
2. each of the study's strikes (its conditions, its day) gets a seat, the level plus its
   scatter, kept within the latch's range, and the quantity of the ensemble's robot at that
   seat at those conditions (interpolated along the seat), as the rig's measuring chain reads
   it (StudyForecaster.measurement);
3. the same least-squares fit as the measured effect (effects.measured_effects) is made on
   those values.

Over DRAWS replays that is the distribution of the effect this study would measure if the twin
were right; its median is the twin's effect and its 2.5-97.5 % the interval. It carries this
day's robot, the study's repeats and the measurement's error, as the measured interval does.

Limits: a scene whose spread also varies the identified parameters and the discrepancy lays
its robots out with those drawn per robot, so interpolating along the seat mixes them into a
strike's scatter (on the rig's day they are fixed): its intervals are then wider than they
need be.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
import math

import numpy as np

from mantis_sim.studies.rig_study.twin_forecast import DAY_QUANTITY, Ensemble, StudyForecaster

#: Replays of the study per forecast: the 2.5 % and 97.5 % quantiles move by about 3 % of
#: the interval's width from seed to seed at this many.
DRAWS = 2000


def strike_values(ensemble: Ensemble, quantity: str, seats: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
    """The ensemble's ``quantity`` at each seat (the latent: interpolated between its robots,
    the end robots beyond the range, as an arm cannot sit beyond the latch); robots that did
    not strike are left out. Without a latent (or fewer than two robots that struck), a
    robot drawn for each."""
    values = ensemble.values[quantity]
    ok = np.isfinite(values)
    if ensemble.latent is None or ok.sum() < 2:
        return np.full(seats.shape, np.nan) if not ok.any() else \
            rng.choice(values[ok], size=seats.shape)
    return np.interp(np.clip(seats, ensemble.lower, ensemble.upper), ensemble.latent[ok],
                     values[ok])


def replay_values(forecaster: StudyForecaster, rows: Sequence[Mapping], quantity: str,
                  conditions_of, draws: int = DRAWS, seed: int = 0) -> np.ndarray:
    """(draws, rows): the twin's ``quantity`` for each of the study's ``rows`` in each replay
    (module docstring). ``conditions_of(row)``: the conditions a row ran at; a row's ``day``
    groups it with the strikes of its day, whose DAY_QUANTITY tells the day's level."""
    rng = np.random.default_rng([seed, 11])
    out = np.empty((draws, len(rows)))
    belief = forecaster.belief
    if belief.latent is None:
        for j, row in enumerate(rows):
            ensemble = forecaster.ensemble(conditions_of(row))
            out[:, j] = strike_values(ensemble, quantity, np.zeros(draws), rng)
        return _with_error(out, forecaster.measurement.get(quantity), rng)
    sds = rng.choice(belief.strike_sds(), size=draws)
    levels = {}
    for day in dict.fromkeys(row.get('day') for row in rows):
        strikes = [(conditions_of(r), r[DAY_QUANTITY]) for r in rows
                   if r.get('day') == day and _finite(r.get(DAY_QUANTITY))]
        levels[day] = forecaster.level_draws(strikes, draws, rng)
    for j, row in enumerate(rows):
        seats = levels[row.get('day')] + sds * rng.normal(0.0, 1.0, draws)
        out[:, j] = strike_values(forecaster.ensemble(conditions_of(row)), quantity, seats,
                                  rng)
    return _with_error(out, forecaster.measurement.get(quantity), rng)


def _with_error(values: np.ndarray, error, rng: np.random.Generator) -> np.ndarray:
    """The values as the rig's measuring chain (a quantities.MeasurementError) reads them."""
    if error is None:
        return values
    return values * (1.0 + rng.choice(np.asarray(error.points), size=values.shape))


def replayed_effects(x: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(draws, columns of x): the least-squares coefficients of each replay's values."""
    pinv = np.linalg.pinv(x)                      # (columns, rows)
    return values @ pinv.T


def _finite(value) -> bool:
    return value is not None and isinstance(value, (int, float)) and math.isfinite(value)


__all__ = ['DRAWS', 'replay_values', 'replayed_effects', 'strike_values']
