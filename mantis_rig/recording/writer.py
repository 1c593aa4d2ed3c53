"""BagWriter: a rosbag2 bag directory (MCAP storage) written from Python, crash-tolerant.

Layout and conventions follow rosbag2_storage_mcap on ROS 2 Jazzy:

* ``<dir>/<dir_name>_0.mcap`` with profile ``ros2``; one schema per type (encoding ``ros2msg``,
  full .msg text with dependencies), one channel per topic (message encoding ``cdr``, metadata
  ``offered_qos_profiles`` and ``topic_type_hash``), messages serialized by rclpy (real CDR);
* a ``rosbag2`` metadata record holding the serialized bag metadata, and ``<dir>/metadata.yaml``
  (version 9), both written by :meth:`BagWriter.close`.

Crash tolerance: the data go out in chunks; every completed chunk is flushed and fsync'ed, and a
background thread closes and syncs the open chunk whenever it is older than ``sync_period_s``, so
a crash (SIGKILL, power loss) loses at most the last ``sync_period_s`` of data. A crashed bag
lacks the summary and metadata.yaml; :mod:`mantis_rig.recording.recover` rebuilds both.
"""
import os
from pathlib import Path
import threading
import time

from mcap.writer import CompressionType, Writer
from rclpy.serialization import serialize_message

from mantis_rig.faults import BagClosedError
from mantis_rig.recording.message_types import message_class, type_description_hash, type_name_of
from mantis_rig.recording.offered_qos import (
    default_offered_qos,
    offered_qos_channel_string,
    offered_qos_list,
)

from .bag_metadata import (
    ROSBAG2_RECORD_KEY,
    ROSBAG2_RECORD_NAME,
    SERIALIZATION_FORMAT,
    BagSummary,
    TopicRecord,
    fsync_dir,
    serialized_metadata,
    write_metadata_yaml,
)
from .message_definition import SCHEMA_ENCODING, full_message_definition

PROFILE = 'ros2'
LIBRARY = 'mantis_rig.recording (python mcap)'
TRIAL_CONDITIONS = 'trial_conditions'
TRIAL_OUTCOME = 'trial_outcome'
#: 256 KiB: ~0.25 s of a 20 kS/s force stream plus a few kHz of small messages, so chunks (the
#: unit of loss in a crash) stay well under the 0.5 s sync period; big enough for compression.
DEFAULT_CHUNK_SIZE_BYTES = 256 * 1024
DEFAULT_SYNC_PERIOD_S = 0.5
COMPRESSIONS = {'none': CompressionType.NONE, 'lz4': CompressionType.LZ4,
                'zstd': CompressionType.ZSTD}


class BagWriteError(BagClosedError):
    """Writing the bag failed (disk full, directory removed): the bag takes no more messages;
    what was synced before the failure stays readable (`mantis recover` completes it)."""

    def __init__(self, path, cause: OSError, durable_messages: int):
        self.cause = cause
        self.durable_messages = durable_messages
        super().__init__(f'{path}: {cause.strerror or cause}')


def mcap_file_name(bag_dir):
    return f'{Path(bag_dir).name}_0.mcap'


class _AppendOnlyFile:
    """Binary file wrapper counting bytes written; its tell() costs no system call."""

    def __init__(self, path):
        self._file = open(path, 'xb')
        self.bytes_written = 0

    def write(self, data):
        self._file.write(data)
        self.bytes_written += len(data)
        return len(data)

    def tell(self):
        return self.bytes_written

    def flush_and_sync(self):
        self._file.flush()
        os.fsync(self._file.fileno())

    def flush(self):
        self._file.flush()

    def close(self):
        self._file.close()


def _as_str_map(name, data):
    result = {}
    for key, value in dict(data).items():
        if isinstance(value, (dict, list, tuple, set, bytes)):
            raise TypeError(f'metadata {name!r}: value of {key!r} must be a string, '
                            f'not {type(value).__name__}')
        result[str(key)] = str(value)
    return result


