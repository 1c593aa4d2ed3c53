"""Force blocks: a run of load-cell samples with its first-sample time and sample period.

Carried in the standard ``std_msgs/msg/Float64MultiArray`` with a fixed convention, so every ROS 2
tool can open the bag without a custom interface package:

* ``layout.data_offset = 2``: the first two elements are a block header, not samples
  (``MultiArrayLayout.data_offset`` is documented as "padding elements at front of data");
* ``data[0]`` = time of the first sample [s since the Unix epoch, float64: ~0.24 us resolution],
  ``data[1]`` = sample period [s];
* ``layout.dim[0]`` = ``{label: 'force_n', size: n, stride: n}``: ``data[2:]`` are n forces [N].

In Python a block is a :class:`~mantis_rig.hardware.device_interfaces.ForceBlock` (seconds,
newtons), the rig's one type of force data, as the DAQ reads it.

Why not the alternatives: ``sensor_msgs/ChannelFloat32`` and a bare Float64MultiArray carry no
time at all; ``sensor_msgs/LaserScan`` has a stamp and ``time_increment`` but tools would draw the
forces as ranges of a laser scan; one ``WrenchStamped`` per sample means 20,000 messages/s.
A dedicated ``mantis_rig_interfaces/msg/ForceBlock`` (Header + period + float64[]) is the clean
long-term answer once the project has an interface package.
"""
from array import array

import numpy as np
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from mantis_rig.hardware.device_interfaces import ForceBlock

__all__ = ['ForceBlock', 'force_block_from_msg', 'force_block_to_msg']

FORCE_LABEL = 'force_n'
HEADER_ELEMENTS = 2


def force_block_to_msg(t0_s, period_s, force_n) -> Float64MultiArray:
    """A Float64MultiArray carrying ``force_n`` [N] sampled from ``t0_s`` [s, ROS time] every
    ``period_s`` [s]."""
    forces = np.asarray(force_n, dtype=np.float64)
    msg = Float64MultiArray()
    msg.layout.data_offset = HEADER_ELEMENTS
    msg.layout.dim = [MultiArrayDimension(label=FORCE_LABEL, size=forces.size,
                                          stride=forces.size)]
    # the header, then the forces' bytes as they are: the message's own array type, filled
    # without a Python float per sample (its setter copies anything else element by element)
    data = array('d', (float(t0_s), float(period_s)))
    data.frombytes(forces.tobytes())
    msg.data = data
    return msg


def force_block_from_msg(msg) -> ForceBlock:
    """Inverse of :func:`force_block_to_msg`: a ForceBlock (t0_s on ROS time, period_s, N)."""
    if msg.layout.data_offset != HEADER_ELEMENTS or not msg.layout.dim \
            or msg.layout.dim[0].label != FORCE_LABEL:
        raise ValueError('not a force block (expected data_offset 2 and dim[0] force_n)')
    data = np.asarray(msg.data, dtype=np.float64)
    size = msg.layout.dim[0].size
    if data.size < HEADER_ELEMENTS + size:
        raise ValueError(f'force block holds {max(data.size - HEADER_ELEMENTS, 0)} samples, its '
                         f'layout declares {size}')
    t0_s, period_s = float(data[0]), float(data[1])
    if not (np.isfinite(t0_s) and t0_s >= 0 and np.isfinite(period_s) and period_s > 0):
        raise ValueError(f'force block start time {t0_s} s / sample period {period_s} s: '
                         f'expected a finite time >= 0 and a period > 0')
    return ForceBlock(t0_s=t0_s, period_s=period_s,
                      force_n=data[HEADER_ELEMENTS:HEADER_ELEMENTS + size])
