"""sim_world_node: owns the simulated world, runs it in simulated time and publishes /clock.

A thread advances the mantis_sim World by `step_s` of simulated time per step, paced at
`real_time_factor` (0: as fast as it can; when a step is late, simulated time slips rather than
catching up), and publishes /clock after each step (while anything subscribes to it). It waits
while the load cell's force stream, or a consumer's progress (/progress: the supervisor's
trial, the stage's force guard), lags it by more than `max_lead_s`; the load cell node and a
consumer in this process tell it by direct calls instead (`note_force_stream`,
`note_progress`). The simulated devices reach the world by direct calls (a LocalWorldPort on
`runner`), in the same process: the node is one part of mantis_rig.simulated.sim_rig, the
simulated rig. Once a wall second, /diagnostics gets the status `sim_world_node: world`, and at
once whenever the robot on the latch changes (a re-latch, a rebuild at new conditions) (keys
time_s, phase, peak_time_s, stage position/velocity, strikes: how often the robot was latched,
latched, and what the current latching's robot was built from: d_t_mm, contact_angle_deg,
medium, latch_offset_deg, latched_angle_deg). The `relatch` parameter says whether the
simulated operator re-latches the robot once the stage is back at its start (mantis_sim.world).

The trial's conditions (contract.WORLD_CONDITIONS: d_t_mm, contact_angle_deg, medium; default
the scene's own) are parameters: each latching's robot is the scene at them
(mantis_sim.trial_conditions), drawn from its spread for that latching. The supervisor sets them
before each simulated trial; a change is taken only while the robot is latched and the stage
has not moved since the latch, and then rebuilds the current latching's robot (the same
latching, the same draw); otherwise, or where the scene cannot take the conditions, it is
refused with the reason. Setting the values they have is always accepted.
"""
from __future__ import annotations

from dataclasses import replace
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, Header

from mantis_rig import contract
from mantis_rig.nodes.device_node import declare, param_value, time_msg
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_rig.runtime.executors import SideNode
from mantis_rig.runtime.lean_node import WithoutDefaultEventHandlers
from mantis_rig.simulated.local_world import WorldRunner
from mantis_sim.errors import InputError
from mantis_sim.model import SimulationError
from mantis_sim.robots import SessionRobots
from mantis_sim.scene import load_scene
from mantis_sim.trial_conditions import conditions_of_scene, scene_for_conditions
from mantis_sim.world import World

PARAMETERS = contract.WORLD_PARAMETERS
#: the trial conditions the world builds its robots from (the rest is read at start-up)
CONDITIONS = tuple(spec.name for spec in contract.WORLD_CONDITIONS)
# The force stream counts as streaming while its last block is younger than this (wall time):
# a load cell that stops must not stop the world.
STREAM_ALIVE_S = 1.0


