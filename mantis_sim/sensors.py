"""What the rig's sensors make of the true signals (no ROS).

Effects, each applied only when the scene names it:
- loadcell_dynamics: the load cell and its amplifier low-pass the force (first order at
  loadcell.bandwidth_hz), add white noise (loadcell.noise_N rms), and the ADC quantises the
  amplifier's voltage to loadcell.adc_bits over +/- loadcell.adc_range_V (clipping beyond).
- camera_sampling: marker positions as the tracker reports them: white tracking noise
  (camera.tracking_noise_px rms), then rounded to the tracker's sub-pixel step
  (camera.tracker_resolution_px of camera.pixel_mm).
Without an effect the sensor passes the truth through. Noise is reproducible from a seed.
Units: SI (s, m, N, V), as the World's API gives the truth (docs/data_path.md).
"""
from __future__ import annotations

import math

import numpy as np

from .scene import Scene


def first_order_lowpass(x: np.ndarray, pole: float, previous: float) -> np.ndarray:
    """y[n] = pole y[n-1] + (1 - pole) x[n] from y[-1] = ``previous`` (scipy.signal.lfilter
    with b = [1 - pole], a = [1, -pole]). Written out because importing scipy.signal costs a
    simulated trial more CPU than this loop over all its 20 kS/s (bench/bench_trial.py)."""
    gain, y, out = 1.0 - pole, previous, []
    append = out.append
    for value in x.tolist():
        y = pole * y + gain * value
        append(y)
    return np.array(out)


class LoadCellSensor:
    """Streaming: feed consecutive blocks of true force; the filter state carries over."""

    def __init__(self, scene: Scene, sample_rate_hz: float, seed: int = 0):
        cell = scene.loadcell
        self.enabled = scene.has('loadcell_dynamics')
        self.newtons_per_volt = cell.newtons_per_volt
        self.range_V = cell.adc_range_V
        self.lsb_V = 2.0 * cell.adc_range_V / 2 ** cell.adc_bits
        self.noise_N = cell.noise_N
        # Exact discretisation of tau dy/dt + y = x for a held input.
        self._pole = math.exp(-2.0 * math.pi * cell.bandwidth_hz / sample_rate_hz)
        self._previous = None                   # the filter's last output, N
        self._rng = np.random.default_rng(seed)

    def measure_volts(self, force_N: np.ndarray) -> np.ndarray:
        """The ADC reading, in volts, of these true forces."""
        force_N = np.asarray(force_N, dtype=float)
        if not self.enabled:
            return force_N / self.newtons_per_volt
        if not force_N.size:
            filtered = force_N
        else:
            if self._previous is None:               # start settled on the first sample
                self._previous = float(force_N[0])
            filtered = first_order_lowpass(force_N, self._pole, self._previous)
            self._previous = float(filtered[-1])
        noisy = filtered + self._rng.normal(0.0, self.noise_N, filtered.size)
        volts = np.clip(noisy / self.newtons_per_volt, -self.range_V, self.range_V)
        return np.round(volts / self.lsb_V) * self.lsb_V


class CameraSensor:
    def __init__(self, scene: Scene, seed: int = 0):
        cam = scene.camera
        self.enabled = scene.has('camera_sampling')
        self.step_m = cam.pixel_mm * cam.tracker_resolution_px * 1e-3
        self.noise_m = cam.pixel_mm * cam.tracking_noise_px * 1e-3
        self._rng = np.random.default_rng(seed)

    def image(self, markers_m: dict) -> dict:
        """Marker positions as the tracking software reports them (m)."""
        if not self.enabled:
            return markers_m
        out = {}
        for name, xy in markers_m.items():
            xy = np.asarray(xy, float)
            if self.noise_m > 0.0:
                xy = xy + self._rng.normal(0.0, self.noise_m, xy.shape)
            out[name] = np.round(xy / self.step_m) * self.step_m
        return out
