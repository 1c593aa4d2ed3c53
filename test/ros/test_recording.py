"""Trial log (rosbag2 MCAP bag) writer, reader and recovery, checked against mcap and rosbags."""
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import warnings

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
import numpy as np
import pytest
from rclpy.qos import qos_profile_sensor_data
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import String
import yaml

from mantis_rig.cli import main as cli_main
from mantis_rig.contract import CAMERA_TRIGGER, DIAGNOSTICS, resolve
from mantis_rig.recording import (
    BagClosedError,
    BagError,
    BagReader,
    BagWriteError,
    BagWriter,
    TruncatedBagWarning,
    read_bag,
    recover_bag,
)
from mantis_rig.recording.force_block import force_block_from_msg, force_block_to_msg
from mantis_rig.recording.mcap_scan import scan_mcap
from mantis_rig.recording.recover import main_recover

REPO = Path(__file__).resolve().parents[2]
T0_NS = 1_700_000_000_000_000_000
TYPES = {
    '/force': 'std_msgs/msg/Float64MultiArray',
    '/joint_states': 'sensor_msgs/msg/JointState',
    '/wrench': 'geometry_msgs/msg/WrenchStamped',
    resolve(CAMERA_TRIGGER): 'sensor_msgs/msg/TimeReference',
    resolve(DIAGNOSTICS): 'diagnostic_msgs/msg/DiagnosticArray',
    '/events': 'std_msgs/msg/String',
}
N_PER_TOPIC = 40
KILLED_AT_BOUNDARY = 'without summary or footer'
KILLED_MID_RECORD = 'mid-record'


def make_message(topic, i):
    """A deterministic, field-rich message number i of a topic."""
    sec, nanosec = divmod(T0_NS + i * 1_000_000, 1_000_000_000)
    if topic == '/force':
        return force_block_to_msg((T0_NS + i * 10_000_000) / 1e9, 50e-6,
                                  np.arange(200) * 0.01 + i)
    if topic == '/joint_states':
        # effort not empty: Fast CDR pads an empty trailing float64[] with 4 alignment bytes
        # (as real Jazzy publishers do) and rosbags 0.11.9 rejects that as a size mismatch.
        msg = JointState(name=['crank', 'coupler'], position=[0.1 * i, -0.2 * i],
                         velocity=[1.5, 2.5], effort=[0.5 * i, 0.0])
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = 'base'
        return msg
    if topic == '/wrench':
        msg = WrenchStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = 'load_cell'
        msg.wrench.force.z = 0.25 * i
        msg.wrench.torque.x = -1.0 / (i + 1)
        return msg
    if topic == resolve(CAMERA_TRIGGER):
        msg = TimeReference(source='phantom_v7_3')
        msg.time_ref.sec, msg.time_ref.nanosec = sec, nanosec
        return msg
    if topic == resolve(DIAGNOSTICS):
        status = DiagnosticStatus(level=DiagnosticStatus.WARN, name='stage', message=f'm{i}',
                                  hardware_id='kdc101',
                                  values=[KeyValue(key='pos_mm', value=str(i / 7))])
        return DiagnosticArray(status=[status])
    return String(data=f'event {i} µ')


def write_reference_bag(path, **writer_options):
    """All TYPES topics, N_PER_TOPIC messages each, interleaved in time; returns expected list."""
    expected = []
    with BagWriter(path, **writer_options) as writer:
        writer.add_topic('/force', TYPES['/force'], qos_profile_sensor_data)
        writer.add_metadata('trial_conditions', {'pull_speed_mm_s': '1.2', 'medium': 'water'})
        for i in range(N_PER_TOPIC):
            for k, topic in enumerate(TYPES):
                t_ns = T0_NS + i * 1_000_000 + k * 1000
                msg = make_message(topic, i)
                writer.write(topic, msg, t_ns)
                expected.append((topic, TYPES[topic], t_ns, msg))
        writer.close(trial_outcome={'struck': 'true', 'peak_force_n': '12.5'})
    return expected


