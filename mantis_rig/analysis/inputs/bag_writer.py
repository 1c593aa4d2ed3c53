"""Write imported marker tracks (and the angles derived from them) into a trial bag: the way
back of :mod:`.bag` (millimetres to metres here), for ``mantis import-tracking``.

The bag carries what the camera node records, so one analysis path serves simulated, rig and
imported trials:

* ``/camera/markers``: marker blocks (std_msgs/Float64MultiArray, metres, camera frame,
  ``time_s`` as in the file), :data:`~mantis_rig.recording.marker_block.FRAMES_PER_BLOCK`
  frames per message, each logged at the time of its last frame;
* ``/analysis/joint_angles``: sensor_msgs/JointState, one per frame, names
  ``['theta1', 'theta3']``: the model's body angle θ1 and the arm angle θ3 relative to the body
  (rad, smoothed) and their rates (rad/s), as :func:`~mantis_rig.analysis.analyze_tracks`
  derives them (pivot fit from the marker arcs, zero-phase adaptive smoothing);
* metadata ``trial_conditions`` (source file, format, the file's header block, the camera
  frame's ``handedness`` and ``tilt_deg`` (left out where the file states no tilt), the frame
  rate, and the d_t and contact angle the user states for the trial), which
  :mod:`.bag` reads back, and
  ``tracking_fit`` (fitted body pivot in the tracker's frame as recorded, and L1).

Log times (and JointState stamps) are the file's times shifted so none is negative:
``t_log = t - min(0, t_first)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from ...contract import JOINT_ANGLES, MARKERS, resolve
from ...recording import TRIAL_CONDITIONS, BagWriter
from ...recording.marker_block import FRAMES_PER_BLOCK, marker_block_to_msg
from .base import MarkerTracks

if TYPE_CHECKING:              # the analysis's result, written; the inputs do not import it
    from ..pipeline import TrialAnalysis

MARKERS_TOPIC = resolve(MARKERS)          # an imported trial's bag: the root namespace
ANGLES_TOPIC = resolve(JOINT_ANGLES)
ANGLE_NAMES = ['theta1', 'theta3']
FIT_RECORD = 'tracking_fit'
_M_PER_MM = 1e-3


@dataclass
class ImportReport:
    output: Path
    frames: int
    marker_messages: int
    angle_messages: int
    time_origin_s: float

    def __str__(self):
        return (f'wrote {self.output}: {self.frames} frames in {self.marker_messages} '
                f'{MARKERS_TOPIC} messages, {self.angle_messages} {ANGLES_TOPIC} messages')


def _conditions(tracks: MarkerTracks, origin_s: float) -> dict:
    source = dict(tracks.source)
    rate = tracks.frame_rate_hz or 1.0 / float(np.median(np.diff(tracks.time_s)))
    record = {'source_file': str(Path(source.pop('path', '')).resolve()),
              'source_format': source.pop('format', 'unknown'),
              'frames': tracks.n_frames,
              'frame_rate_hz': f'{rate:.6g}',
              'markers': ','.join(tracks.markers_mm),
              'handedness': tracks.handedness,
              'time_origin_s': repr(origin_s)}
    if tracks.length_unit is not None:
        record['source_length_unit'] = tracks.length_unit
    if tracks.tilt_deg is not None:
        record['tilt_deg'] = repr(float(tracks.tilt_deg))
    record.update({f'source_{key}'.replace(' ', '_'): value for key, value in source.items()
                   if isinstance(value, (str, int, float))})
    return record


def write_tracking_bag(tracks: MarkerTracks, output, analysis: TrialAnalysis | None = None,
                       frames_per_block: int = FRAMES_PER_BLOCK,
                       conditions: dict | None = None) -> ImportReport:
    """Write ``tracks`` (and ``analysis``'s angles, if given) as a new bag at ``output``.

    ``conditions``: trial conditions the file does not carry (d_t_mm, contact_angle_deg),
    stated by the user; they join ``trial_conditions`` so that analysing the bag uses them.
    """
    origin_s = min(0.0, float(tracks.time_s[0]))
    log_ns = _log_ns(tracks.time_s, origin_s)
    n_blocks = n_angles = 0
    with BagWriter(output, sync_period_s=0) as bag:
        bag.add_topic(MARKERS_TOPIC, 'std_msgs/msg/Float64MultiArray')
        if analysis is not None:
            bag.add_topic(ANGLES_TOPIC, 'sensor_msgs/msg/JointState')
        bag.add_metadata(TRIAL_CONDITIONS, {**_conditions(tracks, origin_s),
                                             **{k: str(v) for k, v in (conditions or {}).items()}})
        if analysis is not None and analysis.linkage is not None:
            x, y = (float(v) for v in analysis.linkage.body_pivot_mm)
            bag.add_metadata(FIT_RECORD, {'body_pivot_x_mm': repr(x), 'body_pivot_y_mm': repr(y),
                                          'body_pivot_frame': 'tracker',
                                          'L1_mm': repr(analysis.L1_mm),
                                          'angles_topic': ANGLES_TOPIC})
        for start in range(0, tracks.n_frames, frames_per_block):
            stop = min(start + frames_per_block, tracks.n_frames)
            if analysis is not None:
                n_angles += _write_angles(bag, analysis, origin_s, tracks.time_s[start],
                                          tracks.time_s[stop - 1])
            block = marker_block_to_msg(
                tracks.time_s[start:stop],
                {name: xy[start:stop] * _M_PER_MM for name, xy in tracks.markers_mm.items()})
            bag.write(MARKERS_TOPIC, block, int(log_ns[stop - 1]))
            n_blocks += 1
    return ImportReport(Path(output), tracks.n_frames, n_blocks, n_angles, origin_s)


def _log_ns(time_s: np.ndarray, origin_s: float) -> np.ndarray:
    return np.round((time_s - origin_s) * 1e9).astype(np.int64)


def _write_angles(bag, a: TrialAnalysis, origin_s: float, first_s: float, last_s: float) -> int:
    """The angles of the analysed frames from first_s to last_s (the frames of one marker
    block). The analysis has no angles for the frames in gaps (too few markers tracked): its
    own times say which frames it has, not their index among the file's."""
    start = int(np.searchsorted(a.time_s, first_s, side='left'))
    stop = int(np.searchsorted(a.time_s, last_s, side='right'))
    msg = JointState(name=ANGLE_NAMES)
    pos = np.column_stack([a.theta1_rad[start:stop], a.theta3_rad[start:stop]]).tolist()
    vel = np.column_stack([a.omega1_radps[start:stop], a.omega3_radps[start:stop]]).tolist()
    for i, t in enumerate(_log_ns(a.time_s[start:stop], origin_s).tolist()):
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
        msg.position, msg.velocity = pos[i], vel[i]
        bag.write_serialized(ANGLES_TOPIC, serialize_message(msg), t)
    return stop - start
