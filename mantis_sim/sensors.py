"""What the rig's sensors make of the true signals (no ROS).

Effects, each applied only when the scene names it:
- loadcell_dynamics: the load cell and its amplifier low-pass the force (first order at
  loadcell.bandwidth_hz), add white noise (loadcell.noise_N rms), and the ADC quantises the
  amplifier's voltage to loadcell.adc_bits over +/- loadcell.adc_range_V (clipping beyond).
- camera_sampling: marker positions as the tracker reports them: white tracking noise
  (camera.tracking_noise_px rms), then rounded to the tracker's sub-pixel step
  (camera.tracker_resolution_px of camera.pixel_mm).
Without an effect the sensor passes the truth through. Noise is reproducible from a seed.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from .scene import Scene


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
        self._state = None
        self._rng = np.random.default_rng(seed)

    def measure_volts(self, force_N: np.ndarray) -> np.ndarray:
        """The ADC reading, in volts, of these true forces."""
        force_N = np.asarray(force_N, dtype=float)
        if not self.enabled:
            return force_N / self.newtons_per_volt
        if self._state is None:                  # start settled on the first sample
            self._state = np.array([self._pole * force_N[0]]) if force_N.size else None
        if force_N.size:
            filtered, self._state = lfilter([1.0 - self._pole], [1.0, -self._pole], force_N,
                                            zi=self._state)
        else:
            filtered = force_N
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
