"""SharedSimClock: simulated time for the nodes of a one-process stack, set by the world at
every step.

Followed through /clock, every node in the process had a subscription of its own, and each
/clock message (100 a second) woke the device nodes' MultiThreadedExecutor once per node. Here
one rclpy TimeSource, with no subscription, holds the nodes' clocks and the world sets it
directly; /clock is still published for everything outside the process.
"""
from __future__ import annotations

from rclpy.time_source import TimeSource


class SharedSimClock:
    def __init__(self):
        self._source = TimeSource()          # no node: it never subscribes to /clock
        self._source.ros_time_is_active = True

    def attach(self, node) -> None:
        """The node's clock follows the world from now on (leave its use_sim_time false)."""
        self._source.attach_clock(node.get_clock())

    def on_clock(self, msg) -> None:
        """A rosgraph_msgs/Clock from the world."""
        self._source.clock_callback(msg)


__all__ = ['SharedSimClock']
