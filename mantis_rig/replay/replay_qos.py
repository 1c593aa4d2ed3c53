"""The QoS a replayed topic is published with, from the bag's offered QoS profiles.

A bag stores, per topic, the QoS profiles its publishers offered (rosbag2 version-9 maps). The
replay publisher must be compatible with every subscriber the original publishers served, so it
takes the strongest offer: reliable if any offer was reliable, transient local if any offer was
(and always for a topic the contract declares transient local, ``supervisor/state``, in
whatever namespace the bag holds it). Depth is the largest
offered depth; volatile topics get at least :data:`MIN_VOLATILE_DEPTH` so a burst (the camera's
marker blocks arrive together) is not cut short by a keep-last history while acks are pending.
Depth does not take part in QoS matching, so this changes no compatibility. Deadline, lifespan
and liveliness are left at their defaults: a replay must not expire or police old data.
"""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mantis_rig.contract import find_topic


def _latched_in_contract(topic: str) -> bool:
    """A topic the contract declares transient local, in whatever namespace it was recorded."""
    found = find_topic(topic)
    return found is not None and found.qos.transient_local

DEFAULT_DEPTH = 10
MIN_VOLATILE_DEPTH = 100


def replay_qos(topic: str, offered: list[dict]) -> QoSProfile:
    """QoSProfile for republishing ``topic`` given its offered profiles (may be empty)."""
    reliable = not offered or any(o.get('reliability') == 'reliable' for o in offered) \
        or all(o.get('reliability') in (None, 'system_default', 'unknown') for o in offered)
    transient = _latched_in_contract(topic) or any(
        o.get('durability') == 'transient_local' for o in offered)
    depths = [int(o.get('depth') or 0) for o in offered]
    depth = max(depths, default=0) or DEFAULT_DEPTH
    if not transient:
        depth = max(depth, MIN_VOLATILE_DEPTH)
    avoid_conventions = any(o.get('avoid_ros_namespace_conventions') for o in offered)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if transient
                    else DurabilityPolicy.VOLATILE),
        avoid_ros_namespace_conventions=bool(avoid_conventions))
