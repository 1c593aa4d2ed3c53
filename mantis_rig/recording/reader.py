"""BagReader / read_bag: messages of a rosbag2 MCAP bag in log-time order, deserialized.

A healthy bag is read through the MCAP summary (mcap's seeking reader). A bag that a crash left
without metadata.yaml, summary or footer, or that is cut mid-chunk or corrupted, is read by a
tolerant sequential scan: every complete message before the damage is returned and the damage is
reported (``BagReader.damage`` / ``.problems`` and a :class:`TruncatedBagWarning`).
"""
from dataclasses import dataclass, field
import heapq
from pathlib import Path
import re
from typing import NamedTuple
import warnings

from mcap.reader import make_reader
from rclpy.serialization import deserialize_message

from mantis_rig.recording.message_types import message_class
from mantis_sim.errors import InputError

from .bag_metadata import (
    METADATA_FILENAME,
    ROSBAG2_RECORD_NAME,
    MetadataFileError,
    read_metadata_yaml,
)
from .mcap_scan import NotMcapError, has_valid_tail, scan_mcap


class BagError(InputError):
    """The path is not a readable rosbag2 MCAP bag (names the file and the problem)."""


class TruncatedBagWarning(UserWarning):
    """The bag was not closed cleanly; only the data before the damage could be read."""


class BagMessage(NamedTuple):
    topic: str
    type_name: str
    log_time_ns: int
    message: object


@dataclass
class TopicInfo:
    name: str
    type_name: str
    message_count: int
    metadata: dict = field(default_factory=dict)  # MCAP channel metadata (offered QoS, hash)
    schema_text: str = ''


def _split_index(path):
    match = re.search(r'_(\d+)\.mcap$', path.name)
    return int(match.group(1)) if match else 0


