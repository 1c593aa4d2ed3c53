"""The trial state machine, as plain logic: what the supervisor does, in which order, and when
it gives up. No ROS here: the supervisor node implements the RigPort (service calls, command
topics) and feeds what it hears (force blocks, stage state, camera trigger, marker frames,
device faults) into the TrialSequence's ``on_*`` methods, from any thread.

``run()`` (the supervisor's worker thread) goes through
configuring -> [homing] -> [returning to the start] -> taking_up_slack -> [taring] -> arming ->
pulling -> released -> stopping -> returning -> done, and ends in ``aborted`` instead when
``abort(reason)`` is called (abort service, force ceiling, travel limit, the stage stopped by a
limit or refusing a move, device fault, timeout, failed call). An abort stops the stage at once,
from the thread that detected it. The trial's travel limit is also set on the stage, whose
controller ends every pull there by itself (and stage_node stops a pull when this process's
heartbeat lapses: mantis_rig.trial.safety_limits); a pull that reached its bound is a motion
stop the stage reports, and ends the trial like the travel check here. On release the force
callback stops the stage and fires the camera trigger itself, without waiting for the worker.

Every trial starts from a known state (a lab runs many on one bring-up): the stage goes to the
trial's start position (``start_position_mm``, or where the first trial of the bring-up
started: ``SessionState``) before it takes up slack, and after any end, an abort too, it goes
back there, unless the stack is shutting down. A robot that struck must be re-latched by hand:
the trial then ends in ``waiting_for_relatch``. A robot that is not latched is caught while
taking up slack: the tendon stays slack over ``latch_check_mm`` of take-up.

In simulation the trial's conditions (d_t_mm, contact_angle_deg, medium) are first set on the
simulated world, which builds the latched robot from them; one it cannot apply ends the trial
before anything moves, with the world's reason. A new robot steps the tendon force: the trial
reads the force only from after the world's status reported the robot at its conditions
(``on_world_status``), so that a step still on its way is not taken for the release.

At each poll the worker reports its progress (``report_progress``): the rig time up to which it
has read the force stream and acted on what it read; 0 once the trial has ended. The simulated
world waits for it, so a worker starved of the processor slows the world down instead of
taking up slack past the release or hearing the release late.
"""
from __future__ import annotations

from collections.abc import Callable
import math
import threading
import time
from typing import Protocol

from mantis_rig.contract import (
    CAMERA_ARM,
    CAMERA_TRIGGER,
    DEVICE_NODES,
    FORCE_CEILING_NAME,
    FORCE_GUARD_NODES,
    SIM_WORLD_NODE,
    STAGE_HOME,
    STAGE_NODE,
    TARE,
    WORLD_CONDITIONS,
)
from mantis_rig.trial.supervisor_settings import TrialConditions

from .force_monitor import ForceMonitor
from .loading_work import LoadingWork
from .safety_limits import PULL_BOUND_NODES, TRAVEL_NAME

STATES = ('idle', 'configuring', 'homing', 'taking_up_slack', 'taring', 'arming', 'pulling',
          'released', 'stopping', 'returning', 'done', 'aborted', 'waiting_for_relatch')
FINAL_STATES = ('idle', 'done', 'aborted', 'waiting_for_relatch')
POLL_S = 0.005                   # the worker's control period
AT_REST_M_PER_S = 1e-6
# A move has ended when the stage rested this long, on the rig's clock: simulated time in
# simulation, where a slow machine slows the world down and 0.3 s of wall time may show no
# motion yet (the supervisor then took a move just sent for one already over).
SETTLED_S = 0.3
MOVE_ATTEMPTS = 3
# A command the stage has not acted on after this long is sent again: the stage refuses a pull
# until its own force feed has a reading, and in a multi-process stack that feed can start after
# the supervisor's (the refusal is a WARN, not a fault). On both clocks: the stage's reaction
# takes rig time, the command's delivery wall time, and at --real-time-factor 0 the simulated
# rig's time runs ahead of a command still on its way.
MOVE_START_S = 0.5
HOMED_WAIT_S = 3.0               # unknown after this long: go on without homing
QUERY_RETRY_S = 5.0              # an idempotent query unanswered this long is sent again
STOP_CONFIRM_S = 2.0             # after an abort, wait this long for the stage to report rest
TRANSITION_GOALS = {'configure': 'inactive', 'activate': 'active', 'deactivate': 'inactive'}
RELATCH_REASON = 're-latch the robot, then start the next trial'
#: the trial conditions the simulated world builds its robot from (d_t_mm, contact_angle_deg,
#: medium; the pull speed is the stage's to command)
WORLD_CONDITION_NAMES = tuple(spec.name for spec in WORLD_CONDITIONS)


