"""supervisor_node: runs a trial on the rig (``ros2 run mantis_rig supervisor_node``).

Services ``/supervisor/start_trial`` and ``/supervisor/abort`` (std_srvs/Trigger); state on
``/supervisor/state`` (std_msgs/String, transient local) and on ``/diagnostics``. One bring-up
runs any number of trials, each from where the first one started
(mantis_rig.trial.sequence.SessionState). A trial's end (``done``, ``aborted``) is published once
its log is closed (the bag holds that state too): whoever hears it can start the next trial and
is never refused.
A second abort while an aborted trial returns the stage stops it where it is. The trial
conditions and procedure settings are parameters (mantis_rig.trial.supervisor_settings); they are
fixed while a trial runs. Each trial is logged to its own bag directory under ``out``; the
start_trial response names it. With ``video`` true the simulated camera films the trial into
``<bag directory>/video/`` (contract.FILM_FOLDER), after the trial's marker frames. The
sequence itself is mantis_rig.trial.sequence.
While the node lives it publishes its heartbeat (``/supervisor/heartbeat``, std_msgs/Header,
every 50 ms of steady time, from a thread of its own): stage_node stops a pull or move the
supervisor commanded when it lapses (docs/architecture.md, Stopping).
"""
from __future__ import annotations

from datetime import datetime
import os
from pathlib import Path
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from lifecycle_msgs.msg import State, TransitionEvent
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Float64MultiArray, Header, String
from std_srvs.srv import Trigger

from mantis_rig import contract
from mantis_rig.contract import DEVICE_NODES
from mantis_rig.recording import TRIAL_CONDITIONS, BagClosedError, BagWriteError, BagWriter
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_rig.recording.marker_block import marker_block_from_msg
from mantis_rig.runtime.executors import SideNode, light_executor, run_node
from mantis_rig.runtime.lean_node import WithoutDefaultEventHandlers
from mantis_rig.runtime.memory import release_freed_memory
from mantis_rig.trial.log_space import free_space_problem
from mantis_rig.trial.sequence import SessionState, TrialSequence
from mantis_rig.trial.supervisor_settings import (
    PARAMETERS,
    ConditionError,
    TrialConditions,
    check_value,
)

from .recorder import Recorder
from .rig_client import RigClient

NODE_NAME = contract.SUPERVISOR_NODE
STATUS_NAME = f'{NODE_NAME}: trial'

LOG_WRITE_FAILED = 'log write failed'     # how the abort reason of a failed log begins
LOG_TAIL_WAIT_S = 2.0
# A start asked for before the end was published (by a client that did not wait for it) is
# refused with this in its reason.
STILL_CLOSING = 'is still closing its log'
END_STATES = ('done', 'aborted')        # held back until the trial's log is closed


def left_active(state_label: str) -> str:
    """The fault of a device node that left the active state for ``state_label``."""
    return f'left the active state (now {state_label})'


def _descriptor(name, spec) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(name=name, description=spec.description)
    if spec.low is not None:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    if spec.choices is not None:
        descriptor.additional_constraints = f'one of: {", ".join(spec.choices)}'
    return descriptor


def bag_directory(out: str) -> Path:
    """A new directory under ``out`` named after the wall-clock time of the trial's start."""
    base = Path(out) / datetime.now().strftime('trial_%Y%m%d_%H%M%S')
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f'{base.name}_{n}')
    return path


class _TrialPort:
    """The rig as one trial's sequence sees it: the supervisor's RigClient, except that the
    trial's states go to ``publish_state`` (SupervisorNode._trial_state, which knows whose
    they are)."""

    def __init__(self, rig: RigClient, publish_state):
        self._rig = rig
        self.publish_state = publish_state

    def __getattr__(self, name):
        return getattr(self._rig, name)