class BagWriter:
    """Write a rosbag2 (MCAP) bag directory; thread-safe; use as a context manager."""

    def __init__(self, path, *, chunk_size_bytes=DEFAULT_CHUNK_SIZE_BYTES, compression='zstd',
                 sync_period_s=DEFAULT_SYNC_PERIOD_S, custom_data=None):
        if compression not in COMPRESSIONS:
            raise ValueError(f'compression must be one of {sorted(COMPRESSIONS)}, '
                             f'not {compression!r}')
        self.path = Path(path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise FileExistsError(f'{self.path}: bag directory already exists and is not empty')
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_path = self.path / mcap_file_name(self.path)
        self._file = _AppendOnlyFile(self.mcap_path)
        self._mcap = Writer(self._file, chunk_size=chunk_size_bytes,
                            compression=COMPRESSIONS[compression])
        self._mcap.start(profile=PROFILE, library=LIBRARY)
        self._file.flush_and_sync()
        fsync_dir(self.path)
        self._lock = threading.RLock()
        self._schema_ids = {}  # type name -> MCAP schema id
        self._channels = {}  # topic -> (channel id, TopicRecord, message class)
        self._sequence = {}
        self._first_ns = None
        self._last_ns = None
        self._custom_data = dict(custom_data or {})
        self._synced_bytes = self._file.bytes_written
        self._durable_messages = 0
        self._unsynced_since = None  # monotonic time of the oldest message not yet on disk
        self._sync_period_s = sync_period_s
        self._closed = False
        self.failure: BagWriteError | None = None
        self.on_failure = None      # called once, with the BagWriteError, by the failing thread
        self._stop = threading.Event()
        self._syncer = None
        if sync_period_s and sync_period_s > 0:
            self._syncer = threading.Thread(target=self._sync_loop, name='bag-sync', daemon=True)
            self._syncer.start()

    # ---------------------------------------------------------------- topics
    def add_topic(self, topic, type_name, qos=None):
        """Register ``topic`` with ``type_name`` ('pkg/msg/Type') and offered QoS profile(s).

        ``qos``: an rclpy QoSProfile, a list of them, or rosbag2 version-9 QoS maps; default
        ``QoSProfile(depth=10)``. Registering a topic again with the same type is a no-op.
        """
        msg_class = message_class(type_name)
        self.add_topic_definition(
            topic, type_name, offered_qos_list(qos if qos is not None else default_offered_qos()),
            full_message_definition(type_name), type_description_hash(type_name), msg_class)

    def add_topic_definition(self, topic, type_name, offered_qos, schema_text, type_hash='',
                             msg_class=None):
        """Register a topic from its parts (used to copy topics verbatim, e.g. in recovery)."""
        with self._lock:
            self._check_open()
            if topic in self._channels:
                registered = self._channels[topic][1].type_name
                if registered != type_name:
                    raise ValueError(f'topic {topic!r} is already registered as {registered}, '
                                     f'not {type_name}')
                return
            schema_id = self._schema_ids.get(type_name)
            if schema_id is None:
                schema_id = self._mcap.register_schema(
                    name=type_name, encoding=SCHEMA_ENCODING, data=schema_text.encode('utf-8'))
                self._schema_ids[type_name] = schema_id
            channel_id = self._mcap.register_channel(
                topic=topic, message_encoding=SERIALIZATION_FORMAT, schema_id=schema_id,
                metadata={'offered_qos_profiles': offered_qos_channel_string(offered_qos),
                          'topic_type_hash': type_hash})
            record = TopicRecord(name=topic, type_name=type_name, offered_qos=list(offered_qos),
                                 type_description_hash=type_hash)
            self._channels[topic] = (channel_id, record, msg_class)
            self._sequence[topic] = 0

    @property
    def topics(self):
        """topic -> type name, in registration order."""
        with self._lock:
            return {topic: entry[1].type_name for topic, entry in self._channels.items()}

    @property
    def message_count(self):
        with self._lock:
            return self._message_total()

    @property
    def durable_message_count(self):
        """Messages known to be on disk (flushed and fsync'ed); a crash keeps at least these."""
        with self._lock:
            return self._durable_messages

    @property
    def closed(self):
        return self._closed

    # ---------------------------------------------------------------- writing
    def write(self, topic, msg, t_ns, publish_time_ns=None):
        """Serialize ``msg`` (a ROS 2 message instance) to CDR and log it at ``t_ns``.

        The topic is registered on first use with the instance's type and the default QoS.
        """
        if topic not in self._channels:
            self.add_topic(topic, type_name_of(msg))
        expected_class = self._channels[topic][2]
        if expected_class is not None and type(msg) is not expected_class:
            raise TypeError(f'topic {topic!r} carries {type_name_of(expected_class)}, '
                            f'not {type(msg).__module__}.{type(msg).__name__}')
        self.write_serialized(topic, serialize_message(msg), t_ns, publish_time_ns)

    def write_serialized(self, topic, data, t_ns, publish_time_ns=None):
        """Log already CDR-serialized bytes on a registered topic (e.g. a raw subscription)."""
        t_ns = int(t_ns)
        if t_ns < 0:
            raise ValueError(f'log time must be >= 0 ns, got {t_ns}')
        with self._lock:
            self._check_open()
            try:
                channel_id, record, _ = self._channels[topic]
            except KeyError:
                raise KeyError(f'topic {topic!r} is not registered; call add_topic() '
                               'first') from None
            self._sequence[topic] += 1
            try:
                self._mcap.add_message(
                    channel_id=channel_id, log_time=t_ns, data=bytes(data),
                    publish_time=t_ns if publish_time_ns is None else int(publish_time_ns),
                    sequence=self._sequence[topic] & 0xFFFFFFFF)
                record.message_count += 1
                self._first_ns = t_ns if self._first_ns is None else min(self._first_ns, t_ns)
                self._last_ns = t_ns if self._last_ns is None else max(self._last_ns, t_ns)
                if self._unsynced_since is None:
                    self._unsynced_since = time.monotonic()
                if self._file.bytes_written != self._synced_bytes:  # a chunk just went out
                    self._sync_file()
            except OSError as exc:
                raise self._fail(exc) from exc

    def add_metadata(self, name, data):
        """Write an MCAP metadata record now (e.g. 'trial_conditions'), then sync to disk."""
        data = _as_str_map(name, data)
        with self._lock:
            self._check_open()
            try:
                self._mcap.add_metadata(name, data)
                self._sync_chunk()
            except OSError as exc:
                raise self._fail(exc) from exc

    def sync(self):
        """Close the open chunk (if any) and fsync: everything written so far is on disk."""
        with self._lock:
            if not self._closed:
                self._check_open()
                try:
                    self._sync_chunk()
                except OSError as exc:
                    raise self._fail(exc) from exc

    # ---------------------------------------------------------------- closing
    def close(self, trial_outcome=None):
        """Write ``trial_outcome`` (if given), the summary and metadata.yaml. Idempotent.

        After a write failure (see `failure`) it only closes the file: the bag stays as it was
        synced, without summary or metadata.yaml, for `mantis recover`. A failure while
        closing is recorded the same way; close() itself does not raise it."""
        outcome = None if trial_outcome is None else _as_str_map(TRIAL_OUTCOME, trial_outcome)
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            try:
                if self.failure is None:
                    self._finish(outcome)
            except OSError as exc:
                self._fail(exc)
            finally:
                try:
                    self._file.close()
                except OSError:
                    pass
        if self._syncer is not None and self._syncer is not threading.current_thread():
            self._syncer.join(timeout=5.0)

    def _finish(self, outcome) -> None:
        if outcome is not None:
            self._mcap.add_metadata(TRIAL_OUTCOME, outcome)
        summary = self._bag_summary()
        self._mcap.add_metadata(ROSBAG2_RECORD_NAME,
                                {ROSBAG2_RECORD_KEY: serialized_metadata(summary)})
        self._mcap.finish()
        self._file.flush_and_sync()
        write_metadata_yaml(self.path, summary)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close()

    # ---------------------------------------------------------------- internals
    def _check_open(self):
        if self.failure is not None:
            raise self.failure
        if self._closed:
            raise BagClosedError(f'{self.path}: bag is closed')

    def _fail(self, cause: OSError) -> BagWriteError:
        """Record the first write failure (and tell on_failure); the error to raise."""
        with self._lock:
            first = self.failure is None
            if first:
                self.failure = BagWriteError(self.path, cause, self._durable_messages)
            failure = self.failure
        if first and self.on_failure is not None:
            self.on_failure(failure)
        return failure

    def _bag_summary(self):
        first = self._first_ns or 0
        return BagSummary(
            relative_file_path=self.mcap_path.name,
            topics=[entry[1] for entry in self._channels.values()],
            starting_time_ns=first,
            duration_ns=(self._last_ns - first) if self._last_ns is not None else 0,
            custom_data=self._custom_data)

    def _message_total(self):
        return sum(entry[1].message_count for entry in self._channels.values())

    def _sync_chunk(self):
        self._mcap.flush()  # finalizes the open chunk
        self._sync_file()

    def _sync_file(self):
        self._file.flush_and_sync()
        self._synced_bytes = self._file.bytes_written
        self._durable_messages = self._message_total()
        self._unsynced_since = None

    def _sync_loop(self):
        period = self._sync_period_s
        while not self._stop.wait(period / 4):
            with self._lock:
                if self._closed or self.failure is not None:
                    return
                since = self._unsynced_since
                if since is not None and time.monotonic() - since >= period:
                    try:
                        self._sync_chunk()
                    except OSError as exc:
                        self._fail(exc)
                        return
