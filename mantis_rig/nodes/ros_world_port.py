"""WorldPort over ROS: a simulated backend in a device node talks to sim_world_node on /sim/*.

The port's topics live on a SideNode (`<device node>_world_port`, executors.py): the world's
streams arrive at 100 messages a second, and through the device node's MultiThreadedExecutor
they cost the simulated DAQ node a whole core and lost force blocks on a 2-core machine.
A backend call (tendon_force, marker_frames, wait_until) blocks in the caller's thread until
the messages it waits for arrive. Held data:

* the true tendon force of the last `history_s` simulated seconds, as the world published it
  (a gap in the stream drops what was held: samples are never made up across a gap);
* the latest stage state; the world's time is the latest time either stream reached;
* replies to camera requests, matched to the request by their first and last frame times.
"""
from __future__ import annotations

from collections import deque
import math
import threading
import time

import numpy as np
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from mantis_rig.hardware.interfaces import DeviceError
from mantis_rig.hardware.world_port import WorldPort, WorldTimeout
from mantis_rig.nodes.executors import SideNode
from mantis_rig.recording.marker_block import marker_block_from_msg

FORCE_TOPIC = '/sim/tendon_force'
STAGE_STATE_TOPIC = '/sim/stage_state'
# Velocity commands and moves share one topic so that the world applies them in the order sent.
STAGE_COMMAND_TOPIC = '/sim/stage_command'
VELOCITY_COMMAND, MOVE_COMMAND = 'velocity', 'move_to'
CAMERA_REQUEST_TOPIC = '/sim/camera_request'
CAMERA_FRAMES_TOPIC = '/sim/camera_frames'
# Deep enough to ride out a few seconds of a busy executor at 100 world steps per second.
STREAM_QOS = QoSProfile(depth=1000)
LATEST_QOS = QoSProfile(depth=1)
HISTORY_S = 2.5
REQUEST_RETRY_S = 5.0
TIME_TOLERANCE_S = 1e-9


