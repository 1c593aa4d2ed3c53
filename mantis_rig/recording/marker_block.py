"""Marker blocks: camera frames of tracked marker positions, many frames per message.

Carried in the standard ``std_msgs/msg/Float64MultiArray`` (no custom interface package), one
message per run of consecutive frames, row-major:

* ``layout.dim[0]`` = ``{label: 'frame', size: n_frames, stride: n_frames * n_columns}``;
* ``layout.dim[1]`` = ``{label: <column names joined by ','>, size: n_columns,
  stride: n_columns}``; the columns are ``time_s`` then ``<marker>_x_m, <marker>_y_m`` per
  marker (``mb*`` on the body, ``ma*`` on the arm), e.g.
  ``time_s,mb1_x_m,mb1_y_m,mb2_x_m,...,ma2_y_m``;
* ``layout.data_offset = 0``; ``data`` holds the n_frames x n_columns values.

Positions are metres in the camera frame, in the tracking software's convention (left-handed:
image y points down, origin at an arbitrary image point; a bag imported from a right-handed or
tilted export says so in its trial conditions, ``handedness`` and ``tilt_deg``), as the
tracker's exports but in SI (REP 103). ``time_s`` is the frame time on the clock of the trial
(ROS time; sim time in simulation). A lost marker is NaN. One message per frame would mean
19,000-37,000 messages per second of video; a block keeps a tracked trial to a few hundred
messages.

In Python a block is a :class:`~mantis_rig.hardware.device_interfaces.MarkerFrames` (metres,
seconds), the rig's one type of marker data: no unit changes between the camera and the bag.
"""
from __future__ import annotations

import numpy as np
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from mantis_rig.hardware.device_interfaces import MarkerFrames

__all__ = ['FRAMES_PER_BLOCK', 'MarkerFrames', 'concatenate', 'marker_block_from_msg',
           'marker_block_to_msg', 'marker_blocks_to_msgs']

FRAME_LABEL = 'frame'
TIME_COLUMN = 'time_s'
FRAMES_PER_BLOCK = 1000


def _columns(names) -> list[str]:
    columns = [TIME_COLUMN]
    for name in names:
        columns += [f'{name}_x_m', f'{name}_y_m']
    return columns


def marker_block_to_msg(time_s, markers_m: dict) -> Float64MultiArray:
    """One message holding every frame given (time_s: (n,), markers_m: name -> (n, 2) m)."""
    time_s = np.asarray(time_s, dtype=np.float64)
    names = list(markers_m)
    table = np.empty((time_s.size, 1 + 2 * len(names)))
    table[:, 0] = time_s
    for i, name in enumerate(names):
        xy = np.asarray(markers_m[name], dtype=np.float64)
        if xy.shape != (time_s.size, 2):
            raise ValueError(f'marker {name}: expected shape ({time_s.size}, 2), got {xy.shape}')
        table[:, 1 + 2 * i:3 + 2 * i] = xy
    msg = Float64MultiArray()
    n_frames, n_columns = table.shape
    msg.layout.data_offset = 0
    msg.layout.dim = [
        MultiArrayDimension(label=FRAME_LABEL, size=n_frames, stride=n_frames * n_columns),
        MultiArrayDimension(label=','.join(_columns(names)), size=n_columns, stride=n_columns),
    ]
    msg.data = table.ravel()
    return msg


def marker_blocks_to_msgs(frames: MarkerFrames, frames_per_block: int = FRAMES_PER_BLOCK):
    """Split a window of frames into messages of at most ``frames_per_block`` frames."""
    for start in range(0, len(frames), frames_per_block):
        stop = start + frames_per_block
        yield marker_block_to_msg(frames.time_s[start:stop],
                                  {k: v[start:stop] for k, v in frames.markers_m.items()})


def marker_block_from_msg(msg) -> MarkerFrames:
    """Inverse of :func:`marker_block_to_msg`; ValueError naming what does not fit."""
    dims = msg.layout.dim
    if len(dims) != 2 or dims[0].label != FRAME_LABEL:
        raise ValueError('not a marker block (expected dim[0] "frame" and dim[1] the columns)')
    columns = dims[1].label.split(',')
    n_frames, n_columns = dims[0].size, dims[1].size
    if columns[0] != TIME_COLUMN or len(columns) != n_columns or n_columns % 2 != 1:
        raise ValueError(f'marker block columns {dims[1].label!r} do not read as time_s then '
                         f'x/y pairs ({n_columns} columns declared)')
    data = np.asarray(msg.data, dtype=np.float64)
    offset = msg.layout.data_offset
    if data.size < offset + n_frames * n_columns:
        raise ValueError(f'marker block holds {data.size - offset} values, its layout '
                         f'declares {n_frames} x {n_columns}')
    table = data[offset:offset + n_frames * n_columns].reshape(n_frames, n_columns)
    markers = {}
    for i in range(1, n_columns, 2):
        name = columns[i].removesuffix('_x_m')
        if columns[i + 1] != f'{name}_y_m' or columns[i] != f'{name}_x_m':
            raise ValueError(f'marker block columns {columns[i]!r}, {columns[i + 1]!r} are '
                             f'not an x_m/y_m pair')
        markers[name] = table[:, i:i + 2].copy()
    return MarkerFrames(table[:, 0].copy(), markers)


def concatenate(blocks) -> MarkerFrames:
    """Join blocks (in time order) into one MarkerFrames; markers must match."""
    blocks = list(blocks)
    if not blocks:
        return MarkerFrames(np.empty(0), {})
    names = list(blocks[0].markers_m)
    for b in blocks[1:]:
        if list(b.markers_m) != names:
            raise ValueError(f'marker blocks disagree on markers: {names} vs {list(b.markers_m)}')
    return MarkerFrames(np.concatenate([b.time_s for b in blocks]),
                        {n: np.concatenate([b.markers_m[n] for b in blocks]) for n in names})
