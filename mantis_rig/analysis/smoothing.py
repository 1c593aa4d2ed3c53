"""Zero-phase smoothing whose window shrinks where the motion is fast.

Loading lasts seconds at ~0.1 rad/s, the strike milliseconds at ~10³ rad/s, and both are seen
through the same quantised marker noise. A fixed window either drowns the slow phases in noise
or flattens the strike. Here each sample gets its own centred window, chosen so the velocity
estimate keeps a fixed relative precision: the slope of a least-squares line through 2h+1
samples has a noise of σ·√(3/(h(h+1)(2h+1)))/dt, so for speed ω h is the largest window whose
noise still reaches rel·ω (a wider one would flatten the motion), clipped to [min, max]. The
window a sample receives is set by the fastest motion within reach of the widest window, so a
wide window never straddles the start of a fast segment. The strike itself is fitted with local
polynomials (:func:`local_poly_fit`), see ``report._strike_rates``.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter1d
from scipy.signal import savgol_filter

# The strike: a centred least-squares polynomial of this degree (Savitzky–Golay). Over the
# few frames of the strike the rates change shape within any window that averages the
# noise down, and a straight line (the slow phases' estimator) would flatten the peaks.
STRIKE_POLY = 5


def centred_moving_average(x: np.ndarray, half_width: np.ndarray) -> np.ndarray:
    """Mean of x[i−h_i .. i+h_i]; h_i is shortened near the ends to keep the window centred."""
    n = len(x)
    idx = np.arange(n)
    h = np.minimum(np.minimum(half_width, idx), n - 1 - idx).astype(np.int64)
    csum = np.concatenate([[0.0], np.cumsum(x - x[0])])
    return (csum[idx + h + 1] - csum[idx - h]) / (2 * h + 1) + x[0]


def centred_linear_rate(time_s: np.ndarray, x: np.ndarray, half_width: np.ndarray
                        ) -> np.ndarray:
    """d/dt by a centred least-squares line through x[i−h_i .. i+h_i] (h_i shortened near the
    ends to keep the window centred).

    The slope Σ j·x_{i+j} / Σ j·t_{i+j} (j = −h..h) is the least-squares slope on uniformly
    spaced frames and stays a sound one across a dropped frame. Its noise, σ·√(3/(h(h+1)(2h+1)))
    / dt, falls as h^-1.5: every frame of the window counts, where a difference of moving
    averages uses the window's two ends only (noise σ/((2h+1)·dt)).
    """
    n = len(x)
    idx = np.arange(n)
    h = np.minimum(np.minimum(half_width, idx), n - 1 - idx).astype(np.int64)
    k = idx.astype(float)

    def weighted_sums(y):
        """Σ_{j=−h..h} j·y[i+j] for every i, from running sums of y and k·y."""
        s0 = np.concatenate([[0.0], np.cumsum(y)])
        s1 = np.concatenate([[0.0], np.cumsum(k * y)])
        lo, hi = idx - h, idx + h + 1
        return (s1[hi] - s1[lo]) - k * (s0[hi] - s0[lo])

    num = weighted_sums(np.asarray(x, float) - x[0])
    den = weighted_sums(np.asarray(time_s, float) - time_s[0])
    rate = np.zeros(n)
    # den > 0 wherever h > 0 for increasing times, unless the times are so large that their
    # differences vanish in rounding (a damaged file): no rate there rather than inf
    np.divide(num, den, out=rate, where=(h > 0) & (den > 0))
    return rate


def linear_rate_noise(noise_rad: float, half_width: np.ndarray, dt_s: float) -> np.ndarray:
    """Noise (rad/s) of :func:`centred_linear_rate` for white angle noise ``noise_rad``."""
    h = np.maximum(np.asarray(half_width, float), 1.0)
    return noise_rad * np.sqrt(3.0 / (h * (h + 1.0) * (2.0 * h + 1.0))) / dt_s


def angle_noise_rad(angle_rad: np.ndarray, floor_rad: float) -> float:
    """Per-frame noise of an angle series: robust spread of second differences (var = 6σ²)."""
    d2 = np.diff(angle_rad, 2)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return max(1.4826 * mad / np.sqrt(6.0), floor_rad)


def adaptive_half_widths(angle_rad: np.ndarray, dt_s: float, noise_rad: float,
                         rel_precision: float = 0.02, max_window_s: float = 0.02,
                         min_half_width: int = 1, iterations: int = 10) -> np.ndarray:
    """Per-sample half-window (samples) for :func:`centred_moving_average`.

    h_i is the largest h on a doubling ladder for which the fastest pilot speed inside
    [i − h, i + h] is slow enough: max|ω| ≤ σ / (2 · rel · h · dt). The pilot speed comes
    from the previous pass (the first pass uses the widest window everywhere), until the
    windows no longer change (at most ``iterations`` passes): a motion much shorter than the
    widest window is flattened by it, so its speed, and the need for short windows, shows
    only pass by pass.
    """
    h_max = max(min_half_width, int(round(0.5 * max_window_s / dt_s)))
    ladder = [min_half_width]
    while ladder[-1] * 2 < h_max:
        ladder.append(ladder[-1] * 2)
    ladder.append(h_max)
    h = np.full(len(angle_rad), h_max, dtype=np.int64)
    for _ in range(iterations):
        speed = np.abs(np.gradient(centred_moving_average(angle_rad, h), dt_s))
        new_h = np.full(len(angle_rad), min_half_width, dtype=np.int64)
        for cand in ladder:
            reach = maximum_filter1d(speed, size=2 * cand + 1, mode='nearest')
            ok = rel_precision * reach <= linear_rate_noise(noise_rad, cand, dt_s)
            new_h[ok] = cand
        if np.array_equal(new_h, h):
            break
        h = new_h
    return h


def smooth_angle(time_s: np.ndarray, angle_rad: np.ndarray, noise_rad: float,
                 rel_precision: float = 0.02, max_window_s: float = 0.02,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed angle, its time derivative (rad/s) and the half-widths used."""
    dt_s = float(np.median(np.diff(time_s)))
    h = adaptive_half_widths(angle_rad, dt_s, noise_rad, rel_precision, max_window_s)
    smooth = centred_moving_average(angle_rad, h)
    return smooth, centred_linear_rate(time_s, angle_rad, h), h