class RosWorldPort(WorldPort):
    def __init__(self, node, history_s: float = HISTORY_S, force: bool = True,
                 stage: bool = True):
        """force / stage: subscribe to the tendon force / the stage state. A device that never
        reads one leaves it out (each message costs every subscriber CPU); the calls that need
        it are then refused. The world's time comes from whichever is subscribed."""
        if not (force or stage):
            raise ValueError('a RosWorldPort needs the force stream or the stage state')
        self.node = node         # the device node: its logger
        self.history_s = history_s
        self._force, self._stage_sub = force, stage
        self._cond = threading.Condition()
        self._blocks: deque = deque()                  # (t0_s, period_s, forces)
        self._stage: tuple[float, float, float] | None = None   # (t_s, position, velocity)
        self._replies: deque = deque(maxlen=8)         # MarkerFrames from the world
        self._closed = False
        self._side = SideNode(node, 'world_port')
        port = self._side.node
        self._command_pub = port.create_publisher(Float64MultiArray, STAGE_COMMAND_TOPIC, 10)
        self._request_pub = port.create_publisher(Float64MultiArray, CAMERA_REQUEST_TOPIC, 10)
        port.create_subscription(Float64MultiArray, CAMERA_FRAMES_TOPIC, self._on_frames, 10)
        if force:
            port.create_subscription(Float64MultiArray, FORCE_TOPIC, self._on_force,
                                     STREAM_QOS)
        if stage:
            # Only the latest state matters: a busy executor must not work through a backlog
            # of stale states (a position move would see the target late and overshoot).
            port.create_subscription(JointState, STAGE_STATE_TOPIC, self._on_stage,
                                     LATEST_QOS)

    def close(self) -> None:
        """Wake every waiter with DeviceError and drop the port's topics (idempotent)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._side.close()

    def wait_for_world(self, timeout_s: float) -> None:
        """Block until every subscribed stream has been heard from."""
        topics = ' and '.join(t for t, on in ((FORCE_TOPIC, self._force),
                                              (STAGE_STATE_TOPIC, self._stage_sub)) if on)
        self._wait(lambda: (self._blocks or not self._force)
                   and (self._stage is not None or not self._stage_sub),
                   timeout_s, f'{topics} from sim_world_node (is it running on this ROS '
                   f'domain?)')

    # --- WorldPort ------------------------------------------------------------------------
    def now_s(self) -> float:
        with self._cond:
            now = self._latest_s()
        if now is None:
            raise DeviceError('nothing heard from sim_world_node yet')
        return now

    def wait_until(self, t_s: float, timeout_s: float) -> None:
        self._wait(lambda: (self._latest_s() or -np.inf) >= t_s - TIME_TOLERANCE_S, timeout_s,
                   f'simulated time {t_s:.4f} s')

    def set_stage_velocity(self, velocity_m_per_s: float) -> None:
        self._command(VELOCITY_COMMAND, velocity_m_per_s)

    def move_stage_to(self, position_m: float, speed_m_per_s: float) -> None:
        self._command(MOVE_COMMAND, position_m, speed_m_per_s)

    def _command(self, kind: str, *values: float) -> None:
        if self._closed:
            raise DeviceError('the world port is closed')
        self._command_pub.publish(stage_command_msg(kind, *values))

    def stage_state(self) -> tuple[float, float]:
        with self._cond:
            stage = self._stage
        if stage is None:
            raise DeviceError(f'no {STAGE_STATE_TOPIC} from sim_world_node yet' if
                              self._stage_sub else 'this world port does not subscribe to '
                              'the stage state')
        return stage[1], stage[2]

    def tendon_force(self, t0_s: float, period_s: float, n: int,
                     timeout_s: float) -> np.ndarray:
        if not self._force:
            raise DeviceError('this world port does not subscribe to the tendon force')
        times = t0_s + period_s * np.arange(n)
        if n == 0:
            return np.empty(0)
        self._wait(lambda: (self._force_end_s() or -np.inf) >= times[-1] - TIME_TOLERANCE_S,
                   timeout_s, f'the tendon force up to {times[-1]:.6f} s')
        with self._cond:
            t, f = self._held_force(times[0], times[-1])
        if t.size == 0 or t[0] > times[0] + TIME_TOLERANCE_S:
            held = f'from {t[0]:.6f} s' if t.size else 'nothing'
            raise DeviceError(f'the tendon force at {times[0]:.6f} s is not held (the port '
                              f'holds {held}: older than its history, or lost in a gap)')
        return np.interp(times, t, f)

    def marker_frames(self, times_s: np.ndarray, timeout_s: float) -> dict:
        times = np.asarray(times_s, dtype=float)
        if times.size == 0:
            return {}
        rate = (times.size - 1) / (times[-1] - times[0]) if times.size > 1 else 1.0
        request = Float64MultiArray(data=[float(times[0]), float(times[-1]), float(rate)])
        deadline = time.monotonic() + timeout_s
        while True:
            self._request_pub.publish(request)
            remaining = deadline - time.monotonic()
            try:
                frames = self._wait(lambda: self._reply_for(times), min(REQUEST_RETRY_S,
                                    max(remaining, 0.0)),
                                    f'the camera frames {times[0]:.6f}..{times[-1]:.6f} s')
                break
            except WorldTimeout:
                if time.monotonic() >= deadline:
                    raise
        if not frames.markers_m:
            raise DeviceError(f'sim_world_node could not provide the frames {times[0]:.6f}..'
                              f'{times[-1]:.6f} s (older than its history?)')
        return frames.markers_m

    # --- internals ------------------------------------------------------------------------
    def _wait(self, ready, timeout_s: float, what: str):
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                if self._closed:
                    raise DeviceError(f'the world port closed while waiting for {what}')
                result = ready()
                if result:
                    return result
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    now = self._latest_s()
                    at = 'has not been heard from' if now is None else f'is at {now:.4f} s'
                    raise WorldTimeout(f'waited {timeout_s:g} s of wall time for {what}; '
                                       f'the simulated world {at}')
                self._cond.wait(remaining)

    def _latest_s(self):
        times = [t for t in (self._force_end_s(), self._stage and self._stage[0])
                 if t is not None]
        return max(times) if times else None

    def _force_end_s(self):
        if not self._blocks:
            return None
        t0, period, forces = self._blocks[-1]
        return t0 + (forces.size - 1) * period

    def _held_force(self, t_first: float, t_last: float):
        chosen = []
        for t0, period, forces in reversed(self._blocks):
            if t0 + (forces.size - 1) * period < t_first - TIME_TOLERANCE_S:
                break
            if t0 <= t_last + TIME_TOLERANCE_S:
                chosen.append((t0 + period * np.arange(forces.size), forces))
        if not chosen:
            return np.empty(0), np.empty(0)
        chosen.reverse()
        return np.concatenate([c[0] for c in chosen]), np.concatenate([c[1] for c in chosen])

    def _reply_for(self, times: np.ndarray):
        for frames in self._replies:
            t = frames.time_s
            if (t.size == times.size and abs(t[0] - times[0]) < 1e-7
                    and abs(t[-1] - times[-1]) < 1e-7):
                self._replies.remove(frames)
                return frames
        return None

    def _on_force(self, msg: Float64MultiArray) -> None:
        data = np.asarray(msg.data, dtype=np.float64)
        n = msg.layout.dim[0].size if msg.layout.dim else data.size - 2
        t0, period, forces = float(data[0]), float(data[1]), data[2:2 + n].copy()
        if forces.size == 0:
            return
        with self._cond:
            if self._blocks:
                last_t0, last_period, last = self._blocks[-1]
                expected = last_t0 + last.size * last_period
                if abs(t0 - expected) > 0.5 * period:
                    self.node.get_logger().warning(
                        f'{FORCE_TOPIC}: expected a block at {expected:.6f} s, got {t0:.6f} s; '
                        f'dropping the held samples')
                    self._blocks.clear()
            self._blocks.append((t0, period, forces))
            oldest = t0 - self.history_s
            while len(self._blocks) > 1 and \
                    self._blocks[0][0] + self._blocks[0][2].size * self._blocks[0][1] < oldest:
                self._blocks.popleft()
            self._cond.notify_all()

    def _on_stage(self, msg: JointState) -> None:
        if not msg.position:
            return
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        velocity = msg.velocity[0] if msg.velocity else 0.0
        with self._cond:
            self._stage = (t, float(msg.position[0]), float(velocity))
            self._cond.notify_all()

    def _on_frames(self, msg: Float64MultiArray) -> None:
        try:
            frames = marker_block_from_msg(msg)
        except ValueError as exc:
            self.node.get_logger().warning(f'{CAMERA_FRAMES_TOPIC}: {exc}')
            return
        if len(frames) == 0:
            return
        with self._cond:
            self._replies.append(frames)
            self._cond.notify_all()


def stage_command_msg(kind: str, *values: float) -> Float64MultiArray:
    """A stage command for sim_world_node: the kind in the layout's label, then its values
    ('velocity': [m/s]; 'move_to': [target m, speed m/s])."""
    msg = Float64MultiArray(data=[float(v) for v in values])
    msg.layout.dim = [MultiArrayDimension(label=kind, size=len(values), stride=len(values))]
    return msg


def stage_command_from_msg(msg: Float64MultiArray) -> tuple[str, list]:
    """(kind, values) of a stage command; ValueError naming what is wrong."""
    kind = msg.layout.dim[0].label if msg.layout.dim else ''
    expected = {VELOCITY_COMMAND: 1, MOVE_COMMAND: 2}.get(kind)
    values = list(msg.data)
    if expected is None:
        raise ValueError(f'unknown stage command {kind!r} (expected {VELOCITY_COMMAND!r} or '
                         f'{MOVE_COMMAND!r})')
    if len(values) != expected or not all(map(math.isfinite, values)):
        raise ValueError(f'stage command {kind!r} needs {expected} finite value(s), got '
                         f'{values}')
    return kind, values
