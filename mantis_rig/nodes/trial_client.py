"""TrialClient: a small node that starts a trial through /supervisor/start_trial and follows
/supervisor/state until the trial ends, and sets the supervisor's parameters between trials
(for `mantis trial`, `mantis start|abort|state`, studies and the tests).

The supervisor publishes a trial's end (``done``, ``aborted``; ``waiting_for_relatch`` after a
strike) once its log is closed, so a start asked for after hearing it is accepted: nothing here
asks again.

A service's answer can be lost: Fast DDS drops a response when the server has not yet matched the
client's response reader (rmw_fastrtps waits about 100 ms, then "client will not receive
response"), which a loaded machine with the supervisor in its own process does hit. So a call
also ends when the supervisor's own publications show that the request took effect: its
diagnostics counting one trial more (with the new bag), or its state reaching an end.
"""
from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from std_msgs.msg import String
from std_srvs.srv import Trigger

from mantis_rig import contract
from mantis_rig.faults import StackError
from mantis_rig.runtime.lean_node import WithoutDefaultEventHandlers
from mantis_rig.trial.supervisor_settings import PARAMETERS

from .supervisor_node import STATUS_NAME

ANSWER_GRACE_S = 2.0    # how long an answer is awaited before the supervisor's publications count
END_STATES = ('done', 'aborted')
# How long wait_for_supervisor waits at a time for the supervisor's first diagnostics once its
# service is up (between two calls of its ``alive()``)
SUPERVISOR_HEARD_CHECK_S = 0.1


def parameter_value(name: str, value) -> ParameterValue:
    """``value`` as the supervisor declares parameter ``name``: a double (an int too), a
    string or a bool; ValueError if it is none of that, KeyError for an unknown name."""
    default = PARAMETERS[name].default
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f'{value!r} is not a boolean')
        return ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f'{value!r} is not a number')
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(value))
    if not isinstance(value, str):
        raise ValueError(f'{value!r} is not a string')
    return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)