def full_window(half_width: np.ndarray) -> np.ndarray:
    """True where the rate's centred window (:func:`centred_linear_rate`) is not cut
    short by the ends of the series: near the ends the window shrinks and the rate is noisy."""
    n = len(half_width)
    idx = np.arange(n)
    return (idx - half_width >= 0) & (idx + half_width <= n - 1)


def local_poly_fit(angle_rad: np.ndarray, dt_s: float, half_width: int,
                   poly: int = STRIKE_POLY) -> tuple[np.ndarray, np.ndarray]:
    """(smoothed angle, rate rad/s): centred least-squares polynomial through 2k+1 frames."""
    window = 2 * int(half_width) + 1
    return (savgol_filter(angle_rad, window, poly),
            savgol_filter(angle_rad, window, poly, deriv=1, delta=dt_s))



def smoothing_spline_fit(time_s: np.ndarray, angle_rad: np.ndarray,
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(smoothed angle, rate rad/s) of a cubic smoothing spline whose smoothing is chosen by
    generalised cross-validation (scipy's ``make_smoothing_spline``): the fit follows the
    motion as closely as the frames' own noise allows, whatever the frame rate. Time runs in
    frames inside (the GCV search is badly scaled in seconds)."""
    from scipy.interpolate import make_smoothing_spline

    dt_s = float(np.median(np.diff(time_s)))
    frames = (time_s - time_s[0]) / dt_s
    spline = make_smoothing_spline(frames, angle_rad)
    return spline(frames), spline.derivative()(frames) / dt_s