def _number(text) -> float:
    """A number a status printed; NaN for a missing or unreadable one (matches nothing)."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


class SessionState:
    """What one bring-up's trials hand on to the next (the supervisor owns it): where the
    trials start, and which devices reported an ERROR (a latched force-guard trip, a fault)
    that the next trial's bring-up must clear by cycling them through inactive."""

    def __init__(self):
        self.start_position_m: float | None = None
        self.devices_in_error: set[str] = set()


class TrialAborted(Exception):
    pass


class _ReturnEnded(Exception):
    """The return after an abort ends where the stage is (a second abort, its time is up)."""


class Pending:
    """The answer to a request, set later from another thread: (ok, message) or a value."""

    def __init__(self, value=None, done=False):
        self._event = threading.Event()
        self._value = value
        if done:
            self._event.set()

    def set(self, value) -> None:
        self._value = value
        self._event.set()

    def done(self) -> bool:
        return self._event.is_set()

    def value(self):
        return self._value


class RigPort(Protocol):
    """What the sequence asks of the rig. Calls return at once; Pending values are
    (ok: bool, message: str), except get_state's (ok, state label)."""

    def now_s(self) -> float: ...
    def get_state(self, node: str) -> Pending: ...
    def change_state(self, node: str, transition: str) -> Pending: ...
    def call(self, service: str) -> Pending: ...          # std_srvs/Trigger, by contract name
    def set_camera(self, frame_rate_hz: float, pre_trigger_s: float,
                   post_trigger_s: float, film_dir: str = '') -> Pending: ...
    def set_parameters(self, node: str, values: dict) -> Pending: ...
    def move_at(self, velocity_m_per_s: float) -> None: ...
    def move_to(self, position_m: float) -> None: ...
    def stop_stage(self) -> None: ...                     # velocity 0 and stage/stop, at once
    def publish_state(self, state: str, reason: str) -> None: ...
    def report_progress(self, rig_time_s: float) -> None: ...   # 0: no trial running


