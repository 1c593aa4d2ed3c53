"""sim_world_node: owns the simulated world, runs it in simulated time and publishes /clock.

A thread advances the mantis_sim World by `step_s` of simulated time per step, paced at
`real_time_factor` (0: as fast as it can; when a step is late, simulated time slips rather than
catching up). After each step it publishes, in this order: the true tendon force on the global
grid k / force_rate_hz for exactly the samples the step added (those in (t_prev, t_new]), the
stage state stamped with the world's time, the answers to camera requests whose window the world
has passed, then /clock. Stage velocity commands take effect at the world's current time
(applied by the runner thread before its next step). Once a wall second, /diagnostics gets
the status `sim_world_node: world` (keys time_s, phase, peak_time_s, stage position/velocity).
See docs/ros_interfaces.md (Simulated world) for the topics.
"""
from __future__ import annotations

from collections import deque
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from mantis_rig.hardware.local_world import WorldRunner
from mantis_rig.nodes.device_node import Param, declare, param_value, time_msg
from mantis_rig.nodes.executors import SideNode, run_node
from mantis_rig.nodes.ros_world_port import (
    CAMERA_FRAMES_TOPIC,
    CAMERA_REQUEST_TOPIC,
    FORCE_TOPIC,
    MOVE_COMMAND,
    STAGE_COMMAND_TOPIC,
    STAGE_STATE_TOPIC,
    STREAM_QOS,
    stage_command_from_msg,
)
from mantis_rig.recording.force_block import force_block_from_msg, force_block_to_msg
from mantis_rig.recording.marker_block import marker_block_to_msg
from mantis_sim.scene import load_scene
from mantis_sim.world import World

DEFAULT_SCENE = 'air_23mm_rig'
DAQ_FORCE_TOPIC = '/loadcell/force_block'
MAX_REQUEST_FRAMES = 200_000

PARAMETERS = (
    Param('scene', DEFAULT_SCENE, 'mantis_sim scene name (see `mantis scenes`) or YAML path'),
    Param('set', [], 'scene overrides, key=value each (as `mantis simulate --set`)'),
    Param('seed', 0, 'random seed (the world itself is deterministic; kept for the command '
                     'line; sensor noise is seeded in the device nodes)', (0, 2**31 - 1)),
    Param('real_time_factor', 1.0, 'simulated seconds per wall second (0: as fast as it can)',
          (0.0, 1000.0)),
    Param('step_s', 0.01, 'simulated time per world step, s', (1e-4, 0.1)),
    Param('force_rate_hz', 20_000.0, 'sample rate of /sim/tendon_force, Hz', (1.0, 2e6)),
    Param('max_lead_s', 0.05, 'simulated time the world may run ahead of the load cell\'s '
          '/loadcell/force_block stream while that streams, s (0: no limit)', (0.0, 10.0)),
)
# The force stream counts as streaming while its last block is younger than this (wall time):
# a load cell that stops must not stop the world.
STREAM_ALIVE_S = 1.0


