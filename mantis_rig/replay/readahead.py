"""Read-ahead of a bag's messages so reading never delays a publication.

Decoding a chunk (decompress + parse a few hundred records) takes milliseconds in Python,
longer than the gap between two messages of a trial. :class:`ReadAhead` therefore loads up to
``max_bytes`` of messages before playback starts (a whole trial bag, normally) and tops the
buffer up during playback only while the next publication is at least ``min_slack_s`` away.
"""
from __future__ import annotations

from collections import deque
import time

DEFAULT_MAX_BYTES = 256 * 1024 * 1024
MIN_SLACK_S = 0.010


class ReadAhead:
    """Buffered ``(log_ns, topic, data)`` items from an iterator of them."""

    def __init__(self, items, max_bytes=DEFAULT_MAX_BYTES, min_slack_s=MIN_SLACK_S):
        self._items = iter(items)
        self._buffer = deque()
        self._bytes = 0
        self._exhausted = False
        self.max_bytes, self.min_slack_s = max_bytes, min_slack_s

    def fill(self, deadline=None, clock=time.perf_counter) -> None:
        """Read until the buffer holds ``max_bytes`` (or the end), stopping early once
        ``deadline - min_slack_s`` has passed (deadline: the next publication, clock s)."""
        while not self._exhausted and self._bytes < self.max_bytes:
            if deadline is not None and clock() > deadline - self.min_slack_s:
                return
            item = next(self._items, None)
            if item is None:
                self._exhausted = True
                return
            self._buffer.append(item)
            self._bytes += len(item[2])

    def pop(self):
        """The next item, or None at the end (reads synchronously if the buffer ran dry)."""
        if not self._buffer:
            self.fill()
            if not self._buffer:
                return None
        item = self._buffer.popleft()
        self._bytes -= len(item[2])
        return item

    def peek(self):
        if not self._buffer:
            self.fill()
        return self._buffer[0] if self._buffer else None

    def __len__(self):
        return len(self._buffer)
