"""BagPlayer: republish a bag's messages (serialized, as recorded) on their original schedule.

The messages go out as the recorded CDR bytes (``Publisher.publish(bytes)``): nothing is
deserialized, so a replay is byte-identical to the recording and cheap enough for 10x real time.
Message i is published at ``start + (t_log_i - t_first) / rate`` (see :mod:`.schedule`); a
player that falls behind publishes at once and never drops a message. With ``clock_hz`` the
player also publishes ``/clock`` (rosgraph_msgs/Clock) carrying the log time, every
``1 / clock_hz`` s of wall time, interleaved with the messages so /clock never runs ahead of
the data it stamps.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import gc
import threading
import time

from rclpy.duration import Duration
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rosgraph_msgs.msg import Clock

from mantis_rig.recording.message_types import MessageTypeError, message_class
from mantis_rig.recording.offered_qos import parse_offered_qos_string
from mantis_rig.replay.replay_qos import replay_qos
from mantis_sim.errors import InputError

from ..contract import CLOCK, resolve
from ..recording import BagError, BagReader
from .readahead import ReadAhead
from .schedule import PlaybackClock, TimingStats, raise_priority, sleep_until

CLOCK_TOPIC = resolve(CLOCK)        # in the player's namespace: the root's unless remapped
RCLError = _rclpy.RCLError
DISCOVERY_SETTLE_S = 0.2
TIME_JUMP_CHOICES = ('refuse', 'skip')
# the metadata's span is stated to the nanosecond; a little slack for writers that round it
SPAN_TOLERANCE_NS = 1_000_000


def metadata_span_ns(reader) -> tuple[int, int] | None:
    """(first, last) log time, ns, that the bag's metadata.yaml says it spans; None without a
    metadata.yaml (a bag not closed cleanly) or without a usable span in it."""
    info = reader.metadata_yaml
    try:
        start = int(info['starting_time']['nanoseconds_since_epoch'])
        duration = int(info['duration']['nanoseconds'])
    except (KeyError, TypeError, ValueError, OverflowError):
        return None
    return (start, start + duration) if duration >= 0 else None


class ReplayError(InputError):
    """The bag cannot be replayed as asked (names the bag and the reason)."""


@dataclass
class PlaybackReport:
    bag: str
    passes: int = 0
    published: dict = field(default_factory=dict)  # topic -> messages published
    clock_ticks: int = 0
    skipped_topics: dict = field(default_factory=dict)  # topic -> why it was not replayed
    problems: list = field(default_factory=list)  # damage found in the bag
    stats: TimingStats = field(default_factory=TimingStats)  # last complete pass
    interrupted: bool = False
    scheduling: str = 'normal'  # of the playback thread
    time_jumps: list = field(default_factory=list)  # messages skipped outside the bag's span
    clock_topic: str = CLOCK_TOPIC

    def __str__(self):
        s = self.stats.summary()
        lines = [f'replayed {sum(self.published.values())} messages from {self.bag} '
                 f'in {self.passes} pass(es)' + (' (interrupted)' if self.interrupted else ''),
                 f'  last pass: {s["log_span_s"]:.3f} s of log in {s["wall_span_s"]:.3f} s '
                 f'(achieved rate {s["achieved_rate"]:.3f}x); lateness mean '
                 f'{s["lateness_mean_ms"]:.3f} ms, p99 {s["lateness_p99_ms"]:.3f} ms, '
                 f'max {s["lateness_max_ms"]:.3f} ms; scheduling {self.scheduling}']
        lines += [f'  {topic}: {n}' for topic, n in self.published.items()]
        if self.clock_ticks:
            lines.append(f'  {self.clock_topic}: {self.clock_ticks}')
        lines += [f'  skipped {topic}: {why}' for topic, why in self.skipped_topics.items()]
        lines += [f'  bag problem: {p}' for p in self.problems]
        lines += [f'  skipped (time jump): {jump}' for jump in self.time_jumps]
        return '\n'.join(lines)


class BagPlayer:
    """Replay the bag at ``path`` through publishers created on ``node``.

    ``topics``: only these (default: every topic of the bag); ``rate``: playback speed factor;
    ``loop``: start again after the last message until stopped; ``clock_hz``: publish /clock at
    this wall-clock frequency (None/0: no /clock); ``realtime``: run the playback thread with
    real-time priority if the system permits (see :func:`.schedule.raise_priority`).
    ``time_jumps``: what to do with a message whose log time lies outside the span the bag's
    metadata.yaml states (a damaged log time, which would otherwise stall the replay for as
    long as it jumps): 'refuse' (ReplayError naming it; the read-ahead holds a whole trial bag
    before the first publication, so nothing of one is played) or 'skip' (listed in the
    report's time_jumps).
    """

    def __init__(self, node, path, *, rate=1.0, loop=False, topics=None, clock_hz=None,
                 realtime=False, time_jumps='refuse'):
        if time_jumps not in TIME_JUMP_CHOICES:
            raise ReplayError(f'time_jumps must be one of {TIME_JUMP_CHOICES}, got '
                              f'{time_jumps!r}')
        if not rate > 0:
            raise ReplayError(f'rate must be > 0, got {rate}')
        if clock_hz is not None and clock_hz < 0:
            raise ReplayError(f'clock frequency must be >= 0 Hz, got {clock_hz}')
        try:
            self.reader = BagReader(path, warn=False)
        except BagError as exc:
            raise ReplayError(str(exc)) from exc
        self.rate, self.loop, self.clock_hz = float(rate), bool(loop), clock_hz or None
        self.realtime = realtime
        self.time_jumps = time_jumps
        self.span_ns = metadata_span_ns(self.reader)
        self.context = node.context
        self.report = PlaybackReport(bag=str(path), problems=list(self.reader.problems))
        available = self.reader.topics
        wanted = list(available) if not topics else list(topics)
        unknown = [t for t in wanted if t not in available]
        if unknown:
            raise ReplayError(f'{path}: no topic(s) {unknown} in the bag '
                              f'(it has {sorted(available)})')
        self.publishers = {}
        for topic in wanted:
            info = available[topic]
            try:
                msg_class = message_class(info.type_name)
            except MessageTypeError as exc:
                self.report.skipped_topics[topic] = str(exc)
                continue
            offered = parse_offered_qos_string(info.metadata.get('offered_qos_profiles', ''))
            self.publishers[topic] = node.create_publisher(
                msg_class, topic, replay_qos(topic, offered))
            self.report.published[topic] = 0
        if not self.publishers:
            raise ReplayError(f'{path}: nothing to replay ({self.report.skipped_topics})')
        self.clock_publisher = (node.create_publisher(Clock, CLOCK.name, CLOCK.qos.publisher())
                                if self.clock_hz else None)
        if self.clock_publisher is not None:
            self.report.clock_topic = self.clock_publisher.topic_name

    def wait_for_subscribers(self, timeout_s, stop=None) -> bool:
        """Wait until every replayed topic has a matched subscriber (True) or time runs out."""
        deadline = time.monotonic() + timeout_s
        stop = stop or threading.Event()
        while not all(p.get_subscription_count() > 0 for p in self.publishers.values()):
            if time.monotonic() >= deadline or stop.wait(0.01):
                return False
        # Matching is seen from the publisher's side first; give the subscribers' side of
        # discovery a moment so the first volatile messages are not sent before they listen.
        return not stop.wait(DISCOVERY_SETTLE_S)

    def wait_for_delivery(self, timeout_s=2.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published (True if so)."""
        if not self.context.ok():
            return False
        deadline = time.monotonic() + timeout_s
        acked = True
        for publisher in self.publishers.values():
            left = max(0.0, deadline - time.monotonic())
            acked &= publisher.wait_for_all_acked(Duration(seconds=left))
        return acked

    def run(self, stop: threading.Event | None = None) -> PlaybackReport:
        """Play once (or until ``stop`` when looping); returns the report."""
        stop = stop or threading.Event()
        if self.realtime:
            try:
                self.report.scheduling = raise_priority()
            except OSError as exc:
                self.report.scheduling = f'normal (real-time scheduling refused: {exc})'
        while not stop.is_set():
            gc.collect()
            gc.disable()  # a full collection mid-pass would stall a publication for ms
            try:
                completed = self._play_once(stop)
            finally:
                gc.enable()
            if not completed:
                self.report.interrupted = True
                break
            self.report.passes += 1
            if not self.loop:
                break
        new_problems = [p for p in self.reader.problems if p not in self.report.problems]
        self.report.problems += new_problems
        return self.report

    def _play_once(self, stop) -> bool:
        stats = TimingStats()
        source = ReadAhead(self._within_span(
            (m.log_time, ch.topic, bytes(m.data))
            for ch, _, m in self.reader.raw_messages(list(self.publishers))))
        source.fill()  # before the clock starts: a trial bag is read whole here
        first = source.peek()
        if first is None:
            self.report.stats = stats
            return True
        clock = PlaybackClock(self.rate, first[0], time.perf_counter())
        tick_ns = max(1, round(1e9 * self.rate / self.clock_hz)) if self.clock_hz else None
        next_tick_ns = first[0]
        while (item := source.pop()) is not None:
            log_ns, topic, data = item
            if tick_ns is not None:
                while next_tick_ns <= log_ns:
                    if not sleep_until(clock.deadline(next_tick_ns), stop):
                        return False
                    self._publish_clock(next_tick_ns)
                    if not self.context.ok():
                        return False
                    next_tick_ns += tick_ns
            due = clock.deadline(log_ns)
            if not sleep_until(due, stop):
                return False
            try:
                self.publishers[topic].publish(data)
            except RCLError:
                if self.context.ok():
                    raise
                return False  # rclpy was shut down (Ctrl-C): stop quietly
            stats.record(log_ns, due, time.perf_counter())
            self.report.published[topic] += 1
            following = source.peek() if len(source) else None
            if following is not None:  # top the buffer up while there is time to spare
                source.fill(clock.deadline(following[0]))
        self.report.stats = stats
        return True

    def _within_span(self, items):
        """The items, checked against the metadata's span (``time_jumps``)."""
        if self.span_ns is None:
            yield from items
            return
        first, last = self.span_ns
        for index, item in enumerate(items):
            log_ns, topic = item[0], item[1]
            if first - SPAN_TOLERANCE_NS <= log_ns <= last + SPAN_TOLERANCE_NS:
                yield item
                continue
            where = (f'message {index} (on {topic}) has log time {log_ns * 1e-9:.6f} s, '
                     f'outside the {first * 1e-9:.6f} .. {last * 1e-9:.6f} s that the '
                     f"bag's metadata.yaml spans")
            if self.time_jumps == 'refuse':
                raise ReplayError(f'{self.report.bag}: {where}; replay refused (--time-jumps '
                                  f'skip replays the bag without such messages)')
            if self.report.passes == 0:            # once, not on every pass of a loop
                self.report.time_jumps.append(where)

    def _publish_clock(self, log_ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(log_ns), 1_000_000_000)
        try:
            self.clock_publisher.publish(msg)
        except RCLError:
            if self.context.ok():
                raise
            return
        self.report.clock_ticks += 1