@pytest.fixture(scope='module')
def reference_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'trial_001'
    return path, write_reference_bag(path)


def rosbags_dict(value):
    """A rosbags-deserialized message as plain Python data."""
    if hasattr(value, '__msgtype__'):
        return {name: rosbags_dict(getattr(value, name)) for name in value.__dataclass_fields__
                if name != '__msgtype__' and not name.isupper()}  # skip constants
    if isinstance(value, np.ndarray):
        return [rosbags_dict(v) for v in value.tolist()]
    if isinstance(value, list):
        return [rosbags_dict(v) for v in value]
    return value


def rclpy_dict(value):
    """An rclpy message as plain Python data (same shape as rosbags_dict)."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {name: rclpy_dict(getattr(value, name))
                for name in value.get_fields_and_field_types()}
    if isinstance(value, (list, tuple)) or type(value).__name__ in ('array', 'ndarray'):
        return [rclpy_dict(v) for v in value]
    if isinstance(value, bytes) and len(value) == 1:  # rclpy 'byte' fields; rosbags gives int
        return value[0]
    return value


# --------------------------------------------------------------------------- healthy bag
def test_layout_and_metadata_yaml(reference_bag):
    path, expected = reference_bag
    assert sorted(p.name for p in path.iterdir()) == ['metadata.yaml', 'trial_001_0.mcap']
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['trial_001_0.mcap']
    assert info['message_count'] == len(expected)
    assert info['starting_time']['nanoseconds_since_epoch'] == expected[0][2]
    assert info['duration']['nanoseconds'] == expected[-1][2] - expected[0][2]
    assert info['files'] == [{
        'path': 'trial_001_0.mcap', 'message_count': len(expected),
        'starting_time': {'nanoseconds_since_epoch': expected[0][2]},
        'duration': {'nanoseconds': expected[-1][2] - expected[0][2]}}]
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {name: t['topic_metadata']['type'] for name, t in topics.items()} == TYPES
    for topic in topics.values():
        assert topic['message_count'] == N_PER_TOPIC
        assert topic['topic_metadata']['serialization_format'] == 'cdr'
        assert topic['topic_metadata']['type_description_hash'].startswith('RIHS01_')
    force_qos = topics['/force']['topic_metadata']['offered_qos_profiles']
    assert force_qos[0]['reliability'] == 'best_effort'
    assert force_qos[0]['history'] == 'keep_last' and force_qos[0]['depth'] == 5
    event_qos = topics['/events']['topic_metadata']['offered_qos_profiles'][0]
    assert event_qos['reliability'] == 'reliable' and event_qos['depth'] == 10
    assert set(event_qos) == {
        'history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan', 'liveliness',
        'liveliness_lease_duration', 'avoid_ros_namespace_conventions'}
    assert event_qos['deadline'] == {'sec': 0, 'nsec': 0}


def test_mcap_conventions_with_mcap_reader(reference_bag):
    path, expected = reference_bag
    with open(path / 'trial_001_0.mcap', 'rb') as stream:
        reader = make_reader(stream, validate_crcs=True)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == set(TYPES.values())
        assert all(s.encoding == 'ros2msg' for s in schemas.values())
        wrench_text = schemas['geometry_msgs/msg/WrenchStamped'].data.decode()
        assert wrench_text.startswith('# A wrench with reference coordinate frame')
        for dependency in ('geometry_msgs/Wrench', 'geometry_msgs/Vector3', 'std_msgs/Header',
                           'builtin_interfaces/Time'):
            assert f'\n{"=" * 80}\nMSG: {dependency}\n' in wrench_text
        assert wrench_text.count('MSG: geometry_msgs/Vector3') == 1  # each dependency once
        diag_text = schemas['diagnostic_msgs/msg/DiagnosticArray'].data.decode()
        assert 'MSG: diagnostic_msgs/DiagnosticStatus' in diag_text
        assert 'MSG: diagnostic_msgs/KeyValue' in diag_text
        string_text = schemas['std_msgs/msg/String'].data.decode()
        assert '=' * 80 not in string_text  # no dependencies
        for channel in summary.channels.values():
            assert channel.message_encoding == 'cdr'
            qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert isinstance(qos, list) and qos[0]['history'] == 'keep_last'
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        assert summary.statistics.message_count == len(expected)
        records = {m.name: m.metadata for m in reader.iter_metadata()}
        assert records['trial_conditions'] == {'pull_speed_mm_s': '1.2', 'medium': 'water'}
        assert records['trial_outcome'] == {'struck': 'true', 'peak_force_n': '12.5'}
        rosbag2 = yaml.safe_load(records['rosbag2']['serialized_metadata'])
        assert rosbag2['version'] == 9 and rosbag2['message_count'] == len(expected)
        count = sum(1 for _ in reader.iter_messages())
    assert count == len(expected)


def test_our_reader_round_trip(reference_bag):
    path, expected = reference_bag
    with warnings.catch_warnings():
        warnings.simplefilter('error')  # a healthy bag must not warn
        reader = BagReader(path)
        got = list(reader)
    assert reader.complete and reader.damage is None
    assert [(m.topic, m.type_name, m.log_time_ns) for m in got] == \
        [(topic, type_name, t) for topic, type_name, t, _ in expected]
    for message, (_, _, _, original) in zip(got, expected, strict=True):
        assert message.message == original
    assert reader.metadata('trial_conditions') == {'pull_speed_mm_s': '1.2', 'medium': 'water'}
    assert reader.metadata('trial_outcome')['struck'] == 'true'
    assert {t: i.message_count for t, i in reader.topics.items()} == \
        {t: N_PER_TOPIC for t in TYPES}
    block = force_block_from_msg(got[0].message)
    assert block.t0_s == pytest.approx(T0_NS / 1e9, abs=3e-7) and block.period_s == 50e-6
    assert block.force_n.tolist() == pytest.approx((np.arange(200) * 0.01).tolist())
    assert [m.topic for m in read_bag(path, topics=['/events'])] == ['/events'] * N_PER_TOPIC


def test_rosbags_reads_every_message(reference_bag):
    path, expected = reference_bag
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with RosbagsReader(path) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TYPES
        for connection in reader.connections:
            assert connection.digest == typestore.hash_rihs01(connection.msgtype)
        by_topic = {c.topic: c for c in reader.connections}
        assert by_topic['/force'].ext.offered_qos_profiles[0].reliability.name == 'BEST_EFFORT'
        decoded = [(c.topic, t, rosbags_dict(typestore.deserialize_cdr(raw, c.msgtype)))
                   for c, t, raw in reader.messages()]
    assert len(decoded) == len(expected)
    for (topic, t_ns, fields), (e_topic, _, e_t_ns, msg) in zip(decoded, expected, strict=True):
        assert (topic, t_ns) == (e_topic, e_t_ns)
        assert fields == rclpy_dict(msg)


# --------------------------------------------------------------------------- writer API
def test_writer_rejects_misuse(tmp_path):
    writer = BagWriter(tmp_path / 'bag')
    writer.write('/a', String(data='x'), 5)
    with pytest.raises(TypeError):
        writer.write('/a', TimeReference(), 6)
    with pytest.raises(ValueError):
        writer.add_topic('/a', 'std_msgs/msg/Float64MultiArray')
    with pytest.raises(TypeError):
        writer.add_metadata('trial_conditions', {'nested': {'no': 'dicts'}})
    writer.close()
    writer.close()  # idempotent
    with pytest.raises(BagClosedError):
        writer.write('/a', String(data='late'), 7)
    with pytest.raises(FileExistsError):
        BagWriter(tmp_path / 'bag')


def test_concurrent_writes_lose_nothing(tmp_path):
    import threading
    path = tmp_path / 'threads'
    writer = BagWriter(path, chunk_size_bytes=2048)

    def produce(topic):
        for i in range(500):
            writer.write(topic, String(data=f'{topic}:{i}'), T0_NS + i)

    threads = [threading.Thread(target=produce, args=(f'/t{k}',)) for k in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    writer.close()
    got = {}
    for message in read_bag(path):
        got.setdefault(message.topic, []).append(message.message.data)
    assert got == {f'/t{k}': [f'/t{k}:{i}' for i in range(500)] for k in range(4)}


@pytest.mark.parametrize('compression', ['none', 'lz4', 'zstd'])
def test_compressions_read_back(tmp_path, compression):
    expected = write_reference_bag(tmp_path / 'bag', compression=compression,
                                   chunk_size_bytes=8192)
    assert [m.message for m in read_bag(tmp_path / 'bag')] == [e[3] for e in expected]


# --------------------------------------------------------------------------- damage
def chunk_indexes(mcap_path):
    with open(mcap_path, 'rb') as stream:
        return sorted(make_reader(stream).get_summary().chunk_indexes,
                      key=lambda c: c.chunk_start_offset)


def crashed_copy(source_bag, destination, cut_at):
    """A copy of the bag as a crash leaves it: no metadata.yaml, .mcap cut at byte cut_at."""
    destination.mkdir()
    source = next(source_bag.glob('*.mcap'))
    data = source.read_bytes()[:cut_at]
    (destination / source.name).write_bytes(data)
    return destination / source.name


def test_truncated_mid_chunk_keeps_earlier_chunks(tmp_path):
    expected = write_reference_bag(tmp_path / 'bag', chunk_size_bytes=4096)
    chunks = chunk_indexes(tmp_path / 'bag' / 'bag_0.mcap')
    assert len(chunks) >= 6
    cut_chunk = chunks[len(chunks) // 2]
    crashed = crashed_copy(tmp_path / 'bag', tmp_path / 'crashed',
                           cut_chunk.chunk_start_offset + cut_chunk.chunk_length // 2)
    last_complete_ns = chunks[len(chunks) // 2 - 1].message_end_time
    survivors = [e for e in expected if e[2] <= last_complete_ns]
    assert 0 < len(survivors) < len(expected)

    with pytest.warns(TruncatedBagWarning, match='mid-record') as caught:
        reader = BagReader(crashed.parent)
    assert 'metadata.yaml' in str(caught[0].message)
    assert not reader.complete
    assert reader.damage.offset == cut_chunk.chunk_start_offset
    assert 'CHUNK' in reader.damage.problem
    got = list(reader)
    assert [(m.topic, m.log_time_ns) for m in got] == [(e[0], e[2]) for e in survivors]
    assert [m.message for m in got] == [e[3] for e in survivors]
    assert reader.metadata('trial_conditions') == {'pull_speed_mm_s': '1.2', 'medium': 'water'}


def test_corrupted_chunk_is_reported_not_raised(tmp_path):
    write_reference_bag(tmp_path / 'bag', chunk_size_bytes=4096, compression='none')
    mcap_path = tmp_path / 'bag' / 'bag_0.mcap'
    chunk = chunk_indexes(mcap_path)[2]
    data = bytearray(mcap_path.read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length - 40] ^= 0xFF  # flip bits in the data
    mcap_path.write_bytes(bytes(data))
    with pytest.warns(TruncatedBagWarning, match='(?i)crc'):
        got = list(BagReader(tmp_path / 'bag'))
    assert len(got) > 0
    scan = scan_mcap(mcap_path)
    assert scan.damage.offset == chunk.chunk_start_offset and 'CRC' in scan.damage.problem


def test_not_a_bag_errors_name_the_file(tmp_path):
    with pytest.raises(BagError, match='no such file'):
        BagReader(tmp_path / 'missing')
    (tmp_path / 'empty_dir').mkdir()
    with pytest.raises(BagError, match='not a bag'):
        BagReader(tmp_path / 'empty_dir')
    bogus = tmp_path / 'bogus'
    bogus.mkdir()
    (bogus / 'bogus_0.mcap').write_bytes(b'this is not an mcap file at all')
    with pytest.raises(BagError, match=r'bogus_0\.mcap: not an MCAP file'):
        BagReader(bogus)
    broken_yaml = tmp_path / 'broken_yaml'
    broken_yaml.mkdir()
    (broken_yaml / 'metadata.yaml').write_text('rosbag2_bagfile_information: [unclosed')
    with pytest.raises(BagError, match='metadata.yaml'):
        BagReader(broken_yaml)
    null_file = tmp_path / 'null_file'
    null_file.mkdir()
    (null_file / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  storage_identifier: mcap\n'
        '  relative_file_paths: [~]\n')
    with pytest.raises(BagError, match='relative_file_paths must be a list of file names'):
        BagReader(null_file)
    (tmp_path / 'notes.txt').write_text('hello')
    with pytest.raises(BagError, match='notes.txt'):
        BagReader(tmp_path / 'notes.txt')


# --------------------------------------------------------------------------- crash + recovery
def test_sigkill_mid_write_then_recover(tmp_path):
    bag = tmp_path / 'killed'
    env = dict(os.environ,
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]))
    process = subprocess.Popen(
        [sys.executable, str(REPO / 'test' / 'recording_killed_writer.py'), str(bag)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    durable = 0
    try:
        reports = 0
        for line in process.stdout:
            if line.startswith('durable '):
                durable = int(line.split()[1])
                reports += 1
                if reports >= 8:
                    break
        else:
            pytest.fail(f'writer ended early: {process.stderr.read()}')
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL
    assert not (bag / 'metadata.yaml').exists()

    with pytest.warns(TruncatedBagWarning):
        reader = BagReader(bag)
    assert reader.damage is not None
    assert any(what in reader.damage.problem for what in (KILLED_AT_BOUNDARY, KILLED_MID_RECORD))
    got = list(reader)
    assert len(got) >= durable > 0
    counters = [int(m.message.data) for m in got if m.topic == '/counter']
    assert counters == list(range(len(counters)))  # no gap, in order
    blocks = [force_block_from_msg(m.message) for m in got if m.topic == '/force']
    assert [b.force_n[3] for b in blocks] == pytest.approx([i + 0.003
                                                             for i in range(len(blocks))])
    assert abs(len(blocks) - len(counters)) <= 1

    report = recover_bag(bag)
    assert report.output == tmp_path / 'killed_recovered'
    assert report.messages_recovered == len(got)
    assert report.problems
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        recovered = BagReader(report.output)
        again = list(recovered)
    assert recovered.complete
    assert [(m.topic, m.log_time_ns, m.message) for m in again] == \
        [(m.topic, m.log_time_ns, m.message) for m in got]
    assert recovered.metadata('trial_conditions') == {'pull_speed_mm_s': '1.0', 'medium': 'air'}
    source_problems = recovered.metadata('mantis_recovery')['source_problems']
    assert any(what in source_problems for what in (KILLED_AT_BOUNDARY, KILLED_MID_RECORD))
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with RosbagsReader(report.output) as rosbags_reader:
        assert rosbags_reader.message_count == len(got)
        rosbags_counters = [
            int(typestore.deserialize_cdr(raw, c.msgtype).data)
            for c, _, raw in rosbags_reader.messages() if c.topic == '/counter']
    assert rosbags_counters == counters


def test_main_recover_cli(tmp_path, capsys):
    write_reference_bag(tmp_path / 'bag', chunk_size_bytes=4096)
    chunks = chunk_indexes(tmp_path / 'bag' / 'bag_0.mcap')
    crashed_copy(tmp_path / 'bag', tmp_path / 'crash', chunks[-1].chunk_start_offset + 20)
    assert main_recover([str(tmp_path / 'crash'), '-o', str(tmp_path / 'fixed')]) == 0
    assert 'recovered' in capsys.readouterr().out
    assert BagReader(tmp_path / 'fixed').complete
    assert cli_main(['recover', str(tmp_path / 'nothing_here')]) == 2     # bad input
    assert capsys.readouterr().err == (f'mantis recover: {tmp_path / "nothing_here"}: no such '
                                       f'file or directory\n')
    with BagWriter(tmp_path / 'empty', sync_period_s=0) as empty:
        empty.add_topic('/events', 'std_msgs/msg/String')
    assert main_recover([str(tmp_path / 'empty'), '-o', str(tmp_path / 'empty_out')]) == 1
    assert 'no message could be recovered from' in capsys.readouterr().err
    shutil.rmtree(tmp_path / 'fixed')


def snapshot(bag, destination):
    """Copy a bag that is still open, as a crash at this instant would leave it."""
    destination.mkdir()
    for path in bag.iterdir():
        shutil.copy(path, destination / path.name)
    return destination


def test_sync_puts_open_chunk_on_disk(tmp_path):
    writer = BagWriter(tmp_path / 'open', sync_period_s=0)  # no background thread
    for i in range(3):
        writer.write('/events', String(data=str(i)), T0_NS + i)
    assert writer.durable_message_count == 0  # still in the open chunk
    writer.sync()
    assert writer.durable_message_count == 3
    with pytest.warns(TruncatedBagWarning, match='without summary or footer'):
        got = [m.message.data for m in read_bag(snapshot(tmp_path / 'open', tmp_path / 'crash'))]
    assert got == ['0', '1', '2']
    writer.close()


def test_background_sync_bounds_the_loss(tmp_path):
    import time
    writer = BagWriter(tmp_path / 'open', sync_period_s=0.2)
    writer.write('/events', String(data='lonely'), T0_NS)
    deadline = time.monotonic() + 10.0  # generous: normally synced after ~0.2-0.25 s
    while writer.durable_message_count < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert writer.durable_message_count == 1
    with pytest.warns(TruncatedBagWarning):
        got = [m.message.data for m in read_bag(snapshot(tmp_path / 'open', tmp_path / 'crash'))]
    assert got == ['lonely']
    writer.close()


def fail_writes_beyond(monkeypatch, limit_bytes):
    """Every bag file write that would pass `limit_bytes` fails as on a full disk."""
    import errno

    from mantis_rig.recording import writer as writer_module
    write = writer_module._AppendOnlyFile.write

    def limited(self, data):
        if self.bytes_written + len(data) > limit_bytes:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return write(self, data)
    monkeypatch.setattr(writer_module._AppendOnlyFile, 'write', limited)


def test_a_write_failure_is_reported_once_and_keeps_what_was_synced(tmp_path, monkeypatch):
    writer = BagWriter(tmp_path / 'full', sync_period_s=0, chunk_size_bytes=1024)
    failures = []
    writer.on_failure = failures.append
    for i in range(20):
        writer.write('/events', String(data=f'{i:04d}' * 50), T0_NS + i)
    writer.sync()
    synced = writer.durable_message_count
    assert synced == 20
    fail_writes_beyond(monkeypatch, writer._file.bytes_written + 10)
    with pytest.raises(BagWriteError, match='No space left on device') as raised:
        for i in range(20, 200):
            writer.write('/events', String(data=f'{i:04d}' * 50), T0_NS + i)
    assert raised.value.durable_messages == synced
    with pytest.raises(BagWriteError):           # and so on: the bag takes no more
        writer.write('/events', String(data='late'), T0_NS + 1000)
    writer.close(trial_outcome={'result': 'aborted'})      # does not raise
    assert failures == [raised.value]
    assert not (tmp_path / 'full' / 'metadata.yaml').exists()
    with pytest.warns(TruncatedBagWarning):
        got = [m.message.data for m in read_bag(tmp_path / 'full')]
    assert got[:synced] == [f'{i:04d}' * 50 for i in range(synced)]
