"""The simulated world's back-pressure: at --real-time-factor 0 it runs no further than
`max_lead_s` ahead of its slowest consumer's progress (/progress) while the force streams, and
stops waiting for a consumer that waits for nothing (progress 0) or that went silent."""
from __future__ import annotations

import time

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from mantis_rig.contract import FORCE_BLOCK, PROGRESS
from mantis_rig.nodes.device_node import time_msg
from mantis_rig.recording.force_block import force_block_to_msg
from mantis_rig.simulated.sim_world_node import STREAM_ALIVE_S, SimWorldNode

LEAD_S = 0.05
STEP_S = 0.01
WAIT_S = 30.0
TRIAL, GUARD = 'supervisor_node/trial', 'stage_node/force_guard'


def _until(condition, what: str, send=lambda: None) -> None:
    """Wait for condition(), sending again every 0.1 s (a message sent before the world's
    subscription matched this publisher is not delivered)."""
    deadline = time.monotonic() + WAIT_S
    while True:
        send()
        sent = time.monotonic()
        while time.monotonic() - sent < 0.1:
            if condition():
                return
            time.sleep(0.01)
        assert time.monotonic() < deadline, f'timed out waiting for {what}'


def test_the_world_waits_for_its_slowest_consumer_and_not_for_a_silent_one(ros):
    world_node = SimWorldNode(parameter_overrides=[
        Parameter('real_time_factor', value=0.0), Parameter('max_lead_s', value=LEAD_S),
        Parameter('step_s', value=STEP_S)])
    peer = Node('pacing_peer')
    force = peer.create_publisher(type(force_block_to_msg(0.0, 1e-3, [0.0])),
                                  FORCE_BLOCK.name, FORCE_BLOCK.qos.publisher())
    progress = peer.create_publisher(Header, PROGRESS.name, PROGRESS.qos.publisher())
    world = world_node.world

    def stream_force(end_s: float) -> None:
        force.publish(force_block_to_msg(end_s - 1e-3, 1e-3, [0.0]))

    def report(progress_s: float, consumer: str = TRIAL) -> None:
        _until(lambda: consumer in world_node.progress        # to the nanosecond
               and abs(world_node.progress[consumer][0] - progress_s) < 1e-9,
               f'the progress of {consumer} to be heard',
               lambda: progress.publish(Header(stamp=time_msg(progress_s), frame_id=consumer)))

    def a_trial_at_the_worlds_time() -> float:
        """Hold the world by a force stream behind it, report a trial there, then let the
        force stream run far ahead: only the trial holds it now. Its progress, s."""
        _until(lambda: world_node._daq_end_s is not None
               and abs(world_node._daq_end_s - 0.001) < 1e-9,
               'the force stream to be heard', lambda: stream_force(0.001))
        held_at_s = world.time_s
        report(held_at_s)
        report(held_at_s + 100.0, GUARD)     # another consumer, far ahead
        stream_force(1e6)
        return held_at_s

    try:
        _until(lambda: force.get_subscription_count() and progress.get_subscription_count(),
               'the world\'s pacing subscriptions')
        held_at_s = a_trial_at_the_worlds_time()
        for _ in range(5):                   # heard again and again: the world stays held
            report(held_at_s)
            report(held_at_s + 100.0, GUARD)
            stream_force(1e6)
            time.sleep(0.1)
            assert world.time_s <= held_at_s + LEAD_S + STEP_S * 1.5, world.time_s
        report(0.0)                          # the trial ended: nothing to wait for
        report(held_at_s + 2.0, GUARD)
        _until(lambda: world.time_s > held_at_s + 1.0, 'the world after the trial ended')

        silent_at_s = a_trial_at_the_worlds_time()
        while True:                          # the trial silent, the others going on
            world_time_s = world.time_s
            if time.monotonic() - world_node.progress[TRIAL][1] >= STREAM_ALIVE_S:
                break
            assert world_time_s <= silent_at_s + LEAD_S + STEP_S * 1.5, world_time_s
            stream_force(1e6)
            report(silent_at_s + 100.0, GUARD)
            time.sleep(0.1)
        _until(lambda: world.time_s > silent_at_s + 1.0, 'the world after the trial went silent')
    finally:
        peer.destroy_node()
        world_node.destroy_node()
        rclpy.try_shutdown()
