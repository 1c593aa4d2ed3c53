"""rosbag2 ``metadata.yaml`` (version 9, as ROS 2 Jazzy writes it): build, write, read."""
from dataclasses import dataclass, field
import os
from pathlib import Path
import time

import yaml

from mantis_sim.durable_files import fsync_dir, write_atomically  # noqa: F401 - the writer's
from mantis_sim.errors import InputError

from .yaml_emit import emit_yaml

METADATA_FILENAME = 'metadata.yaml'
# libyaml's safe loader where PyYAML was built with it: the same documents, a tenth of the
# pure-Python parser's time (80 ms a bag's metadata), which every reading of a bag pays
_SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
METADATA_VERSION = 9
STORAGE_IDENTIFIER = 'mcap'
SERIALIZATION_FORMAT = 'cdr'
#: Name and key of the MCAP metadata record in which rosbag2 keeps a copy of the bag metadata.
ROSBAG2_RECORD_NAME = 'rosbag2'
ROSBAG2_RECORD_KEY = 'serialized_metadata'


@dataclass
class TopicRecord:
    """One topic of a bag: what metadata.yaml says about it."""

    name: str
    type_name: str
    offered_qos: list  # version-9 QoS maps, see qos.offered_qos_list
    type_description_hash: str = ''
    message_count: int = 0
    serialization_format: str = SERIALIZATION_FORMAT


@dataclass
class BagSummary:
    """Everything metadata.yaml records about a single-file bag."""

    relative_file_path: str
    topics: list = field(default_factory=list)  # TopicRecord, in registration order
    starting_time_ns: int = 0
    duration_ns: int = 0
    custom_data: dict = field(default_factory=dict)
    ros_distro: str = field(default_factory=lambda: os.environ.get('ROS_DISTRO', 'jazzy'))

    @property
    def message_count(self):
        return sum(t.message_count for t in self.topics)


def bag_metadata_dict(summary):
    """The ``rosbag2_bagfile_information`` map, keys in rosbag2's order."""
    return {
        'version': METADATA_VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': {'nanoseconds': summary.duration_ns},
        'starting_time': {'nanoseconds_since_epoch': summary.starting_time_ns},
        'message_count': summary.message_count,
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': t.name,
                    'type': t.type_name,
                    'serialization_format': t.serialization_format,
                    'offered_qos_profiles': t.offered_qos,
                    'type_description_hash': t.type_description_hash,
                },
                'message_count': t.message_count,
            }
            for t in summary.topics
        ],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [summary.relative_file_path],
        'files': [{
            'path': summary.relative_file_path,
            'starting_time': {'nanoseconds_since_epoch': summary.starting_time_ns},
            'duration': {'nanoseconds': summary.duration_ns},
            'message_count': summary.message_count,
        }],
        'custom_data': {str(k): str(v) for k, v in summary.custom_data.items()},
        'ros_distro': summary.ros_distro,
    }


def serialized_metadata(summary):
    """Text of the ``rosbag2`` MCAP metadata record (the map without its top-level key)."""
    return emit_yaml(bag_metadata_dict(summary)).rstrip('\n')


def write_metadata_yaml(bag_dir, summary):
    """Write <bag_dir>/metadata.yaml atomically (temp file, fsync, rename)."""
    path = Path(bag_dir) / METADATA_FILENAME
    text = emit_yaml({'rosbag2_bagfile_information': bag_metadata_dict(summary)})
    return write_atomically(path, text, temp_name=METADATA_FILENAME + '.tmp')


class MetadataFileError(InputError):
    """metadata.yaml exists but is not a readable rosbag2 metadata file."""


def read_metadata_yaml(path):
    """Parse a metadata.yaml into its ``rosbag2_bagfile_information`` dict."""
    path = Path(path)
    try:
        document = yaml.load(path.read_text(encoding='utf-8'), Loader=_SAFE_LOADER)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise MetadataFileError(f'{path}: cannot parse rosbag2 metadata: {exc}') from exc
    info = document.get('rosbag2_bagfile_information') if isinstance(document, dict) else None
    if not isinstance(info, dict):
        raise MetadataFileError(f'{path}: no rosbag2_bagfile_information map')
    return info


def wait_closed(bag_dir, timeout_s: float, failed=lambda: False) -> bool:
    """Whether the bag at ``bag_dir`` was closed (its metadata.yaml written, the writer's last
    step) within ``timeout_s`` of wall time; False as soon as ``failed()`` says it never will
    be. The supervisor publishes a trial's end once its bag is closed, so this waits only on a
    writer in another process or on a log that failed."""
    deadline = time.monotonic() + timeout_s
    metadata = Path(bag_dir) / METADATA_FILENAME
    while not metadata.exists():
        if time.monotonic() > deadline or failed():
            return False
        time.sleep(0.05)
    return True
