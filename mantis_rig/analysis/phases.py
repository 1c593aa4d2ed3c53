"""Phase boundaries of a strike from smoothed joint angles and rates.

- loading start: θ1 first leaves its initial value by more than the detection threshold.
- unlatching (I→II): the arm leaves the contact angle for good. θ3 while latched sits on a
  floor (it may sag a little as the contact compresses); unlatching is the last time before
  the strike that smoothed θ3 is within the threshold of its lowest pre-strike value. That
  crossing is late by the time the arm takes to leave the latch by the threshold; where the
  departure has the released arm's form, analysis.onset fits it back to its start.
- overcentering (II→III): the tendon line c–d passes over the arm pivot b, i.e.
  ∂l_t/∂θ3 = 0 ⇔ L1 sin(θ3 + β) + d_t sin(θ1 − θ3 − β) = 0 (model angles). The guide hole is
  not tracked, so this needs the model θ1 (caller's θ1 reference) and the absolute θ3 (arm
  axis). A trajectory-only estimate is offered too (:func:`trajectory_knee_time`).
- max spring contraction (III→IV): θ̇1 crosses zero upwards just before the strike, θ1 is
  minimal; located by linear interpolation between frames.
- peak tip speed (end of IV): first maximum of |v_tip| after the start of IV.

Thresholds are multiples of the noise of the smoothed signal, never absolute angles.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DETECTION_SIGMAS = 5.0   # rates: against the noise of the smoothed rate
LEVEL_SIGMAS = 3.0       # angle levels: against the per-frame angle noise


@dataclass
class PhaseTimes:
    loading_start_s: float
    unlatch_s: float
    overcentering_s: float
    max_contraction_s: float
    peak_tip_speed_s: float
    index_max_contraction: int
    index_peak: int


def _interp_crossing(t: np.ndarray, y: np.ndarray, i: int) -> float:
    """Time where y crosses zero between samples i and i+1."""
    y0, y1 = y[i], y[i + 1]
    if y1 == y0:
        return float(t[i])
    return float(t[i] + (t[i + 1] - t[i]) * (-y0) / (y1 - y0))


def strike_index(omega1_radps: np.ndarray, valid: np.ndarray | None = None) -> int:
    """Sample of the peak body speed: the strike is the body's fastest motion.

    ``valid``: samples that may hold it (e.g. not the ends, where the rate is noisiest).
    """
    if valid is None or not valid.any():
        return int(np.argmax(omega1_radps))
    return int(np.argmax(np.where(valid, omega1_radps, -np.inf)))


def loading_rate(t: np.ndarray, theta1_rad: np.ndarray, i_strike: int,
                 span_s: float = 0.1, gap_s: float = 0.01) -> float:
    """θ̇1 at the end of loading: the least-squares slope of θ1 over ``span_s`` ending
    ``gap_s`` before the strike (NaN if there are too few frames). A long baseline: the
    slow loading moves a marker by a pixel only every few tens of ms."""
    lo, hi = np.searchsorted(t, [t[i_strike] - span_s - gap_s, t[i_strike] - gap_s])
    if hi - lo < 3:
        return float('nan')
    return float(np.polyfit(t[lo:hi] - t[hi - 1], theta1_rad[lo:hi], 1)[0])


@dataclass(frozen=True)
class BandExits:
    """Where θ̇1 leaves its hysteresis band ±b round the turn (see :func:`max_contraction`)."""

    below_s: float              # the last exit below -b before the strike
    above_s: float              # the first exit above +b after it
    i_above: int                # the first frame above +b
    band_radps: np.ndarray      # b at each frame
    resolved: bool              # the loading is faster than the band: the turn is seen


def band_exits(t: np.ndarray, omega1_radps: np.ndarray, omega1_noise_radps: np.ndarray,
               i_strike: int, loading_rate_radps: float = float('nan')) -> BandExits:
    band = DETECTION_SIGMAS * omega1_noise_radps
    loading = np.nonzero(omega1_radps[:i_strike] < -band[:i_strike])[0]
    if len(loading) == 0:
        raise ValueError('θ̇1 is never clearly negative before the strike: no loading seen')
    i_neg = int(loading[-1])
    t_neg = _interp_crossing(t, omega1_radps + band, i_neg)
    rising = np.nonzero(omega1_radps[i_neg:i_strike + 1] > band[i_neg:i_strike + 1])[0]
    if len(rising) == 0:
        raise ValueError('θ̇1 never turns clearly positive after the loading: the frames do '
                         'not hold the strike (the spring never releases in them)')
    i_pos = i_neg + int(rising[0])
    t_pos = _interp_crossing(t, omega1_radps - band, i_pos - 1)
    resolved = not np.mean(band[i_neg:i_pos + 1]) >= abs(loading_rate_radps)
    return BandExits(t_neg, t_pos, i_pos, band, bool(resolved))


def max_contraction(t: np.ndarray, omega1_radps: np.ndarray, omega1_noise_radps: np.ndarray,
                    i_strike: int, loading_rate_radps: float = float('nan'),
                    ) -> tuple[float, int]:
    """Start of phase IV: the upward zero crossing of θ̇1 just before the strike.

    A noisy zero crossing is located with a symmetric hysteresis band ±b, b =
    DETECTION_SIGMAS × local rate noise: the last exit below −b before the strike and the
    first exit above +b after it, each interpolated between frames; the crossing is their
    midpoint. If the body rests a while at maximum contraction (θ̇1 ≈ 0 for some ms), this is
    the centre of the rest; if it turns round at once, it is the crossing itself.

    That needs the loading to be resolved up to the turn. Where the band between the two
    exits is wider than the loading rate (``loading_rate_radps``, :func:`loading_rate`; coarse
    pixels, slow loading), the apparent rest is only loading too slow to see, and the midpoint
    would fall far before the turn; then the crossing is extrapolated back from the rising
    side: the tangent of θ̇1 where it leaves the band, followed down to θ̇1 = 0.
    """
    return turn_time(t, omega1_radps,
                     band_exits(t, omega1_radps, omega1_noise_radps, i_strike, loading_rate_radps))


def turn_time(t: np.ndarray, omega1_radps: np.ndarray, exits: BandExits) -> tuple[float, int]:
    """:func:`max_contraction` from the band's exits already found."""
    if exits.resolved:                      # (or no loading rate to judge by)
        t_iv = 0.5 * (exits.below_s + exits.above_s)
    else:
        i_pos, band = exits.i_above, exits.band_radps
        slope = _rising_slope(t, omega1_radps, band, i_pos)
        b = float(np.interp(exits.above_s, t[i_pos - 1:i_pos + 1], band[i_pos - 1:i_pos + 1]))
        t_iv = max(exits.below_s, exits.above_s - b / slope) if slope > 0 else exits.above_s
    return float(t_iv), int(np.argmin(np.abs(t - t_iv)))


