"""The start of unlatching from the form of the arm's departure, with its interval.

At unlatching the contact torque that held the arm crosses zero while the pull goes on, so the
released arm's net torque grows linearly from zero, against a hinge whose linearised motion
about the latched pose is unstable at some rate λ (λ = 0: neutral). Its departure from the
latch, τ after the start, is then

    d(τ) = c3 · 6 (sinh λτ − λτ) / λ³        (c3 τ³ at λ = 0; zero before the start),

a cube at first, an exponential later. For most of its first milliseconds it stays below the
tracking noise, so a level crossing finds it late (by 2.4 ms on the simulated camera at 19,000
frames/s). Fitted to the raw frames around the crossing, the form puts the start back where
it was: the profile likelihood of the start (the floor, c3 and λ fitted at each candidate)
gives the value and its interval (:meth:`Onset.interval`). A growing exponential shifted in
time is the same curve scaled, so the frames often do not bound the start from below: the
interval then reaches back to the start of the frames fitted (LOOKBACK_RISES of the
departure's rise before the crossing).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The frames fitted reach the departure's rise time this many times before the level crossing.
LOOKBACK_RISES = 8.0
#: ... and end where the departure (smoothed) is this many per-frame noise sds above the latch.
FIT_END_SIGMAS = 15.0
#: The instability rates tried reach this many per rise time (the rise: crossing to fit end).
MAX_RATE_PER_RISE = 8.0
RATES_TRIED = 30
#: Golden-section steps refining each start's λ between its grid neighbours (0.62^20: 1e-4).
GOLDEN_STEPS = 20
#: Candidate starts: one a frame, or this many over the frames fitted if that is fewer.
MAX_STARTS = 400
#: Fewer frames of rise than this after the crossing: too few to fit its form.
MIN_FRAMES_AFTER = 5
#: A departure slower than this from crossing to fit end is not a released arm's run-away (it
#: takes ~1.5 ms on the simulated robot; the real robot's arm can creep off its latch for most
#: of a second): not fitted.
MAX_RISE_S = 0.01
#: Residuals above this many times the frames' noise variance: the form does not describe
#: the departure, and the level crossing stands.
MAX_RESIDUAL_VARIANCE_RATIO = 2.0


@dataclass(frozen=True)
class Onset:
    start_s: float
    rate_per_s: float           # λ at the best start
    candidates_s: np.ndarray    # the starts tried, first to last
    profile: np.ndarray         # each one's residual sum of squares over the best's (variances)

    @property
    def step_s(self) -> float:
        """The spacing of the starts tried: the start and its interval are found on them."""
        return float(self.candidates_s[1] - self.candidates_s[0]) if len(self.candidates_s) > 1 \
            else 0.0

    def interval(self, level: float) -> tuple[float, float, bool]:
        """The ``level`` profile-likelihood interval of the start, and whether the frames bound
        it below (False: its low end is the first start tried)."""
        from scipy.stats import chi2
        inside = self.candidates_s[self.profile <= chi2.ppf(level, 1)]
        return float(inside.min()), float(inside.max()), bool(inside.min() > self.candidates_s[0])


def departure_form(rate_per_s: float, tau_s: np.ndarray) -> np.ndarray:
    """6 (sinh λτ − λτ) / λ³ for τ > 0 (τ³ at λ = 0), zero before."""
    tau = np.clip(tau_s, 0.0, None)
    x = rate_per_s * tau
    small = x < 1e-3
    safe = np.where(small, 1.0, x)
    shape = np.where(small, 1.0 + x * x / 20.0, 6.0 * (np.sinh(safe) - safe) / safe ** 3)
    return tau ** 3 * shape


def unlatch_onset(t: np.ndarray, arm_raw_rad: np.ndarray, arm_smoothed_rad: np.ndarray,
                  noise_rad: float, crossing_s: float, i_end: int,
                  i_first: int = 0) -> Onset | None:
    """The start of the departure that the level crossing at ``crossing_s`` found late.

    ``arm_raw_rad``: the arm's angle to the body per frame (it rises off the latch);
    ``arm_smoothed_rad`` the same smoothed, to find where the fitted frames end; ``noise_rad``
    its per-frame noise; ``i_end``: the frames fitted end before it (the strike), and begin
    no earlier than ``i_first`` (the loading's start: the arm cannot leave before). None where
    the departure is not a released arm's: not seen rising after the crossing, rising for
    longer than MAX_RISE_S, or not of the form (residuals over
    MAX_RESIDUAL_VARIANCE_RATIO noise variances, or a start at the first frame tried)."""
    i_cross = int(np.searchsorted(t, crossing_s))
    if not noise_rad > 0 or i_cross >= i_end:
        return None
    level = arm_smoothed_rad[i_cross] + FIT_END_SIGMAS * noise_rad
    above = np.nonzero(arm_smoothed_rad[i_cross:i_end] > level)[0]
    if len(above) == 0 or above[0] < MIN_FRAMES_AFTER:
        return None
    j_end = i_cross + int(above[0])
    rise_s = t[j_end] - t[i_cross]
    if rise_s > MAX_RISE_S:
        return None
    i_start = max(int(np.searchsorted(t, crossing_s - LOOKBACK_RISES * rise_s)), i_first)
    frame_s = float(np.median(np.diff(t[i_start:j_end + 1])))
    tau = t[i_start:j_end + 1] - crossing_s
    y = arm_raw_rad[i_start:j_end + 1]
    tracked = np.isfinite(y)                # a lost marker's frames say nothing
    tau, y = tau[tracked], y[tracked]
    if len(y) < 2 * MIN_FRAMES_AFTER:
        return None
    starts = np.arange(tau[0], frame_s, max(frame_s, (frame_s - tau[0]) / MAX_STARTS))
    sse, best_rate = _profile_over_rates(tau, y, starts, MAX_RATE_PER_RISE / rise_s)
    i_best = int(np.argmin(sse))
    residual_variance = sse[i_best] / max(len(y) - 4, 1)
    if i_best == 0 or residual_variance > MAX_RESIDUAL_VARIANCE_RATIO * noise_rad ** 2:
        return None
    # The residuals' own variance where the form fits worse than the noise says.
    variance = max(residual_variance, noise_rad ** 2)
    return Onset(start_s=crossing_s + float(starts[i_best]), rate_per_s=float(best_rate[i_best]),
                 candidates_s=crossing_s + starts, profile=(sse - sse[i_best]) / variance)


def _profile_over_rates(tau: np.ndarray, y: np.ndarray, starts: np.ndarray,
                        max_rate_per_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate start: the least residual sum of squares over λ, and its λ. A grid of
    RATES_TRIED rates, then a golden-section search between each start's best grid rate's
    neighbours: the grid alone leaves the profile jagged by as much as the interval's cut."""
    shifted = tau[None, :] - starts[:, None]

    def sse_at(rate_per_start):
        return _floor_and_form_sse(departure_form(rate_per_start[:, None], shifted), y)
    rates = np.linspace(0.0, max_rate_per_s, RATES_TRIED)
    grid = np.array([sse_at(np.full(len(starts), rate)) for rate in rates])
    k = np.argmin(grid, axis=0)
    low, high = rates[np.maximum(k - 1, 0)], rates[np.minimum(k + 1, RATES_TRIED - 1)]
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    c, d = high - ratio * (high - low), low + ratio * (high - low)
    sse_c, sse_d = sse_at(c), sse_at(d)
    for _ in range(GOLDEN_STEPS):
        left = sse_c < sse_d                # the minimum lies in [low, d]; else in [c, high]
        low, high = np.where(left, low, c), np.where(left, d, high)
        new_c = np.where(left, high - ratio * (high - low), d)
        new_d = np.where(left, c, low + ratio * (high - low))
        fresh = sse_at(np.where(left, new_c, new_d))
        sse_c, sse_d = np.where(left, fresh, sse_d), np.where(left, sse_c, fresh)
        c, d = new_c, new_d
    refined = np.minimum(sse_c, sse_d)
    refined_rate = np.where(sse_c <= sse_d, c, d)
    on_grid = grid[k, np.arange(len(starts))]
    better = refined < on_grid
    return np.where(better, refined, on_grid), np.where(better, refined_rate, rates[k])


def _floor_and_form_sse(forms: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per row of ``forms``: the residual sum of squares of y = floor + c3 · form, least squares
    with c3 > 0 (a departure away from the latch); a floor alone where c3 would not be."""
    scale = forms.max(axis=1, keepdims=True)
    f = np.divide(forms, scale, out=np.zeros_like(forms), where=scale > 0)
    y0 = y - y.mean()
    syy = float(y0 @ y0)
    fc = f - f.mean(axis=1, keepdims=True)
    sff = np.einsum('ij,ij->i', fc, fc)
    sfy = fc @ y0
    gain = np.divide(sfy * sfy, sff, out=np.zeros_like(sff), where=sff > 1e-300)
    gain[sfy <= 0] = 0.0
    return syy - gain


__all__ = ['Onset', 'departure_form', 'unlatch_onset']