def _locate(path):
    """(bag directory or None, list of .mcap files, metadata.yaml path or None)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such file or directory')
    if path.is_file():
        if path.suffix != '.mcap':
            raise BagError(f'{path}: not a bag (expected a bag directory or a .mcap file)')
        yaml_path = path.parent / METADATA_FILENAME
        return path.parent, [path], yaml_path if yaml_path.exists() else None
    yaml_path = path / METADATA_FILENAME
    if yaml_path.exists():
        try:
            info = read_metadata_yaml(yaml_path)
        except MetadataFileError as exc:
            raise BagError(str(exc)) from exc
        storage = info.get('storage_identifier')
        if storage != 'mcap':
            raise BagError(f'{yaml_path}: storage_identifier is {storage!r}, only mcap bags '
                           'are supported')
        names = info.get('relative_file_paths') or []
        if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
            raise BagError(f'{yaml_path}: relative_file_paths must be a list of file names, '
                           f'not {names!r}')
        files = [path / name for name in names]
        missing = [str(f) for f in files if not f.exists()]
        if missing or not files:
            raise BagError(f'{yaml_path}: lists storage files that do not exist: {missing}')
        return path, files, yaml_path
    files = sorted(path.glob('*.mcap'), key=_split_index)
    if not files:
        raise BagError(f'{path}: not a bag (no metadata.yaml and no .mcap file)')
    return path, files, None


class BagReader:
    """Read a bag directory (or a single .mcap file). Iterating yields :class:`BagMessage`."""

    def __init__(self, path, *, warn=True):
        self.path = Path(path)
        self.bag_dir, self.mcap_paths, self.metadata_yaml_path = _locate(self.path)
        self.metadata_yaml = (read_metadata_yaml(self.metadata_yaml_path)
                              if self.metadata_yaml_path else None)
        self.problems = []
        self.damage = None  # first mcap_scan.Damage met, if any
        self._scans = {}  # damaged file -> ScanResult
        self._schemas = {}  # (file, schema id) -> Schema
        self._channels = {}  # (file, channel id) -> Channel
        self._counts = {}  # topic -> message count
        self.metadata_records = []  # (name, dict) in file order, rosbag2's own record excluded
        self.rosbag2_metadata = None  # text of the 'rosbag2' record, if present
        if self.metadata_yaml_path is None:
            self.problems.append(f'{self.bag_dir / METADATA_FILENAME} is missing: the bag was '
                                 'not closed cleanly (see mantis_rig.recording.recover_bag)')
        for mcap_path in self.mcap_paths:
            self._load(mcap_path)
        if warn and self.problems:
            warnings.warn(TruncatedBagWarning('; '.join(self.problems)), stacklevel=2)

    # ------------------------------------------------------------------ loading
    def _load(self, mcap_path):
        try:
            if has_valid_tail(mcap_path):
                self._load_indexed(mcap_path)
                return
        except BagError:
            raise
        except (OSError, ValueError) as exc:  # tail unreadable: fall back to a scan
            self.problems.append(f'{mcap_path}: summary unreadable ({exc}), scanned instead')
        try:
            scan = scan_mcap(mcap_path)
        except NotMcapError as exc:
            raise BagError(str(exc)) from exc
        except OSError as exc:
            raise BagError(f'{mcap_path}: cannot read: {exc}') from exc
        self._check_profile(mcap_path, scan.header.profile if scan.header else None)
        self._scans[mcap_path] = scan
        self._register(mcap_path, scan.schemas, scan.channels)
        for message in scan.messages:
            topic = scan.channels[message.channel_id].topic
            self._counts[topic] = self._counts.get(topic, 0) + 1
        self._add_metadata(scan.metadata)
        if scan.damage is not None:
            self.damage = self.damage or scan.damage
            last = max((m.log_time for m in scan.messages), default=None)
            self.problems.append(f'{scan.damage}; read {len(scan.messages)} complete messages'
                                 + (f' (last log time {last} ns)' if last is not None else ''))

    def _load_indexed(self, mcap_path):
        try:
            with open(mcap_path, 'rb') as stream:
                reader = make_reader(stream)
                header = reader.get_header()
                summary = reader.get_summary()
                metadata = list(reader.iter_metadata())
        except Exception as exc:  # noqa: BLE001 - reported, then scanned
            raise ValueError(f'{type(exc).__name__}: {exc}') from exc
        if summary is None:
            raise ValueError('no summary section')
        self._check_profile(mcap_path, header.profile)
        self._register(mcap_path, summary.schemas, summary.channels)
        for channel_id, count in summary.statistics.channel_message_counts.items():
            topic = summary.channels[channel_id].topic
            self._counts[topic] = self._counts.get(topic, 0) + count
        self._add_metadata(metadata)

    @staticmethod
    def _check_profile(mcap_path, profile):
        if profile is not None and profile != 'ros2':
            raise BagError(f'{mcap_path}: MCAP profile is {profile!r}, not a ROS 2 bag')

    def _register(self, mcap_path, schemas, channels):
        for schema_id, schema in schemas.items():
            self._schemas[(mcap_path, schema_id)] = schema
        for channel_id, channel in channels.items():
            self._channels[(mcap_path, channel_id)] = channel
            self._counts.setdefault(channel.topic, 0)

    def _add_metadata(self, records):
        for record in records:
            if record.name == ROSBAG2_RECORD_NAME:
                self.rosbag2_metadata = record.metadata.get('serialized_metadata')
            else:
                self.metadata_records.append((record.name, dict(record.metadata)))

    # ------------------------------------------------------------------ queries
    @property
    def complete(self):
        """True if the bag was closed cleanly (metadata.yaml, summary, no damage)."""
        return not self.problems

    @property
    def topics(self):
        """topic -> :class:`TopicInfo`."""
        result = {}
        for (mcap_path, _), channel in self._channels.items():
            schema = self._schemas.get((mcap_path, channel.schema_id))
            result[channel.topic] = TopicInfo(
                name=channel.topic, type_name=schema.name if schema else '',
                message_count=self._counts.get(channel.topic, 0),
                metadata=dict(channel.metadata),
                schema_text=schema.data.decode('utf-8', 'replace') if schema else '')
        return result

    @property
    def message_count(self):
        return sum(self._counts.values())

    def metadata(self, name):
        """The last metadata record called ``name`` (dict), or None."""
        found = [data for record_name, data in self.metadata_records if record_name == name]
        return found[-1] if found else None

    # ------------------------------------------------------------------ messages
    def raw_messages(self, topics=None):
        """(Channel, Schema, mcap Message) in log-time order, without deserializing."""
        wanted = set(topics) if topics is not None else None
        streams = [self._file_messages(p, wanted) for p in self.mcap_paths]
        if len(streams) == 1:
            return streams[0]
        return heapq.merge(*streams, key=lambda item: item[2].log_time)

    def _file_messages(self, mcap_path, wanted):
        scan = self._scans.get(mcap_path)
        if scan is not None:
            ordered = sorted(scan.messages, key=lambda m: m.log_time)  # stable
            for message in ordered:
                channel = scan.channels[message.channel_id]
                if wanted is None or channel.topic in wanted:
                    yield channel, scan.schemas.get(channel.schema_id), message
            return
        with open(mcap_path, 'rb') as stream:
            reader = make_reader(stream, validate_crcs=True)
            try:
                for schema, channel, message in reader.iter_messages(
                        topics=wanted, log_time_order=True):
                    yield channel, schema, message
            except Exception as exc:  # noqa: BLE001 - corrupt chunk behind a valid summary
                damage = f'{mcap_path}: unreadable data behind a valid summary: ' \
                         f'{type(exc).__name__}: {exc}'
                self.problems.append(damage)
                warnings.warn(TruncatedBagWarning(damage), stacklevel=3)

    def messages(self, topics=None):
        """Iterate :class:`BagMessage` (topic, type_name, log_time_ns, message) by log time."""
        for index, (channel, schema, message) in enumerate(self.raw_messages(topics)):
            type_name = schema.name if schema is not None else '(no schema)'
            try:
                msg = deserialize_message(message.data, message_class(type_name))
            except Exception as exc:  # noqa: BLE001 - rclpy's decode errors share no base class
                raise BagError(
                    f'{self.path}: message {index} on {channel.topic} at log time '
                    f'{message.log_time * 1e-9:.6f} s cannot be decoded as {type_name}: '
                    f'{type(exc).__name__}: {exc}') from exc
            yield BagMessage(channel.topic, type_name, message.log_time, msg)

    def __iter__(self):
        return self.messages()


def read_bag(path, topics=None):
    """Iterate the messages of the bag at ``path`` (see :class:`BagReader`)."""
    return BagReader(path).messages(topics)