class TrialClient(WithoutDefaultEventHandlers, Node):
    def __init__(self, node_name: str = contract.TRIAL_CLIENT_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.states: list[str] = []
        self.trial_start = 0
        self._changed = threading.Condition()
        c = contract
        self._start = self.create_client(Trigger, c.START_TRIAL.name)
        self._abort = self.create_client(Trigger, c.ABORT.name)
        self._set_parameters = self.create_client(
            SetParameters, c.node_interface(c.SUPERVISOR_NODE, c.SET_PARAMETERS))
        self._get_parameters = self.create_client(
            GetParameters, c.node_interface(c.SUPERVISOR_NODE, c.GET_PARAMETERS))
        self.create_subscription(String, c.SUPERVISOR_STATE.name, self._on_state,
                                 c.SUPERVISOR_STATE.qos.subscriber())
        self.reason = ''            # the supervisor's reason for its state (its diagnostics)
        self.supervisor_trials: int | None = None     # trials it has started (its diagnostics)
        self.supervisor_bag = ''                      # its current or last bag (its diagnostics)
        self.supervisor_status: dict[str, str] = {}   # all its diagnostics' values
        self.reasons: dict[tuple[str, str], str] = {}  # (bag, state) -> its reason, as heard
        self.create_subscription(DiagnosticArray, c.DIAGNOSTICS.name, self._on_diagnostics,
                                 c.DIAGNOSTICS.qos.subscriber())

    def _on_state(self, msg) -> None:
        with self._changed:
            self.states.append(msg.data)
            self._changed.notify_all()

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            if status.name == STATUS_NAME:
                values = {kv.key: kv.value for kv in status.values}
                with self._changed:
                    self.supervisor_status = values
                    self.reasons[values.get('bag', ''), values.get('state', '')] = \
                        values.get('reason', '')
                    self.reason = values.get('reason', '')
                    self.supervisor_trials = int(values.get('trials') or 0)
                    self.supervisor_bag = values.get('bag', '')
                    self._changed.notify_all()

    def wait_for_supervisor(self, timeout_s: float = 60.0, alive=lambda: None) -> bool:
        """Wait for /supervisor/start_trial and for the supervisor's diagnostics (the count of
        trials a start is judged against); ``alive()`` may raise to stop waiting."""
        deadline = time.monotonic() + timeout_s
        while not self._start.wait_for_service(timeout_sec=0.5) or \
                not self._heard_supervisor(SUPERVISOR_HEARD_CHECK_S):
            alive()
            if time.monotonic() > deadline:
                return False
        return True

    def _heard_supervisor(self, timeout_s: float) -> bool:
        """Whether the supervisor's diagnostics have been heard, waiting up to ``timeout_s``
        for them (the service is up before its first status comes: without a wait, the loop
        above spun, 0.7 CPU s of a multi-process trial's command line)."""
        with self._changed:
            if self.supervisor_trials is None:
                self._changed.wait(timeout_s)
            return self.supervisor_trials is not None

    def call(self, which: str, timeout_s: float = 30.0) -> tuple[bool, str]:
        """Call start_trial or abort; (success, message), or (False, why) on timeout. Without
        an answer, a call that the supervisor's publications show took effect succeeds."""
        client = {'start_trial': self._start, 'abort': self._abort}[which]
        name = self.resolve_service_name(client.srv_name)
        if not client.wait_for_service(timeout_sec=timeout_s):
            return False, f'{name} is not available after {timeout_s} s'
        took_effect = {'start_trial': self._trial_started_since(self.supervisor_trials),
                       'abort': self._trial_ended_since(len(self.states))}[which]
        future = client.call_async(Trigger.Request())
        future.add_done_callback(lambda _: self._notify())
        called = time.monotonic()
        with self._changed:
            while not future.done():
                waited = time.monotonic() - called
                effect = took_effect() if waited >= ANSWER_GRACE_S else None
                if effect is not None:
                    self.get_logger().warning(f'{name} did not answer; {effect}')
                    return True, effect
                if waited >= timeout_s:
                    return False, f'{name} did not answer within {timeout_s} s'
                next_look = ANSWER_GRACE_S if waited < ANSWER_GRACE_S else timeout_s
                self._changed.wait(min(next_look, timeout_s) - waited)
        return future.result().success, future.result().message

    def _notify(self) -> None:
        with self._changed:
            self._changed.notify_all()

    def _trial_started_since(self, trials_before: int | None):
        """What the supervisor's diagnostics say of a trial started since it had started
        ``trials_before`` (None: never heard, nothing to judge by)."""
        def started() -> str | None:
            if trials_before is None or self.supervisor_trials is None or \
                    self.supervisor_trials <= trials_before or not self.supervisor_bag:
                return None
            return f'trial started; logging to {self.supervisor_bag}'
        return started

    def _trial_ended_since(self, first_state: int):
        """The end of a trial heard at or after index ``first_state`` of self.states."""
        def ended() -> str | None:
            final = self._first_heard(END_STATES, first_state)
            return None if final is None else f'the trial ended ({final})'
        return ended

    def _first_heard(self, states, after: int) -> str | None:
        return next((s for s in self.states[after:] if s in states), None)

    def wait_for_state(self, states, after: int = 0, timeout_s: float = 120.0) -> str | None:
        """The first state in ``states`` heard at or after index ``after`` of self.states."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                found = self._first_heard(states, after)
                remaining = deadline - time.monotonic()
                if found is not None or remaining <= 0:
                    return found
                self._changed.wait(remaining)

    def start_trial(self) -> tuple[bool, str]:
        """Ask the supervisor to start a trial; (started, its message). `trial_start` is then
        the index in self.states from which wait_for_end() looks."""
        self.trial_start = len(self.states)
        ok, message = self.call('start_trial')
        if ok:
            self.wait_for_state(('configuring',), self.trial_start, timeout_s=10.0)
            with self._changed:
                self.trial_start = next((i for i in range(self.trial_start, len(self.states))
                                         if self.states[i] == 'configuring'), self.trial_start)
        return ok, message

    def wait_for_end(self, timeout_s: float = 300.0, alive=lambda: None,
                     check_every_s: float = 0.5) -> str | None:
        """'done' or 'aborted' once the trial started by start_trial() ends, None on timeout;
        ``alive()`` is called between checks and may raise to stop waiting."""
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            final = self.wait_for_state(END_STATES, self.trial_start,
                                        timeout_s=min(check_every_s, max(remaining, 0.0)))
            if final is not None or remaining <= 0:
                return final
            alive()

    def reason_of(self, bag, state: str, timeout_s: float = 5.0) -> str | None:
        """The supervisor's reason for ``state`` in the trial logging to ``bag`` (its status
        follows the state topic by a moment), None if not heard within ``timeout_s``."""
        key = (str(bag), state)
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while key not in self.reasons:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._changed.wait(remaining)
            return self.reasons[key]

    def run_trial(self, timeout_s: float = 300.0) -> tuple[bool, str, str | None]:
        """Start a trial and wait for its end: (started, start message, final state)."""
        ok, message = self.start_trial()
        if not ok:
            return False, message, None
        return True, message, self.wait_for_end(timeout_s)

    # ------------------------------------------------------------------ parameters
    def set_parameters(self, values: dict, timeout_s: float = 10.0) -> tuple[bool, str]:
        """Set the supervisor's parameters ``values`` (name -> value, typed as it declares
        them: a float for a double, an int too), in order: (True, ''), or (False,
        '<name>: <why>') for the first one refused, by the supervisor (the later ones are
        set all the same) or here (an unknown name, a value of the wrong type: nothing is
        sent). StackError if the supervisor does not answer within ``timeout_s``."""
        parameters = []
        for name, value in values.items():
            try:
                parameters.append(Parameter(name=name, value=parameter_value(name, value)))
            except KeyError:
                return False, f'{name}: not a parameter of the supervisor'
            except ValueError as exc:
                return False, f'{name}: {exc}'
        response = self._ask(self._set_parameters, SetParameters.Request(parameters=parameters),
                             timeout_s)
        for parameter, result in zip(parameters, response.results):
            if not result.successful:
                return False, f'{parameter.name}: {result.reason}'
        return True, ''

    def get_parameters(self, names, timeout_s: float = 10.0) -> dict:
        """The supervisor's parameters ``names`` (name -> value; None for one it does not
        have). StackError if it does not answer within ``timeout_s``."""
        names = list(names)
        response = self._ask(self._get_parameters, GetParameters.Request(names=names), timeout_s)
        return {name: parameter_value_to_python(value)
                for name, value in zip(names, response.values)}

    def _ask(self, client, request, timeout_s: float):
        """The answer of an idempotent service call, asked again after ANSWER_GRACE_S without
        one (a lost answer, see above); StackError after ``timeout_s``."""
        name = self.resolve_service_name(client.srv_name)
        deadline = time.monotonic() + timeout_s
        if not client.wait_for_service(timeout_sec=timeout_s):
            raise StackError(f'{name} is not available after {timeout_s} s')
        while True:
            future = client.call_async(request)
            future.add_done_callback(lambda _: self._notify())
            ask_again = min(time.monotonic() + ANSWER_GRACE_S, deadline)
            with self._changed:
                while not future.done() and time.monotonic() < ask_again:
                    self._changed.wait(ask_again - time.monotonic())
            if future.done():
                return future.result()
            client.remove_pending_request(future)
            if time.monotonic() >= deadline:
                raise StackError(f'{name} did not answer within {timeout_s} s')
