"""The live view (issue 12): `mantis trial --live` serves the trial's topics over the Foxglove
WebSocket protocol. A real client (the `websockets` package) connects during a simulated trial,
sees the channels with their ros2msg schemas, subscribes to the force and stage topics and
decodes the CDR it gets, with the advertised schemas (mcap-ros2-support), into the bag's values.
A second client that subscribes to everything and never reads does not stall the trial: the bag's
force stream stays gap-free. A port in use or a bad host is refused before the trial starts."""
import json
import os
from pathlib import Path
import re
import socket
import struct
import subprocess
import sys
import threading
import time

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from mantis_rig.contract import FORCE_BLOCK, JOINT_STATE, resolve
from mantis_rig.recording import BagReader
from mantis_rig.recording.force_block import force_block_from_msg

REPO = Path(__file__).resolve().parents[2]
SUBPROTOCOL = 'foxglove.sdk.v1'
MESSAGE_DATA = 0x01
WANTED = (resolve(FORCE_BLOCK), resolve(JOINT_STATE))

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow, pytest.mark.ros]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def open_client(url: str, timeout_s: float = 60.0):
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            # No keepalive pings: on a loaded machine a reply queued behind unread frames would
            # close the connection (ping timeout), which is not what these tests are about.
            # A direct connection (legacy=True), not a context manager: the stalled client is
            # closed from a thread of its own at the end.
            return connect(url, subprotocols=[SUBPROTOCOL], open_timeout=5, max_size=None,
                           ping_interval=None, legacy=True)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def channels_of(ws) -> dict:
    """topic -> advertised channel, from the server's first messages."""
    channels = {}
    while not all(topic in channels for topic in WANTED):
        message = json.loads(ws.recv(timeout=30))
        if message['op'] == 'advertise':
            channels.update({c['topic']: c for c in message['channels']})
    return channels


def subscribe(ws, channels: dict, topics) -> dict:
    """subscription id -> channel."""
    subscriptions = {i: channels[t] for i, t in enumerate(topics, start=1)}
    ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
        {'id': i, 'channelId': c['id']} for i, c in subscriptions.items()]}))
    return subscriptions