class SimWorldNode(WithoutDefaultEventHandlers, Node):
    def __init__(self, node_name: str = contract.SIM_WORLD_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        for spec in PARAMETERS:
            if not spec.from_scene:
                declare(self, spec)
        value = self._value
        self.scene = load_scene(value('scene'), [s for s in value('set') or [] if s])
        own = conditions_of_scene(self.scene)
        for spec in contract.WORLD_CONDITIONS:        # default: the scene's own
            declare(self, replace(spec, default=own[spec.name]))
        self.conditions = {name: value(name) for name in CONDITIONS}
        # the scene at the conditions: each latching's robot is drawn about it
        self._base = scene_for_conditions(self.scene, self.conditions)
        self._robots = (SessionRobots(self.scene, value('seed'))
                        if value('draw_robots') and self.scene.spread is not None else None)
        self.world = World(self._robot(1), relatch_scene=self._robot,
                           operator_relatches=value('relatch'))
        self.step_s = value('step_s')
        self._step_index = round(self.world.time_s / self.step_s)
        self._latching = self.world.strikes
        self._phase = self.world.phase

        self._clock_pub = self.create_publisher(Clock, contract.CLOCK.name,
                                                contract.CLOCK.qos.publisher())
        # in-process followers of the world's time (the rig's shared sim clock)
        self.clock_listeners: list = []
        self._diag_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                               contract.DIAGNOSTICS.qos.publisher())
        self.create_timer(1.0, self.publish_diagnostics,
                          clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        # Back-pressure: on a busy machine the stack perceives the world late (force blocks
        # reached the supervisor up to 0.4 s of simulated time late in one process at 1x, and
        # the camera's buffer missed the strike). The world waits for the force stream and for
        # its consumers' progress (mantis_rig.nodes.progress: a starved supervisor took up
        # slack past the release at --real-time-factor 0, a starved stage guard tripped on
        # stale force); the subscriptions sit on a lean node of their own, as the supervisor's
        # recorder does.
        self.max_lead_s = value('max_lead_s')
        self._daq_end_s: float | None = None
        self._daq_heard = 0.0
        self.progress: dict[str, tuple[float, float]] = {}   # consumer: (rig s, heard at)
        self._pacing = SideNode(self, contract.PACING_SUFFIX)
        self._daq_subscription = self._pacing.node.create_subscription(
            Float64MultiArray, contract.FORCE_BLOCK.name, self._on_daq_block,
            contract.FORCE_BLOCK.qos.subscriber())
        self._pacing.node.create_subscription(Header, contract.PROGRESS.name,
                                              self._on_progress,
                                              contract.PROGRESS.qos.subscriber())
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
        self._daq_end_s = block.end_s
        self._daq_heard = time.monotonic()

    def _on_progress(self, msg: Header) -> None:
        self.progress[msg.frame_id] = (
            msg.stamp.sec + msg.stamp.nanosec * 1e-9, time.monotonic())

    # --- consumers in this process (mantis_rig.simulated.sim_rig): direct calls, not topics --
    def note_force_stream(self, end_s: float) -> None:
        """The force stream has been published up to ``end_s`` (rig time), told by the load
        cell node of this process right after it published the block."""
        self._daq_end_s = end_s
        self._daq_heard = time.monotonic()

    def note_progress(self, consumer: str, rig_time_s: float) -> None:
        """A consumer's progress (what /progress carries: frame_id, stamp), from a consumer in
        this process."""
        self.progress[consumer] = (rig_time_s, time.monotonic())

    def take_force_stream_directly(self):
        """The load cell node is in this process and reports each block's end itself
        (note_force_stream): the pacing node's subscription to the force stream, one of the
        stream's three deliveries in this process, goes. Returns note_force_stream."""
        subscription, self._daq_subscription = self._daq_subscription, None
        if subscription is not None:
            self._pacing.node.destroy_subscription(subscription)
        return self.note_force_stream

    def waiting_for_consumers(self) -> bool:
        """True while the force streams and lags the world by more than max_lead_s, or a
        consumer's progress does. A consumer not heard for STREAM_ALIVE_S (dead, frozen) is not
        waited for: the rig's own guards deal with it, in simulated time."""
        end = self._daq_end_s
        now = time.monotonic()
        if self.max_lead_s <= 0 or end is None or now - self._daq_heard >= STREAM_ALIVE_S:
            return False
        behind_s = self.world.time_s - self.max_lead_s
        return end < behind_s or any(
            0.0 < progress_s < behind_s and now - heard < STREAM_ALIVE_S
            for progress_s, heard in list(self.progress.values()))

    def publish_clock(self, msg: Clock) -> None:
        # only when something listens (the supervisor of the multi-process layout, a tool):
        # /clock is volatile, so a message no subscription matches is lost anyway, and the
        # nodes of this process follow the world's SharedSimClock instead
        if self._clock_pub.get_subscription_count():
            self._clock_pub.publish(msg)

    def _robot(self, latching: int):
        """The robot of a latching: the scene at the current conditions, drawn from its spread
        for that latching (the world calls it at each re-latch, under the runner's lock)."""
        return self._robots(latching, self._base) if self._robots else self._base

    def publish_diagnostics(self) -> None:
        with self.runner.lock:
            world = self.world
            robot = world.robot
            values = dict(time_s=f'{world.time_s:.4f}', phase=world.phase,
                          peak_time_s=f'{world.peak_time_s:.6f}',
                          stage_position_m=f'{world.stage_position_m():.7f}',
                          stage_velocity_m_per_s=f'{world.stage_velocity_m_per_s():.7f}',
                          strikes=str(world.strikes),
                          latched='true' if world.latched else 'false',
                          scene=self.scene.name,
                          # what the current latching's robot was built from
                          d_t_mm=f'{robot.geometry.d_t_mm:g}',
                          contact_angle_deg=f'{robot.geometry.contact_angle_deg:g}',
                          medium=robot.medium.name,
                          latch_offset_deg=f'{robot.geometry.latch_offset_deg:.6g}',
                          latched_angle_deg=f'{robot.geometry.latched_angle_deg:.6g}')
        failure = self.runner.failure
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR if failure else DiagnosticStatus.OK,
            name=contract.world_status_name(self.get_name()), hardware_id=self.get_name(),
            message=f'stopped: {failure}' if failure else f'running, phase {values["phase"]}',
            values=[KeyValue(key=k, value=v) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = time_msg(float(values['time_s']))
        self._diag_pub.publish(array)

    def _value(self, name):
        return param_value(self, name)

    def _on_set_parameters(self, params):
        names = {spec.name for spec in PARAMETERS}
        wanted = dict(self.conditions)
        for param in params:
            if param.name in CONDITIONS:
                wanted[param.name] = param.value
            elif param.name in names:
                return SetParametersResult(
                    successful=False,
                    reason=f'{param.name} is read at start-up: restart {self.get_name()} with '
                           f'the new value')
        if wanted == self.conditions:        # the values it has: nothing to apply
            return SetParametersResult(successful=True)
        problem = self.apply_conditions(wanted)
        return SetParametersResult(successful=problem is None, reason=problem or '')

    def apply_conditions(self, conditions: dict) -> str | None:
        """Rebuild the current latching's robot at ``conditions`` (every one of CONDITIONS) and
        build the later latchings' at them; None, or why the world cannot apply them now (and
        then nothing changed)."""
        changed = ', '.join(f'{k} = {v}' for k, v in conditions.items()
                            if v != self.conditions[k])
        try:
            base = scene_for_conditions(self.scene, conditions)
            with self.runner.lock:
                if self.world.held:
                    # struck and not latched again yet (the next trial's start may come while
                    # the stage is still on its way back): the next latching is built at them,
                    # and a trial cannot pull before the robot is latched again
                    self._base, self.conditions = base, dict(conditions)
                    what = f'latching {self.world.strikes + 1} will be built'
                else:
                    self.world.rebuild_latched(
                        self._robots(self.world.strikes, base) if self._robots else base)
                    self._base, self.conditions = base, dict(conditions)
                    what = f'latching {self.world.strikes} rebuilt'
        except InputError as exc:            # names the condition the scene cannot take
            return str(exc)
        except SimulationError as exc:       # RobotInUse: loaded
            return f'{changed}: {exc}'
        self.get_logger().info(f'{what} at {changed}')
        self.publish_diagnostics()           # a bag shows the robot the trial pulls on
        return None

    # --- the world's step (runner thread) ---------------------------------------------------
    def next_step_time_s(self) -> float:
        self._step_index += 1
        return self._step_index * self.step_s

    def relatched(self) -> bool:
        """After a step, under the world's lock: whether the robot was latched anew since the
        last step."""
        latching, self._latching = self._latching, self.world.strikes
        return latching != self._latching

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
                relatched = self.node.relatched()
                self.lock.notify_all()
            for listener in self.node.clock_listeners:
                listener(clock)
            self.node.publish_clock(clock)
            if relatched:
                self.node.publish_diagnostics()
        except Exception as exc:
            self.node.get_logger().fatal(f'the simulated world stopped: {exc!r}')
            raise

