"""Offered QoS profiles in rosbag2's metadata version 9 form.

rosbag2 (Jazzy, metadata version 9) stores each topic's offered QoS profiles as a list of maps with
policy names as strings (``keep_last``, ``reliable``...) and durations as ``{sec, nsec}``: a YAML
list inside metadata.yaml, and the same list dumped to a YAML string in the MCAP channel's
``offered_qos_profiles`` metadata entry.
"""
from rclpy.qos import QoSProfile
import yaml

from mantis_rig.recording.yaml_emit import emit_yaml

_NS_PER_S = 1_000_000_000


def default_offered_qos():
    """What a publisher created with ``create_publisher(type, topic, 10)`` offers."""
    return QoSProfile(depth=10)


def _duration_map(duration):
    total_ns = duration.nanoseconds
    return {'sec': total_ns // _NS_PER_S, 'nsec': total_ns % _NS_PER_S}


def qos_to_dict(profile):
    """One rclpy QoSProfile as rosbag2's version-9 QoS map (key order as rosbag2 writes it)."""
    return {
        'history': profile.history.short_key,
        'depth': int(profile.depth),
        'reliability': profile.reliability.short_key,
        'durability': profile.durability.short_key,
        'deadline': _duration_map(profile.deadline),
        'lifespan': _duration_map(profile.lifespan),
        'liveliness': profile.liveliness.short_key,
        'liveliness_lease_duration': _duration_map(profile.liveliness_lease_duration),
        'avoid_ros_namespace_conventions': bool(profile.avoid_ros_namespace_conventions),
    }


def offered_qos_list(profiles):
    """QoSProfile(s) or version-9 QoS maps (passed through) -> list of version-9 QoS maps."""
    if isinstance(profiles, (QoSProfile, dict)):
        profiles = [profiles]
    return [dict(p) if isinstance(p, dict) else qos_to_dict(p) for p in profiles]


def parse_offered_qos_string(text):
    """The MCAP channel's ``offered_qos_profiles`` string -> list of QoS maps ([] if empty)."""
    loaded = yaml.safe_load(text) if text else None
    return loaded if isinstance(loaded, list) else []


def offered_qos_channel_string(qos_maps):
    """The MCAP channel metadata value: the list dumped as YAML, no trailing newline."""
    return emit_yaml(qos_maps).rstrip('\n')
