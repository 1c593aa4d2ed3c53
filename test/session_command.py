"""A command in a session of its own, for the tests and the bench scripts: started, its output
collected line by line as it comes, signalled, waited for, and every process of its session
killed at the end.

    with SessionCommand(mantis_argv('trial', '--backend', 'sim')) as trial:
        bag = trial.wait_for_line(lambda line: line.startswith('bag: '), 90.0)
        sent_at = trial.signal_group(signal.SIGINT)         # as a terminal's Ctrl-C
        status = trial.wait(60.0)

`mantis(*args, **kw)` starts a `mantis` command so. The output: ``stdout`` and ``stderr``, a
list a stream, and ``lines``, both in the order they were read. A node process of the command
runs in the command's session (in a process group of its own): `kill` and `left_running` find
it there.
"""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

from mantis_rig.runtime import process_state

REPO = Path(__file__).resolve().parents[1]
STREAMS = ('stdout', 'stderr')
#: how long after a command has exited the helpers multiprocessing started for it may take to
#: end on their own (left_running's settle_s)
SETTLE_S = 5.0


def mantis_argv(*args) -> list:
    """The command line of `mantis ARGS` in this interpreter."""
    return [sys.executable, '-m', 'mantis_rig.cli', *map(str, args)]


def mantis(*args, **kwargs) -> SessionCommand:
    """`mantis ARGS` started in a session of its own (keywords: SessionCommand's)."""
    return SessionCommand(mantis_argv(*args), **kwargs)


class SessionCommand:
    """``argv`` started in a new session (its pid is the session's id) with ``cwd`` and ``env``
    (None: this process's), its standard input a pipe (``stdin=True``: `write`) or /dev/null.
    Used as a context manager it kills what is left of the session on the way out."""

    def __init__(self, argv, *, cwd=REPO, env=None, stdin=False, preexec_fn=None):
        self.argv = [str(arg) for arg in argv]
        self.process = subprocess.Popen(
            self.argv, cwd=cwd, env=env, text=True, errors='replace',
            stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
            preexec_fn=preexec_fn)
        self.pid = self.process.pid
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self.lines: list[str] = []          # both streams, in the order they were read
        self.tree: set[int] = set()         # every child noted by note_tree
        self._changed = threading.Condition()
        self._open = set(STREAMS)
        self._readers = [threading.Thread(target=self._read, args=(name,), daemon=True)
                         for name in STREAMS]
        for reader in self._readers:
            reader.start()

    def __enter__(self) -> SessionCommand:
        return self

    def __exit__(self, *exc) -> None:
        self.kill()

    def _read(self, name: str) -> None:
        for line in getattr(self.process, name):
            with self._changed:
                line = line.rstrip('\n')
                getattr(self, name).append(line)
                self.lines.append(line)
                self._changed.notify_all()
        with self._changed:
            self._open.discard(name)
            self._changed.notify_all()

    # ----------------------------------------------------------------------------- output
    def wait_for_line(self, match, timeout_s: float, stream: str = 'stdout',
                      start: int = 0) -> str | None:
        """The first line of ``stream`` ('stdout', 'stderr' or 'any') from index ``start`` on
        that ``match`` holds for (a predicate, or text the line contains), as soon as it is
        read; None when none came within ``timeout_s`` or the stream ended without one."""
        holds = match if callable(match) else (lambda line: match in line)
        lines = self.lines if stream == 'any' else getattr(self, stream)
        ends = set(STREAMS) if stream == 'any' else {stream}
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                for line in lines[start:]:
                    if holds(line):
                        return line
                start = max(start, len(lines))
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not self._open & ends:
                    return None
                self._changed.wait(remaining)

    def text(self) -> str:
        """Everything it wrote, both streams, in the order read."""
        return '\n'.join(self.lines)

    def tail(self, lines: int = 40) -> str:
        return '\n'.join(self.lines[-lines:])

    def write(self, text: str) -> None:
        """To its standard input (started with ``stdin=True``)."""
        self.process.stdin.write(text)
        self.process.stdin.flush()

    # -------------------------------------------------------------------- signals, waiting
    def signal(self, signum) -> float:
        """``signum`` to the process alone; the time.monotonic() it was sent at."""
        self.process.send_signal(signum)
        return time.monotonic()

    def signal_group(self, signum) -> float:
        """``signum`` to its process group, as a terminal sends it; when it was sent."""
        os.killpg(self.pid, signum)
        return time.monotonic()

    def wait(self, timeout_s: float | None = None) -> int | None:
        """Its exit status (the output read to its end), None if it still runs after
        ``timeout_s``."""
        try:
            status = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None
        for reader in self._readers:
            reader.join(timeout=5.0)
        return status

    def finish(self, timeout_s: float) -> int:
        """Its exit status; if it still runs after ``timeout_s``, it is killed and the test
        fails with the end of its output."""
        status = self.wait(timeout_s)
        if status is None:
            self.kill()
            raise AssertionError('timed out:\n' + self.tail())
        return status

    # ---------------------------------------------------------------------------- processes
    def children(self) -> list[int]:
        """Its child processes now."""
        return process_state.children(self.pid)

    def note_tree(self) -> None:
        """Note its children now in ``tree`` (they outlive it in /proc's eyes: re-parented)."""
        self.tree |= set(self.children())

    def left_running(self, settle_s: float = 0.0) -> list[int]:
        """The processes of its session that still run (zombies, which no longer run, not
        counted: an exited process whose parent had gone waits for PID 1 to reap it). With
        ``settle_s``, those still running that long after: a helper multiprocessing started
        for the command (its resource tracker, a forkserver) ends on its own once the command
        has exited and closed its end of their pipe, a moment later."""
        deadline = time.monotonic() + settle_s
        while True:
            running = process_state.in_session(self.pid)
            if not running or time.monotonic() >= deadline:
                return running
            time.sleep(0.02)

    def assert_nothing_left(self, settle_s: float = SETTLE_S) -> None:
        """Fail, naming each process and its command line, if any of its session still runs
        ``settle_s`` after it exited."""
        left = self.left_running(settle_s)
        assert not left, 'left running: ' + '; '.join(
            f'{pid} {process_state.cmdline(pid)[:120]}' for pid in left)

    def kill(self) -> None:
        """SIGCONT and SIGKILL to every process of its session (a stopped one too), then
        wait for it (10 s at the most)."""
        for pid in self.left_running():
            for signum in (signal.SIGCONT, signal.SIGKILL):
                try:
                    os.kill(pid, signum)
                except ProcessLookupError:
                    pass
        try:
            self.process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            pass
