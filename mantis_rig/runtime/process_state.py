"""A process's state as Linux's /proc says it: the one reader of ``/proc/<pid>/stat`` (and of
``/proc/<pid>/cmdline``) for the package, the tests and the bench scripts.

`read(pid)` gives a `ProcessState`, or None for a process that is gone (no entry, or one that
went while it was read): a process may end at any moment, so every caller has to expect it,
and None says it without an exception to catch. The functions over every process (`children`,
`tree`, `in_session`) skip processes that go while they look. Each takes ``root``, the /proc
to read (a fake one in the unit tests).
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path

PROC = Path('/proc')
TICKS_PER_S = os.sysconf('SC_CLK_TCK')
ZOMBIE = 'Z'


@dataclass(frozen=True)
class ProcessState:
    """What ``/proc/<pid>/stat`` says of a process (proc(5)): its name (``comm``), its
    one-letter state (``R`` running, ``S`` sleeping, ``T`` stopped, ``Z`` zombie...), its
    parent, process group and session, its CPU seconds (user, system: all its threads) and
    when it started (seconds after boot)."""

    pid: int
    name: str
    state: str
    ppid: int
    pgrp: int
    session: int
    utime_s: float
    stime_s: float
    started_s: float

    @property
    def cpu_s(self) -> float:
        """User + system CPU seconds."""
        return self.utime_s + self.stime_s

    @property
    def running(self) -> bool:
        """Not a zombie: an exited process waiting for its parent to reap it no longer runs."""
        return self.state != ZOMBIE


def parse_stat(pid: int, text: str) -> ProcessState | None:
    """The state in the text of ``/proc/<pid>/stat``; None when it is not one. The name is in
    parentheses and may hold anything, ')' and spaces included: the fields follow the last ')'."""
    name, _, rest = text.partition('(')[2].rpartition(')')
    fields = rest.split()
    try:
        return ProcessState(pid=pid, name=name, state=fields[0], ppid=int(fields[1]),
                            pgrp=int(fields[2]), session=int(fields[3]),
                            utime_s=int(fields[11]) / TICKS_PER_S,
                            stime_s=int(fields[12]) / TICKS_PER_S,
                            started_s=int(fields[19]) / TICKS_PER_S)
    except (IndexError, ValueError):
        return None


def read(pid: int, root: Path = PROC) -> ProcessState | None:
    """Process ``pid``'s state, None if it is gone."""
    try:
        text = (Path(root) / str(pid) / 'stat').read_text(encoding='ascii', errors='replace')
    except OSError:
        return None
    return parse_stat(pid, text)


def state_of(pid: int, root: Path = PROC) -> str | None:
    """Process ``pid``'s one-letter state (``T``: stopped), None if it is gone."""
    state = read(pid, root)
    return None if state is None else state.state


def running(pid: int, root: Path = PROC) -> bool:
    """Whether process ``pid`` is there and not a zombie."""
    state = read(pid, root)
    return state is not None and state.running


def argv(pid: int, root: Path = PROC) -> list[str]:
    """Process ``pid``'s command line, an argument an item; [] if it is gone (or a zombie)."""
    try:
        raw = (Path(root) / str(pid) / 'cmdline').read_bytes()
    except OSError:
        return []
    return [arg.decode('utf-8', 'replace') for arg in raw.split(b'\0')[:-1]] if raw else []


def cmdline(pid: int, root: Path = PROC) -> str:
    """Process ``pid``'s command line, its arguments joined by spaces; '' if it is gone."""
    return ' '.join(argv(pid, root))


def every(root: Path = PROC) -> list[ProcessState]:
    """The state of every process there is."""
    found = []
    for entry in Path(root).iterdir():
        if entry.name.isdigit():
            state = read(int(entry.name), root)
            if state is not None:
                found.append(state)
    return found


def children(pid: int, root: Path = PROC) -> list[int]:
    """The processes whose parent is ``pid`` (zombies included), in pid order."""
    return sorted(s.pid for s in every(root) if s.ppid == pid)


def tree(pid: int, root: Path = PROC) -> list[int]:
    """``pid`` and every descendant of it (zombies included)."""
    below: dict[int, list[int]] = {}
    for state in every(root):
        below.setdefault(state.ppid, []).append(state.pid)
    found, todo = [], [pid]
    while todo:
        found.append(todo.pop())
        todo.extend(below.get(found[-1], []))
    return found


def in_session(sid: int, root: Path = PROC) -> list[int]:
    """The processes of session ``sid`` that still run (zombies excluded), in pid order."""
    return sorted(s.pid for s in every(root) if s.session == sid and s.running)


__all__ = ['ProcessState', 'argv', 'children', 'cmdline', 'every', 'in_session', 'parse_stat',
           'read', 'running', 'state_of', 'tree']
