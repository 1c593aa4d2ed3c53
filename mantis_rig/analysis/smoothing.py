"""Zero-phase moving average whose window shrinks where the motion is fast.

Loading lasts seconds at ~0.1 rad/s, the strike milliseconds at ~10³ rad/s, and both are seen
through the same quantised marker noise. A fixed window either drowns the slow phases in noise
or flattens the strike. Here each sample gets its own centred window, chosen so the velocity
estimate keeps a fixed relative precision: differentiating an N-sample moving average leaves a
velocity noise of about σ/(N·dt), so for speed ω we want N ≈ σ / (rel · ω · dt), clipped to
[min, max]. The window a sample receives is set by the fastest motion within reach of the
widest window, so a wide window never straddles the start of a fast segment.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter1d


def centred_moving_average(x: np.ndarray, half_width: np.ndarray) -> np.ndarray:
    """Mean of x[i−h_i .. i+h_i]; h_i is shortened near the ends to keep the window centred."""
    n = len(x)
    idx = np.arange(n)
    h = np.minimum(np.minimum(half_width, idx), n - 1 - idx).astype(np.int64)
    csum = np.concatenate([[0.0], np.cumsum(x - x[0])])
    return (csum[idx + h + 1] - csum[idx - h]) / (2 * h + 1) + x[0]


def centred_moving_average_rate(time_s: np.ndarray, x: np.ndarray,
                                half_width: np.ndarray) -> np.ndarray:
    """d/dt of the moving average, each sample differentiated with its own window.

    Central difference of MA_h(i+1) and MA_h(i−1) with the same h = h_i, so a change of window
    between neighbouring samples does not show up as a spurious jump in the rate.
    """
    n = len(x)
    idx = np.arange(n)
    lo = np.clip(idx - 1, 0, n - 1)
    hi = np.clip(idx + 1, 0, n - 1)
    h = np.minimum(np.minimum(half_width, lo), n - 1 - hi).astype(np.int64)
    csum = np.concatenate([[0.0], np.cumsum(x - x[0])])
    upper = (csum[hi + h + 1] - csum[hi - h]) / (2 * h + 1)
    lower = (csum[lo + h + 1] - csum[lo - h]) / (2 * h + 1)
    return (upper - lower) / (time_s[hi] - time_s[lo])


def angle_noise_rad(angle_rad: np.ndarray, floor_rad: float) -> float:
    """Per-frame noise of an angle series: robust spread of second differences (var = 6σ²)."""
    d2 = np.diff(angle_rad, 2)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return max(1.4826 * mad / np.sqrt(6.0), floor_rad)


def adaptive_half_widths(angle_rad: np.ndarray, dt_s: float, noise_rad: float,
                         rel_precision: float = 0.02, max_window_s: float = 0.02,
                         min_half_width: int = 1, iterations: int = 3) -> np.ndarray:
    """Per-sample half-window (samples) for :func:`centred_moving_average`.

    h_i is the largest h on a doubling ladder for which the fastest pilot speed inside
    [i − h, i + h] is slow enough: max|ω| ≤ σ / (2 · rel · h · dt). The pilot speed comes
    from the previous pass (the first pass uses the widest window everywhere).
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
            ok = reach * (2.0 * rel_precision * cand * dt_s) <= noise_rad
            new_h[ok] = cand
        h = new_h
    return h


def smooth_angle(time_s: np.ndarray, angle_rad: np.ndarray, noise_rad: float,
                 rel_precision: float = 0.02, max_window_s: float = 0.02,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed angle, its time derivative (rad/s) and the half-widths used."""
    dt_s = float(np.median(np.diff(time_s)))
    h = adaptive_half_widths(angle_rad, dt_s, noise_rad, rel_precision, max_window_s)
    smooth = centred_moving_average(angle_rad, h)
    return smooth, centred_moving_average_rate(time_s, angle_rad, h), h


def full_window(half_width: np.ndarray) -> np.ndarray:
    """True where the rate's centred window (:func:`centred_moving_average_rate`) is not cut
    short by the ends of the series: near the ends the window shrinks and the rate is noisy."""
    n = len(half_width)
    idx = np.arange(n)
    return (idx - 1 - half_width >= 0) & (idx + 1 + half_width <= n - 1)
