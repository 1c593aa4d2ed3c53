"""Playback timing: map log time to wall time at a rate, wait precisely, record lateness.

Message i is due at ``start + (t_log_i - t_first) / rate`` on ``time.perf_counter()`` (a
monotonic clock, ~ns resolution). :func:`sleep_until` sleeps until :data:`SPIN_MARGIN_S` before
the deadline (a sleeping thread wakes ~0.1 ms late on average, but up to ~1.5 ms late on a
virtual machine) and spins the rest, yielding the GIL on every turn so other Python threads
keep running. The spin costs CPU: up to SPIN_MARGIN_S per message.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import os
import threading
import time

import numpy as np

SPIN_MARGIN_S = 0.0015
MAX_SLEEP_S = 0.05
_NS_PER_S = 1e9


def sleep_until(deadline: float, stop: threading.Event | None = None,
                clock=time.perf_counter) -> bool:
    """Wait until ``clock() >= deadline``; False if ``stop`` was set first."""
    while True:
        remaining = deadline - clock()
        if remaining <= 0:
            return True
        if stop is not None and stop.is_set():
            return False
        if remaining > SPIN_MARGIN_S:
            # time.sleep (clock_nanosleep) wakes far more punctually than Event.wait (up to
            # ms late on a VM); cap each sleep so a long gap in the log stays interruptible.
            time.sleep(min(remaining - SPIN_MARGIN_S, MAX_SLEEP_S))
        else:
            time.sleep(0)  # yield the GIL, then check again


@dataclass
class PlaybackClock:
    """Log time (ns) -> wall deadline (perf_counter s) for one pass through the bag."""

    rate: float
    first_log_ns: int
    start_wall_s: float

    def __post_init__(self):
        if not self.rate > 0:
            raise ValueError(f'rate must be > 0, got {self.rate}')

    def deadline(self, log_ns: int) -> float:
        return self.start_wall_s + (log_ns - self.first_log_ns) / _NS_PER_S / self.rate

    def log_time_at(self, wall_s: float) -> int:
        return self.first_log_ns + round((wall_s - self.start_wall_s) * self.rate * _NS_PER_S)


@dataclass
class TimingStats:
    """Per-publication lateness (actual - due, s) and the log/wall spans of the playback: the
    wall span runs from when the first publication was due to when the last went out, so a
    late start (a busy machine) does not make the playback look faster than it was."""

    lateness_s: list = field(default_factory=list)
    log_span_s: float = 0.0
    wall_span_s: float = 0.0
    _first: tuple | None = None  # (log ns, due wall s) of the first publication

    def record(self, log_ns: int, due_s: float, actual_s: float) -> None:
        self.lateness_s.append(actual_s - due_s)
        if self._first is None:
            self._first = (log_ns, due_s)
        else:
            self.log_span_s = (log_ns - self._first[0]) / _NS_PER_S
            self.wall_span_s = actual_s - self._first[1]

    @property
    def count(self) -> int:
        return len(self.lateness_s)

    @property
    def achieved_rate(self) -> float:
        return self.log_span_s / self.wall_span_s if self.wall_span_s > 0 else float('nan')

    def summary(self) -> dict:
        late = np.asarray(self.lateness_s) if self.lateness_s else np.zeros(1)
        return {
            'messages': self.count,
            'log_span_s': self.log_span_s,
            'wall_span_s': self.wall_span_s,
            'achieved_rate': self.achieved_rate,
            'lateness_mean_ms': 1e3 * float(np.mean(late)),
            'lateness_p99_ms': 1e3 * float(np.percentile(late, 99)),
            'lateness_max_ms': 1e3 * float(np.max(late)),
        }


REALTIME_PRIORITY = 10


def raise_priority(priority: int = REALTIME_PRIORITY) -> str:
    """Put the calling thread in the SCHED_FIFO class (Linux; needs root or CAP_SYS_NICE).

    A real-time thread wakes on time and is not preempted by ordinary work on a busy machine.
    The kernel's real-time throttling (95% of each second by default) still bounds it.
    Returns a short description; raises OSError if not permitted or not supported.
    """
    if not hasattr(os, 'sched_setscheduler'):
        raise OSError('real-time scheduling is not supported on this platform')
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    return f'SCHED_FIFO priority {priority}'
