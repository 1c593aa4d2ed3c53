"""Nodes whose publishers and subscriptions carry no default QoS-event handlers.

rclpy gives every publisher and subscription one handler per event kind it can report
(incompatible QoS, incompatible type), each a Waitable that the Python executors walk, count
and add to a new wait set on every wake-up. On the simulated rig they were a third of the
entities the device nodes' executor rebuilt its wait set from on each message, and dropping
them saved 16 % of a whole trial's CPU (bench/bench_trial.py). Their only work is a warning
when a peer with an incompatible QoS or type appears. A peer outside this package (ros2 topic
echo, a bag recorder) still warns with its own handler; between two of our nodes a mismatch
would be silent, so their QoS is fixed in code, documented in docs/ros_interfaces.md, and the
trial tests check that every topic reaches the bag. A caller that wants handlers passes
``event_callbacks`` as usual.
"""
from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node


class WithoutDefaultEventHandlers:
    """Mixin for a Node (or LifecycleNode) class: no default QoS-event handlers."""

    def create_publisher(self, *args, event_callbacks=None, **kwargs):
        if event_callbacks is None:
            event_callbacks = PublisherEventCallbacks(use_default_callbacks=False)
        return super().create_publisher(*args, event_callbacks=event_callbacks, **kwargs)

    def create_subscription(self, *args, event_callbacks=None, **kwargs):
        if event_callbacks is None:
            event_callbacks = SubscriptionEventCallbacks(use_default_callbacks=False)
        return super().create_subscription(*args, event_callbacks=event_callbacks, **kwargs)


class LeanNode(WithoutDefaultEventHandlers, Node):
    """rclpy's Node without default QoS-event handlers (for rclpy.create_node's uses)."""