def max_contraction_earliest(t: np.ndarray, exits: BandExits, loading_rate_radps: float,
                             overcentering_s: float) -> float:
    """The earliest the turn can be where :func:`max_contraction` extrapolated it back along
    θ̇1's rise (NaN where the midpoint stands, or overcentering is not before the exit).

    The tangent it follows is late on a convex rise. From overcentering on, the tendon drives
    the arm out and the body's deceleration only grows, so θ̇1 is convex from there through the
    turn to the exit: it rises from the loading rate v at t_III to 0 at the turn t_IV, so its
    slope at the turn is at least |v| / (t_IV − t_III), and it then reaches the band b at the
    exit t_b no later than b (t_IV − t_III) / |v| after the turn. Hence
    t_IV ≥ (|v| t_b + b t_III) / (|v| + b). This takes θ̇1 at overcentering to be the loading
    rate (the body is still being loaded then: -0.215 against -0.216 rad/s on the simulated
    rig); had the body already slowed, the bound would come out late.
    """
    v = abs(loading_rate_radps)
    if exits.resolved or not (v > 0 and overcentering_s < exits.above_s):
        return float('nan')
    i = exits.i_above
    b = float(np.interp(exits.above_s, t[i - 1:i + 1], exits.band_radps[i - 1:i + 1]))
    return float((v * exits.above_s + b * overcentering_s) / (v + b))


def _rising_slope(t: np.ndarray, omega1_radps: np.ndarray, band: np.ndarray, i_pos: int,
                  ) -> float:
    """dθ̇1/dt where θ̇1 rises out of the band: the least-squares line through the frames from
    two before ``i_pos`` to the first above three bands (at least six). Two frames alone give
    a slope as noisy as its value, and the tangent then reached back tens of frames."""
    lo = max(i_pos - 2, 0)
    above = np.nonzero(omega1_radps[i_pos:] > 3.0 * band[i_pos:])[0]
    hi = i_pos + (int(above[0]) if len(above) else 0)
    hi = min(max(hi, lo + 5), len(t) - 1)
    return float(np.polyfit(t[lo:hi + 1] - t[i_pos], omega1_radps[lo:hi + 1], 1)[0])


