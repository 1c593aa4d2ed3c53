"""sim_world_node: owns the simulated world, runs it in simulated time and publishes /clock.

A thread advances the mantis_sim World by `step_s` of simulated time per step, paced at
`real_time_factor` (0: as fast as it can; when a step is late, simulated time slips rather than
catching up), and publishes /clock after each step. The simulated devices reach the world by
direct calls (a LocalWorldPort on `runner`), in the same process: the node is one part of
mantis_rig.nodes.sim_rig, the simulated rig. Once a wall second, /diagnostics gets the status
`sim_world_node: world` (keys time_s, phase, peak_time_s, stage position/velocity, strikes:
how often the robot was latched, latched). The `relatch` parameter says whether the simulated
operator re-latches the robot once the stage is back at its start (mantis_sim.world).
"""
from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from mantis_rig import contract
from mantis_rig.hardware.local_world import WorldRunner
from mantis_rig.nodes.device_node import declare, param_value, time_msg
from mantis_rig.nodes.executors import SideNode
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_sim.robots import SessionRobots
from mantis_sim.scene import load_scene
from mantis_sim.world import World

from .lean_node import WithoutDefaultEventHandlers

PARAMETERS = contract.WORLD_PARAMETERS
# The force stream counts as streaming while its last block is younger than this (wall time):
# a load cell that stops must not stop the world.
STREAM_ALIVE_S = 1.0


class SimWorldNode(WithoutDefaultEventHandlers, Node):
    def __init__(self, node_name: str = contract.SIM_WORLD_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        for spec in PARAMETERS:
            declare(self, spec)
        value = self._value
        self.scene = load_scene(value('scene'), [s for s in value('set') or [] if s])
        robots = (SessionRobots(self.scene, value('seed'))
                  if value('draw_robots') and self.scene.spread is not None else None)
        self.world = (World(robots(1), relatch_scene=robots, operator_relatches=value('relatch'))
                      if robots else World(self.scene, operator_relatches=value('relatch')))
        self.step_s = value('step_s')
        self._step_index = round(self.world.time_s / self.step_s)
        self._phase = self.world.phase

        self._clock_pub = self.create_publisher(Clock, contract.CLOCK.name,
                                                contract.CLOCK.qos.publisher())
        # in-process followers of the world's time (the rig's shared sim clock)
        self.clock_listeners: list = []
        self._diag_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                               contract.DIAGNOSTICS.qos.publisher())
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
        self._pacing = SideNode(self, contract.PACING_SUFFIX)
        self._pacing.node.create_subscription(Float64MultiArray, contract.FORCE_BLOCK.name,
                                              self._on_daq_block,
                                              contract.FORCE_BLOCK.qos.subscriber())
        self.runner = _StepRunner(self.world, value('real_time_factor'), self.step_s, self)
        self.runner.start()
        self.get_logger().info(
            f'simulated world {self.scene.name!r} running at {value("real_time_factor")}x, '
            f'steps of {self.step_s * 1e3:g} ms')

    def destroy_node(self):
        self.runner.stop()
        self._pacing.close()
        super().destroy_node()

    def _on_daq_block(self, msg: Float64MultiArray) -> None:
        try:
            block = force_block_from_msg(msg)
        except (ValueError, IndexError):      # not a force block: nothing to pace by
            return
        self._daq_end_s = block.t0_s + block.period_s * block.force_n.size
        self._daq_heard = time.monotonic()

    def waiting_for_consumers(self) -> bool:
        """True while the load cell's stream lags the world by more than max_lead_s."""
        end = self._daq_end_s
        return (self.max_lead_s > 0 and end is not None
                and time.monotonic() - self._daq_heard < STREAM_ALIVE_S
                and self.world.time_s - end > self.max_lead_s)

    def publish_clock(self, msg: Clock) -> None:
        self._clock_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        with self.runner.lock:
            world = self.world
            values = dict(time_s=f'{world.time_s:.4f}', phase=world.phase,
                          peak_time_s=f'{world.peak_time_s:.6f}',
                          stage_position_m=f'{world.stage_position_m():.7f}',
                          stage_velocity_m_per_s=f'{world.stage_velocity_m_per_s():.7f}',
                          strikes=str(world.strikes),
                          latched='true' if world.latched else 'false',
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

    # --- the world's step (runner thread) ---------------------------------------------------
    def next_step_time_s(self) -> float:
        self._step_index += 1
        return self._step_index * self.step_s

    def clock_message(self) -> Clock:
        """After a step, under the world's lock: the world's time, as /clock carries it."""
        if self.world.phase != self._phase:
            self._phase = self.world.phase
            self.get_logger().info(f'phase {self._phase} at {self.world.time_s:.3f} s')
        return Clock(clock=time_msg(self.world.time_s))


class _StepRunner(WorldRunner):
    """WorldRunner that publishes /clock after each step (outside the world's lock)."""

    def __init__(self, world: World, real_time_factor: float, step_s: float,
                 node: SimWorldNode):
        super().__init__(world, real_time_factor, step_s, hold=node.waiting_for_consumers)
        self.node = node

    def step(self) -> None:
        try:
            with self.lock:
                self.world.advance_to(self.node.next_step_time_s())
                clock = self.node.clock_message()
                self.lock.notify_all()
            for listener in self.node.clock_listeners:
                listener(clock)
            self.node.publish_clock(clock)
        except Exception as exc:
            self.node.get_logger().fatal(f'the simulated world stopped: {exc!r}')
            raise

