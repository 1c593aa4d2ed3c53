"""The node processes of a stack, watched: a process that ended, froze or hung is found, named in
one plain line, and the stack fails safe (issue 41).

What counts as a fault of a node process (`ProcessWatch.check`, called every WATCH_PERIOD_S by
`mantis bringup` and `mantis trial`):

* **ended**: it exited, or was killed by a signal (``Popen.poll``), found within WATCH_PERIOD_S;
* **frozen**: its state in ``/proc/<pid>/stat`` is ``T`` (stopped: SIGSTOP, SIGTSTP, a terminal's
  job control) on two looks STOPPED_S apart: the fast path, found within about half a second;
* **hung**: it stopped answering: one of its nodes, heard on ``/diagnostics`` before (every node
  publishes there at 1 Hz on a steady-clock timer, and on every state change), has not been
  heard for SILENT_S (a blocking call in its executor's thread, a deadlock, swapped out). The
  process still runs, so nothing else would find it.

The line names the process and how it failed, e.g. ``node process supervisor_node was killed by
SIGKILL`` or ``node process sim_rig froze (stopped by SIGSTOP or another stop signal) and was
killed with SIGKILL``. What the stack does with it: `mantis_rig.stack.bringup.Stack.fail_safe`.

`stop_stage_at_port` stops a KDC101 whose node process is gone: it opens the serial port itself
and sends MOT_MOVE_STOP (the controller would otherwise finish its last command).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import signal
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray

from mantis_rig import contract
from mantis_rig.faults import StackError
from mantis_rig.runtime.process_state import state_of

WATCH_PERIOD_S = 0.1       # how often the bring-up looks at its node processes
STOPPED_S = 0.3            # a process seen stopped ('T') this long apart is frozen
SILENT_S = 5.0             # a node heard before and silent on /diagnostics this long: hung
PORT_STOP_TIMEOUT_S = 1.0  # how long stop_stage_at_port waits for MOT_MOVE_STOPPED


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f'signal {signum}'


def describe_exit(code: int) -> str:
    """How a process ended, from its Popen returncode, in words."""
    if code < 0:
        return f'was killed by {signal_name(-code)}'
    if code > 128 and code - 128 in signal.Signals._value2member_map_:
        return (f'exited with status {code} (it stopped itself on '
                f'{signal_name(code - 128)})')
    return f'exited with status {code}'


def process_state(pid: int) -> str | None:
    """The one-letter state of process ``pid`` (``R``, ``S``, ``T``, ``Z``...), None if gone."""
    return state_of(pid)


class ProcessFault(StackError):
    """A node process ended, froze or hung. ``name``: the process; ``how``: what happened, as
    the line says it; ``ended``: it had ended by itself (not frozen or hung)."""

    def __init__(self, name: str, how: str, ended: bool, detail: str = ''):
        self.name, self.how, self.ended, self.detail = name, how, ended, detail
        super().__init__(self.line)

    @property
    def line(self) -> str:
        return f'node process {self.name} {self.how}' + (f' ({self.detail})'
                                                         if self.detail else '')


@dataclass
class _Look:
    stopped_since: float | None = None


class ProcessWatch:
    """Looks at the node processes of a stack (name -> Popen) and the /diagnostics of their
    nodes (``nodes_of``: process name -> its node names). `check()` returns the first fault
    found, or None. Attach `on_diagnostics` to a /diagnostics subscription."""

    def __init__(self, processes: dict, nodes_of: dict, silent_s: float = SILENT_S,
                 stopped_s: float = STOPPED_S, clock=time.monotonic):
        self.processes = processes
        self.process_of = {node: name for name, nodes in nodes_of.items() for node in nodes}
        self.silent_s = silent_s
        self.stopped_s = stopped_s
        self.clock = clock
        self._heard: dict[str, float] = {}
        self._looks = {name: _Look() for name in processes}
        self._lock = threading.Lock()

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        now = self.clock()
        with self._lock:
            for status in msg.status:
                node = status.name.split(':', 1)[0].strip().rsplit('/', 1)[-1]
                if node in self.process_of:
                    self._heard[node] = now

    def heard(self) -> dict:
        with self._lock:
            return dict(self._heard)

    def check(self) -> ProcessFault | None:
        now = self.clock()
        for name, process in self.processes.items():
            code = process.poll()
            if code is not None:
                return ProcessFault(name, describe_exit(code), ended=True)
        for name, process in self.processes.items():
            look = self._looks.setdefault(name, _Look())
            if process_state(process.pid) == 'T':
                if look.stopped_since is None:
                    look.stopped_since = now
                elif now - look.stopped_since >= self.stopped_s:
                    return ProcessFault(name, 'froze (stopped by SIGSTOP or another stop '
                                        'signal)', ended=False)
            else:
                look.stopped_since = None
        with self._lock:
            heard = dict(self._heard)
        for node, last in heard.items():
            if now - last > self.silent_s:
                name = self.process_of[node]
                return ProcessFault(name, f'stopped answering: its node {node} was not heard '
                                    f'on /diagnostics for {now - last:.1f} s (hung)',
                                    ended=False)
        return None


def stop_stage_at_port(port_path: str, timeout_s: float = PORT_STOP_TIMEOUT_S) -> str:
    """Open the KDC101's serial port and send MOT_MOVE_STOP (immediate): the stop of a stage
    whose node process is gone. Returns what happened, in words for the line; never raises."""
    try:
        import serial
        import thorlabs_apt_protocol as apt

        from mantis_rig.hardware.kdc101 import CHANNEL, CONTROLLER, HOST, STOP_IMMEDIATE
    except ImportError as exc:
        return f'the stage could not be stopped at its port {port_path}: {exc}'
    try:
        with serial.Serial(port_path, baudrate=115200, bytesize=serial.EIGHTBITS,
                           parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                           rtscts=True, timeout=0.05, write_timeout=timeout_s,
                           exclusive=True) as port:
            port.write(apt.mot_move_stop(CONTROLLER, HOST, CHANNEL, STOP_IMMEDIATE))
            port.flush()
            stopped = _wait_for_stopped(port, apt, timeout_s)
    except (serial.SerialException, OSError, ValueError) as exc:
        return f'stopping the stage at its port {port_path} failed: {exc}'
    return (f'stage stopped at its port {port_path} (MOT_MOVE_STOP'
            + (', confirmed)' if stopped else ', sent; no MOT_MOVE_STOPPED within '
               f'{timeout_s:g} s)'))


def _wait_for_stopped(port, apt, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    unpacker = apt.Unpacker(port)
    while time.monotonic() < deadline:
        try:
            for message in unpacker:
                if message.msg == 'mot_move_stopped':
                    return True
        except Exception:          # noqa: BLE001 - a garbled byte: the stop was sent anyway
            return False
    return False


def stage_port(stage_parameters: dict) -> str | None:
    """The KDC101's port from stage_node's parameters (its serial number found, if given)."""
    port = stage_parameters.get('serial_port', contract.DEFAULT_SERIAL_PORT)
    serial_number = stage_parameters.get('stage_serial_number', '')
    if not serial_number:
        return port
    try:
        from mantis_rig.hardware.discovery import choose_kdc101
        return choose_kdc101(port, serial_number).port
    except Exception:              # noqa: BLE001 - no controller found: nothing to stop
        return None


__all__ = ['LaunchWatch', 'ProcessFault', 'ProcessWatch', 'describe_exit', 'process_state',
           'stop_stage_at_port', 'stage_port']


class LaunchWatch:
    """What launch/mantis_rig.launch.py does when a node process of its stack ends or freezes
    (its OnProcessExit handlers and its periodic look at the processes call this; nothing here
    imports `launch`, so that it is tested without it).

    The first process to end is the stack's fault: `on_exit` writes its line for the supervisor
    (the reason its trial in flight aborts with, STOP_REASON_ENV), stops the stage at the
    KDC101's port when the stage node's own process died on hardware, and returns the line; the
    launch file then logs it and shuts the launch down (every other node gets SIGINT: the stage
    node stops the stage, the supervisor aborts and closes its log). Later exits (the shutdown's
    own) return None. `frozen` names a process seen stopped (``T``) on two looks STOPPED_S
    apart; the launch file kills it, and its exit is then reported as the freeze."""

    def __init__(self, backend: str, stage_parameters: dict, reason_file: str | None,
                 clock=time.monotonic):
        self.backend = backend
        self.stage_parameters = stage_parameters
        self.reason_file = reason_file
        self.clock = clock
        self.fault: str | None = None
        self._frozen: dict[str, str] = {}
        self._stopped_since: dict[str, float] = {}
        self._lock = threading.Lock()

    def shutting_down(self) -> None:
        """The launch is shutting down (Ctrl-C, or after a fault): exits from now on are its
        own, not faults."""
        with self._lock:
            if self.fault is None:
                self.fault = 'the launch is shutting down'

    def frozen(self, pids: dict) -> str | None:
        """The name of a process of ``pids`` (name -> pid) that froze, once; None otherwise."""
        now = self.clock()
        for name, pid in pids.items():
            if pid is None or name in self._frozen:
                continue
            if process_state(pid) == 'T':
                since = self._stopped_since.setdefault(name, now)
                if now - since >= STOPPED_S:
                    self._frozen[name] = 'froze (stopped by SIGSTOP or another stop signal)'
                    return name
            else:
                self._stopped_since.pop(name, None)
        return None

    def on_exit(self, name: str, returncode: int | None) -> str | None:
        with self._lock:
            if self.fault is not None:
                return None
            how = self._frozen.get(name)
            how = f'{how} and was killed with SIGKILL' if how else \
                describe_exit(returncode if returncode is not None else 0)
            fault = f'node process {name} {how}'
            self.fault = fault
        if self.reason_file:
            try:
                Path(self.reason_file).write_text(fault, encoding='utf-8')
            except OSError:
                pass
        stage = 'stage stopped'
        if self.backend == 'hardware' and name == contract.STAGE_NODE:
            port = stage_port(self.stage_parameters)
            stage = stop_stage_at_port(port) if port else \
                "the stage's port could not be found to stop it"
        return f'{fault}; {stage}, nodes ended'
