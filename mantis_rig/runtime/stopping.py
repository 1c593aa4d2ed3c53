"""SIGINT and SIGTERM for the rig's processes: the first asks for an orderly stop (stage
stopped, reason logged, log closed, processes ended), a second one during that stop stops the
stage and exits at once.

rclpy's own handler is not used (``rclpy.init(signal_handler_options=NO)``): it shuts the
context down first, after which nothing can publish the stage's stop or the trial's end.
"""
from __future__ import annotations

from collections.abc import Callable
import os
import signal
import sys
import threading
import time
from typing import Optional

from mantis_rig.runtime.process_state import state_of

SIGNAL_NAMES = {signal.SIGINT: 'SIGINT (Ctrl-C)', signal.SIGTERM: 'SIGTERM'}
# How a node process that stops its stage on a signal says so in the error of the move it cut
# short: the supervisor's abort reason then shows the process is on its way out.
PROCESS_STOPPING = 'stage stopped by its own process'
PARENT_CHECK_S = 0.5
# A stack's process stopped (frozen: SIGSTOP) this long is taken for gone: its node processes
# stop themselves, since nothing would find a node of theirs that died or hung meanwhile.
PARENT_FROZEN_S = 2.0
# Set by a stack for its node processes: a file that holds the reason the stack stops them for
# (a node process that ended, froze or hung: the supervisor aborts its trial with it).
STOP_REASON_ENV = 'MANTIS_STACK_STOP_REASON'
_parent_gone: list = []        # why watch_parent stopped this process, once it has


def stop_reason(signal_reason: str) -> str:
    """Why this node process is stopping: the stack's reason when it gave one (its file), what
    watch_parent found, or the signal's own (``signal_reason``)."""
    path = os.environ.get(STOP_REASON_ENV)
    if path:
        try:
            text = open(path, encoding='utf-8').read().strip()
        except OSError:
            text = ''
        if text:
            return text
    return _parent_gone[0] if _parent_gone else signal_reason


class StopRequested(BaseException):
    """Raised in the main thread by the first SIGINT or SIGTERM. A BaseException, like
    KeyboardInterrupt, so that no `except Exception` on the way swallows it."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(self.reason)

    @property
    def name(self) -> str:
        return SIGNAL_NAMES.get(self.signum, signal.Signals(self.signum).name)

    @property
    def reason(self) -> str:
        return f'interrupted by {self.name}'

    @property
    def exit_status(self) -> int:
        """The shell's convention: 128 + the signal number (130 SIGINT, 143 SIGTERM)."""
        return 128 + self.signum


class StopSignals:
    """Install with `install()` in the main thread. `emergency_stop` is what a second signal
    does before the process exits: stop the stage, by the quickest route there is."""

    def __init__(self, program: str, emergency_stop: Optional[Callable[[], None]] = None):
        self.program = program
        self.emergency_stop = emergency_stop
        self.first: Optional[StopRequested] = None
        self._shielded = False
        self._deferred = False
        self._lock = threading.Lock()

    def install(self, deferred: bool = False) -> StopSignals:
        """deferred: the first signal is only noted, and `raise_if_stopped()` raises it where
        the caller knows it is safe to (a node process's spin loop). Raised from the handler, it
        can land inside rclpy's C++ message conversion, which turns it into a RuntimeError: the
        supervisor then closed its trial as 'supervisor shutting down', with a traceback."""
        self._deferred = deferred
        for signum in SIGNAL_NAMES:
            signal.signal(signum, self._on_signal)
        return self

    def raise_if_stopped(self) -> None:
        """Raise the first signal's StopRequested, if one came (and the stop is not under way)."""
        if self.first is not None and not self._shielded:
            raise self.first

    def shield(self) -> None:
        """The orderly stop is under way: from now on a first signal is only noted (see
        `first`), not raised into it; a second one still exits at once."""
        self._shielded = True

    def _on_signal(self, signum, frame) -> None:
        with self._lock:
            first, self.first = self.first, self.first or StopRequested(signum)
        if first is None:
            if self._shielded or self._deferred:
                return
            raise self.first
        self._exit_now(signum)

    def _exit_now(self, signum: int) -> None:
        stopped = 'stage stopped'
        try:
            if self.emergency_stop is not None:
                self.emergency_stop()
        except Exception as exc:       # noqa: BLE001 - exiting at once is what was asked
            stopped = f'stopping the stage failed: {exc}'
        name = SIGNAL_NAMES.get(signum, str(signum))
        say(f'{self.program}: second {name} during shutdown: {stopped}; exiting now')
        os._exit(128 + signum)


def say(line: str) -> None:
    """One line on stderr in one write: the nodes' loggers write to the same descriptor from
    other threads, and print() writes the text and its newline apart."""
    sys.stderr.flush()
    os.write(sys.stderr.fileno(), (line + '\n').encode('utf-8', 'replace'))


def watch_parent(parent_pid: int) -> threading.Thread:
    """SIGTERM this process when its parent is gone (a node process of a stack whose parent was
    killed outright must not go on driving a device), or frozen (stopped, e.g. by SIGSTOP) for
    PARENT_FROZEN_S: nothing would then find a node process that died or hung."""
    def watch() -> None:
        stopped_since = None
        while os.getppid() == parent_pid:
            threading.Event().wait(PARENT_CHECK_S)
            if state_of(parent_pid) == 'T':
                stopped_since = stopped_since or time.monotonic()
                if time.monotonic() - stopped_since >= PARENT_FROZEN_S:
                    _parent_gone.append(f'the stack\'s process (pid {parent_pid}) froze '
                                        f'(stopped by SIGSTOP or another stop signal)')
                    break
            else:
                stopped_since = None
        else:
            _parent_gone.append(f'the stack\'s process (pid {parent_pid}) ended')
        os.kill(os.getpid(), signal.SIGTERM)

    thread = threading.Thread(target=watch, name='parent-watch', daemon=True)
    thread.start()
    return thread


def end_process(status: int) -> None:
    """End this process now with ``status``, its work done and closed (every node stopped and
    destroyed, rclpy shut down, the log closed): os._exit after flushing stdout and stderr. The
    interpreter's own teardown (every module and object freed, rclpy's and numba's finalizers,
    DDS participants) costs CPU and, after an interrupt, seconds, and holds nothing that is
    still to be written. Only for the command line's own `mantis trial` / `mantis bringup`
    process (cli.main), never for a caller in the same process (the tests call cli.main with
    argv) nor for a stack's node processes."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):       # closed, or its reader gone: nothing to keep
            pass
    os._exit(status)


__all__ = ['StopRequested', 'StopSignals', 'end_process', 'say', 'stop_reason',
           'watch_parent']
