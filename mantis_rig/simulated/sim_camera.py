"""Simulated high-speed camera trigger: records the simulated world's markers.

Once armed, the camera's circular buffer runs: frames fall on its frame grid (k / frame rate on
the world's clock). A trigger keeps the frames from pre_trigger_s before it to post_trigger_s
after it, never earlier than the arming. The marker positions of those frames come from the
world, pixel-quantised when the scene asks (effect camera_sampling), in metres as the world
gives them (camera frame, image y down, as the tracking software writes them).

The simulated camera also films, when asked (``film``; docs/simulated_rig.md, "Filming"): the
same recorded window, frame for frame, rendered as the rig's camera films it
(mantis_sim.camera.render) into a folder that appears whole or not at all. What a film needs
of the world is taken at once (``take``: the poses on a fine grid), since the world forgets
and runs on while a film renders.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import math
import os
from pathlib import Path
import shutil
from typing import Optional

import numpy as np

from mantis_rig.hardware.device_interfaces import (
    CameraConfig,
    CameraStatus,
    CameraTrigger,
    ConfigurationError,
    DeviceError,
    FilmError,
    MarkerFrames,
    check_camera_config,
)
from mantis_rig.simulated.world_port import WorldPort
from mantis_sim.durable_files import fsync_dir
from mantis_sim.scene import Scene
from mantis_sim.sensors import CameraSensor

MAX_RECORD_S = 1.0       # the buffer (and the simulated world's kept history) holds this much
FILM_FORMAT = 'cine'     # a .cine states its rate and each frame's time from the trigger
FILM_TMP_SUFFIX = '.tmp'
#: the poses a film renders from are taken finer than a frame where a point moves more than
#: this from one frame to the next (mantis_sim.camera.recorded_pose.record_frames)
FILM_TOLERANCE_PX = 0.002


@dataclass(frozen=True)
class FilmTake:
    """What a film of one recording needs, taken from the world at once: the poses on a fine
    grid, the frame grid (frame 0: the first frame at or after the trigger, as a camera
    numbers them) and the recorded window's first and last frame times (world seconds)."""

    pose: object                   # a mantis_sim.camera.recorded_pose.RecordedPose
    rate_hz: float
    trigger_frame_s: float
    first_s: float
    last_s: float

    @property
    def frame_count(self) -> int:
        return round((self.last_s - self.first_s) * self.rate_hz) + 1


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
        self.scene = scene
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

    # ------------------------------------------------------------------ filming
    def take(self, timeout_s: float = 30.0) -> Optional[FilmTake]:
        """What a film of the recorded window needs, taken from the world now (None before a
        trigger); blocks until the world has run one frame past the window."""
        times = self.frame_timestamps()
        if times is None or len(times) == 0:
            return None
        rate = self._config.frame_rate_hz
        first_s, last_s = float(times[0]), float(times[-1])
        pose = self.port.record_frames(times, FILM_TOLERANCE_PX * self.scene.camera.pixel_mm,
                                       timeout_s)
        trigger_frame_s = math.ceil(self._trigger_s * rate - 1e-9) / rate
        return FilmTake(pose, rate, trigger_frame_s, first_s, last_s)

    def film(self, out_dir, take: Optional[FilmTake] = None, seed: int = 0,
             video_format: str = FILM_FORMAT, progress=None, timeout_s: float = 30.0):
        """Film the recorded window (``take``, or one taken now) into the folder ``out_dir``:
        ``video.cine`` (its rate and each frame's time from the trigger in it), or
        ``video.avi`` with ``video_format`` 'avi' / 'avi-raw', beside ``calibration.yaml``
        and ``truth.csv`` (mantis_sim.camera.render.film). The same frames as the marker
        frames, at the armed rate; pixels of the scene's ``camera.pixel_mm``; the look of the
        medium the robot struck in. Rendered into ``.<name>.tmp`` beside it, renamed to
        ``out_dir`` once whole: a reader sees the whole film or none. Returns the FilmResult
        (paths in ``out_dir``); FilmError says why it could not."""
        from mantis_sim.camera.render import CameraSetup, film
        out_dir = Path(out_dir)
        if out_dir.exists():
            raise FilmError(f'cannot film into {out_dir}: it exists already')
        take = take if take is not None else self.take(timeout_s)
        if take is None:
            raise FilmError('nothing to film: the camera has not been triggered')
        medium = take.pose.medium if take.pose.medium in ('air', 'water') else 'air'
        setup = CameraSetup(rate_hz=take.rate_hz,
                            scale_px_per_mm=1.0 / self.scene.camera.pixel_mm,
                            seed=seed).in_medium(medium)
        tmp = out_dir.with_name(f'.{out_dir.name}{FILM_TMP_SUFFIX}')
        half = 0.25 / take.rate_hz          # the window's own frames, none more (float rounding)
        try:
            shutil.rmtree(tmp, ignore_errors=True)
            result = film(take.pose, tmp, take.trigger_frame_s, take.first_s - half,
                          take.last_s + half, setup, video_format, progress=progress)
            _sync_tree(tmp)
            os.replace(tmp, out_dir)
            fsync_dir(out_dir.parent)
        except (OSError, ValueError, RuntimeError) as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise FilmError(f'filming into {out_dir}: {exc}') from exc
        if result.frame_count != take.frame_count:
            raise FilmError(f'filmed {result.frame_count} frames of a recording of '
                            f'{take.frame_count}')
        return replace(result, video=out_dir / result.video.name,
                       calibration=out_dir / result.calibration.name,
                       truth=out_dir / result.truth.name)


def _sync_tree(folder: Path) -> None:
    """Every file in ``folder`` on disk, and the folder's entries."""
    for path in folder.iterdir():
        if path.is_file():
            with open(path, 'rb') as handle:
                os.fsync(handle.fileno())
    fsync_dir(folder)