def peak_time_and_value(t: np.ndarray, values: np.ndarray, i: int) -> tuple[float, float]:
    """Sub-frame maximum near sample i: the vertex of the parabola through i−1, i, i+1."""
    if i <= 0 or i >= len(values) - 1:
        return float(t[i]), float(values[i])
    y0, y1, y2 = values[i - 1], values[i], values[i + 1]
    curvature = y0 - 2.0 * y1 + y2
    if not curvature < 0.0:
        return float(t[i]), float(y1)
    shift = 0.5 * (y0 - y2) / curvature
    dt = 0.5 * (t[i + 1] - t[i - 1])
    return float(t[i] + shift * dt), float(y1 - 0.25 * (y0 - y2) * shift)


def loading_under_way(t: np.ndarray, theta1_rad: np.ndarray, noise_rad: float,
                      span_s: float = 0.1) -> bool:
    """True if θ1 already turns clearly over the first ``span_s`` of the frames: the recording
    began during the loading (a camera window around the release), so its start is not seen.
    The slope of a least-squares line, against its noise (white noise of the larger of
    ``noise_rad`` and the line's residual)."""
    n = int(np.searchsorted(t, t[0] + span_s))
    if n < 10:
        return False
    coef, resid, *_ = np.polyfit(t[:n] - t[0], theta1_rad[:n], 1, full=True)
    sigma = max(noise_rad, float(np.sqrt(resid[0] / n)) if len(resid) else 0.0)
    slope_noise = sigma * np.sqrt(12.0 / (n ** 3 - n)) / float(np.median(np.diff(t[:n])))
    return bool(abs(coef[0]) > DETECTION_SIGMAS * slope_noise)


def loading_start(t: np.ndarray, theta1_s: np.ndarray, threshold_rad: float, i_end: int,
                  n_ref: int) -> float:
    """First time θ1 departs from its initial value (mean of the first n_ref samples)."""
    ref = np.mean(theta1_s[:max(1, n_ref)])
    moved = np.nonzero(np.abs(theta1_s[:i_end] - ref) > threshold_rad)[0]
    return float(t[moved[0]]) if len(moved) else float(t[0])


def unlatch_time(t: np.ndarray, theta3_s: np.ndarray, threshold_rad: float,
                 i_start: int, i_end: int) -> float:
    seg = theta3_s[i_start:i_end]
    near_floor = np.nonzero(seg <= seg.min() + threshold_rad)[0]
    return float(t[i_start + near_floor[-1]])


def overcentering_residual(theta1_rad: np.ndarray, theta3_rad: np.ndarray, L1_mm: float,
                           beta_rad: float, d_t_mm: float) -> np.ndarray:
    """∝ ∂l_t/∂θ3 (mm): positive while the tendon holds the arm closed, zero at overcentering."""
    return (L1_mm * np.sin(theta3_rad + beta_rad)
            + d_t_mm * np.sin(theta1_rad - theta3_rad - beta_rad))


def geometric_overcentering(t: np.ndarray, residual: np.ndarray, i_start: int,
                            i_end: int) -> float:
    """Last sign change of the overcentering residual in [i_start, i_end); NaN if none."""
    s = np.sign(residual[i_start:i_end])
    flips = np.nonzero(s[:-1] * s[1:] < 0)[0]
    if len(flips) == 0:
        return float('nan')
    return _interp_crossing(t, residual, i_start + int(flips[-1]))


def trajectory_knee_time(t: np.ndarray, theta1_s: np.ndarray, theta3_s: np.ndarray,
                         i_start: int, i_end: int, n_candidates: int = 300) -> float:
    """Overcentering estimate from the (θ1, θ3) path alone (no tendon geometry).

    While the tendon holds the arm, θ3 follows the body's rotation at a near-constant rate;
    past overcentering the tendon's opening moment grows with its moment arm, so the rate
    grows. Fit θ3 = c + r·u + ½k·max(0, u − u_k)², u = body rotation since unlatching, and
    return the time of the knee u_k. Weakly determined when the path bends gradually.
    """
    step = max(1, (i_end - i_start) // 5000)
    u = -(theta1_s[i_start:i_end:step] - theta1_s[i_start])
    y = theta3_s[i_start:i_end:step]
    tt = t[i_start:i_end:step]
    best = (np.inf, float('nan'))
    for knee in np.linspace(u.min(), u.max(), n_candidates)[1:-1]:
        x = np.column_stack([np.ones_like(u), u, 0.5 * np.maximum(0.0, u - knee) ** 2])
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        sse = float(np.sum((x @ coef - y) ** 2))
        if sse < best[0]:
            best = (sse, float(tt[np.argmin(np.abs(u - knee))]))
    return best[1]


def peak_after(values: np.ndarray, i_from: int) -> int:
    return i_from + int(np.argmax(values[i_from:]))
