"""Benchmark the trial log writer: 60 s of a 20 kS/s force stream plus a few kHz of other topics.

Prints, per chunk compression: wall and CPU time to write, messages/s, file size, chunks, and a
read-back check that every message arrived intact (zero loss). Run:

    .venv/bin/python bench/bench_recording.py [--seconds 60] [--compression none lz4 zstd]
"""
import argparse
from pathlib import Path
import sys
import tempfile
import time

import numpy as np
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import String

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mantis_rig.recording import BagReader, BagWriter  # noqa: E402
from mantis_rig.recording.force_block import force_block_from_msg, force_block_to_msg  # noqa: E402

T0_NS = 1_700_000_000_000_000_000
FORCE_RATE_HZ = 20_000
BLOCK_SAMPLES = 200
STAGE_RATE_HZ = 1_000  # stage/mechanism state (JointState)
TRIGGER_RATE_HZ = 2_000  # camera frame-sync edges (TimeReference)
EVENT_RATE_HZ = 10
VOLTS_PER_COUNT = 20.0 / 2**16  # USB-6363, +-10 V, 16 bit
NEWTONS_PER_VOLT = 11.1


def force_samples(n, rng, start):
    """A tendon-pull ramp with noise, quantized like the 16-bit DAQ, in newtons."""
    t_s = (start + np.arange(n)) / FORCE_RATE_HZ
    volts = 0.8 * t_s % 1.6 + rng.normal(0.0, 0.003, n)
    return np.round(volts / VOLTS_PER_COUNT) * VOLTS_PER_COUNT * NEWTONS_PER_VOLT


def timeline(seconds):
    """(t_ns, topic, index) for every message of the trial, in time order."""
    events = []
    for topic, rate in (('/force', FORCE_RATE_HZ // BLOCK_SAMPLES), ('/stage/state', STAGE_RATE_HZ),
                        ('/camera/sync', TRIGGER_RATE_HZ), ('/events', EVENT_RATE_HZ)):
        period_ns = 1_000_000_000 // rate
        events += [(T0_NS + i * period_ns, topic, i) for i in range(int(seconds * rate))]
    events.sort()
    return events


def make_message(topic, index, t_ns, rng):
    if topic == '/force':
        first = index * BLOCK_SAMPLES
        return force_block_to_msg(t_ns / 1e9, 1.0 / FORCE_RATE_HZ,
                                  force_samples(BLOCK_SAMPLES, rng, first))
    sec, nanosec = divmod(t_ns, 1_000_000_000)
    if topic == '/stage/state':
        msg = JointState(name=['stage_z'], position=[index * 1e-3], velocity=[1.0], effort=[0.1])
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        return msg
    if topic == '/camera/sync':
        msg = TimeReference(source='phantom_strobe')
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.time_ref.sec, msg.time_ref.nanosec = sec, nanosec
        return msg
    return String(data=f'event {index}')


def write_trial(bag_dir, seconds, compression, chunk_size_bytes):
    rng = np.random.default_rng(0)
    events = timeline(seconds)
    writer_s = 0.0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    writer = BagWriter(bag_dir, compression=compression, chunk_size_bytes=chunk_size_bytes)
    writer.add_metadata('trial_conditions', {'pull_speed_mm_s': '1.0', 'medium': 'air'})
    force_sum = 0.0
    for t_ns, topic, index in events:
        msg = make_message(topic, index, t_ns, rng)
        if topic == '/force':
            force_sum += float(np.sum(msg.data[2:]))
        start = time.perf_counter()
        writer.write(topic, msg, t_ns)
        writer_s += time.perf_counter() - start
    start = time.perf_counter()
    writer.close(trial_outcome={'struck': 'true'})
    writer_s += time.perf_counter() - start
    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    return events, force_sum, wall_s, cpu_s, writer_s


def verify(bag_dir, events, force_sum):
    """Read back: same count per topic, force blocks contiguous, same force total."""
    start = time.perf_counter()
    reader = BagReader(bag_dir)
    expected = {}
    for _, topic, _ in events:
        expected[topic] = expected.get(topic, 0) + 1
    counts, read_sum, previous_t0 = {}, 0.0, None
    period_ns = BLOCK_SAMPLES * 1_000_000_000 // FORCE_RATE_HZ
    contiguous = True
    for message in reader:
        counts[message.topic] = counts.get(message.topic, 0) + 1
        if message.topic == '/force':
            block = force_block_from_msg(message.message)
            read_sum += float(block.force_n.sum())
            if previous_t0 is not None and abs(block.t0_s - previous_t0 - period_ns / 1e9) > 1e-6:
                contiguous = False
            previous_t0 = block.t0_s
    ok = (counts == expected and contiguous and reader.complete
          and abs(read_sum - force_sum) <= 1e-9 * max(1.0, abs(force_sum)))
    return ok, time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--compression', nargs='+', default=['none', 'lz4', 'zstd'])
    parser.add_argument('--chunk-kib', type=int, default=256)
    args = parser.parse_args(argv)
    print(f'trial: {args.seconds:g} s; /force {FORCE_RATE_HZ} S/s in blocks of {BLOCK_SAMPLES} '
          f'(Float64MultiArray); /stage/state {STAGE_RATE_HZ} Hz; /camera/sync '
          f'{TRIGGER_RATE_HZ} Hz; /events {EVENT_RATE_HZ} Hz; chunk {args.chunk_kib} KiB')
    print(f'{"compression":>11} {"msgs":>8} {"wall s":>7} {"cpu s":>6} {"write() s":>9} '
          f'{"msgs/s":>8} {"MB":>6} {"MB/s data":>9} {"read s":>6}  zero loss')
    all_ok = True
    with tempfile.TemporaryDirectory() as tmp:
        for compression in args.compression:
            bag_dir = Path(tmp) / f'bench_{compression}'
            events, force_sum, wall_s, cpu_s, writer_s = write_trial(
                bag_dir, args.seconds, compression, args.chunk_kib * 1024)
            size_mb = sum(p.stat().st_size for p in bag_dir.iterdir()) / 1e6
            ok, read_s = verify(bag_dir, events, force_sum)
            all_ok &= ok
            print(f'{compression:>11} {len(events):>8} {wall_s:>7.2f} {cpu_s:>6.2f} '
                  f'{writer_s:>9.2f} {len(events) / writer_s:>8.0f} {size_mb:>6.1f} '
                  f'{size_mb / args.seconds:>9.3f} {read_s:>6.2f}  {"yes" if ok else "NO"}')
    print('wall/cpu: whole loop incl. building messages; write(): time inside BagWriter.write '
          '(serialize + MCAP + fsync per chunk) and close()')
    return 0 if all_ok else 1


if __name__ == '__main__':
    sys.exit(main())