def test_a_client_sees_the_trial_live_and_a_stalled_one_does_not_slow_it(tmp_path):
    port = free_port()
    out = tmp_path / 'trials'
    process = subprocess.Popen(
        [sys.executable, '-m', 'mantis_rig.cli', 'trial', '--out', str(out), '--live',
         f'127.0.0.1:{port}'], cwd=REPO, env=os.environ.copy(), stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    url = f'ws://127.0.0.1:{port}'
    received = []
    stalled = []
    try:
        reader = open_client(url)
        channels = channels_of(reader)
        subscriptions = subscribe(reader, channels, WANTED)
        staller = open_client(url)                    # subscribes to everything, never reads
        subscribe(staller, channels_of(staller), list(channels))
        stalled.append(staller)
        try:
            while True:
                frame = reader.recv(timeout=120)
                if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                    sub_id, _ = struct.unpack_from('<IQ', frame, 1)
                    received.append((subscriptions[sub_id], frame[13:]))
        except (ConnectionClosed, TimeoutError) as end:
            ended = repr(end)                         # the trial is over: the server stopped
        stdout, stderr = process.communicate(timeout=120)
    finally:
        for ws in stalled:
            threading.Thread(target=ws.close, daemon=True).start()
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stdout + stderr
    assert f'live view: ws://127.0.0.1:{port}' in stdout

    for topic in WANTED:
        channel = channels[topic]
        assert channel['encoding'] == 'cdr' and channel['schemaEncoding'] == 'ros2msg'
    assert channels[resolve(FORCE_BLOCK)]['schemaName'] == 'std_msgs/msg/Float64MultiArray'
    assert 'MSG: std_msgs/MultiArrayLayout' in channels[resolve(FORCE_BLOCK)]['schema']

    factory = DecoderFactory()
    decoders = {t: factory.decoder_for('cdr', Schema(id=c['id'], name=c['schemaName'],
                                                     encoding='ros2msg',
                                                     data=c['schema'].encode()))
                for t, c in channels.items() if t in WANTED}     # (cached by schema id)
    live_force = {}
    live_stage = {}
    for channel, payload in received:
        message = decoders[channel['topic']](payload)
        if channel['topic'] == resolve(FORCE_BLOCK):
            live_force[tuple(message.data[:2])] = list(message.data)
        else:
            stamp = (message.header.stamp.sec, message.header.stamp.nanosec)
            live_stage[stamp] = (list(message.position), list(message.velocity))

    bag = next(p for p in out.iterdir() if p.is_dir())
    reader_bag = BagReader(bag)
    bag_force, bag_stage = {}, {}
    for topic, _, _, msg in reader_bag.messages(list(WANTED)):
        if topic == resolve(FORCE_BLOCK):
            bag_force[tuple(msg.data[:2])] = list(msg.data)
        else:
            bag_stage[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = (
                list(msg.position), list(msg.velocity))
    # the bag closes with the trial; the stream (and the live view) go on a moment longer
    during = {k: v for k, v in live_force.items() if k[0] <= max(bag_force)[0]}
    seen = {s['topic']: sum(1 for c, _ in received if c is s) for s in subscriptions.values()}
    assert len(during) > 50, (f'{len(received)} frames {seen}, {len(live_force)} force blocks, '
                              f'{ended}; the trial said: {stdout[-1500:]}{stderr[-1500:]}')
    relayed = re.search(r'live view closed: relayed .*/loadcell/force_block (\d+)', stdout)
    assert relayed and int(relayed.group(1)) >= len(during), stdout
    assert {k: bag_force.get(k) for k in during} == during
    during = {k: v for k, v in live_stage.items() if k <= max(bag_stage)}
    assert len(during) > 50 and {k: bag_stage.get(k) for k in during} == during

    # What Foxglove needs to open the bag itself: the ros2 profile, CDR messages, a ros2msg
    # schema with the type's full definition for every channel; every message decodes with
    # the bag's own schemas, as Foxglove decodes it (mcap-ros2-support).
    from mcap.reader import make_reader

    from mantis_rig.recording.message_definition import full_message_definition
    for mcap_path in bag.glob('*.mcap'):
        with open(mcap_path, 'rb') as f:
            mcap = make_reader(f, decoder_factories=[DecoderFactory()])
            assert mcap.get_header().profile == 'ros2'
            summary = mcap.get_summary()
            for channel in summary.channels.values():
                schema = summary.schemas[channel.schema_id]
                assert channel.message_encoding == 'cdr', channel.topic
                assert schema.encoding == 'ros2msg', channel.topic
                assert schema.data.decode() == full_message_definition(schema.name)
            decoded = sum(1 for _ in mcap.iter_decoded_messages())
        assert decoded == sum(s.message_count for s in [summary.statistics])

    blocks = sorted((force_block_from_msg(m) for t, _, _, m in
                     reader_bag.messages([resolve(FORCE_BLOCK)])), key=lambda b: b.t0_s)
    for before, after in zip(blocks, blocks[1:]):
        assert after.t0_s == pytest.approx(before.t0_s + before.force_n.size * before.period_s,
                                           abs=1e-6)


@pytest.mark.parametrize('address, why', [
    ('127.0.0.1:{busy}', 'Address already in use'),
    ('no.such.host.invalid:8765', 'cannot serve on no.such.host.invalid:8765'),
    ('127.0.0.1:99999', 'a port of 0-65535'),
    ('eighty', 'expected [HOST:]PORT'),
])
def test_a_bad_live_address_is_refused_before_the_trial(tmp_path, address, why):
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        result = subprocess.run(
            [sys.executable, '-m', 'mantis_rig.cli', 'trial', '--out', str(tmp_path / 'out'),
             '--live', address.format(busy=busy.getsockname()[1])], cwd=REPO,
            env=os.environ.copy(), capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stdout + result.stderr
    assert why in result.stderr and result.stderr.count('\n') == 1, result.stderr
    assert 'Traceback' not in result.stderr
    assert not (tmp_path / 'out').exists() or not any((tmp_path / 'out').iterdir())


def test_a_client_that_connects_as_the_relay_starts_gets_every_channel():
    """A viewer connected while the relay starts: it may subscribe to every channel it is told
    of at once. (With the channels added after the server started, one start in a few advertised
    a channel to such a client before the server had it on record for it, refused the
    subscription as 'unknown channel', and the client never got that topic.)"""
    import rclpy

    from mantis_rig.live import LiveRelay
    from mantis_rig.nodes.recorder import TRIAL_TOPICS

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for _ in range(12):
            port = free_port()
            ready = threading.Event()
            client = {}

            def connect_at_once(port=port, ready=ready, client=client):
                ws = open_client(f'ws://127.0.0.1:{port}', timeout_s=30)
                ready.set()
                channels = {}
                while len(channels) < len(TRIAL_TOPICS):
                    message = json.loads(ws.recv(timeout=30))
                    if message['op'] == 'advertise':
                        channels.update({c['topic']: c for c in message['channels']})
                subscribe(ws, channels, list(channels))
                client['ws'] = ws

            thread = threading.Thread(target=connect_at_once, daemon=True)
            thread.start()
            relay = LiveRelay(f'127.0.0.1:{port}', ros_context=context)
            try:
                thread.join(30)
                ws = client['ws']
                refusals = []
                try:
                    while True:          # the server's answers to the subscription, if any
                        message = ws.recv(timeout=0.3)
                        if isinstance(message, str) and json.loads(message)['op'] == 'status':
                            refusals.append(json.loads(message)['message'])
                except TimeoutError:
                    pass
                assert refusals == []
                ws.close()
            finally:
                relay.close()
    finally:
        rclpy.shutdown(context=context)
