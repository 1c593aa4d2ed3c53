"""The tendon drive: how far the stage has pulled the tendon's far end (mm, ms).

The tendon's free length between c and d is l_free(t) = l_free(0) - pulled(t).
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from .scene import Scene


class ConstantPull:
    """The stage moves at constant speed from t = 0 (an ideal, instantaneous start)."""

    def __init__(self, speed_mm_per_ms: float):
        self.v = speed_mm_per_ms

    def pulled(self, t: float) -> tuple[float, float, float]:
        """(displacement mm, velocity mm/ms, acceleration mm/ms^2) at t ms."""
        return self.v * t, self.v, 0.0

    def breakpoints(self) -> list[float]:
        return []

    def time_to_pull(self, distance_mm: float) -> float:
        """When (ms) the stage has pulled distance_mm; inf if it never does."""
        return distance_mm / self.v if self.v > 0 else math.inf


class RampedPull:
    """Effect stage_profile: the commanded velocity ramps up at a constant acceleration, and the
    servo follows it with a first-order lag of time constant tau (the following error), so the
    actual velocity obeys tau dv/dt + v = v_cmd(t)."""

    def __init__(self, speed_mm_per_ms: float, accel_mm_per_ms2: float, tau_ms: float):
        self.v, self.a, self.tau = speed_mm_per_ms, accel_mm_per_ms2, tau_ms
        self.t_ramp = self.v / self.a if self.a > 0 else 0.0

    def pulled(self, t: float) -> tuple[float, float, float]:
        if t <= 0.0:
            return 0.0, 0.0, 0.0
        tau, tr = self.tau, self.t_ramp
        if t < tr:
            return self._ramping(t)
        # After the ramp: the state at its end, in closed form (the solver asks for t = tr
        # itself, at the breakpoint; this branch once found that state by calling pulled(tr),
        # which came back here for ever: a RecursionError whenever tau > 0).
        pos_r, vel_r, _ = self._ramping(tr) if tr > 0 else (0.0, 0.0, 0.0)
        if tau <= 0.0:
            return pos_r + self.v * (t - tr), self.v, 0.0
        decay = math.exp(-(t - tr) / tau)
        gap = vel_r - self.v
        vel = self.v + gap * decay
        pos = pos_r + self.v * (t - tr) + gap * tau * (1.0 - decay)
        return pos, vel, -gap * decay / tau

    def _ramping(self, t: float) -> tuple[float, float, float]:
        """The state at 0 <= t <= t_ramp, while the commanded velocity still ramps up."""
        a, tau = self.a, self.tau
        if tau <= 0.0:
            return 0.5 * a * t * t, a * t, a
        decay = math.exp(-t / tau)
        vel = a * (t - tau * (1.0 - decay))
        pos = a * (0.5 * t * t - tau * t + tau * tau * (1.0 - decay))
        return pos, vel, a * (1.0 - decay)

    def breakpoints(self) -> list[float]:
        return [self.t_ramp] if self.t_ramp > 0 else []

    def time_to_pull(self, distance_mm: float) -> float:
        """When (ms) the stage has pulled distance_mm (pulled(t) only grows: bisection)."""
        if self.v <= 0:
            return math.inf
        hi = max(self.t_ramp, 1.0) + self.tau + distance_mm / self.v
        while self.pulled(hi)[0] < distance_mm:
            hi *= 2.0
        # Newton on the monotonic pulled(t), kept inside a shrinking bracket (a step that would
        # leave it bisects instead), to a picosecond in a second
        lo, t = 0.0, hi
        for _ in range(200):
            x, v, _ = self.pulled(t)
            if x < distance_mm:
                lo = t
            else:
                hi = t
            step = (x - distance_mm) / v if v > 0.0 else math.inf
            after = t - step
            if not lo < after < hi:
                after = 0.5 * (lo + hi)
            if abs(after - t) <= 1e-12 * hi:
                return after
            t = after
        return hi


def make_drive(scene: Scene):
    speed = scene.drive.pull_speed_mm_per_s * 1e-3
    if scene.has('stage_profile') and speed > 0:
        return RampedPull(speed, scene.drive.acceleration_mm_per_s2 * 1e-6,
                          scene.drive.following_time_constant_ms)
    return ConstantPull(speed)


class CommandedPull:
    """The stage as the simulated rig commands it while running (mantis_sim.world).

    Commands arrive one after the other at the world's current time. A new velocity is
    reached at a constant acceleration; a stop (velocity 0) is immediate, as the controller's
    abort. A move to a position starts from rest (a moving stage stops first) and follows a
    trapezoidal profile (a triangle for a short move) that ends at rest on the target. Between
    knots the acceleration is constant.
    """

    def __init__(self, accel_mm_per_ms2: float):
        self.a = accel_mm_per_ms2
        self.knots = [(0.0, 0.0, 0.0, 0.0)]        # (t ms, pulled mm, v mm/ms, a mm/ms^2)

    def command(self, t: float, velocity_mm_per_ms: float) -> None:
        x, v, _ = self.pulled(t)
        self.knots = [k for k in self.knots if k[0] < t]
        change = velocity_mm_per_ms - v
        if velocity_mm_per_ms == 0.0 or change == 0.0 or not math.isfinite(self.a):
            self.knots.append((t, x, velocity_mm_per_ms, 0.0))
            return
        accel = math.copysign(self.a, change)
        ramp = abs(change) / self.a
        self.knots.append((t, x, v, accel))
        self.knots.append((t + ramp, x + v * ramp + 0.5 * accel * ramp * ramp,
                           velocity_mm_per_ms, 0.0))

    def move_to(self, t: float, target_mm: float, speed_mm_per_ms: float) -> None:
        x = self.pulled(t)[0]
        self.knots = [k for k in self.knots if k[0] < t]
        distance, sign = abs(target_mm - x), math.copysign(1.0, target_mm - x)
        if distance == 0.0 or speed_mm_per_ms <= 0.0:
            self.knots.append((t, x, 0.0, 0.0))
            return
        if not math.isfinite(self.a):
            self.knots += [(t, x, sign * speed_mm_per_ms, 0.0),
                           (t + distance / speed_mm_per_ms, target_mm, 0.0, 0.0)]
            return
        a, v = self.a, min(speed_mm_per_ms, math.sqrt(distance * self.a))
        ramp, ramp_mm = v / a, 0.5 * v * v / a
        cruise = (distance - 2.0 * ramp_mm) / v
        self.knots += [(t, x, 0.0, sign * a),
                       (t + ramp, x + sign * ramp_mm, sign * v, 0.0),
                       (t + ramp + cruise, target_mm - sign * ramp_mm, sign * v, -sign * a),
                       (t + 2.0 * ramp + cruise, target_mm, 0.0, 0.0)]

    def pulled(self, t: float) -> tuple[float, float, float]:
        if t <= 0.0:
            return 0.0, 0.0, 0.0
        i = bisect.bisect_right(self.knots, t, key=lambda k: k[0]) - 1
        t0, x, v, a = self.knots[i]
        dt = t - t0
        return x + v * dt + 0.5 * a * dt * dt, v + a * dt, a

    def pulled_mm(self, times_ms: np.ndarray) -> np.ndarray:
        """The pulled distance (mm) at each of many times (ms): pulled()[0], vectorised for
        the load cell's stream, which asks for every sample while the world holds still."""
        knots = np.asarray(self.knots)
        i = np.searchsorted(knots[:, 0], times_ms, side='right') - 1
        t0, x, v, a = knots[np.maximum(i, 0)].T
        dt = times_ms - t0
        return np.where(times_ms <= 0.0, 0.0, x + v * dt + 0.5 * a * dt * dt)

    def breakpoints(self) -> list[float]:
        return [k[0] for k in self.knots[1:]]
