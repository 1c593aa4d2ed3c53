"""stage_node: the translation stage as a managed node (docs/ros_interfaces.md).

Active: /stage/joint_state at `joint_state_rate_hz` (node clock: sim time in simulation;
effort [0.0]: not measured, but never empty, which the rosbags reader needs),
/stage/velocity_command and /stage/position_command move the stage (a position move runs in a
worker thread; any new command or /stage/stop ends it), /stage/home blocks until homed.
/stage/stop works whenever the device is open. A command the driver's safety envelope refuses
(speed ceiling, travel limits) is refused with a warning; a device error is a fault. A refusal
of that kind, and a move the stage stopped at a travel limit (soft limit or limit switch), are
counted on /diagnostics (`motion_stops`, `last_motion_stop`): the supervisor ends its trial
on them at once.
The force ceiling holds in the driver layer too: the stage is a StageGuard fed with every
/loadcell/force_block (on a SideNode: 100 messages a second), which stops the stage above
`force_ceiling_n` and refuses or stops a pull when the readings are older than
`max_force_age_s` (simulated time on the simulated rig); a trip is a fault.
/diagnostics carries the stage's position, velocity and `homed` ('true'/'false') whenever the
stage is open.

Every pull is bounded at the controller: a velocity command in the pull direction is executed
as a bounded move (Stage.move_at(v, bound_m)) to where the pull starts + `travel_mm` (the
supervisor sets its trial's travel_mm here before each trial; capped at the soft limit), which
the KDC101 (MOT_MOVE_ABSOLUTE at the pull speed) or the simulated world ends at rest there
with nothing commanding it: a dead process cannot leave the stage pulling. A command while a
pull is under way keeps that pull's bound (the same velocity again, while the stage moves,
changes nothing). A pull that reaches its bound is counted as a
motion stop (`last_motion_stop` says so), on which the supervisor ends its trial.

A motion needs a live supervisor: a pull or move commanded while the supervisor's heartbeat
(/supervisor/heartbeat) is heard is stopped when no heartbeat has come for
`supervisor_heartbeat_timeout_s` of steady time (a watchdog thread of its own takes the
heartbeats itself every HEARTBEAT_CHECK_S, from a subscription no executor spins), and
counted as a motion stop, `supervisor heartbeat lost for X s`: the supervisor, once it runs
again, ends its trial with that reason. A command that comes while the
heartbeat of a supervisor once heard has lapsed is refused with the same reason. Without any
heartbeat ever heard (no supervisor: a tool or a test driving the stage) motions are not
watched, nor are they by a supervisor in this same process (the one-process layout), which
could not freeze without freezing this node with it. The heartbeat's age, the longest gap
between two heard while active and the longest between two sent (their stamps: the
supervisor's steady clock) are on /diagnostics. While active, its force guard reports how far
it has read the force stream on /progress (mantis_rig.nodes.progress).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import math
import os
import sys
import threading
import time

from rclpy.exceptions import InvalidHandle
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, Header
from std_srvs.srv import Trigger

from mantis_rig import backends, contract
from mantis_rig.contract import FORCE_CEILING_NAME, TRAVEL_NAME, side_node_name
from mantis_rig.hardware.device_interfaces import ConfigurationError, DeviceError, SafetyLimitError
from mantis_rig.nodes.device_node import ERROR, OK, WARN, DeviceNode
from mantis_rig.nodes.progress import ProgressReporter
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_rig.runtime.clock_ticker import ClockTicker
from mantis_rig.runtime.executors import SideNode, run_node
from mantis_rig.runtime.lean_node import LeanNode

HOME_TIMEOUT_S = 120.0
MOVE_TIMEOUT_S = 120.0
PULL_DIRECTION = 1              # positive velocity pulls the tendon (StageGuard's default)
BOUND_REACHED_M = 50e-6         # a pull at rest this close to its bound has reached it
HEARTBEAT_CHECK_S = 0.05        # how often the heartbeat watchdog looks (steady clock)


@dataclass(frozen=True)
class _Pull:
    """A bounded pull under way: where it started and where the controller ends it."""

    start_m: float
    bound_m: float
    travel_mm: float
    at_soft_limit: bool
    velocity_m_per_s: float

    def describe(self) -> str:
        limit = ' lies beyond the soft travel limit' if self.at_soft_limit else ''
        return (f'{self.bound_m * 1e3:.4f} mm (its start {self.start_m * 1e3:.4f} mm + '
                f'{TRAVEL_NAME} {self.travel_mm:g} mm{limit})')


class StageNode(DeviceNode):
    DEVICE = 'stage'
    PARAMETERS = contract.STAGE_PARAMETERS

    def __init__(self, node_name: str = contract.STAGE_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        c = contract
        self._state_pub = self.create_publisher(JointState, c.JOINT_STATE.name,
                                                c.JOINT_STATE.qos.publisher())
        self.create_subscription(Float64, c.VELOCITY_COMMAND.name, self._on_velocity,
                                 c.VELOCITY_COMMAND.qos.subscriber(),
                                 callback_group=self.services_group)
        self.create_subscription(Float64, c.POSITION_COMMAND.name, self._on_position,
                                 c.POSITION_COMMAND.qos.subscriber(),
                                 callback_group=self.services_group)
        self.create_service(Trigger, c.STAGE_HOME.name, self._on_home,
                            callback_group=self.services_group)
        self.create_service(Trigger, c.STAGE_STOP.name, self._on_stop,
                            callback_group=self.services_group)
        self._state_ticker = None
        self._move: threading.Thread | None = None
        self._move_lock = threading.Lock()
        self._last_state = None
        self._refused: str | None = None
        self._motion_stops = 0
        self._last_motion_stop = ''
        self._at_limit = False
        self._stopping = False          # a move ending now was stopped on purpose
        self._stop_cause = ''           # why the process stopped the stage (emergency_stop)
        self._reported_trip: str | None = None
        self._pull: _Pull | None = None         # the bounded pull under way
        self._pull_lock = threading.Lock()
        # the supervisor's heartbeat (steady clock): the last one heard, the longest gap, and
        # the motion commanded while it was heard that its lapse must stop
        self._heartbeat_at: float | None = None
        self._heartbeat_max_gap_s = 0.0
        self._supervised: str | None = None
        self.add_post_set_parameters_callback(self._on_parameters_set)
        # how far the guard has read the force stream, for the simulated world to wait for
        self._guard_progress = ProgressReporter(self, contract.FORCE_GUARD_SUFFIX)
        self._force_feed = SideNode(self, contract.FORCE_GUARD_SUFFIX)
        self._force_feed.node.create_subscription(Float64MultiArray, contract.FORCE_BLOCK.name,
                                                  self._on_force_block,
                                                  contract.FORCE_BLOCK.qos.subscriber())
        # The heartbeat is taken by the watchdog thread itself, from a subscription no
        # executor spins: whatever else this process is busy with, each round of the watchdog
        # sees every heartbeat that has arrived (DDS keeps them meanwhile), so only a silent
        # supervisor looks silent.
        self._heartbeat_node = LeanNode(
            side_node_name(self.get_name(), contract.HEARTBEAT_SUFFIX),
            namespace=self.get_namespace(), context=self.context,
            start_parameter_services=False)
        self._heartbeat_sub = self._heartbeat_node.create_subscription(
            Header, contract.HEARTBEAT.name, lambda msg: None,
            contract.HEARTBEAT.qos.subscriber())
        self._heartbeat_sent_s: float | None = None     # the latest one's stamp (its clock)
        self._heartbeat_max_send_gap_s = 0.0
        self._watchdog_stop = threading.Event()
        self._watchdog = threading.Thread(target=self._watch_heartbeat, daemon=True,
                                          name='stage-heartbeat-watchdog')
        self._watchdog.start()

    # --- lifecycle hooks --------------------------------------------------------------------
    def open_device(self, port):
        stage = backends.make_stage(self.backend_name, port,
                                    serial_port=self.param('serial_port'),
                                    stage_serial_number=self.param('stage_serial_number'),
                                    counts_per_mm=self.param('counts_per_mm'),
                                    force_ceiling_n=self.param(FORCE_CEILING_NAME),
                                    max_force_age_s=self.param('max_force_age_s'),
                                    clock_s=self._guard_clock())
        choice = getattr(getattr(stage, 'stage', stage), 'choice', None)
        if choice is not None and self.param('stage_serial_number'):
            self.get_logger().info(f'stage port {choice.reason}')
        stage.open()
        try:
            info = stage.identify()
            self.get_logger().info(f'stage {info.model} #{info.serial_number} ({info.firmware})')
        except Exception:
            stage.close()
            raise
        return stage

    def start_streaming(self) -> None:
        self.device.clear_force_trip()      # refused while the force is still over the ceiling
        self._refused = None
        self._reported_trip = None
        self._set_pull(None)
        self._supervised = None
        self._heartbeat_max_gap_s = self._heartbeat_max_send_gap_s = 0.0
        self._publish_state()
        self._state_ticker = ClockTicker(self.get_clock(),
                                         1.0 / self.param('joint_state_rate_hz'),
                                         self._publish_state, 'stage-joint-state')

    def stop_streaming(self) -> None:
        ticker, self._state_ticker = self._state_ticker, None    # deactivate and destroy race
        if ticker is not None:
            ticker.stop()
        self._stop_motion()
        self._guard_progress.report(0.0)                          # no pull to guard now

    def diagnostic_values(self) -> dict:
        values = {}
        stage = self.device
        if stage is not None and not self.is_active:
            try:
                self._last_state = stage.state()
            except DeviceError as exc:
                values['state_error'] = str(exc)
        state = self._last_state if stage is not None else None
        if state is not None:
            values.update(position_m=f'{state.position_m:.7f}',
                          velocity_m_per_s=f'{state.velocity_m_per_s:.7f}',
                          homed=_flag(state.homed), forward_limit=_flag(state.forward_limit),
                          reverse_limit=_flag(state.reverse_limit))
        if self._refused:
            values['last_refused_command'] = self._refused
        values[contract.MOTION_STOPS_KEY] = str(self._motion_stops)
        if self._last_motion_stop:
            values[contract.LAST_MOTION_STOP_KEY] = self._last_motion_stop
        heard = self._heartbeat_at
        if heard is not None:
            values[contract.HEARTBEAT_AGE_KEY] = f'{time.monotonic() - heard:.3f}'
            values[contract.HEARTBEAT_MAX_GAP_KEY] = f'{self._heartbeat_max_gap_s:.3f}'
            values[contract.HEARTBEAT_MAX_SEND_GAP_KEY] = \
                f'{self._heartbeat_max_send_gap_s:.3f}'
        return values

    def destroy_node(self):
        self._watchdog_stop.set()
        if self._watchdog is not threading.current_thread():
            self._watchdog.join(timeout=2.0)
        super().destroy_node()
        self._force_feed.close()
        self._heartbeat_node.destroy_node()

    def emergency_stop(self, cause: str = '') -> None:
        """Stop the stage now, from any thread, without waiting for a move in progress (a
        process being interrupted: ``cause`` says so in the error the stopped move reports)."""
        if cause:
            self._stop_cause = cause
        stage = self.device
        if stage is not None:
            stage.stop()

    # --- the force guard --------------------------------------------------------------------
    def report_progress_to(self, direct) -> None:
        """The force guard's progress goes to ``direct`` (the simulated world of this process)
        rather than to /progress."""
        self._guard_progress.report_to(direct)

    def _on_parameters_set(self, parameters) -> None:
        stage = self.device
        for parameter in parameters:
            if parameter.name == FORCE_CEILING_NAME and stage is not None:
                stage.set_force_ceiling(parameter.value)

    def _guard_clock(self):
        if not self.sim():
            return time.monotonic
        return lambda: self.get_clock().now().nanoseconds * 1e-9

    def _on_force_block(self, msg: Float64MultiArray) -> None:
        stage = self.device
        if stage is None:
            return
        try:
            block = force_block_from_msg(msg)
            trip = stage.observe_force(block.force_n)
        except (DeviceError, ValueError) as exc:    # a malformed block: force_block's own
            self.fault(f'force guard: {exc}')
            return
        if trip is not None:
            self._report_trip(trip)
        if self.is_active:
            self._guard_progress.report(block.end_s)

    def _report_trip(self, trip) -> None:
        """A force-guard trip (over the ceiling, or readings gone stale) is not a device fault:
        the stage is stopped and the guard latched (no pull until the next activate); the stage
        stays open and keeps reporting that it stands. Reported once, as an ERROR."""
        reason = f'force guard: {trip}'
        if reason == self._reported_trip:
            return
        self._reported_trip = reason
        self._set_pull(None)                  # the guard stopped it: that pull is over
        self.get_logger().error(reason)
        self.report(ERROR, reason)

    # --- streaming --------------------------------------------------------------------------
    def _publish_state(self) -> None:
        stage = self.device
        if stage is None or not self.is_active:
            return
        try:
            state = stage.state()
        except DeviceError as exc:
            self.fault(f'reading the stage state: {exc}')
            return
        self._last_state = state
        self._watch_limits(state)
        self._watch_pull(state)
        msg = JointState(name=['stage'], position=[state.position_m],
                         velocity=[state.velocity_m_per_s], effort=[0.0])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._state_pub.publish(msg)
        trip = getattr(stage, 'tripped', None)
        if trip is not None:
            self._report_trip(trip)
        if state.fault and state.fault != str(trip):
            self.fault(f'stage reports a fault: {state.fault}')

    def _watch_pull(self, state) -> None:
        """A bounded pull that rests at its bound has ended there: the controller stopped it."""
        pull = self._pull
        if pull is None or state.moving \
                or (pull.bound_m - state.position_m) * PULL_DIRECTION > BOUND_REACHED_M:
            return
        with self._pull_lock:
            if self._pull is not pull:
                return
            self._pull = None
        self._supervised = None
        where = f'{state.position_m * 1e3:.4f} mm'
        if pull.at_soft_limit:
            self._motion_stopped(
                f'stopped at the forward travel limit (soft limit) at {where}: the pull\'s '
                f'bound {pull.describe()}; the controller stopped it there')
        else:
            self._motion_stopped(f'the pull reached its bound {pull.describe()} at {where}: '
                                 f'the controller stopped it there')

    def _watch_limits(self, state) -> None:
        at_limit = state.forward_limit or state.reverse_limit
        if at_limit and not self._at_limit:
            which = 'forward' if state.forward_limit else 'reverse'
            self._motion_stopped(f'stopped at the {which} travel limit (soft limit or limit '
                                 f'switch) at {state.position_m * 1e3:.4f} mm')
        self._at_limit = at_limit

    def _motion_stopped(self, reason: str) -> None:
        """The stage stopped or refused a move itself: count it and say why (WARN)."""
        self._motion_stops += 1
        self._last_motion_stop = reason
        self.get_logger().warning(reason)
        self.report(WARN, reason)

    # --- commands ---------------------------------------------------------------------------
    def _on_velocity(self, msg: Float64) -> None:
        velocity = msg.data
        if not self._accepting('velocity command', velocity):
            return
        self._stop_motion(stop_stage=False)
        what = f'velocity {velocity * 1e3:.4f} mm/s'
        if velocity * PULL_DIRECTION <= 0:
            self._set_pull(None)
            if velocity == 0.0:
                self._supervised = None
            elif not self._supervise(what):
                return
            self._command(lambda: self.device.move_at(velocity), what)
            return
        if not self._supervise(f'pull at {velocity * 1e3:.4f} mm/s'):
            return
        current, last = self._pull, self._last_state
        if current is not None and current.velocity_m_per_s == velocity \
                and last is not None and last.moving:
            return                      # pulling so already (a command sent again)
        try:
            pull = replace(current, velocity_m_per_s=velocity) if current is not None \
                else self._new_pull(velocity)
        except DeviceError as exc:
            self.fault(f'{what}: reading the stage state for the pull\'s bound: {exc}')
            return
        if self._command(lambda: self.device.move_at(velocity, pull.bound_m),
                         f'{what} bounded at {pull.describe()}'):
            self._set_pull(pull)
        else:
            self._set_pull(None)
            self._supervised = None

    def _new_pull(self, velocity: float) -> _Pull:
        """A pull from where the stage is now, bounded at its travel (or the soft limit)."""
        start_m = self.device.state().position_m
        travel_mm = float(self.param(TRAVEL_NAME))
        bound_m = start_m + PULL_DIRECTION * travel_mm * 1e-3
        limits = self.device.limits
        capped = min(max(bound_m, limits.min_position_m), limits.max_position_m)
        return _Pull(start_m, capped, travel_mm, capped != bound_m, velocity)

    def _set_pull(self, pull: _Pull | None) -> None:
        with self._pull_lock:
            self._pull = pull

    def _on_position(self, msg: Float64) -> None:
        if not self._accepting('position command', msg.data):
            return
        self._stop_motion()
        target, speed = msg.data, self.param('move_speed_m_per_s')
        what = f'move to {target * 1e3:.4f} mm'
        if not self._supervise(what):
            return

        def move():
            if self._command(lambda: self.device.move_to(target, speed, MOVE_TIMEOUT_S), what):
                if self._supervised == what:
                    self._supervised = None       # arrived: nothing left to watch
        with self._move_lock:
            self._move = threading.Thread(target=move, name='stage-move', daemon=True)
            self._move.start()

    # --- the supervisor's heartbeat ---------------------------------------------------------
    def _take_heartbeats(self) -> None:
        """Take every heartbeat that has arrived; any at all: the supervisor is heard now."""
        sent = None
        try:
            with self._heartbeat_sub.handle:
                while (taken := self._heartbeat_sub.handle.take_message(Header, False)):
                    if contract.heartbeat_source_pid(taken[0].frame_id) == os.getpid():
                        continue      # a supervisor in this process freezes with it
                    stamp = taken[0].stamp
                    sent = stamp.sec + stamp.nanosec * 1e-9
                    last_sent, self._heartbeat_sent_s = self._heartbeat_sent_s, sent
                    if last_sent is not None and self.is_active:
                        self._heartbeat_max_send_gap_s = max(self._heartbeat_max_send_gap_s,
                                                             sent - last_sent)
        except InvalidHandle:        # being destroyed
            return
        if sent is None:
            return
        now = time.monotonic()
        last, self._heartbeat_at = self._heartbeat_at, now
        if last is not None and self.is_active:
            self._heartbeat_max_gap_s = max(self._heartbeat_max_gap_s, now - last)

    def _heartbeat_lapse(self) -> float | None:
        """How long the heartbeat of a supervisor once heard has been silent, if longer than
        supervisor_heartbeat_timeout_s; None otherwise."""
        heard = self._heartbeat_at
        if heard is None:
            return None
        silent_s = time.monotonic() - heard
        return silent_s if silent_s > self.param('supervisor_heartbeat_timeout_s') else None

    def _supervise(self, what: str) -> bool:
        """Before a motion: refuse it if the supervisor's heartbeat has lapsed, else watch it
        (when a supervisor is heard) so that its lapse stops it."""
        lapse = self._heartbeat_lapse()
        if lapse is not None:
            self._set_pull(None)
            self._supervised = None
            self._motion_stopped(f'{what} refused: supervisor heartbeat lost for {lapse:.2f} s '
                                 f'(limit {self.param("supervisor_heartbeat_timeout_s"):g} s)')
            return False
        self._supervised = what if self._heartbeat_at is not None else None
        return True

    def _watch_heartbeat(self) -> None:
        """Each round: take the heartbeats that came, then stop a supervised motion if none
        has come for supervisor_heartbeat_timeout_s. This process not running for a while
        (swapped out, starved) makes no lapse: the heartbeats sent meanwhile are taken
        first."""
        while not self._watchdog_stop.wait(HEARTBEAT_CHECK_S):
            self._take_heartbeats()
            what = self._supervised
            if what is None or not self.is_active:
                continue
            lapse = self._heartbeat_lapse()
            if lapse is None:
                continue
            try:
                self._stop_for_lapse(what, lapse)
            except Exception as exc:  # noqa: BLE001 - the watchdog must go on
                self.get_logger().error(f'heartbeat watchdog: {exc}')

    def _stop_for_lapse(self, what: str, lapse: float) -> None:
        stage = self.device
        if stage is None or self._supervised != what:
            return
        self._supervised = None
        with self._move_lock:
            moving_thread = self._move is not None and self._move.is_alive()
        last = self._last_state
        moving = moving_thread or self._pull is not None or (last is not None and last.moving)
        self._stop_motion()
        if moving:
            self._motion_stopped(
                f'supervisor heartbeat lost for {lapse:.2f} s (limit '
                f'{self.param("supervisor_heartbeat_timeout_s"):g} s): the {what} was stopped')

    def _on_home(self, request, response):
        if not self.is_active:
            response.success, response.message = False, self._inactive_reason('home')
            return response
        self._stop_motion()
        try:
            self.device.home(HOME_TIMEOUT_S)
        except DeviceError as exc:
            self.fault(f'homing: {exc}')
            response.success, response.message = False, f'homing failed: {exc}'
            return response
        response.success, response.message = True, 'homed'
        return response

    def _on_stop(self, request, response):
        stage = self.device
        if stage is None:
            response.success = False
            response.message = f'no stage is open (node {self.state_label}): nothing to stop'
            return response
        self._stop_motion()
        response.success, response.message = True, 'stopped'
        return response

    def _accepting(self, what: str, value: float) -> bool:
        if not self.is_active:
            self.get_logger().warning(self._inactive_reason(what))
            return False
        if not math.isfinite(value):
            self._refuse(f'{what} {value} is not a finite number')
            return False
        return True

    def _command(self, action, what: str) -> bool:
        """Run a motion command; True if the stage took it (a move: reached its target)."""
        stage = self.device
        try:
            action()
            if self._refused is not None:
                self._refused = None
                self.report(OK, f'active ({self.backend_name})')
            return True
        except ConfigurationError as exc:       # outside the envelope: no retry will help
            self._refused = f'{what} refused: {exc}'
            self._motion_stopped(self._refused)
        except SafetyLimitError as exc:         # the force guard: may pass once a reading comes
            self._refuse(f'{what} refused: {exc}')
        except DeviceError as exc:
            if self.device is stage and self.is_active and not self._stopping:
                cause = f' ({self._stop_cause})' if self._stop_cause else ''
                self.fault(f'{what}: {exc}{cause}')
            else:
                self.get_logger().info(f'{what} ended: {exc}')
        return False

    def _refuse(self, reason: str) -> None:
        self._refused = reason
        self.get_logger().warning(reason)
        self.report(WARN, reason)

    def _stop_motion(self, stop_stage: bool = True) -> None:
        """End a position move in progress; stop the stage (which ends a pull, and leaves no
        motion for the heartbeat watchdog to watch)."""
        if stop_stage:
            self._set_pull(None)
            self._supervised = None
        with self._move_lock:
            move, self._move = self._move, None
            self._stopping = True
            try:
                stage = self.device
                if stage is not None and (stop_stage or move is not None):
                    try:
                        stage.stop()
                    except Exception as exc:  # noqa: BLE001 - stopping must go on
                        self.get_logger().error(f'stopping the stage: {exc}')
                if move is not None and move is not threading.current_thread():
                    move.join(timeout=5.0)
            finally:
                self._stopping = False

    def _inactive_reason(self, what: str) -> str:
        return f'{what} refused: stage_node is {self.state_label}, not active'


def _flag(value: bool) -> str:
    return 'true' if value else 'false'


def main(args=None) -> int:
    return run_node(StageNode, args)


if __name__ == '__main__':
    sys.exit(main())
