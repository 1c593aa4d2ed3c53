"""A synthetic trial bag with every topic of the trial contract (tests, benchmarks, demos).

Rates as on the rig: stage/joint_state 100 Hz, loadcell/wrench 200 Hz, loadcell/force_block
20 blocks/s of 1000 samples (20 kS/s), diagnostics 1 Hz, supervisor/state on changes, one
camera/trigger_time, and the camera's marker blocks as a burst near the end; each topic with
the QoS its publishers offer on the rig (mantis_rig.contract), in the namespace asked for
(default the root: /stage/joint_state...). Each topic sits on its own sub-millisecond offset
of a 10 ms grid, so no two topics share a log time (order across topics is then unambiguous);
the marker blocks of the burst are 10 us apart.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import String

from .. import contract as c
from ..recording import BagWriter
from ..recording.force_block import force_block_to_msg
from ..recording.marker_block import marker_block_to_msg

T0_NS = 1_763_000_000_000_000_000
MS = 1_000_000
STATES = ['arming', 'pulling', 'released', 'stopping', 'done']
#: the contract topics a synthetic trial holds (the stage commands aside)
SYNTHETIC_TOPICS = (c.JOINT_STATE, c.FORCE_BLOCK, c.WRENCH, c.TRIGGER_TIME, c.MARKERS,
                    c.SUPERVISOR_STATE, c.DIAGNOSTICS)


def topics(namespace: str = '/') -> dict:
    """full topic name -> (type name, offered QoS) of a synthetic trial in ``namespace``."""
    return {c.resolve(t, namespace): (t.type_name, t.qos.publisher()) for t in SYNTHETIC_TOPICS}


TOPICS = topics()


def _stamp(msg, t_ns):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)
    return msg


def synthetic_messages(duration_s=2.0, marker_blocks=5, frames_per_block=200, namespace='/'):
    """(topic, message, log time ns) of a synthetic trial, in log-time order."""
    def name(topic):
        return c.resolve(topic, namespace)
    rng = np.random.default_rng(7)
    n10 = int(round(duration_s * 100))
    out = []
    for k in range(n10):
        t = T0_NS + k * 10 * MS
        out.append((name(c.JOINT_STATE), _stamp(JointState(
            name=['stage'], position=[1e-5 * k], velocity=[2.3e-3]), t), t))
        for half in (2.5, 7.5):
            tw = t + int(half * MS)
            w = _stamp(WrenchStamped(), tw)
            w.wrench.force.x = 10.0 + rng.normal(0, 0.05)
            out.append((name(c.WRENCH), w, tw))
        if k % 5 == 0:
            tf = t + int(1.25 * MS)
            out.append((name(c.FORCE_BLOCK), force_block_to_msg(
                (tf - 50 * MS) / 1e9, 50_000 / 1e9, 10.0 + rng.normal(0, 0.05, 1000)), tf))
        if k % 100 == 1:
            out.append((name(c.DIAGNOSTICS), DiagnosticArray(status=[DiagnosticStatus(
                name=c.LOADCELL_NODE, message=f'ok {k}')]), t + 5 * MS))
    for i, state in enumerate(STATES):
        t = T0_NS + int(i * duration_s / len(STATES) * 1e9) // (10 * MS) * 10 * MS + int(6.25 * MS)
        out.append((name(c.SUPERVISOR_STATE), String(data=state), t))
    t_trig = T0_NS + int(0.6 * duration_s * 1e9) // (10 * MS) * 10 * MS + int(3.75 * MS)
    trig = _stamp(TimeReference(source='camera'), t_trig)
    out.append((name(c.TRIGGER_TIME), trig, t_trig))
    t_burst = T0_NS + int(0.9 * duration_s * 1e9) // (10 * MS) * 10 * MS + int(3.75 * MS)
    for b in range(marker_blocks):
        frames = b * frames_per_block + np.arange(frames_per_block)
        times = t_trig / 1e9 + frames / 19000.0  # ROS time of each frame, s
        markers = {name: rng.normal(0, 0.01, (frames_per_block, 2))
                   for name in ('mb1', 'mb2', 'mb3', 'ma1', 'ma2')}
        out.append((name(c.MARKERS), marker_block_to_msg(times, markers),
                    t_burst + b * 10_000))
    out.sort(key=lambda item: item[2])
    return out


def write_synthetic_trial(path, duration_s=2.0, **kwargs):
    """Write the synthetic trial as a bag at ``path``; returns the message list."""
    messages = synthetic_messages(duration_s, **kwargs)
    with BagWriter(path, sync_period_s=0) as bag:
        for topic, (type_name, qos) in topics(kwargs.get('namespace', '/')).items():
            bag.add_topic(topic, type_name, qos)
        bag.add_metadata('trial_conditions', {'medium': 'air', 'pull_speed_mm_s': '2.3',
                                              'note': 'synthetic'})
        for topic, msg, t_ns in messages:
            bag.write(topic, msg, t_ns)
        bag.close(trial_outcome={'completed': 'true'})
    return messages
