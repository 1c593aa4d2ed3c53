"""TrialClient: a small node that starts a trial through /supervisor/start_trial and follows
/supervisor/state until the trial ends (for `mantis trial` and the tests).

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
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Trigger

from mantis_rig import contract

from .lean_node import WithoutDefaultEventHandlers
from .supervisor_node import STATUS_NAME, STILL_CLOSING

ANSWER_GRACE_S = 2.0    # how long an answer is awaited before the supervisor's publications count
# A trial reports 'done' or 'aborted' before its log is closed (the bag holds that state); a
# start refused meanwhile is asked again for this long.
CLOSING_WAIT_S = 15.0
CLOSING_RETRY_S = 0.1


class TrialClient(WithoutDefaultEventHandlers, Node):
    def __init__(self, node_name: str = contract.TRIAL_CLIENT_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.states: list[str] = []
        self.trial_start = 0
        self._changed = threading.Condition()
        c = contract
        self._start = self.create_client(Trigger, c.START_TRIAL.name)
        self._abort = self.create_client(Trigger, c.ABORT.name)
        self.create_subscription(String, c.SUPERVISOR_STATE.name, self._on_state,
                                 c.SUPERVISOR_STATE.qos.subscriber())
        self.reason = ''            # the supervisor's reason for its state (its diagnostics)
        self.supervisor_trials: int | None = None     # trials it has started (its diagnostics)
        self.supervisor_bag = ''                      # its current or last bag (its diagnostics)
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
                    self.reason = values.get('reason', '')
                    self.supervisor_trials = int(values.get('trials') or 0)
                    self.supervisor_bag = values.get('bag', '')
                    self._changed.notify_all()

    def wait_for_supervisor(self, timeout_s: float = 60.0, alive=lambda: None) -> bool:
        """Wait for /supervisor/start_trial and for the supervisor's diagnostics (the count of
        trials a start is judged against); ``alive()`` may raise to stop waiting."""
        deadline = time.monotonic() + timeout_s
        while not self._start.wait_for_service(timeout_sec=0.5) or \
                self.supervisor_trials is None:
            alive()
            if time.monotonic() > deadline:
                return False
        return True

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
            final = self._first_heard(('done', 'aborted'), first_state)
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
        deadline = time.monotonic() + CLOSING_WAIT_S
        ok, message = self.call('start_trial')
        while not ok and STILL_CLOSING in message and time.monotonic() < deadline:
            time.sleep(CLOSING_RETRY_S)
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
            final = self.wait_for_state(('done', 'aborted'), self.trial_start,
                                        timeout_s=min(check_every_s, max(remaining, 0.0)))
            if final is not None or remaining <= 0:
                return final
            alive()

    def run_trial(self, timeout_s: float = 300.0) -> tuple[bool, str, str | None]:
        """Start a trial and wait for its end: (started, start message, final state)."""
        ok, message = self.start_trial()
        if not ok:
            return False, message, None
        return True, message, self.wait_for_end(timeout_s)