class TrialSequence:
    def __init__(self, rig: RigPort, conditions: TrialConditions,
                 close_log: Callable[[dict], None] | None = None,
                 session: SessionState | None = None, film_dir: str = ''):
        """film_dir: where the simulated camera films this trial ('' : no film; the
        supervisor's ``video``); set on the camera with its window before it is armed."""
        self.rig = rig
        self.conditions = conditions
        self.film_dir = str(film_dir)
        self.session = session or SessionState()
        self._reset_devices = set(self.session.devices_in_error)
        self.close_log = close_log or (lambda outcome: None)
        self.monitor = ForceMonitor(conditions.force_ceiling_n, conditions.release_jump_n)
        self.loading = LoadingWork()
        self.state = 'idle'
        self.reason = ''
        self.outcome: dict = {}
        self.state_times: list[tuple[str, float]] = []
        self.finished = threading.Event()
        self._lock = threading.RLock()
        self._abort = threading.Event()
        self._return_after_abort = True
        self._stop_return = threading.Event()      # a second abort ends the return too
        self._released = threading.Event()
        self._active_devices = False
        # what the rig reported
        self.stage_position_m: float | None = None
        self.stage_velocity_m_per_s: float | None = None
        self.stage_homed: bool | None = None
        self._stage_updates = 0
        self.start_position_m: float | None = None
        self.pull_start_position_m: float | None = None
        self.return_error_m: float | None = None
        self._last_motion = -math.inf           # rig time the stage was last seen moving
        self.trigger_time_s: float | None = None
        self.marker_span_s: tuple[float, float] | None = None
        self.marker_frames = 0
        self.device_messages: dict[str, str] = {}
        self.device_in_error: dict[str, bool] = {}
        self._trigger_call: Pending | None = None
        self._world_asked = False
        self.world_built_s: float | None = None   # rig time the world had the trial's robot

    # ------------------------------------------------------------------ status
    @property
    def running(self) -> bool:
        return self.state not in FINAL_STATES

    def _set_state(self, state: str, reason: str = '') -> None:
        with self._lock:
            self.state = state
            self.state_times.append((state, self.rig.now_s()))
        self.rig.publish_state(state, reason)

    # ------------------------------------------------------------------ aborting
    def abort(self, reason: str, return_stage: bool = True) -> tuple[bool, str]:
        """Stop the stage now and end the trial as aborted, then return the stage to the
        start (not with ``return_stage=False``: the stack is shutting down); refused (False,
        why) when no trial is in progress or it is already ending."""
        with self._lock:
            if not self.running:
                return False, f'no trial in progress (state {self.state})'
            if self._abort.is_set():
                return False, f'the trial is already aborting: {self.reason}'
            self.reason = reason
            self._return_after_abort = return_stage
            self._abort.set()
        self.rig.stop_stage()
        return True, f'aborting: {reason}'

    def stop_where_it_is(self) -> None:
        """A second abort request from the operator: stop the stage, and no return to the
        start after this abort."""
        self._stop_return.set()
        self.rig.stop_stage()

    def _check(self) -> None:
        if self._abort.is_set():
            raise TrialAborted(self.reason)

    def _fail(self, reason: str) -> None:
        self.abort(reason)
        raise TrialAborted(self.reason)

    def _wait(self, ready: Callable[[], bool], what: str, timeout_s: float | None = None):
        if not self._wait_for(ready, timeout_s or self.conditions.phase_timeout_s):
            self._fail(f'timeout: {what} (state {self.state})')

    def _wait_for(self, ready: Callable[[], bool], timeout_s: float) -> bool:
        """Poll until ready() (True) or timeout_s of wall time (False); raise on abort."""
        deadline = time.monotonic() + timeout_s
        while True:
            self._check()
            heard_s = self._heard_until_s()
            if ready():
                return True
            if time.monotonic() > deadline:
                return False
            self._pause(heard_s)

    def _heard_until_s(self) -> float:
        """The rig time up to which this process has heard the rig and acted on it: its
        clock, and the force stream's end once that streams (it may lag the clock); no further
        than the release while the camera's trigger is on its way (its buffer must hold the
        strike)."""
        heard_s = self.rig.now_s()
        force_end_s = self.monitor.end_t_s
        if force_end_s is not None:
            heard_s = min(heard_s, force_end_s)
        trigger, release_s = self._trigger_call, self.monitor.release_t_s
        if trigger is not None and not trigger.done() and release_s is not None:
            heard_s = min(heard_s, release_s)
        return heard_s

    def _pause(self, acted_until_s: float) -> None:
        """Between two polls: report that everything heard up to acted_until_s (read before
        the poll's decision) has been acted on, then sleep one poll period."""
        self.rig.report_progress(acted_until_s)
        time.sleep(POLL_S)

    def _await(self, pending: Pending, what: str):
        self._wait(pending.done, what)
        ok, message = pending.value()
        if not ok:
            self._fail(f'{what} failed: {message}')
        return message

    # ------------------------------------------------------------------ observations
    def on_force_block(self, t0_s: float, period_s: float, forces) -> None:
        with self._lock:
            self.monitor.feed(t0_s, period_s, forces)
            hit = self.monitor.ceiling_hit
            release = (self.state == 'pulling' and self.monitor.release_t_s is not None
                       and not self._released.is_set())
            if release:
                self._released.set()
                self.loading.stop()
        if hit is not None and self.running and self.conditions.supervisor_force_monitor:
            self.abort(f'force ceiling: {hit[1]:.2f} N > {self.conditions.force_ceiling_n} N '
                       f'at t = {hit[0]:.4f} s')
        elif release and not self._abort.is_set():
            self.rig.stop_stage()                        # the tendon stiffens after the strike
            self._trigger_call = self.rig.call(CAMERA_TRIGGER.name)
            self._set_state('released')

    def on_stage_state(self, position_m: float, velocity_m_per_s: float) -> None:
        previous = self.stage_position_m
        if abs(velocity_m_per_s) >= AT_REST_M_PER_S or previous is None \
                or abs(position_m - previous) > 1e-6:
            self._last_motion = self.rig.now_s()
        self.stage_position_m, self.stage_velocity_m_per_s = position_m, velocity_m_per_s
        self.loading.step(position_m, self.monitor.latest_n)
        self._stage_updates += 1
        start = self.pull_start_position_m
        if start is not None and self.state in ('taking_up_slack', 'pulling') \
                and abs(position_m - start) > self.conditions.travel_mm * 1e-3:
            self.abort(f'travel limit: the stage moved {abs(position_m - start) * 1e3:.3f} mm '
                       f'> {self.conditions.travel_mm} mm')

    def on_stage_homed(self, homed: bool) -> None:
        self.stage_homed = homed

    def on_camera_trigger(self, t_s: float) -> None:
        self.trigger_time_s = t_s

    def on_markers(self, first_s: float, last_s: float, n_frames: int) -> None:
        with self._lock:
            span = self.marker_span_s
            self.marker_span_s = (first_s, last_s) if span is None else \
                (min(span[0], first_s), max(span[1], last_s))
            self.marker_frames += n_frames

    def on_world_status(self, status: dict) -> None:
        """The simulated world's status (its diagnostics' values, as printed): ``time_s``, its
        rig time, and the conditions its current robot was built at (WORLD_CONDITION_NAMES).
        A value missing or unreadable matches nothing."""
        if not self._world_asked or self.world_built_s is not None:
            return
        for name in WORLD_CONDITION_NAMES:
            wanted, built = getattr(self.conditions, name), status.get(name)
            if isinstance(wanted, str):
                if built != wanted:
                    return
            elif not math.isclose(_number(built), wanted, rel_tol=1e-5):
                return
        time_s = _number(status.get('time_s'))
        if math.isfinite(time_s):
            self.world_built_s = time_s

    def on_device_message(self, node: str, message: str, in_error: bool = False) -> None:
        self.device_messages[node] = message
        self.device_in_error[node] = in_error

    def on_stage_motion_stop(self, reason: str) -> None:
        """The stage stopped a move itself (a soft travel limit, a limit switch) or refused
        one outside its envelope: the trial cannot go on as planned, so it ends now."""
        if self._active_devices and self.running:
            self.abort(f'stage stopped: {reason}')

    def on_device_fault(self, node: str, reason: str) -> None:
        if self._active_devices and self.running:
            self.abort(f'device fault: {node}: {reason}')

    # ------------------------------------------------------------------ the trial
    def start(self) -> threading.Thread:
        """Enter 'configuring' now (so an abort is accepted at once) and run() in a thread."""
        self._set_state('configuring')
        worker = threading.Thread(target=self.run, name='trial', daemon=True)
        worker.start()
        return worker

    def run(self) -> dict:
        """Run one trial to its end; return the outcome (also given to close_log)."""
        try:
            self._bring_up()
            self._home()
            self._take_up_slack()
            if self.conditions.tare:
                self._set_state('taring')
                self._await(self.rig.call(TARE.name), 'loadcell tare')
            self._arm()
            self._pull()
            self._stop_and_record()
            self._return()
            return self._finish('done', 'completed', '')
        except TrialAborted:
            return self._finish('aborted', 'aborted', self.reason)
        except Exception as exc:  # noqa: BLE001 - the trial thread's boundary: a bug must still stop the stage and close the log (its name is the abort reason)
            self.abort(f'supervisor error: {type(exc).__name__}: {exc}')
            return self._finish('aborted', 'aborted', self.reason)

    def _bring_up(self) -> None:
        if self.state != 'configuring':
            self._set_state('configuring')
        # Simulated: the rig's clock is the world's (/clock); before its first tick it reads 0
        # and nothing logged or timed would be on the world's time.
        self._wait(lambda: self.rig.now_s() > 0.0, 'the rig clock (simulated: /clock)')
        if self.conditions.backend == 'sim':
            self._simulate_the_conditions()
        for node in DEVICE_NODES:
            label = self._device_state(node)
            steps = {'unconfigured': ('configure', 'activate'), 'inactive': ('activate',),
                     'active': ()}.get(label)
            if steps is None:
                self._fail(f'{node} is {label}, cannot bring it up'
                           + self._device_hint(node))
            if label == 'active' and node in self._reset_devices:
                steps = ('deactivate', 'activate')     # clears a latched trip or fault
            limits = {}                          # one value of each limit for every guard
            if node in FORCE_GUARD_NODES:
                limits[FORCE_CEILING_NAME] = self.conditions.force_ceiling_n
            if node in PULL_BOUND_NODES:        # the controller ends each pull at its travel
                limits[TRAVEL_NAME] = self.conditions.travel_mm
            if limits:
                self._await(self.rig.set_parameters(node, limits),
                            f'setting the safety limits ({", ".join(limits)}) on {node}')
            for transition in steps:
                self._transition(node, transition)
        for node in self._reset_devices:
            # its status since the reset: an ERROR still on its way would abort the trial
            self.device_in_error[node] = True
            self._wait(lambda node=node: not self.device_in_error.get(node, False),
                       f'{node} to report its status after the reset'
                       + self._device_hint(node))
        self.session.devices_in_error -= self._reset_devices
        self._active_devices = True

    def _simulate_the_conditions(self) -> None:
        """Simulated: before anything moves, the world builds the latched robot at the trial's
        conditions (the ones the bag records); one it cannot apply (its robot already loaded,
        a scene that cannot take them) ends the trial, so that nothing is recorded as if it
        had been simulated."""
        c = self.conditions
        values = {name: getattr(c, name) for name in WORLD_CONDITION_NAMES}
        # the first call of a trial to the rig: a reply lost while DDS still matches a process
        # that has just started is asked for again (setting the same values again is accepted)
        deadline = time.monotonic() + c.phase_timeout_s
        self._world_asked = True
        while True:
            pending = self.rig.set_parameters(SIM_WORLD_NODE, values)
            if self._wait_for(pending.done, min(QUERY_RETRY_S, deadline - time.monotonic())):
                break
            if time.monotonic() >= deadline:
                self._fail(f'timeout: {SIM_WORLD_NODE} taking the trial\'s conditions (state '
                           f'{self.state})')
        ok, message = pending.value()
        if not ok:
            self._fail(f'the simulated world could not apply the trial\'s conditions: '
                       f'{message}')

    def _device_state(self, node: str) -> str:
        """The node's lifecycle state label. A query that goes unanswered is sent again: a
        reply can be lost while DDS is still matching a node that has just started."""
        deadline = time.monotonic() + self.conditions.phase_timeout_s
        while True:
            pending = self.rig.get_state(node)
            if self._wait_for(pending.done, min(QUERY_RETRY_S, deadline - time.monotonic())):
                ok, label = pending.value()
                if not ok:
                    self._fail(f'{node} get_state failed: {label}')
                return label
            if time.monotonic() >= deadline:
                self._fail(f'timeout: {node} get_state (state {self.state})')

    def _transition(self, node: str, transition: str) -> None:
        """Request a lifecycle transition and wait for it; if its answer is slow, ask the node
        for its state: a transition that took effect counts even if its reply was lost."""
        goal = TRANSITION_GOALS[transition]
        pending = self.rig.change_state(node, transition)
        deadline = time.monotonic() + self.conditions.phase_timeout_s
        while not self._wait_for(pending.done, min(QUERY_RETRY_S, deadline - time.monotonic())):
            if time.monotonic() >= deadline:
                self._fail(f'timeout: {node} {transition} (state {self.state})')
            state = self.rig.get_state(node)
            if self._wait_for(state.done, QUERY_RETRY_S) and state.value() == (True, goal):
                return
        ok, message = pending.value()
        if not ok:
            self._fail(f'{node} {transition} failed: {message}' + self._device_hint(node))

    def _device_hint(self, node: str) -> str:
        message = self.device_messages.get(node)
        return f' ({node} reports: {message})' if message else ''

    def _home(self) -> None:
        self._wait(lambda: self.stage_position_m is not None, 'stage state', 10.0)
        deadline = time.monotonic() + HOMED_WAIT_S     # stage_node's diagnostics say it
        self._wait(lambda: self.stage_homed is not None or time.monotonic() > deadline,
                   'stage diagnostics')
        if self.stage_homed is False:
            self._set_state('homing')
            self._await(self.rig.call(STAGE_HOME.name), 'stage home')
        c = self.conditions
        start_m = c.start_position_mm * 1e-3 if c.start_position_mm >= 0 \
            else self.session.start_position_m
        if start_m is not None and \
                abs(self.stage_position_m - start_m) >= c.position_tolerance_mm * 1e-3:
            self._set_state('returning')
            error_m = self._move_to(start_m, 'move to the start position')
            if abs(error_m) >= c.position_tolerance_mm * 1e-3:
                self._fail(f'the stage stopped {error_m * 1e3:+.4f} mm from the start position')
        self.start_position_m = self.stage_position_m if start_m is None else start_m
        if self.session.start_position_m is None:
            self.session.start_position_m = self.start_position_m

    def _move_to(self, target_m: float, what: str,
                 wait: Callable[[Callable[[], bool]], None] | None = None) -> float:
        """Move to target_m and let the stage settle; retry a move that ends outside the
        tolerance, or never starts (MOVE_ATTEMPTS in all). Return the remaining error, m.
        ``wait(ready)`` waits for each move (default: :meth:`_wait`, which ends on an abort)."""
        wait = wait or (lambda ready: self._wait(ready, what))
        tolerance_m = self.conditions.position_tolerance_mm * 1e-3
        for _ in range(MOVE_ATTEMPTS):
            self.rig.move_to(target_m)
            commanded = self._command_sent()

            def settled(since=commanded) -> bool:
                acted = self._last_motion > since[0] \
                    or abs(self.stage_position_m - target_m) < tolerance_m
                if not acted:
                    return self._not_acted_on(since)
                return self._at_rest() and SETTLED_S <= self.rig.now_s() - self._last_motion \
                    and SETTLED_S <= self.rig.now_s() - since[0]

            wait(settled)
            error_m = self.stage_position_m - target_m
            if abs(error_m) < tolerance_m:
                break
        return error_m

    def _command_sent(self) -> tuple[float, float]:
        """(rig time, wall time) of a command just sent."""
        return self.rig.now_s(), time.monotonic()

    def _not_acted_on(self, sent: tuple[float, float]) -> bool:
        """MOVE_START_S has passed on both clocks since ``sent`` (:meth:`_command_sent`)."""
        return (self.rig.now_s() - sent[0] >= MOVE_START_S
                and time.monotonic() - sent[1] >= MOVE_START_S)

    def _take_up_slack(self) -> None:
        self._set_state('taking_up_slack')
        self._wait(lambda: self.monitor.latest_n is not None, 'the force stream')
        if self.conditions.backend == 'sim':
            self._wait(lambda: self.world_built_s is not None,
                       'the simulated world\'s status at the trial\'s conditions')
            self._wait(lambda: self.monitor.end_t_s > self.world_built_s,
                       'the force of the robot built at the trial\'s conditions')
        c = self.conditions
        if self.monitor.latest_n < c.slack_force_n:
            self.pull_start_position_m = start = self.stage_position_m

            def taut() -> bool:
                return self.monitor.latest_n >= c.slack_force_n

            def slack_too_long() -> bool:
                return abs(self.stage_position_m - start) > c.latch_check_mm * 1e-3

            self._start_moving(c.slack_speed_mm_s * 1e-3, 'taking up slack', taut)
            self._wait(lambda: taut() or slack_too_long(), 'taking up slack')
            self.rig.stop_stage()
            if not taut():
                self._fail(f'the robot is not latched: the tendon force stayed below '
                           f'{c.slack_force_n} N over {c.latch_check_mm} mm of take-up '
                           f'(latch_check_mm); {RELATCH_REASON}')
            self._wait(self._at_rest, 'the stage to stop after taking up slack')

    def _at_rest(self) -> bool:
        return abs(self.stage_velocity_m_per_s) < AT_REST_M_PER_S

    def _arm(self) -> None:
        self._set_state('arming')
        c = self.conditions
        self._await(self.rig.set_camera(c.frame_rate_hz, c.pre_trigger_s, c.post_trigger_s,
                                        self.film_dir),
                    'set camera parameters')
        self._await(self.rig.call(CAMERA_ARM.name), 'camera arm')

    def _pull(self) -> None:
        self.pull_start_position_m = self.stage_position_m
        with self._lock:
            self.loading.start(self.stage_position_m)
            self.monitor.arm_release()
            self._set_state('pulling')
        self._start_moving(self.conditions.pull_speed_mm_s * 1e-3, 'the pull',
                           self._released.is_set)
        self._wait(self._released.is_set, 'release not detected')

    def _start_moving(self, velocity_m_per_s: float, what: str,
                      done: Callable[[], bool]) -> None:
        """Command a constant velocity until the stage moves (or ``done()``): a command it has
        not acted on within MOVE_START_S (:meth:`_not_acted_on`) is sent again, MOVE_ATTEMPTS in
        all."""
        for _ in range(MOVE_ATTEMPTS):
            self.rig.move_at(velocity_m_per_s)
            commanded = self._command_sent()
            self._wait(lambda since=commanded: not self._at_rest() or done()
                       or self._not_acted_on(since), what)
            if not self._at_rest() or done():
                return
        self._fail(f'{what}: the stage did not start moving after {MOVE_ATTEMPTS} velocity '
                   'commands' + self._device_hint(STAGE_NODE))

    def _stop_and_record(self) -> None:
        self._set_state('stopping')
        self._wait(self._at_rest, 'the stage to stop')
        self._await(self._trigger_call, 'camera trigger')
        self._wait(lambda: self.trigger_time_s is not None, 'the camera trigger time')
        c = self.conditions
        end = self.trigger_time_s + c.post_trigger_s
        self._wait(lambda: self.rig.now_s() >= end, 'the camera post-trigger window')
        if c.expect_markers:
            tolerance = max(2.0 / c.frame_rate_hz, 0.01)
            self._wait(lambda: self.marker_span_s is not None
                       and self.marker_span_s[1] >= end - tolerance, 'the marker frames')

    def _return(self) -> None:
        self._set_state('returning')
        self.return_error_m = self._move_to(self.start_position_m, 'return to the start position')

    def _finish(self, state: str, result: str, reason: str) -> dict:
        stage_stopped = stage_returned = None
        if state == 'aborted':
            stage_stopped = self._stop_and_confirm()
            if self._return_after_abort:
                stage_returned = self._return_after_an_abort()
        outcome = self._outcome(result, reason)
        if stage_stopped is not None:
            outcome['stage_stopped'] = stage_stopped
        if stage_returned:
            outcome['stage_returned'] = stage_returned
        self._set_state(state, reason)
        self.outcome = outcome
        try:
            self.close_log(outcome)
        finally:
            if self.monitor.release_t_s is not None:     # it struck: a person re-latches it
                self._set_state('waiting_for_relatch', RELATCH_REASON)
            self.rig.report_progress(0.0)                # nothing more to wait for
            self.finished.set()
        return outcome

    def _return_after_an_abort(self) -> str:
        """Take the stage back to the trial's start after an abort, at the stage's move speed,
        so that the next trial finds it there: 'true', or why not. A move that does not start,
        or ends short (the abort's own stop call may reach the stage after it), is sent again
        (:meth:`_move_to`). A second abort ends the attempt where the stage is."""
        target = self.start_position_m
        if target is None or self.stage_position_m is None:
            return ''
        tolerance_m = self.conditions.position_tolerance_mm * 1e-3
        if abs(self.stage_position_m - target) < tolerance_m:
            return 'true'
        self._set_state('returning', self.reason)
        deadline = time.monotonic() + self.conditions.phase_timeout_s

        def wait(ready: Callable[[], bool]) -> None:
            while True:
                heard_s = self._heard_until_s()
                if ready():
                    return
                if self._stop_return.is_set():
                    raise _ReturnEnded('stopped by a second abort')
                if time.monotonic() > deadline:
                    self.rig.stop_stage()
                    raise _ReturnEnded(f'not back within {self.conditions.phase_timeout_s} s')
                self._pause(heard_s)

        try:
            error_m = self._move_to(target, 'return to the start', wait)
        except _ReturnEnded as ended:
            return f'false: {ended}'
        if abs(error_m) < tolerance_m:
            return 'true'
        return 'false: the stage did not reach the start' + self._device_hint(STAGE_NODE)

    def _stop_and_confirm(self) -> str:
        """Stop the stage and wait (briefly) for a stage state reporting rest, so that the
        log shows the stage standing: 'true', or 'unconfirmed' if none came."""
        self.rig.stop_stage()
        if self.stage_position_m is None:
            return 'unconfirmed'
        seen = self._stage_updates
        deadline = time.monotonic() + STOP_CONFIRM_S
        while time.monotonic() < deadline:
            heard_s = self._heard_until_s()
            if self._stage_updates > seen and self._at_rest():
                return 'true'
            self._pause(heard_s)
        return 'unconfirmed'

    def _outcome(self, result: str, reason: str) -> dict:
        m = self.monitor
        out = {'result': result, 'reason': reason,
               'force_samples': m.samples, 'force_gaps': len(m.gaps),
               'force_stream_s': f'{m.duration_s:.6f}',
               'peak_force_n': f'{m.peak_n:.4f}' if m.samples else '',
               'peak_force_time_s': f'{m.peak_t_s:.6f}' if m.samples else '',
               'release_time_s': '' if m.release_t_s is None else f'{m.release_t_s:.6f}',
               'loading_work_mj': f'{self.loading.mj:.4f}'
               if self.loading.started and m.release_t_s is not None else '',
               'camera_trigger_time_s': '' if self.trigger_time_s is None
               else f'{self.trigger_time_s:.6f}',
               'marker_frames': self.marker_frames,
               'return_error_mm': '' if self.return_error_m is None
               else f'{self.return_error_m * 1e3:.4f}',
               'states': ';'.join(f'{s}@{t:.4f}' for s, t in self.state_times)}
        if self.marker_span_s is not None:
            out['marker_span_s'] = f'{self.marker_span_s[0]:.6f},{self.marker_span_s[1]:.6f}'
            if m.release_t_s is not None:
                caught = self.marker_span_s[0] <= m.release_t_s <= self.marker_span_s[1]
                out['release_in_camera_window'] = str(caught).lower()
        return out
