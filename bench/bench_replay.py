"""Figures for issue 5: analysis of the real 3.4 s trial read from a bag, and replay speed.

    .venv/bin/python bench/bench_replay.py [--realtime]

1. Imports test/data's real trial (65,255 frames at 19,000 frames/s) into a bag, then times
   reading the bag (marker blocks -> MarkerTracks) and the analysis (goal: < 2 s together).
2. Replays a synthetic 10 s trial bag (every topic of the trial contract at rig rates, ~3,300
   messages) at --rate 10 while a subscriber process receives them: achieved rate, lateness of
   each publication against its schedule, messages delivered. Also 1x, and the imported
   trial's marker blocks at 10x.
"""
import argparse
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from mantis_rig.contract import MARKERS, resolve  # noqa: E402
from mantis_rig.runtime.ros_env import claim_local_domain  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / 'test' / 'data' / \
    'air_23mm_2p3mmps_trial1_markers.csv.gz'
SUBSCRIBER = '''
import sys, time, rclpy
from mantis_rig.recording import BagReader
from mantis_rig.recording.message_types import message_class
from mantis_rig.replay import replay_qos
from mantis_rig.recording.offered_qos import parse_offered_qos_string
from rclpy.qos import QoSProfile
rclpy.init()
node = rclpy.create_node('bench_subscriber')
count = [0]
for topic, info in BagReader(sys.argv[1], warn=False).topics.items():
    q = replay_qos(topic, parse_offered_qos_string(info.metadata['offered_qos_profiles']))
    node.create_subscription(message_class(info.type_name), topic,
                             lambda m: count.__setitem__(0, count[0] + 1),
                             QoSProfile(depth=1000, reliability=q.reliability,
                                        durability=q.durability), raw=True)
end = time.monotonic() + float(sys.argv[2])
last, seen = time.monotonic(), 0
while time.monotonic() < end:  # until 1.5 s without a message after the first
    rclpy.spin_once(node, timeout_sec=0.05)
    if count[0] != seen:
        last, seen = time.monotonic(), count[0]
    elif seen and time.monotonic() - last > 1.5:
        break
print(count[0])
'''


def bench_analysis(workdir: Path) -> None:
    from mantis_rig.analysis import analyze_tracks
    from mantis_rig.analysis.inputs.bag import read_trial_bag
    from mantis_rig.cli import main

    bag = workdir / 'real_trial'
    t0 = time.perf_counter()
    main(['import-tracking', str(DATA), '--out', str(bag)])
    print(f'  import-tracking (load CSV, derive angles, write {bag.name}): '
          f'{time.perf_counter() - t0:.2f} s')
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        trial = read_trial_bag(bag)
        t1 = time.perf_counter()
        summary = analyze_tracks(trial.tracks).summary()
        t2 = time.perf_counter()
        runs.append((t1 - t0, t2 - t1, t2 - t0))
    read_s, analyse_s, total_s = (float(np.median(col)) for col in zip(*runs, strict=True))
    best = min(r[2] for r in runs)
    print(f'  analysis from the bag, {trial.tracks.n_frames} frames: read {read_s:.3f} s + '
          f'analyse {analyse_s:.3f} s = {total_s:.3f} s median of 3 (best {best:.3f} s); '
          f'goal < 2 s: {"met" if total_s < 2 else "NOT met"}')
    print(f'  peak tip speed {summary["peak_tip_speed_mps"]:.2f} m/s, phase IV at '
          f'{summary["phase_start_s"]["IV"]:.4f} s')
    return bag


def bench_replay(bag: Path, rate: float, topics=None, realtime=False) -> None:
    import rclpy

    from mantis_rig.replay import BagPlayer

    sub = subprocess.Popen([sys.executable, '-c', SUBSCRIBER, str(bag), '60'],
                           stdout=subprocess.PIPE, text=True, env=os.environ.copy())
    rclpy.init()
    node = rclpy.create_node('bench_player')
    try:
        player = BagPlayer(node, bag, rate=rate, topics=topics, realtime=realtime)
        matched = player.wait_for_subscribers(20.0)
        report = player.run()
        player.wait_for_delivery(2.0)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    delivered = sub.communicate(timeout=60)[0].strip()
    s = report.stats.summary()
    sent = sum(report.published.values())
    print(f'  {bag.name} at --rate {rate:g}{" (" + ",".join(topics) + ")" if topics else ""}: '
          f'{sent} messages, {s["log_span_s"]:.3f} s of log in {s["wall_span_s"]:.3f} s -> '
          f'achieved {s["achieved_rate"]:.3f}x ({sent / max(s["wall_span_s"], 1e-9):.0f} msg/s); '
          f'lateness mean {s["lateness_mean_ms"]:.3f} ms, p99 {s["lateness_p99_ms"]:.3f} ms, '
          f'max {s["lateness_max_ms"]:.3f} ms; scheduling {report.scheduling}; subscriber '
          f'{"matched" if matched else "NOT matched"}'
          + (f', received {delivered}' if delivered else ''))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--realtime', action='store_true',
                        help='play from a SCHED_FIFO thread (root / CAP_SYS_NICE)')
    args = parser.parse_args()
    claim_local_domain()
    from mantis_rig.replay.synthetic import write_synthetic_trial

    with tempfile.TemporaryDirectory(prefix='bench_replay_') as tmp:
        tmp = Path(tmp)
        print(f'machine: {os.cpu_count()} CPUs; ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}')
        print('analysis of the real trial from a bag')
        real = bench_analysis(tmp) if DATA.exists() else None
        print('replay (the subscriber is a separate process)')
        synthetic = tmp / 'synthetic_10s'
        write_synthetic_trial(synthetic, duration_s=10.0)
        bench_replay(synthetic, 10.0, realtime=args.realtime)
        bench_replay(synthetic, 1.0, realtime=args.realtime)
        if real is not None:
            bench_replay(real, 10.0, topics=[resolve(MARKERS)], realtime=args.realtime)


if __name__ == '__main__':
    main()
