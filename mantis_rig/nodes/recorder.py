"""Recorder: raw (still serialized) subscriptions on a node, every message into a BagWriter.

Like ``ros2 bag record``: no deserialization, each message logged with the node's clock at
reception (sim time under ``use_sim_time``). The subscriptions ask for what each publisher of
the contract offers (docs/ros_interfaces.md): reliable everywhere, transient local for
``/supervisor/state`` (so the state current at the start is recorded too).
"""
from __future__ import annotations

from dataclasses import dataclass
import threading

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mantis_rig.recording import BagClosedError
from mantis_rig.recording.interfaces import message_class

RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def reliable(depth: int = 10) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass(frozen=True)
class TopicSpec:
    topic: str
    type_name: str
    latched: bool = False      # transient local (else volatile); always reliable
    depth: int = 100           # subscriber queue: room for bursts (marker blocks, stalls)

    @property
    def offered_qos(self) -> QoSProfile:
        return LATCHED if self.latched else RELIABLE


#: Every topic of the contract that a trial's bag holds.
TRIAL_TOPICS = (
    TopicSpec('/stage/joint_state', 'sensor_msgs/msg/JointState'),
    TopicSpec('/stage/velocity_command', 'std_msgs/msg/Float64'),
    TopicSpec('/stage/position_command', 'std_msgs/msg/Float64'),
    TopicSpec('/loadcell/force_block', 'std_msgs/msg/Float64MultiArray', depth=1000),
    TopicSpec('/loadcell/wrench', 'geometry_msgs/msg/WrenchStamped'),
    TopicSpec('/camera/trigger_time', 'sensor_msgs/msg/TimeReference'),
    TopicSpec('/camera/markers', 'std_msgs/msg/Float64MultiArray', depth=1000),
    TopicSpec('/supervisor/state', 'std_msgs/msg/String', latched=True, depth=10),
    TopicSpec('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray'),
)


def subscription_qos(spec: TopicSpec) -> QoSProfile:
    offered = spec.offered_qos
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(spec.depth, offered.depth),
                      reliability=offered.reliability, durability=offered.durability)


class Recorder:
    """Record ``topics`` on ``node`` into a bag between start(bag) and stop()."""

    def __init__(self, node, topics=TRIAL_TOPICS, callback_group=None, clock=None):
        """clock: what stamps each message's log time (default: the node's)."""
        self.node = node
        self.clock = clock or node.get_clock()
        self.topics = tuple(topics)
        self.callback_group = callback_group
        self.counts: dict[str, int] = {}
        self.dropped_after_close = 0
        self.on_message = None     # optional hook: on_message(topic, data) before each write
        self.on_written = None     # optional hook: on_written(topic, data) after each write
        self._bag = None
        self._subscriptions = []
        self._lock = threading.Lock()

    @property
    def recording(self) -> bool:
        return self._bag is not None

    def start(self, bag) -> None:
        if self._bag is not None:
            raise RuntimeError('the recorder is already recording')
        for spec in self.topics:
            bag.add_topic(spec.topic, spec.type_name, spec.offered_qos)
        self.counts = {spec.topic: 0 for spec in self.topics}
        self._bag = bag
        clock = self.clock
        for spec in self.topics:
            def on_message(data, topic=spec.topic):
                self._write(topic, data, clock.now().nanoseconds)
            self._subscriptions.append(self.node.create_subscription(
                message_class(spec.type_name), spec.topic, on_message, subscription_qos(spec),
                callback_group=self.callback_group, raw=True))

    def _write(self, topic: str, data: bytes, t_ns: int) -> None:
        bag = self._bag
        if bag is None:
            self.dropped_after_close += 1
            return
        if self.on_message is not None:
            self.on_message(topic, data)
        try:
            bag.write_serialized(topic, data, max(t_ns, 0))
        except BagClosedError:
            self.dropped_after_close += 1
            return
        with self._lock:
            self.counts[topic] += 1
        if self.on_written is not None:
            self.on_written(topic, data)

    def stop(self) -> None:
        """Stop recording (the bag stays open: its owner closes it)."""
        subscriptions, self._subscriptions = self._subscriptions, []
        self._bag = None
        for subscription in subscriptions:
            self.node.destroy_subscription(subscription)
