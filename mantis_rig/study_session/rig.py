"""The study's rig and its person: a running rig reached through the supervisor's services and
parameters (a TrialClient), and what the person is asked to do between trials.

On the simulated rig the world re-latches the robot and sets the guide itself: nobody is asked
anything. On hardware, before each trial the person is told what to change ("set the guide
distance to 19 mm (was 25)"), to re-latch the robot, and to press Enter, or to call the study's
Trigger service ``<ns>/study/continue`` (a GUI or Foxglove button); after each trial, the name
to save its video's tracker export under (`mantis study attach` matches it).
"""
from __future__ import annotations

from collections.abc import Callable
import math
from pathlib import Path
import sys
import threading
import time
from typing import Optional

from mantis_rig.faults import StackError
from mantis_rig.recording import TRIAL_OUTCOME, BagReader
from mantis_rig.recording.bag_metadata import wait_closed
from mantis_rig.trial.supervisor_settings import ConditionError
from mantis_sim.studies.rig_study.plan import CONDITION_KEYS
from mantis_sim.studies.rig_study.quantities import CONDITION_LABELS

END_STATES = ('done', 'aborted')
BAG_CLOSE_WAIT_S = 30.0
#: what the person does by hand for each condition (the pull speed is the stage's)
BY_HAND = ('d_t_mm', 'contact_angle_deg', 'medium')


class ClientRig:
    """A RigPort over a TrialClient. ``alive()`` raises when the stack under it died."""

    def __init__(self, client, alive: Callable[[], None] = lambda: None,
                 trial_timeout_s: float = 600.0):
        self.client, self.alive, self.trial_timeout_s = client, alive, trial_timeout_s
        self.bag: Optional[Path] = None

    def set_conditions(self, values: dict) -> None:
        ok, message = self.client.set_parameters(values)
        if not ok:
            raise ConditionError(f'the supervisor refused a trial condition: {message}')

    def conditions(self) -> dict:
        return self.client.get_parameters(CONDITION_KEYS)

    def backend(self) -> str:
        """'sim' or 'hardware': which measuring chain the rig's trials go through."""
        return str(self.client.get_parameters(['backend']).get('backend') or 'hardware')

    def start(self) -> Path:
        ok, message = self.client.start_trial()
        if not ok:
            raise StackError(f'the supervisor refused to start a trial: {message}')
        self.bag = Path(message.rsplit('logging to ', 1)[-1])
        return self.bag

    def follow(self, on_state: Callable[[str], None]) -> tuple[str, str]:
        client, seen = self.client, self.client.trial_start
        deadline = time.monotonic() + self.trial_timeout_s
        final = None
        while final is None:
            if time.monotonic() > deadline:
                client.call('abort', timeout_s=5.0)
                raise StackError(f'no end of trial within {self.trial_timeout_s} s; aborted')
            client.wait_for_state(END_STATES, seen, timeout_s=0.25)
            states = client.states[seen:]
            for state in states:
                on_state(state)
                if state in END_STATES:
                    final = state
                    break
            seen += len(states)
            self.alive()
        return final, self._reason()

    def _reason(self) -> str:
        """The trial's outcome reason, from its closed bag ('' when it completed)."""
        bag = self.bag
        # alive() raises when the stack died; otherwise the wait goes on to its end
        if not wait_closed(bag, BAG_CLOSE_WAIT_S, failed=lambda: self.alive() or False):
            raise StackError(f'the trial ended but its log {bag} was not closed within '
                             f'{BAG_CLOSE_WAIT_S:g} s')
        outcome = BagReader(bag, warn=False).metadata(TRIAL_OUTCOME) or {}
        return outcome.get('reason', '')


class SimulatedOperator:
    """The simulated rig's operator: the world re-latches the robot and takes each trial's
    conditions from the supervisor; nothing to ask."""

    def before_trial(self, row: dict, previous: Optional[dict], total: int) -> None:
        pass

    def after_trial(self, row: dict) -> None:
        pass


def _value(name: str, value) -> str:
    unit = CONDITION_LABELS[name][1]
    if isinstance(value, float) and math.isfinite(value):
        return f'{value:g} {unit}'.strip()
    return f'{value} {unit}'.strip()


def what_to_do(row: dict, previous: Optional[dict]) -> list[str]:
    """The person's steps before trial ``row`` (``previous``: the trial before, if any)."""
    steps = []
    for name in BY_HAND:
        value = row.get(name)
        if value is None:
            continue
        before = None if previous is None else previous.get(name)
        if before != value:
            label = CONDITION_LABELS[name][0]
            was = f' (was {_value(name, before)})' if before is not None else ''
            steps.append(f'set the {label} to {_value(name, value)}{was}')
    steps.append('re-latch the robot')
    return steps


class PersonOperator:
    """A person at the rig: told what to do, answers with Enter on ``stdin`` or through the
    continue event (the study's Trigger service sets it)."""

    def __init__(self, say: Callable[[str], None], service_name: str,
                 stdin=None, proceed: Optional[threading.Event] = None):
        self.say = say
        self.service_name = service_name
        self.stdin = stdin if stdin is not None else sys.stdin
        self.proceed = proceed or threading.Event()
        self._line = threading.Event()
        self._reader: Optional[threading.Thread] = None

    def before_trial(self, row: dict, previous: Optional[dict], total: int) -> None:
        steps = what_to_do(row, previous)
        self.say(f'next: run {row["run"]} of {total}: ' + ', '.join(steps)
                 + f'; then press Enter (or call {self.service_name})')
        self.proceed.clear()
        self._line.clear()
        self._read_a_line()
        while not (self.proceed.is_set() or self._line.is_set()):
            self.proceed.wait(0.1)

    def _read_a_line(self) -> None:
        if self._reader is not None and self._reader.is_alive():
            return          # still waiting for the line asked for before

        def read() -> None:
            line = self.stdin.readline()
            if line == '':          # no more input: only the service can go on
                return
            self._line.set()

        self._reader = threading.Thread(target=read, name='study-prompt', daemon=True)
        self._reader.start()

    def after_trial(self, row: dict) -> None:
        if row.get('status') == 'done':
            self.say(f'run {row["run"]} done: save its video\'s tracker export as '
                     f'{row["video"]}.xlsx (or .csv) for `mantis study attach`')


__all__ = ['ClientRig', 'PersonOperator', 'SimulatedOperator', 'what_to_do']
