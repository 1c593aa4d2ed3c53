"""Watch a force-block stream: continuity, peak, force ceiling and the release (no ROS).

Fed with consecutive blocks (first-sample time, period, forces) in arrival order, it keeps:

* continuity: a block whose first sample is not where the previous block ended counts as a gap
  (``gaps``: list of (t_s, missing samples)); ``samples`` counts every sample fed;
* the peak force and its time; the latest 1 ms mean (``latest_n``);
* the first sample above the force ceiling (``ceiling_hit``: (t_s, force));
* the release, once ``arm_release()`` was called: the first 1 ms mean that differs from the
  previous 1 ms mean by more than ``release_jump_n``. A slow pull moves the 1 ms mean by a few
  mN; unlatching moves it by newtons within a millisecond (docs/ros_interfaces.md, notes).
"""
from __future__ import annotations

import math

import numpy as np


class ForceMonitor:
    def __init__(self, ceiling_n: float, release_jump_n: float = 1.0, window_s: float = 1e-3):
        self.ceiling_n = ceiling_n
        self.release_jump_n = release_jump_n
        self.window_s = window_s
        self.samples = 0
        self.blocks = 0
        self.first_t_s: float | None = None
        self.end_t_s: float | None = None          # time just after the last sample fed
        self.period_s: float | None = None
        self.gaps: list[tuple[float, int]] = []
        self.peak_n = -math.inf
        self.peak_t_s: float | None = None
        self.latest_n: float | None = None
        self.ceiling_hit: tuple[float, float] | None = None
        self.release_t_s: float | None = None
        self._armed = False
        self._carry = np.empty(0)                  # samples of an unfinished window
        self._carry_t_s = 0.0
        self._prev_mean: float | None = None

    @property
    def duration_s(self) -> float:
        if self.first_t_s is None:
            return 0.0
        return self.end_t_s - self.first_t_s

    def arm_release(self) -> None:
        """Look for the release from the next complete window on."""
        self._armed = True

    def feed(self, t0_s: float, period_s: float, forces) -> None:
        forces = np.asarray(forces, dtype=np.float64)
        if forces.size == 0:
            return
        if self.end_t_s is not None and abs(t0_s - self.end_t_s) > 0.5 * period_s:
            self.gaps.append((self.end_t_s, round((t0_s - self.end_t_s) / period_s)))
            self._carry = np.empty(0)               # never compare across a gap
            self._prev_mean = None
        if self.first_t_s is None:
            self.first_t_s = t0_s
        self.period_s = period_s
        self.samples += forces.size
        self.blocks += 1
        self.end_t_s = t0_s + forces.size * period_s
        i_peak = int(np.argmax(forces))
        if forces[i_peak] > self.peak_n:
            self.peak_n, self.peak_t_s = float(forces[i_peak]), t0_s + i_peak * period_s
        if self.ceiling_hit is None and forces[i_peak] > self.ceiling_n:
            i_hit = int(np.argmax(forces > self.ceiling_n))
            self.ceiling_hit = (t0_s + i_hit * period_s, float(forces[i_hit]))
        self._windows(t0_s, period_s, forces)

    def _windows(self, t0_s: float, period_s: float, forces: np.ndarray) -> None:
        n_win = max(1, round(self.window_s / period_s))
        if self._carry.size == 0:
            self._carry_t_s = t0_s
        data = np.concatenate([self._carry, forces])
        n_full = data.size // n_win
        if n_full == 0:
            self._carry = data
            return
        means = data[:n_full * n_win].reshape(n_full, n_win).mean(axis=1)
        self._carry = data[n_full * n_win:]
        first_window_t = self._carry_t_s
        self._carry_t_s = first_window_t + n_full * n_win * period_s
        if self._armed and self.release_t_s is None:
            previous = np.concatenate([[self._prev_mean if self._prev_mean is not None
                                        else means[0]], means[:-1]])
            jumps = np.flatnonzero(np.abs(means - previous) > self.release_jump_n)
            if jumps.size:
                self.release_t_s = first_window_t + int(jumps[0]) * n_win * period_s
        self._prev_mean = float(means[-1])
        self.latest_n = self._prev_mean
