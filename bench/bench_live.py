"""What the live view costs: one `air_23mm_rig` trial (one process, real-time factor 1) without
and with `--live` and one Foxglove WebSocket client subscribed to every channel and reading
everything (prints figures; not a test).

    .venv/bin/python bench/bench_live.py [--runs 2]

CPU seconds (user + system) of the trial's process, the client's excluded, per run; the
relay's cost is the difference of the medians.
"""
import argparse
import json
import os
from pathlib import Path
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def read_everything(port: int, counts: dict) -> None:
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect
    deadline = time.monotonic() + 60
    while True:
        try:
            ws = connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'],
                         max_size=None)
            break
        except OSError:
            if time.monotonic() > deadline:
                return
            time.sleep(0.05)
    subscribed = False
    try:
        while True:
            frame = ws.recv(timeout=60)
            if isinstance(frame, str):
                message = json.loads(frame)
                if message['op'] == 'advertise' and not subscribed:
                    ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                        {'id': c['id'], 'channelId': c['id']} for c in message['channels']]}))
                    subscribed = True
            else:
                counts['messages'] += 1
                counts['bytes'] += len(frame)
    except (ConnectionClosed, TimeoutError):
        pass


def trial_cpu_s(live: bool) -> tuple[float, dict]:
    out = Path(tempfile.mkdtemp(prefix='bench_live_'))
    command = [sys.executable, '-m', 'mantis_rig.cli', 'trial', '--out', str(out)]
    counts = {'messages': 0, 'bytes': 0}
    reader = None
    if live:
        port = free_port()
        command += ['--live', f'127.0.0.1:{port}']
        reader = threading.Thread(target=read_everything, args=(port, counts))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    process = subprocess.Popen(command, cwd=REPO, env=os.environ.copy(),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if reader:
        reader.start()
    assert process.wait(timeout=300) == 0, 'the trial failed'
    if reader:
        reader.join(timeout=60)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=2)
    args = parser.parse_args()
    plain = [trial_cpu_s(False)[0] for _ in range(args.runs)]
    live = [trial_cpu_s(True) for _ in range(args.runs)]
    live_cpu = [cpu for cpu, _ in live]
    counts = live[-1][1]
    print(f'trial without --live: CPU {", ".join(f"{c:.2f}" for c in plain)} s')
    print(f'trial with --live and one client reading every channel: CPU '
          f'{", ".join(f"{c:.2f}" for c, _ in live)} s; the client got {counts["messages"]} '
          f'messages, {counts["bytes"] / 1e6:.1f} MB')
    print(f'the relay costs {statistics.median(live_cpu) - statistics.median(plain):.2f} CPU s '
          f'per trial (median difference)')


if __name__ == '__main__':
    main()