class SupervisorNode(WithoutDefaultEventHandlers, Node):
    def __init__(self, node_name: str = NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        self._group = ReentrantCallbackGroup()
        self._declare_parameters()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.sequence: TrialSequence | None = None
        self.bag: BagWriter | None = None
        self.bag_path: Path | None = None
        self.trials = 0
        self.session = SessionState()
        self._stage_motion_stops: int | None = None    # the stage's count (its diagnostics)
        self.last_abort_reason = ''
        self._state, self._state_reason = 'idle', ''
        self._state_lock = threading.Lock()
        # A start and a trial's end made public, one at a time: a client that heard the end
        # finds the start accepted (taken before _state_lock, never after).
        self._start_lock = threading.RLock()
        self._log_closed = True            # the last trial's log is closed and its end public
        self._end: tuple[str, str] | None = None     # its end, held until then
        self._tail: DiagnosticArray | None = None    # the status that marks the log's tail
        self._tail_logged = threading.Event()

        c = contract
        self._state_pub = self.create_publisher(String, c.SUPERVISOR_STATE.name,
                                                c.SUPERVISOR_STATE.qos.publisher())
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, c.DIAGNOSTICS.name,
                                                      c.DIAGNOSTICS.qos.publisher())
        self.rig = RigClient(self, self._group, self._publish_state)
        self._clock_node = self._follow_clock_aside()
        # The recorder's ~400 messages a second go through a lean node of their own: through
        # this node's executor (in one process shared with sim_world_node) they reached the
        # trial 0.1-0.5 s late, and the camera's buffer missed the strike.
        self._recorder_node = SideNode(self, c.RECORDER_SUFFIX)
        self.recorder = Recorder(self._recorder_node.node, clock=self.get_clock())
        self.recorder.on_written = self._on_logged
        group = {'callback_group': self._group}
        self.create_service(Trigger, c.START_TRIAL.name, self._on_start, **group)
        self.create_service(Trigger, c.ABORT.name, self._on_abort, **group)
        # What the trial watches arrives through the recorder's raw subscriptions (one
        # callback per message for both jobs), deserialized here before it is logged. The
        # recorder's hooks name each topic by its contract name (relative).
        self._watched = {
            c.FORCE_BLOCK.name: (Float64MultiArray, self._on_force),
            c.JOINT_STATE.name: (JointState, self._on_joint_state),
            c.TRIGGER_TIME.name: (TimeReference, self._on_trigger_time),
            c.MARKERS.name: (Float64MultiArray, self._on_markers),
            c.DIAGNOSTICS.name: (DiagnosticArray, self._on_diagnostics),
        }
        self.recorder.on_message = self._on_recorded
        for device in DEVICE_NODES:
            self.create_subscription(
                TransitionEvent, c.node_interface(device, c.TRANSITION_EVENT),
                lambda msg, device=device: self._on_transition(device, msg), 10, **group)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME), **group)
        self._publish_state('idle', '')
        # The heartbeat stage_node needs to keep a pull going (contract.HEARTBEAT): from a
        # thread of its own on the steady clock, so that neither simulated time (which stops
        # with the world) nor a busy executor holds it back; only a frozen process does.
        self._heartbeat_pub = self.create_publisher(Header, c.HEARTBEAT.name,
                                                    c.HEARTBEAT.qos.publisher())
        self._heartbeat_stop = threading.Event()
        self._heartbeat = threading.Thread(target=self._beat, name='supervisor-heartbeat',
                                           daemon=True)
        self._heartbeat.start()

    def _follow_clock_aside(self) -> SideNode | None:
        """On use_sim_time (the multi-process layout), rclpy's time source subscribes to
        /clock on this node: each of the world's 100 steps a second then woke this node's
        executor, which rebuilds its wait set in Python over every service, client and
        subscription of the node. The subscription moves to a side node of its own on the
        EventsExecutor, which feeds the same time source (the node's clock as before)."""
        source = getattr(self, '_time_source', None)
        subscription = getattr(source, '_clock_sub', None)
        if subscription is None:            # wall time, or the world's shared clock: nothing
            return None
        side = SideNode(self, contract.CLOCK_SUFFIX)
        # the topic as the time source resolved it (namespace, remapping) and its profile
        side.node.create_subscription(ClockMsg, subscription.topic_name, source.clock_callback,
                                      QoSProfile(depth=1,
                                                 reliability=ReliabilityPolicy.BEST_EFFORT))
        self.destroy_subscription(subscription)
        source._clock_sub = None
        return side

    # ------------------------------------------------------------------ parameters
    def _declare_parameters(self) -> None:
        backend = self.declare_parameter('backend', PARAMETERS['backend'].default,
                                         _descriptor('backend', PARAMETERS['backend'])).value
        defaults = {'tare': backend == 'hardware', 'expect_markers': backend == 'sim'}
        for name, spec in PARAMETERS.items():
            if name != 'backend':
                self.declare_parameter(name, defaults.get(name, spec.default),
                                       _descriptor(name, spec))
        self.conditions()   # refuse to start with values out of range

    def conditions(self) -> TrialConditions:
        values = {name: self.get_parameter(name).value for name in PARAMETERS}
        return TrialConditions.from_mapping(values).validate()

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        running = self.sequence is not None and self.sequence.running
        for parameter in parameters:
            if parameter.name not in PARAMETERS:
                continue
            if running:
                return SetParametersResult(successful=False, reason=(
                    f'{parameter.name}: a trial is in progress (state {self.sequence.state}); '
                    f'trial parameters are fixed until it ends'))
            try:
                check_value(parameter.name, parameter.value)
            except ConditionError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ services
    def _on_start(self, request, response):
        response.success, response.message = self.start_trial()
        return response

    def _on_abort(self, request, response):
        response.success, response.message = self.abort(
            f'abort requested ({contract.resolve(contract.ABORT, self.get_namespace())})')
        return response

    def start_trial(self) -> tuple[bool, str]:
        with self._start_lock:
            return self._start_trial()

    def _start_trial(self) -> tuple[bool, str]:
        previous = self.sequence
        if previous is not None and previous.running:
            return False, f'a trial is already in progress (state {previous.state})'
        if not self._log_closed:
            return False, (f'trial {self.trials} {STILL_CLOSING} (it ended {previous.state}); '
                           f'its end is published once it has')
        try:
            conditions = self.conditions()
            path = bag_directory(conditions.out)
            problem = free_space_problem(path.parent, conditions)
            if problem:
                return False, f'cannot start a trial: {problem}'
            bag = BagWriter(path)
            bag.add_metadata(TRIAL_CONDITIONS, conditions.metadata())
        except (ConditionError, OSError, BagWriteError) as exc:
            return False, f'cannot start a trial: {exc}'
        bag.on_failure = self._on_log_failure
        self.bag, self.bag_path = bag, path
        self.trials += 1
        self._log_closed, self._end = False, None
        number = self.trials
        port = _TrialPort(self.rig, lambda state, reason: self._trial_state(number, state, reason))
        film_dir = str((path / contract.FILM_FOLDER).resolve()) if conditions.video else ''
        sequence = TrialSequence(port, conditions,
                                 lambda outcome: self._close_log(outcome, number, bag, path),
                                 self.session, film_dir=film_dir)
        self.sequence = sequence
        self.recorder.start(bag)
        sequence.start()
        self.get_logger().info(f'trial {number} started; logging to {path}')
        return True, f'trial started; logging to {path}'

    def abort(self, reason: str) -> tuple[bool, str]:
        if self.sequence is None:
            return False, 'no trial in progress (state idle)'
        sequence = self.sequence
        ok, message = sequence.abort(reason)
        if not ok and sequence.running:         # asked again: not even the return goes on
            sequence.stop_where_it_is()
            message += '; the stage is stopped where it is'
        return ok, message

    def _on_log_failure(self, failure: BagWriteError) -> None:
        """The bag cannot be written (disk full, directory removed): stop the stage and end
        the trial; what was synced before stays readable."""
        sequence = self.sequence
        reason = (f'{LOG_WRITE_FAILED} at rig time {self.rig.now_s():.3f} s: '
                  f'{failure.cause.strerror or failure.cause}; stage stopped; '
                  f'{failure.durable_messages} messages written before the failure')
        self.get_logger().error(reason)
        if sequence is not None:          # no return: a move the log cannot hold
            sequence.abort(reason, return_stage=False)

    def _close_log(self, outcome: dict, number: int, bag: BagWriter, path: Path) -> None:
        """Close trial ``number``'s log ``bag`` (at ``path``) with its end state in it, then
        publish that end (the next start is accepted from then on), and say so in one line."""
        try:
            if bag.failure is None:
                self._await_log_tail()
                self._log_end(bag)
            self.recorder.stop()
            if self.bag is bag:
                self.bag = None
            bag.close(trial_outcome=outcome)
        finally:
            if outcome.get('result') == 'aborted':
                self.last_abort_reason = outcome.get('reason', '')
            self._publish_end()
        self.get_logger().info(f'trial {number} {outcome.get("result")}: '
                               f'{outcome.get("reason") or "ok"}; log closed: {path}')
        release_freed_memory()

    def _await_log_tail(self) -> None:
        """Wait (LOG_TAIL_WAIT_S at most) until the recorder has logged a status published now:
        what reached it before (the stage's last states) is then in the bag."""
        array = self._diagnostics()
        self._tail_logged.clear()
        self._tail = array
        if self._publish(self._diagnostics_pub, array):
            self._tail_logged.wait(LOG_TAIL_WAIT_S)
        self._tail = None

    def _log_end(self, bag: BagWriter) -> None:
        """Write the trial's end state into its bag, as the recorder would have heard it."""
        if self._end is None:
            return
        try:
            self.recorder.record(contract.SUPERVISOR_STATE.name,
                                 serialize_message(String(data=self._end[0])))
        except (BagClosedError, BagWriteError):   # on_failure has ended the trial: no more
            pass

    def _publish_end(self) -> None:
        """The trial's log is closed: publish its end, and accept the next start."""
        with self._start_lock:
            end, self._end = self._end, None
            self._log_closed = True
            if end is not None:
                self._publish_state(*end)

    def _on_recorded(self, topic: str, data: bytes) -> None:
        watched = self._watched.get(topic)
        if watched is not None:
            watched[1](deserialize_message(data, watched[0]))

    def _on_logged(self, topic: str, data: bytes) -> None:
        tail = self._tail
        if tail is not None and topic == contract.DIAGNOSTICS.name \
                and deserialize_message(data, DiagnosticArray) == tail:
            self._tail_logged.set()

    # ------------------------------------------------------------------ state
    def _trial_state(self, number: int, state: str, reason: str) -> None:
        """A state of trial ``number``'s sequence: its end is held until its log is closed
        (_publish_end); what it says after a later trial has started is not published."""
        with self._start_lock:
            if number != self.trials:
                return
            if state in END_STATES and not self._log_closed:
                self._end = (state, reason)
                return
            self._publish_state(state, reason)

    def _publish_state(self, state: str, reason: str) -> None:
        with self._state_lock:
            self._state, self._state_reason = state, reason
            self._publish(self._state_pub, String(data=state))
        self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        self._publish(self._diagnostics_pub, self._diagnostics())

    @staticmethod
    def _publish(publisher, msg) -> bool:
        try:
            publisher.publish(msg)
            return True
        except RuntimeError:   # shutting down: rclpy's InvalidHandle / RCLError (its context gone)
            return False

    def _diagnostics(self) -> DiagnosticArray:
        state, reason = self._state, self._state_reason
        level = DiagnosticStatus.WARN if state == 'aborted' else DiagnosticStatus.OK
        values = {'state': state, 'reason': reason, 'last_abort_reason': self.last_abort_reason,
                  'trials': str(self.trials), 'bag': str(self.bag_path or '')}
        status = DiagnosticStatus(
            level=level, name=STATUS_NAME, hardware_id='mantis_rig',
            message=state if not reason else f'{state}: {reason}',
            values=[KeyValue(key=k, value=v) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        return array

    # ------------------------------------------------------------------ observations
    def _on_force(self, msg) -> None:
        if self.sequence is None:
            return
        block = force_block_from_msg(msg)
        self.sequence.on_force_block(block.t0_s, block.period_s, block.force_n)

    def _on_joint_state(self, msg) -> None:
        if msg.position and self.sequence is not None:
            self.sequence.on_stage_state(msg.position[0],
                                         msg.velocity[0] if msg.velocity else 0.0)

    def _on_trigger_time(self, msg) -> None:
        if self.sequence is not None:
            stamp = msg.header.stamp
            self.sequence.on_camera_trigger(stamp.sec + stamp.nanosec * 1e-9)

    def _on_markers(self, msg) -> None:
        frames = marker_block_from_msg(msg)
        if self.sequence is not None and len(frames):
            self.sequence.on_markers(float(frames.time_s[0]), float(frames.time_s[-1]),
                                     len(frames))

    def _on_diagnostics(self, msg) -> None:
        sequence = self.sequence
        for status in msg.status:
            if status.name == contract.world_status_name():
                if sequence is not None:
                    sequence.on_world_status({kv.key: kv.value for kv in status.values})
                continue
            device = next((d for d in DEVICE_NODES
                           if d in status.name or d == status.hardware_id), None)
            if device is None:
                continue
            in_error = status.level == DiagnosticStatus.ERROR
            if in_error:                     # the next trial's bring-up clears it
                self.session.devices_in_error.add(device)
            values = {kv.key: kv.value for kv in status.values}
            stopped = self._stage_stopped_a_move(device, values)
            if sequence is None:
                continue
            sequence.on_device_message(device, status.message, in_error)
            homed = values.get('homed')
            if homed is not None:
                sequence.on_stage_homed(homed.strip().lower() in ('true', '1', 'yes'))
            if stopped:
                sequence.on_stage_motion_stop(values.get(contract.LAST_MOTION_STOP_KEY, ''))
            if in_error:
                sequence.on_device_fault(device, status.message or 'diagnostic level ERROR')

    def _stage_stopped_a_move(self, device: str, values: dict) -> bool:
        """Whether the stage's diagnostics count a move stopped or refused by the stage itself
        (a travel limit, its envelope) since they were last heard."""
        count = values.get(contract.MOTION_STOPS_KEY)
        if device != contract.STAGE_NODE or count is None:
            return False
        count, before = int(count), self._stage_motion_stops
        self._stage_motion_stops = count
        return before is not None and count > before

    def _on_transition(self, device: str, msg) -> None:
        if msg.start_state.id == State.PRIMARY_STATE_ACTIVE \
                and msg.goal_state.id != State.PRIMARY_STATE_ACTIVE \
                and self.sequence is not None:
            self.sequence.on_device_fault(device, left_active(msg.goal_state.label))

    def _beat(self) -> None:
        """Publish the heartbeat every HEARTBEAT_PERIOD_S of steady time until destroyed; a
        beat that is late is sent at once and the period starts afresh from it."""
        period = contract.HEARTBEAT_PERIOD_S
        due = time.monotonic()
        while not self._heartbeat_stop.wait(max(0.0, due - time.monotonic())):
            now = time.monotonic()
            due = due + period if due + period > now else now + period
            # stamped on the steady clock; named with this process (contract.heartbeat_source)
            beat = Header(frame_id=contract.heartbeat_source(self.get_name(), os.getpid()))
            beat.stamp.sec, beat.stamp.nanosec = divmod(time.monotonic_ns(), 1_000_000_000)
            if not self._publish(self._heartbeat_pub, beat):
                return

    def destroy_node(self):
        self.shutdown_trial()         # the heartbeat goes on while the trial stops the stage
        self._heartbeat_stop.set()
        if self._heartbeat is not threading.current_thread():
            self._heartbeat.join(timeout=1.0)
        self._recorder_node.close()
        clock_node = getattr(self, '_clock_node', None)
        if clock_node is not None:
            clock_node.close()
        super().destroy_node()

    def shutdown_trial(self, reason: str = 'supervisor shutting down') -> None:
        """Abort a running trial; wait (briefly) for the log of the last trial to close: a
        trial that has just ended may still be closing it."""
        sequence = self.sequence
        if sequence is None:
            return
        if sequence.running:
            self.get_logger().info(f'aborting trial {self.trials}: {reason}')
            sequence.abort(reason, return_stage=False)
        sequence.finished.wait(5.0)


def main(args=None) -> int:
    return run_node(SupervisorNode, args, light_executor)   # no supervisor callback blocks


if __name__ == '__main__':
    sys.exit(main())
