"""A trial bag (rosbag2/MCAP), read into a :class:`~.base.TrialInput`: MarkerTracks (mm) and
the tendon force samples.

The marker frames come from the contract's ``camera/markers`` (marker blocks, metres, camera
frame; see :mod:`mantis_rig.recording.marker_block`), converted to millimetres here (the one
conversion between the bag and the analysis), the force from ``loadcell/force_block`` (force
blocks, see :mod:`mantis_rig.recording.force_block`), each in the namespace the bag was
recorded in (``/camera/markers``, or ``/rig2/camera/markers`` for a rig under ``/rig2``).
Both carry times on the trial's clock, so the force is used for the tendon's work only where
its time span overlaps the frames'.

The camera frame's orientation is the bag's: ``trial_conditions`` ``handedness`` ('left', the
tracker's and the simulated camera's convention, where the bag states none) and ``tilt_deg``
(absent: not stated, the analysis finds it from the markers), as ``mantis import-tracking``
writes them from the export's calibration.

A damaged bag (cut short, corrupted) is read up to the damage: :attr:`TrialInput.problems`
says what was wrong and :attr:`TrialInput.truncated` is set; whether the frames before the
damage suffice is for the analysis to decide.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from ...contract import FORCE_BLOCK, MARKERS, bag_namespace, resolve
from ...recording import BagError, BagReader, TruncatedBagWarning
from ...recording.force_block import force_block_from_msg
from ...recording.marker_block import concatenate, marker_block_from_msg
from .base import HANDEDNESS, MarkerTracks, TrackFormatError, TrialInput

_MM_PER_M = 1000.0


def _frame_numbers(time_s: np.ndarray) -> np.ndarray:
    """Frame indices from the times (blocks carry no frame numbers): a gap of k frame periods
    between two frames counts k, so dropped frames stay dropped."""
    steps = np.diff(time_s)
    if steps.size == 0 or not np.median(steps) > 0:
        return np.arange(len(time_s), dtype=np.int64)
    with np.errstate(over='ignore', invalid='ignore'):
        periods = np.round(steps / np.median(steps))
    if not np.all(np.isfinite(periods)) or np.max(periods) > 2.0 ** 40:
        # damaged times (non-finite, or a jump no recording spans): the tracks' own check
        # names them; a frame count would only overflow here
        return np.arange(len(time_s), dtype=np.int64)
    counts = np.maximum(1, periods).astype(np.int64)
    return np.concatenate([[0], np.cumsum(counts)])


def read_trial_bag(path) -> TrialInput:
    """Marker tracks and force samples of the bag at ``path`` (BagError if unreadable).

    TrackFormatError if the bag holds no usable marker frames (the message names why).
    """
    reader = BagReader(path, warn=False)
    namespace = bag_namespace(reader.topics)
    markers_topic, force_topic = resolve(MARKERS, namespace), resolve(FORCE_BLOCK, namespace)
    marker_blocks, force_blocks = [], []
    with warnings.catch_warnings():  # damage found while reading lands in reader.problems
        warnings.simplefilter('ignore', TruncatedBagWarning)
        for topic, _, log_time_ns, msg in reader.messages([markers_topic, force_topic]):
            try:
                if topic == markers_topic:
                    marker_blocks.append(marker_block_from_msg(msg))
                else:
                    force_blocks.append(force_block_from_msg(msg))
            except (ValueError, IndexError, OverflowError) as exc:
                raise BagError(f'{path}: a malformed block on {topic} at log time '
                               f'{log_time_ns * 1e-9:.6f} s: {exc}') from exc
    problems = list(reader.problems)
    if not marker_blocks:
        has = markers_topic in reader.topics
        why = 'no complete message before the damage' if has and problems else \
            'no messages' if has else 'no such topic'
        raise TrackFormatError(
            f'{path}: no marker frames on {markers_topic} ({why}; topics: '
            f'{sorted(reader.topics)})' + (f'; bag problems: {"; ".join(problems)}'
                                           if problems else ''))
    try:
        frames = concatenate(marker_blocks)
    except (ValueError, IndexError) as exc:
        raise BagError(f'{path}: the marker blocks on {markers_topic} do not fit together: '
                       f'{exc}') from exc
    order = np.argsort(frames.time_s, kind='stable')
    time_s = frames.time_s[order]
    conditions = reader.metadata('trial_conditions') or {}
    tracks = MarkerTracks(
        time_s=time_s, frames=_frame_numbers(time_s),
        markers_mm={name: xy[order] * _MM_PER_M for name, xy in frames.markers_m.items()},
        **_camera_frame(conditions, path),
        source={'path': str(path), 'format': 'bag', 'topic': markers_topic, **conditions})
    tracks.validate()
    force_t, force = _force_samples(force_blocks, time_s)
    return TrialInput(tracks=tracks, force_time_s=force_t, force_N=force, problems=problems,
                      truncated=bool(problems),
                      conditions=dict(conditions))


def _camera_frame(conditions: dict, path) -> dict:
    """The tracks' handedness, tilt and frame rate as the bag's trial conditions state them
    (``tilt_deg``; ``source_calibration_tilt_deg`` in bags imported before it was written
    apart); TrackFormatError naming a value that does not read as one."""
    handedness = str(conditions.get('handedness', 'left')).strip().lower()
    if handedness not in HANDEDNESS:
        raise TrackFormatError(f'{path}: trial condition handedness {handedness!r}: expected '
                               f'one of {HANDEDNESS}')
    tilt = conditions.get('tilt_deg', conditions.get('source_calibration_tilt_deg'))
    tilt_deg = _number(tilt)
    if tilt not in (None, '') and tilt_deg is None:
        raise TrackFormatError(f'{path}: trial condition tilt_deg {tilt!r} is not a finite '
                               'angle')
    rate = _number(conditions.get('frame_rate_hz'))      # else the frames' median step
    return {'handedness': handedness, 'tilt_deg': tilt_deg,
            'frame_rate_hz': rate if rate is not None and rate > 0 else None}


def _number(value) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _force_samples(blocks, frame_time_s):
    """Concatenated (time s, force N) of the blocks if they overlap the frames, else Nones."""
    if not blocks:
        return None, None
    times = np.concatenate([b.t0_s + np.arange(len(b.force_n)) * b.period_s for b in blocks])
    forces = np.concatenate([b.force_n for b in blocks])
    order = np.argsort(times, kind='stable')
    times, forces = times[order], forces[order]
    if times[-1] < frame_time_s[0] or times[0] > frame_time_s[-1]:
        return None, None
    return times, forces
