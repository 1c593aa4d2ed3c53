"""mantis_rig.runtime.process_state, the one reader of /proc/<pid>/stat: this process's own
entry and its parent's, one that is gone, and a fake /proc for the functions over every
process (no subprocess in a unit test)."""
import os
from pathlib import Path

from mantis_rig.runtime import process_state
from mantis_rig.runtime.process_state import (
    TICKS_PER_S,
    argv,
    children,
    cmdline,
    in_session,
    parse_stat,
    read,
    running,
    state_of,
    tree,
)


def _gone_pid() -> int:
    """A pid no process can have: above the kernel's largest."""
    return int(Path('/proc/sys/kernel/pid_max').read_text()) + 1


def test_this_process_as_proc_says_it():
    times = os.times()
    me = read(os.getpid())
    assert me is not None and me.pid == os.getpid()
    assert me.state == 'R'                          # reading its own entry: running
    assert (me.ppid, me.pgrp, me.session) == (os.getppid(), os.getpgrp(), os.getsid(0))
    assert me.running and running(os.getpid()) and state_of(os.getpid()) == 'R'
    assert me.cpu_s == me.utime_s + me.stime_s
    assert abs(me.cpu_s - (times.user + times.system)) <= 0.1 + 2 / TICKS_PER_S
    assert me.name                                   # comm: the program's name
    assert cmdline(os.getpid()) == ' '.join(argv(os.getpid()))
    assert argv(os.getpid())[0]


def test_the_parent_and_where_this_process_stands_below_it():
    parent = read(os.getppid())
    assert parent is not None and parent.pid == os.getppid() and parent.running
    assert parent.started_s <= read(os.getpid()).started_s
    assert os.getpid() in children(os.getppid())
    assert os.getpid() in tree(os.getppid())
    assert os.getpid() in in_session(os.getsid(0))


def test_a_process_that_is_gone():
    pid = _gone_pid()
    assert read(pid) is None and state_of(pid) is None
    assert not running(pid)
    assert cmdline(pid) == '' and argv(pid) == []
    assert children(pid) == [] and in_session(pid) == []


def test_a_name_with_parentheses_and_spaces():
    state = parse_stat(7, '7 (a (b) c) T 1 7 7 0 -1 4194560 0 0 0 0 150 25 0 0 20 0 1 0 '
                          '1000 0 0')
    assert state.name == 'a (b) c' and state.state == 'T'
    assert (state.ppid, state.pgrp, state.session) == (1, 7, 7)
    assert state.utime_s == 150 / TICKS_PER_S and state.stime_s == 25 / TICKS_PER_S
    assert state.started_s == 1000 / TICKS_PER_S
    assert parse_stat(7, '7 (cut short) S 1') is None


def fake_proc(root: Path, processes: dict) -> Path:
    """A /proc holding ``processes``: pid -> (state, ppid, session, argv)."""
    for pid, (state, ppid, session, args) in processes.items():
        entry = root / str(pid)
        entry.mkdir()
        fields = [state, ppid, pid, session] + [0] * 7 + [3, 4] + [0] * 6 + [99]
        (entry / 'stat').write_text(f'{pid} (p{pid}) ' + ' '.join(map(str, fields)) + '\n')
        (entry / 'cmdline').write_bytes(b''.join(a.encode() + b'\0' for a in args))
    (root / 'self').mkdir()                 # not a process's entry
    (root / '999').mkdir()                  # a process gone while it was looked at: no stat
    return root


def test_children_tree_and_session_over_a_fake_proc(tmp_path):
    root = fake_proc(tmp_path, {
        1: ('S', 0, 1, ['init']),
        10: ('S', 1, 10, ['python', '-m', 'mantis_rig.cli', 'bringup']),
        11: ('T', 10, 10, ['python', '-m', 'mantis_rig.simulated.sim_rig']),
        12: ('Z', 10, 10, []),
        13: ('R', 11, 10, ['helper', 'an argument']),
        20: ('S', 1, 20, ['other']),
    })
    assert children(10, root) == [11, 12]
    assert sorted(tree(10, root)) == [10, 11, 12, 13]
    assert in_session(10, root) == [10, 11, 13]              # the zombie no longer runs
    assert state_of(11, root) == 'T' and running(11, root) and not running(12, root)
    assert read(11, root).cpu_s == (3 + 4) / TICKS_PER_S
    assert cmdline(10, root) == 'python -m mantis_rig.cli bringup'
    assert argv(13, root) == ['helper', 'an argument']
    assert cmdline(12, root) == ''
    assert read(999, root) is None
    assert sorted(s.pid for s in process_state.every(root)) == [1, 10, 11, 12, 13, 20]
