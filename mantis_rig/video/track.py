"""Track a recording: find and name the markers in its first frame, follow them to its end,
and write the tracks in the tracker's CSV form (``mantis_sim.camera.tracker_csv``).

Positions are image pixels (x right, y down, (0, 0) the top-left pixel's centre), NaN where a
marker was not found; written in millimetres through a calibration, or as pixels without one.
"""
from __future__ import annotations

from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mantis_sim.camera.calibration import Calibration
from mantis_sim.camera.tracker_csv import TrackerCsvWriter
from mantis_sim.errors import InputError

from .follow import Follower
from .markers import find_markers, grey_frame
from .naming import Naming, name_markers, names_from_points

__all__ = ['Tracks', 'TrackingError', 'name_first_frame', 'track', 'write_tracks']


class TrackingError(InputError):
    """A recording that cannot be tracked (no frames, its markers not found), naming it."""


@dataclass
class Tracks:
    """Each marker's position (px) per frame: ``xy_px[name]`` an (n, 2) array (float32: one
    compact row a frame, memory flat in the recording's length), NaN in a gap.
    ``index``: the recording's frame numbers; ``time_s``: their times (NaN where unknown).
    ``lost``: marker -> the last frame it was seen in, for markers missing at the end."""

    index: np.ndarray
    time_s: np.ndarray
    xy_px: dict
    naming: Naming
    rate_hz: float | None = None
    source: str = ''
    lost: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return sorted(self.xy_px)

    def found_share(self) -> dict:
        """name -> share of frames it was found in."""
        return {n: float(np.mean(np.isfinite(xy[:, 0]))) for n, xy in self.xy_px.items()}


def name_first_frame(image, names: dict | None = None, where: str = 'frame') -> Naming:
    """The first frame's markers, named from the linkage, or as a person named them
    (``names``: marker -> (x, y) px, each snapped to the blob found there)."""
    grey = grey_frame(image, where)
    blobs = find_markers(grey, where=where)
    points = [(b.x_px, b.y_px) for b in blobs]
    if names:
        return names_from_points(names, points, where=where)
    return name_markers(points, [b.diameter_px for b in blobs], where=where)


def track(recording, calibration: Calibration | None = None, names: dict | None = None,
          progress: Callable[[int, int], None] | None = None, start: int = 0,
          stop: int | None = None) -> Tracks:
    """Track ``recording`` (a ``mantis_rig.video.recording.Recording``, or anything with
    ``frames()`` yielding frames with ``index``, ``time_s`` and ``image``). ``calibration`` is
    kept for writing (the tracking itself is in pixels). ``progress(done, total)`` every few
    hundred frames. A bad frame ends the tracking with the recording's error; what was tracked
    before it is lost to the caller unless it writes as it goes (:func:`write_tracks`)."""
    with _one_opencv_thread():
        return _track(recording, names, progress, start, stop)


@contextmanager
def _one_opencv_thread():
    """OpenCV on one thread while tracking: its thread pool costs more than it gains on the
    follower's small windows (measured: 15 % more CPU, 13 % more wall time on 20,000 frames
    on this 2-core machine). Restored after."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _track(recording, names, progress, start: int, stop: int | None) -> Tracks:
    follower, naming = None, None
    where = str(getattr(recording, 'path', 'recording'))
    total = _frame_total(recording, start, stop)
    # One compact row a frame, allocated for the frames announced (at most 65,536 at first: a
    # damaged header may announce billions; grown as more come): 56 bytes a frame for 5
    # markers (positions in float32: steps under 1/10,000 px in a picture of 1,024 px).
    rows = min(max(total, 1), 1 << 16)
    index = np.empty(rows, np.int64)
    time_s = np.empty(rows, np.float64)
    xy = None
    count = 0
    for k, frame in enumerate(_frames(recording, start, stop)):
        if follower is None:
            naming = name_first_frame(frame.image, names, f'{where}, frame {frame.index}')
            follower = Follower(frame.image, naming, frame.index, where)
            xy = np.empty((len(index), len(follower.names), 2), np.float32)
            found = follower.first_xy
        else:
            found = follower.step(frame.image, frame.index)
        if k == len(index):
            index, time_s, xy = (_grown(a) for a in (index, time_s, xy))
        index[k], time_s[k], xy[k] = frame.index, frame.time_s, found
        count = k + 1
        if progress is not None and (k % 500 == 0 or k + 1 == total):
            progress(k + 1, total)
    if follower is None:
        raise TrackingError(f'{where}: no frames to track')
    index, time_s, xy = index[:count], time_s[:count], xy[:count]
    xy_px = {n: xy[:, i] for i, n in enumerate(follower.names)}
    last = int(index[-1])
    lost = {n: seen for n, seen in follower.last_seen.items() if seen != last}
    return Tracks(index, time_s, xy_px, naming, getattr(recording, 'rate_hz', None), where,
                  lost)


def _grown(a: np.ndarray) -> np.ndarray:
    bigger = np.empty((2 * len(a),) + a.shape[1:], a.dtype)
    bigger[:len(a)] = a
    return bigger


def write_tracks(tracks: Tracks, path, calibration: Calibration | None = None,
                 video_name: str = '') -> Path:
    """The tracks in the tracker's CSV form: mm through ``calibration``, else pixels. Without a
    known rate, the time column holds frame numbers and the rate is written N/A, as the
    tracker does."""
    rate = tracks.rate_hz
    times = tracks.time_s
    if rate is None or not np.all(np.isfinite(times)):
        times = tracks.index.astype(float) if rate is None else tracks.index / rate
    with TrackerCsvWriter(path, tracks.names, rate, calibration,
                          video_name or Path(tracks.source).name) as out:
        # In blocks: the writer's working copies stay small, however long the recording.
        for lo in range(0, len(tracks.index), WRITE_BLOCK):
            block = slice(lo, lo + WRITE_BLOCK)
            out.write_frames(tracks.index[block], times[block],
                             {n: xy[block] for n, xy in tracks.xy_px.items()})
    return Path(path)


WRITE_BLOCK = 2048


def _frames(recording, start: int, stop: int | None):
    if hasattr(recording, 'frames'):
        try:
            return recording.frames(start, stop)
        except TypeError:
            return recording.frames()
    return iter(recording)


def _frame_total(recording, start: int, stop: int | None) -> int:
    n = getattr(recording, 'frame_count', None)
    if n is None:
        return 0
    return (n if stop is None else min(stop, n)) - start
