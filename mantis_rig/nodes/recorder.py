"""Recorder: raw (still serialized) subscriptions on a node, every message into a BagWriter.

Like ``ros2 bag record``: no deserialization, each message logged with the node's clock at
reception (sim time under ``use_sim_time``). The subscriptions ask for what each publisher of
the contract offers (docs/ros_interfaces.md): reliable everywhere, transient local for
``/supervisor/state`` (so the state current at the start is recorded too).

Each trial state is synced to disk as soon as it is written (BagWriter.sync): a recorder killed
or frozen mid-trial (its process, the supervisor's) leaves a bag that `mantis recover` reads up
to the state the trial was in, however soon after its start that came, and the data up to the
writer's own last sync (at most its sync period, 0.5 s, before the end).
"""
from __future__ import annotations

import threading

from mantis_rig import contract
from mantis_rig.recording import BagClosedError, BagWriteError
from mantis_rig.recording.message_types import message_class

#: Every topic of the contract that a trial's bag holds (mantis_rig.contract).
TRIAL_TOPICS = contract.TRIAL_TOPICS


def subscription_qos(topic: contract.Topic):
    """What a recording subscription asks for: its kind's subscriber profile (contract)."""
    return topic.qos.subscriber()


class Recorder:
    """Record ``topics`` on ``node`` into a bag between start(bag) and stop()."""

    def __init__(self, node, topics=TRIAL_TOPICS, callback_group=None, clock=None):
        """topics: contract Topics, resolved in the node's namespace (the bag holds the full
        names); clock: what stamps each message's log time (default: the node's)."""
        self.node = node
        self.clock = clock or node.get_clock()
        self.topics = tuple(topics)
        self.callback_group = callback_group
        self.counts: dict[str, int] = {}
        self.dropped_after_close = 0
        self.on_message = None     # optional hook: on_message(topic, data) before each write
        self.on_written = None     # optional hook: on_written(topic, data) after each write
        self._bag = None
        self._names: dict[str, str] = {}     # contract name -> resolved, while recording
        self._subscriptions = []
        self._lock = threading.Lock()

    @property
    def recording(self) -> bool:
        return self._bag is not None

    def start(self, bag) -> None:
        if self._bag is not None:
            raise RuntimeError('the recorder is already recording')
        names = {spec.name: self.node.resolve_topic_name(spec.name) for spec in self.topics}
        for spec in self.topics:
            bag.add_topic(names[spec.name], spec.type_name, spec.qos.publisher())
        self.counts = {spec.name: 0 for spec in self.topics}
        self._names = names
        self._bag = bag
        clock = self.clock
        for spec in self.topics:
            def on_message(data, name=spec.name, full=names[spec.name]):
                self._write(name, full, data, clock.now().nanoseconds)
            self._subscriptions.append(self.node.create_subscription(
                message_class(spec.type_name), spec.name, on_message, subscription_qos(spec),
                callback_group=self.callback_group, raw=True))

    def _write(self, name: str, full_name: str, data: bytes, t_ns: int) -> None:
        """name: the contract's (relative) name, which the hooks and counts use; full_name:
        the resolved one, under which the bag holds it."""
        bag = self._bag
        if bag is None:
            self.dropped_after_close += 1
            return
        if self.on_message is not None:
            self.on_message(name, data)
        try:
            bag.write_serialized(full_name, data, max(t_ns, 0))
        except BagClosedError:
            self.dropped_after_close += 1
            return
        with self._lock:
            self.counts[name] += 1
        if name == contract.SUPERVISOR_STATE.name:
            try:
                bag.sync()          # a trial's state on disk at once (a killed recorder)
            except (BagClosedError, BagWriteError):   # the bag's on_failure says so
                pass
        if self.on_written is not None:
            self.on_written(name, data)

    def record(self, name: str, data: bytes) -> None:
        """Log ``data`` (serialized) on contract topic ``name`` as if heard now: a message its
        publisher has not published yet (the supervisor's end state, published once the bag
        is closed). BagClosedError once stopped."""
        if self._bag is None:
            raise BagClosedError(f'the recorder is not recording ({name})')
        self._write(name, self._names[name], data, self.clock.now().nanoseconds)

    def stop(self) -> None:
        """Stop recording (the bag stays open: its owner closes it)."""
        subscriptions, self._subscriptions = self._subscriptions, []
        self._bag = None
        for subscription in subscriptions:
            self.node.destroy_subscription(subscription)
