"""A recording tracked into the tracker's CSV form, what `mantis track` does and what the
analysis and a study's `attach` take a video through: open it, track it with a progress line,
write the tracks, and keep them when the recording turns out damaged part-way (the frames
tracked before the damage are written, then the damage is reported).

The calibration: a YAML file given (``--calibration``), else ``calibration.yaml`` beside the
recording (the simulated camera writes one), else a scale from a known distance between two
named markers on the first frame (``--marker-distance mb1,mb2=10.3``), else none: the tracks
are then in image pixels.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math
from pathlib import Path
import sys
from typing import Optional, TextIO

import numpy as np

from mantis_rig.video.recording_error import RecordingError
from mantis_sim.camera.calibration import Calibration, CalibrationError, load_calibration

from .recording import open_recording
from .stills import PICTURE_SUFFIXES
from .track import Tracks, track, write_tracks

BESIDE = 'calibration.yaml'
RECORDING_SUFFIXES = ('.cine', '.avi') + PICTURE_SUFFIXES


def is_recording(path) -> bool:
    """A recording this tracks: a .cine, an .avi, a picture, or a folder of pictures that is
    not a bag (no .mcap in it)."""
    path = Path(path)
    if path.is_dir():
        return not any(path.glob('*.mcap')) and any(
            p.suffix.lower() in PICTURE_SUFFIXES for p in path.iterdir())
    return path.suffix.lower() in RECORDING_SUFFIXES


@dataclass
class TrackedVideo:
    """What tracking one recording gave: the CSV written, its tracks, the calibration used and
    where it came from, the recording's rate and where that came from, and the damage that
    ended it early ('' when none)."""
    csv: Path
    tracks: Tracks
    calibration: Optional[Calibration]
    calibration_source: str
    rate_hz: Optional[float]
    rate_source: str
    damage: str = ''


class _UpToDamage:
    """A recording whose frames end, cleanly, at the first damaged one (kept in ``damage``)."""

    def __init__(self, recording):
        self.recording, self.damage = recording, ''
        self.path = recording.path
        self.rate_hz = recording.rate_hz
        self.frame_count = recording.frame_count

    def frames(self, start: int = 0, stop: Optional[int] = None):
        try:
            yield from self.recording.frames(start, stop)
        except RecordingError as exc:
            self.damage = str(exc)


def find_calibration(video: Path, given: Optional[Path]) -> tuple[Optional[Calibration], str]:
    """(the calibration, where it came from in words) for a recording (module docstring)."""
    if given is not None:
        return load_calibration(given), str(given)
    beside = (video if video.is_dir() else video.parent) / BESIDE
    if beside.is_file():
        return load_calibration(beside), f'{beside} (beside the recording)'
    return None, 'none: image pixels'


def parse_marker_distance(text: str) -> tuple[str, str, float]:
    """'mb1,mb2=10.3' -> ('mb1', 'mb2', 10.3 mm)."""
    pair, sep, value = text.partition('=')
    names = [n.strip() for n in pair.split(',')]
    try:
        distance_mm = float(value)
    except ValueError:
        distance_mm = math.nan
    if not sep or len(names) != 2 or not all(names) or not math.isfinite(distance_mm) \
            or distance_mm <= 0:
        raise CalibrationError(f'--marker-distance {text!r}: expected A,B=MM, two markers and '
                               f'their distance in millimetres, e.g. mb1,mb2=10.3')
    return names[0], names[1], distance_mm


def calibration_from_distance(tracks: Tracks, text: str) -> Calibration:
    """The scale from two markers' distance on the first frame both were found in."""
    a, b, distance_mm = parse_marker_distance(text)
    for name in (a, b):
        if name not in tracks.xy_px:
            raise CalibrationError(f'--marker-distance {text!r}: no marker {name} was tracked '
                                   f'(found: {", ".join(tracks.names)})')
    both = np.isfinite(tracks.xy_px[a][:, 0]) & np.isfinite(tracks.xy_px[b][:, 0])
    if not both.any():
        raise CalibrationError(f'--marker-distance {text!r}: {a} and {b} were never found in '
                               'one frame')
    k = int(np.argmax(both))
    return Calibration.from_marker_distance(tracks.xy_px[a][k], tracks.xy_px[b][k], distance_mm)


def track_to_csv(video, out, calibration_path=None, rate_hz: Optional[float] = None,
                 names: Optional[dict] = None, marker_distance: Optional[str] = None,
                 progress: Optional[Callable[[int, int], None]] = None) -> TrackedVideo:
    """Track ``video`` into the CSV ``out`` (module docstring). Damage part-way is in the
    result's ``damage``, the tracks before it written."""
    video, out = Path(video), Path(out)
    calibration, source = find_calibration(video, calibration_path)
    with open_recording(video, rate_hz) as recording:
        frames = _UpToDamage(recording)
        tracks = track(frames, calibration, names, progress)
    if marker_distance:
        calibration = calibration_from_distance(tracks, marker_distance)
        source = f'--marker-distance {marker_distance}'
    write_tracks(tracks, out, calibration, video.name)
    return TrackedVideo(out, tracks, calibration, source, recording.rate_hz,
                        recording.rate_source, frames.damage)


class ProgressLine:
    """A progress bar on a terminal (``\\rtrack: [#####     ] 5000/20000 frames``); on anything
    else (a log, a pipe) a line at each tenth."""

    def __init__(self, label: str, stream: Optional[TextIO] = None, width: int = 24):
        self.label, self.width = label, width
        self.stream = stream if stream is not None else sys.stderr
        try:
            self.tty = self.stream.isatty()
        except (AttributeError, ValueError):
            self.tty = False
        self._tenth = -1

    def __call__(self, done: int, total: int) -> None:
        if total <= 0:
            return
        if self.tty:
            filled = round(self.width * done / total)
            self.stream.write(f'\r{self.label}: [{"#" * filled}{" " * (self.width - filled)}] '
                              f'{done}/{total} frames' + ('\n' if done >= total else ''))
        else:
            tenth = 10 * done // total
            if tenth == self._tenth:
                return
            self._tenth = tenth
            self.stream.write(f'{self.label}: {done}/{total} frames\n')
        self.stream.flush()


__all__ = ['BESIDE', 'ProgressLine', 'RECORDING_SUFFIXES', 'TrackedVideo',
           'calibration_from_distance', 'find_calibration', 'is_recording',
           'parse_marker_distance', 'track_to_csv']
