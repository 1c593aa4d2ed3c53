"""What every input becomes: :class:`MarkerTracks`, the analysis's one type of marker data
(millimetres in the tracker's camera frame, with the frame's orientation (handedness, tilt), the
frame rate and the unit the numbers came in as fields), and :class:`TrialInput`, a trial as read
(its tracks, the tendon force if recorded, its conditions, the damage found); the readers' one
error, :class:`TrackFormatError`.

Every source becomes one: the tracker's exports (:mod:`.tracker_export`), the project's CSV
(:mod:`.project_csv`), a trial bag (:mod:`.bag`: its marker blocks are metres, converted there
once) and the simulated camera study. ``docs/data_path.md`` has the layers and units.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mantis_sim.errors import InputError

MIN_FRAMES = 50
# No camera of the rig sees a marker 100 m from its origin: a bigger coordinate is a damaged
# cell (read as a position, it would wreck every fit), not a position.
MAX_COORDINATE_MM = 1e5
HANDEDNESS = ('left', 'right')
#: The tracker writes a lost marker as (-1, -1).
LOST_MARKER = -1.0


class TrackFormatError(InputError):
    """A tracking file does not have a layout the readers accept, or contradicts itself (the
    readers' one error for bad tracking files)."""


@dataclass
class MarkerTracks:
    """Marker positions over time: millimetres in the tracker's camera frame.

    The frame is the tracker's, as its calibration states it: ``handedness`` 'left' (image y
    down, the lab's exports) or 'right' (y up); ``tilt_deg`` the calibration's tilt, the
    tracker's axes turned against the image (None where nothing states it, a header-less CSV:
    the analysis then finds the robot's frame from the markers and sets ``tilt_inferred``).
    ``frame_rate_hz``: the frame rate the source states or implies (None if unknown);
    ``length_unit``: the unit the source's numbers were in, converted to mm here (None: not
    stated, millimetres assumed). ``source``:
    provenance (path, format, the export's header block), free-form.
    """

    time_s: np.ndarray
    frames: np.ndarray
    markers_mm: dict[str, np.ndarray]
    handedness: str = 'left'
    tilt_deg: float | None = None
    source: dict = field(default_factory=dict)
    frame_rate_hz: float | None = None
    length_unit: str | None = None
    tilt_inferred: bool = False

    @property
    def body_markers(self) -> list[str]:
        return sorted(n for n in self.markers_mm if n.startswith('mb'))

    @property
    def arm_markers(self) -> list[str]:
        return sorted(n for n in self.markers_mm if n.startswith('ma'))

    @property
    def n_frames(self) -> int:
        return len(self.time_s)

    def validate(self) -> None:
        """Raise TrackFormatError unless the tracks can be analysed."""
        if self.handedness not in HANDEDNESS:
            raise TrackFormatError(f'handedness {self.handedness!r}: expected one of '
                                   f'{HANDEDNESS}')
        if self.tilt_deg is not None and not np.isfinite(self.tilt_deg):
            raise TrackFormatError(f'tilt {self.tilt_deg} degrees is not a finite angle')
        if self.n_frames < MIN_FRAMES:
            raise TrackFormatError(
                f'too few frames: {self.n_frames} (need at least {MIN_FRAMES})')
        if len(self.body_markers) < 2:
            raise TrackFormatError(
                f'need at least 2 body markers (mb*), found {self.body_markers}')
        if len(self.arm_markers) < 2:
            raise TrackFormatError(
                f'need at least 2 arm markers (ma*), found {self.arm_markers}')
        if not np.all(np.isfinite(self.time_s)):
            bad = int(np.nonzero(~np.isfinite(self.time_s))[0][0])
            raise TrackFormatError(f'time of frame {bad} is not a finite number')
        if np.any(np.diff(self.time_s) <= 0):
            bad = int(np.nonzero(np.diff(self.time_s) <= 0)[0][0])
            raise TrackFormatError(f'time must increase strictly: frame {bad + 1} is not after '
                                   f'frame {bad}')
        for name, xy in self.markers_mm.items():
            if xy.shape != (self.n_frames, 2):
                raise TrackFormatError(f'marker {name}: shape {xy.shape}, expected (n, 2)')
            beyond = np.nonzero(np.abs(np.nan_to_num(xy)) > MAX_COORDINATE_MM)[0]
            if beyond.size:
                frame = int(beyond[0])
                raise TrackFormatError(
                    f'marker {name} in frame {frame} (t = {self.time_s[frame]:.6f} s) is at '
                    f'{xy[frame].tolist()} mm, beyond any camera\'s field (|x|, |y| up to '
                    f'{MAX_COORDINATE_MM:g} mm)')


def frame_numbers(frames: np.ndarray, fname: str) -> np.ndarray:
    """A frame column as integers; TrackFormatError for a non-finite or huge value."""
    if not np.all(np.isfinite(frames)) or np.any(np.abs(frames) > 2 ** 53):
        raise TrackFormatError(f'{fname}: the frame column holds a non-finite or huge value')
    return frames.astype(np.int64)


def lost_as_gaps(xy: np.ndarray) -> np.ndarray:
    """(n, 2) positions with every lost frame NaN in both coordinates: the tracker's (-1, -1),
    a blank or a non-finite cell."""
    xy = np.array(xy, float)
    xy[np.all(xy == LOST_MARKER, axis=1) | np.any(~np.isfinite(xy), axis=1)] = np.nan
    return xy


@dataclass
class TrialInput:
    """What the analysis needs from a trial, and how complete it was: the tracks, the tendon
    force where the trial recorded it (a bag), what was wrong with a damaged input (read up to
    the damage: ``truncated``), and the trial's conditions as recorded."""

    tracks: MarkerTracks
    force_time_s: np.ndarray | None = None
    force_N: np.ndarray | None = None
    problems: list = field(default_factory=list)
    truncated: bool = False
    conditions: dict = field(default_factory=dict)
