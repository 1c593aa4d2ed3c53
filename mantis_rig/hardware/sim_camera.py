"""Simulated high-speed camera trigger: records the simulated world's markers.

Once armed, the camera's circular buffer runs: frames fall on its frame grid (k / frame rate on
the world's clock). A trigger keeps the frames from pre_trigger_s before it to post_trigger_s
after it, never earlier than the arming. The marker positions of those frames come from the
world, pixel-quantised when the scene asks (effect camera_sampling), in metres as the world
gives them (camera frame, image y down, as the tracking software writes them).
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from mantis_sim.scene import Scene
from mantis_sim.sensors import CameraSensor

from .interfaces import (
    CameraConfig,
    CameraStatus,
    CameraTrigger,
    ConfigurationError,
    DeviceError,
    MarkerFrames,
    check_camera_config,
)
from .world_port import WorldPort

MAX_RECORD_S = 1.0       # the buffer (and the simulated world's kept history) holds this much


def validate_camera_config(config: CameraConfig, max_frame_rate_hz: float) -> None:
    check_camera_config(config, max_frame_rate_hz)
    if config.pre_trigger_s + config.post_trigger_s > MAX_RECORD_S:
        raise ConfigurationError(
            f'pre_trigger_s + post_trigger_s = '
            f'{config.pre_trigger_s + config.post_trigger_s} s exceeds the camera buffer '
            f'{MAX_RECORD_S} s')


class SimCameraTrigger(CameraTrigger):
    max_frame_rate_hz = 37_000.0

    def __init__(self, port: WorldPort, scene: Scene):
        self.port = port
        self.sensor = CameraSensor(scene)
        self._open = False
        self._config: Optional[CameraConfig] = None
        self._armed_at_s: Optional[float] = None
        self._trigger_s: Optional[float] = None

    def open(self) -> None:
        self.port.now_s()
        self._open = True

    def close(self) -> None:
        self._open = False
        self._armed_at_s = None

    def arm(self, config: CameraConfig) -> None:
        if not self._open:
            raise DeviceError('cannot arm: the simulated camera is not open')
        validate_camera_config(config, self.max_frame_rate_hz)
        self._config = config
        self._armed_at_s = self.port.now_s()
        self._trigger_s = None

    def trigger(self) -> float:
        if self._armed_at_s is None:
            raise DeviceError('cannot trigger: the camera is not armed')
        if self._trigger_s is not None:
            raise DeviceError(f'the camera was already triggered at {self._trigger_s:.6f} s; '
                              f'arm it again for a new recording')
        self._trigger_s = self.port.now_s()
        return self._trigger_s

    def status(self) -> CameraStatus:
        return CameraStatus(armed=self._armed_at_s is not None,
                            triggered=self._trigger_s is not None,
                            trigger_time_s=self._trigger_s)

    def frame_timestamps(self) -> Optional[np.ndarray]:
        if self._trigger_s is None:
            return None
        config = self._config
        first_s = max(self._armed_at_s, self._trigger_s - config.pre_trigger_s)
        last_s = self._trigger_s + config.post_trigger_s
        first = math.ceil(first_s * config.frame_rate_hz)
        last = math.floor(last_s * config.frame_rate_hz)
        return np.arange(first, last + 1) / config.frame_rate_hz

    def marker_frames(self, timeout_s: float = 30.0) -> Optional[MarkerFrames]:
        """The recorded window's markers; blocks until the world has run past the window."""
        times = self.frame_timestamps()
        if times is None:
            return None
        return MarkerFrames(time_s=times,
                            markers_m=self.sensor.image(self.port.marker_frames(times, timeout_s)))