class SimWorldNode(Node):
    def __init__(self, node_name: str = 'sim_world_node', **kwargs):
        super().__init__(node_name, **kwargs)
        for spec in PARAMETERS:
            declare(self, spec)
        value = self._value
        self.scene = load_scene(value('scene'), [s for s in value('set') or [] if s])
        self.world = World(self.scene)
        self.step_s = value('step_s')
        self.force_rate_hz = value('force_rate_hz')
        self._next_sample = math.ceil(self.world.time_s * self.force_rate_hz - 1e-6)
        self._step_index = round(self.world.time_s / self.step_s)
        self._requests: list[tuple[float, float, float]] = []
        # Commands wait here for the runner thread: taking the world's lock from a callback
        # would starve while the runner, behind its pace, steps back to back.
        self._inbox: deque = deque()
        self._phase = self.world.phase

        self._force_pub = self.create_publisher(Float64MultiArray, FORCE_TOPIC, STREAM_QOS)
        self._stage_pub = self.create_publisher(JointState, STAGE_STATE_TOPIC, STREAM_QOS)
        self._frames_pub = self.create_publisher(Float64MultiArray, CAMERA_FRAMES_TOPIC, 10)
        self._clock_pub = self.create_publisher(Clock, '/clock', QoSProfile(depth=10))
        # in-process followers of the world's time (a one-process stack's shared sim clock)
        self.clock_listeners: list = []
        self.create_subscription(Float64MultiArray, STAGE_COMMAND_TOPIC, self._on_stage_command,
                                 10)
        self.create_subscription(Float64MultiArray, CAMERA_REQUEST_TOPIC, self._on_request, 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        # Back-pressure: on a busy machine the stack perceives the world late (force blocks
        # reached the supervisor up to 0.4 s of simulated time late in one process at 1x, and
        # the camera's buffer missed the strike). The world waits for the force stream instead;
        # its subscription sits on a lean node of its own, as the supervisor's recorder does.
        self.max_lead_s = value('max_lead_s')
        self._daq_end_s: float | None = None
        self._daq_heard = 0.0
        self._pacing = SideNode(self, 'pacing')
        self._pacing.node.create_subscription(Float64MultiArray, DAQ_FORCE_TOPIC,
                                              self._on_daq_block, 100)
        self.runner = _StepRunner(self.world, value('real_time_factor'), self.step_s, self)
        self.runner.start()
        self.get_logger().info(
            f'simulated world {self.scene.name!r} running at {value("real_time_factor")}x, '
            f'steps of {self.step_s * 1e3:g} ms, force at {self.force_rate_hz:g} Hz')

    def destroy_node(self):
        self.runner.stop()
        self._pacing.close()
        super().destroy_node()

    def _on_daq_block(self, msg: Float64MultiArray) -> None:
        try:
            block = force_block_from_msg(msg)
        except (ValueError, IndexError):      # not a force block: nothing to pace by
            return
        self._daq_end_s = (block.t0_ns + block.period_ns * block.forces_n.size) * 1e-9
        self._daq_heard = time.monotonic()

    def waiting_for_consumers(self) -> bool:
        """True while the load cell's stream lags the world by more than max_lead_s."""
        end = self._daq_end_s
        return (self.max_lead_s > 0 and end is not None
                and time.monotonic() - self._daq_heard < STREAM_ALIVE_S
                and self.world.time_s - end > self.max_lead_s)

    def _publish_diagnostics(self) -> None:
        with self.runner.lock:
            world = self.world
            values = dict(time_s=f'{world.time_s:.4f}', phase=world.phase,
                          peak_time_s=f'{world.peak_time_s:.6f}',
                          stage_position_m=f'{world.stage_position_m():.7f}',
                          stage_velocity_m_per_s=f'{world.stage_velocity_m_per_s():.7f}',
                          scene=self.scene.name)
        failure = self.runner.failure
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR if failure else DiagnosticStatus.OK,
            name=f'{self.get_name()}: world', hardware_id=self.get_name(),
            message=f'stopped: {failure}' if failure else f'running, phase {values["phase"]}',
            values=[KeyValue(key=k, value=v) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = time_msg(float(values['time_s']))
        self._diag_pub.publish(array)

    def _value(self, name):
        return param_value(self, name)

    def _on_set_parameters(self, params):
        names = {spec.name for spec in PARAMETERS}
        for param in params:
            if param.name in names:
                return SetParametersResult(
                    successful=False,
                    reason=f'{param.name} is read at start-up: restart sim_world_node with '
                           f'the new value')
        return SetParametersResult(successful=True)

    # --- from the device nodes (executor threads) -------------------------------------------
    def _on_stage_command(self, msg: Float64MultiArray) -> None:
        try:
            self._inbox.append(stage_command_from_msg(msg))
        except ValueError as exc:
            self.get_logger().warning(f'{STAGE_COMMAND_TOPIC}: ignored: {exc}')

    def _on_request(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != 3:
            self.get_logger().warning(f'{CAMERA_REQUEST_TOPIC}: expected [t_start_s, t_end_s, '
                                      f'frame_rate_hz], got {len(msg.data)} values')
            return
        t_start, t_end, rate = (float(x) for x in msg.data)
        frames = (t_end - t_start) * rate + 1
        if not (t_end >= t_start and rate > 0 and 0 < frames <= MAX_REQUEST_FRAMES):
            self.get_logger().warning(f'{CAMERA_REQUEST_TOPIC}: refused request {t_start}, '
                                      f'{t_end}, {rate} (at most {MAX_REQUEST_FRAMES} frames)')
            return
        self._inbox.append(('request', (t_start, t_end, rate)))

    # --- the world's step (runner thread) ---------------------------------------------------
    def before_step(self) -> float:
        """Under the world's lock: apply what arrived; return the step's target time."""
        while self._inbox:
            kind, values = self._inbox.popleft()
            if kind == 'request':
                self._requests.append(values)
            elif kind == MOVE_COMMAND:
                self.world.move_stage_to(*values)
            else:
                self.world.set_stage_velocity(*values)
        self._step_index += 1
        return self._step_index * self.step_s

    def collect(self) -> list:
        """After a step, under the world's lock: the messages to publish, in order."""
        world, t_new = self.world, self.world.time_s
        out = []
        end = math.floor(t_new * self.force_rate_hz + 1e-6) + 1
        if end > self._next_sample:
            index = np.arange(self._next_sample, end)
            forces = world.tendon_force_N(index / self.force_rate_hz)
            out.append((self._force_pub, force_block_to_msg(
                round(self._next_sample * 1e9 / self.force_rate_hz),
                round(1e9 / self.force_rate_hz), forces)))
            self._next_sample = end
        state = JointState(name=['stage'], position=[world.stage_position_m()],
                           velocity=[world.stage_velocity_m_per_s()], effort=[0.0])
        state.header.stamp = time_msg(t_new)
        out.append((self._stage_pub, state))
        due = [r for r in self._requests if r[1] <= t_new + 1e-9]
        self._requests = [r for r in self._requests if r[1] > t_new + 1e-9]
        out += [(self._frames_pub, self._frames(*r)) for r in due]
        out.append((self._clock_pub, Clock(clock=time_msg(t_new))))
        if world.phase != self._phase:
            self._phase = world.phase
            self.get_logger().info(f'phase {self._phase} at {t_new:.3f} s')
        return out

    def _frames(self, t_start: float, t_end: float, rate: float) -> Float64MultiArray:
        times = t_start + np.arange(round((t_end - t_start) * rate) + 1) / rate
        try:
            markers = self.world.marker_positions_m(times)
        except Exception as exc:     # outside the history: reply with the times and no markers
            self.get_logger().error(f'camera request {t_start:.6f}..{t_end:.6f} s: {exc}')
            markers = {}
        return marker_block_to_msg(times, markers)


class _StepRunner(WorldRunner):
    """WorldRunner that publishes what each step produced (outside the world's lock)."""

    def __init__(self, world: World, real_time_factor: float, step_s: float,
                 node: SimWorldNode):
        super().__init__(world, real_time_factor, step_s, hold=node.waiting_for_consumers)
        self.node = node

    def step(self) -> None:
        try:
            with self.lock:
                self.world.advance_to(self.node.before_step())
                messages = self.node.collect()
                self.lock.notify_all()
            for publisher, msg in messages:
                publisher.publish(msg)
                if isinstance(msg, Clock):
                    for listener in self.node.clock_listeners:
                        listener(msg)
        except Exception as exc:
            self.node.get_logger().fatal(f'the simulated world stopped: {exc!r}')
            raise


def main(args=None) -> int:
    return run_node(SimWorldNode, args)


if __name__ == '__main__':
    sys.exit(main())
