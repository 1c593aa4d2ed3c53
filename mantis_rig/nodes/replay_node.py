"""replay_node: ``ros2 run mantis_rig replay_node --ros-args -p bag:=trials/trial_042``.

Parameters (read once at start): ``bag`` (string, required), ``rate`` (double, 1.0), ``loop``
(bool, false), ``topics`` (string array, default every topic of the bag), ``clock`` (bool,
false: publish /clock from the log times), ``clock_rate_hz`` (double, 100.0),
``wait_for_subscribers_s`` (double, 0.0: start at once). The node spins (parameter services stay
up) while a worker thread plays the bag; it exits when playback ends (never with ``loop``).
"""
from __future__ import annotations

import sys
import threading

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter

from mantis_rig.contract import REPLAY_NODE_EXECUTABLE
from mantis_rig.replay import BagPlayer, ReplayError
from mantis_rig.runtime.lean_node import WithoutDefaultEventHandlers
from mantis_rig.runtime.ros_env import claim_local_domain


class ReplayNode(WithoutDefaultEventHandlers, Node):
    def __init__(self):
        super().__init__(REPLAY_NODE_EXECUTABLE)
        self.declare_parameter('bag', '')
        self.declare_parameter('rate', 1.0)
        self.declare_parameter('loop', False)
        self.declare_parameter('topics', Parameter.Type.STRING_ARRAY)
        self.declare_parameter('clock', False)
        self.declare_parameter('clock_rate_hz', 100.0)
        self.declare_parameter('wait_for_subscribers_s', 0.0)
        bag = self.get_parameter('bag').value
        if not bag:
            raise ReplayError('parameter "bag" is not set (-p bag:=<bag directory>)')
        clock_hz = self.get_parameter('clock_rate_hz').value \
            if self.get_parameter('clock').value else None
        self.player = BagPlayer(self, bag, rate=self.get_parameter('rate').value,
                                loop=self.get_parameter('loop').value,
                                topics=self.get_parameter('topics').value or None,
                                clock_hz=clock_hz)
        for problem in self.player.report.problems:
            self.get_logger().warning(f'bag damaged, replaying what precedes the damage: '
                                      f'{problem}')
        self.stop = threading.Event()
        self.done = threading.Event()
        self.worker = threading.Thread(target=self._play, name='replay', daemon=True)

    def _play(self):
        try:
            wait_s = self.get_parameter('wait_for_subscribers_s').value
            if wait_s > 0:
                self.player.wait_for_subscribers(wait_s, self.stop)
            report = self.player.run(self.stop)
            self.get_logger().info(str(report))
        finally:
            self.done.set()


def main(args=None) -> int:
    claim_local_domain()
    rclpy.init(args=args)
    try:
        try:
            node = ReplayNode()
        except ReplayError as exc:
            print(f'replay_node: {exc}', file=sys.stderr)
            return 1
        node.worker.start()
        try:
            while rclpy.ok() and not node.done.is_set():
                rclpy.spin_once(node, timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            node.stop.set()
            node.worker.join(timeout=2.0)
            node.destroy_node()
        return 0
    finally:
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == '__main__':
    sys.exit(main())
