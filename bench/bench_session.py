"""A lab's day on the simulated rig: one `mantis bringup`, many trials, then Ctrl-C.

    .venv/bin/python bench/bench_session.py [--trials 20] [--processes single multi]
                                            [--multi-trials N] [--write] [--keep DIR]

Starts ``mantis bringup --backend sim --real-time-factor 0`` (loopback DDS, a domain of its
own), starts each trial over /supervisor/start_trial once the previous one has ended, and
after each trial reads the bring-up's process tree: resident memory (RSS), open file
descriptors, Fast DDS's shared-memory files in /dev/shm and CPU seconds. Then every bag goes
through `mantis analyze --table`, the bring-up gets SIGINT, and the bench checks that it exited
and left no process of the tree running. It prints the first, second and last trials and the
growth from the second to the last (issue 30 asks for RSS within 10 % and constant fds); with
--write it also writes docs/session_benchmark.md with the commit and the yardstick.
"""
import argparse
import csv
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from bench.machine import stamp  # noqa: E402
from mantis_rig.nodes.trial_client import TrialClient  # noqa: E402
from mantis_rig.runtime import process_state  # noqa: E402
from mantis_rig.runtime.ros_env import claim_free_domain, release_domain  # noqa: E402

TRIAL_TIMEOUT_S = 300.0


def tree_usage(root: int) -> dict:
    """RSS (MiB), open fds and CPU s (user + system) summed over the tree; /dev/shm files."""
    rss_kib = fds = 0
    cpu_s = 0.0
    by_process = {}
    pids = process_state.tree(root)
    for pid in pids:
        proc = process_state.PROC / str(pid)
        try:
            status = (proc / 'status').read_text()
            rss = int(next(line.split()[1] for line in status.splitlines()
                           if line.startswith('VmRSS:')))
            fd_count = len(os.listdir(proc / 'fd'))
        except (OSError, StopIteration):
            continue
        state = process_state.read(pid)
        if state is None:
            continue
        rss_kib += rss
        by_process[' '.join(process_state.argv(pid)[1:3])] = rss / 1024
        fds += fd_count
        cpu_s += state.cpu_s
    shm = sum(1 for name in os.listdir('/dev/shm') if name.startswith(('fastrtps', 'fast_')))
    return {'processes': len(pids), 'rss_mib': rss_kib / 1024, 'fds': fds,
            'shm_files': shm, 'cpu_s': cpu_s, 'by_process': by_process}


def run_session(trials: int, processes: str, out: Path) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    command = [sys.executable, '-m', 'mantis_rig.cli', 'bringup', '--backend', 'sim',
               '--processes', processes, '--real-time-factor', '0', '--out', str(out),
               '--log-dir', str(out / 'logs')]
    # to a file: a pipe nobody reads until the end fills after ~130 trials of log lines, and
    # the supervisor's next log line then blocks its trial thread for good
    output = out / 'bringup.log'
    bringup = subprocess.Popen(command, cwd=REPO, env=env, stdout=output.open('w'),
                               stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    client = TrialClient()
    executor = SingleThreadedExecutor()
    executor.add_node(client)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    rows, finals, refused = [], [], []
    tree: list[int] = []
    try:
        if not client.wait_for_supervisor(120.0):
            raise SystemExit('the supervisor did not come up within 120 s')
        before = tree_usage(bringup.pid)
        for i in range(trials):
            started = time.perf_counter()
            ok, message, final = client.run_trial(TRIAL_TIMEOUT_S)
            if not ok:                  # said, counted, and the session goes on
                refused.append(f'trial {i + 1}: {message}')
                print(f'trial {i + 1:4d}: not started: {message}', flush=True)
                client.wait_for_state(('done', 'aborted'), client.trial_start, TRIAL_TIMEOUT_S)
                continue
            finals.append((final, client.reason))
            usage = tree_usage(bringup.pid)
            usage['wall_s'] = time.perf_counter() - started
            usage['trial_cpu_s'] = usage['cpu_s'] - (rows[-1]['cpu_s'] if rows else
                                                     before['cpu_s'])
            rows.append(usage)
            print(f'trial {i + 1:4d}: {final:8s} {usage["wall_s"]:5.1f} s, CPU '
                  f'{usage["trial_cpu_s"]:5.2f} s, RSS {usage["rss_mib"]:7.1f} MiB, fds '
                  f'{usage["fds"]}, shm files {usage["shm_files"]}, processes '
                  f'{usage["processes"]}; MiB by process: '
                  + ', '.join(f'{k}: {v:.0f}' for k, v in usage['by_process'].items()),
                  flush=True)
        tree = process_state.tree(bringup.pid)
        bringup.send_signal(signal.SIGINT)
        try:
            bringup.wait(timeout=30)
        except subprocess.TimeoutExpired:
            bringup.kill()
            bringup.wait()
        time.sleep(1.0)
        left = [pid for pid in tree if process_state.read(pid) is not None]
    finally:
        if bringup.poll() is None:       # the bench itself failed: leave nothing running
            bringup.kill()
            bringup.wait()
        executor.shutdown()
        client.destroy_node()
        rclpy.try_shutdown()
    return {'rows': rows, 'finals': finals, 'refused': refused, 'exit': bringup.returncode,
            'left': left,
            'last_line': _last_line(output)}


def _last_line(path: Path) -> str:
    lines = path.read_text(errors='replace').strip().splitlines()
    return lines[-1] if lines else ''


def analyse(out: Path) -> tuple[int, int]:
    """(bags analysed ok, bags) by `mantis analyze <out> --table`."""
    table = out / 'day.csv'
    subprocess.run([sys.executable, '-m', 'mantis_rig.cli', 'analyze', str(out), '--table',
                    str(table)], cwd=REPO, capture_output=True, text=True, check=False)
    with table.open(newline='') as f:
        rows = list(csv.DictReader(f))
    return sum(row['status'] == 'ok' for row in rows), len(rows)


def report(result: dict, processes: str, analysed: tuple[int, int]) -> str:
    rows = result['rows']
    first, second, last = rows[0], rows[min(1, len(rows) - 1)], rows[-1]
    done = sum(final == 'done' for final, _ in result['finals'])
    unconfirmed = len(result['refused'])
    growth = 100.0 * (last['rss_mib'] - second['rss_mib']) / second['rss_mib']
    lines = [
        f'| {processes} | {len(rows) + unconfirmed} | {done} | {unconfirmed} | '
        f'{analysed[0]} of {analysed[1]} | '
        f'{first["rss_mib"]:.0f} / {second["rss_mib"]:.0f} / {last["rss_mib"]:.0f} '
        f'({growth:+.1f} %) | {first["fds"]} / {second["fds"]} / {last["fds"]} | '
        f'{first["shm_files"]} / {last["shm_files"]} | '
        f'{first["trial_cpu_s"]:.2f} / {second["trial_cpu_s"]:.2f} / '
        f'{last["trial_cpu_s"]:.2f} | exit {result["exit"]}, '
        f'{len(result["left"])} left |']
    return '\n'.join(lines)


HEADER = ('| layout | trials | done | starts not confirmed | bags analysed | '
          'tree RSS MiB: first / second / last '
          '(second to last) | fds: first / second / last | shm files: first / last | '
          'CPU s per trial: first / second / last | after Ctrl-C |\n'
          '|---|---|---|---|---|---|---|---|---|---|')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--trials', type=int, default=20)
    parser.add_argument('--multi-trials', type=int,
                        help='trials in the multi-process layout (default: --trials)')
    parser.add_argument('--processes', choices=('single', 'multi'), nargs='+',
                        default=['single'])
    parser.add_argument('--write', action='store_true',
                        help='write docs/session_benchmark.md')
    parser.add_argument('--keep', type=Path, help='keep the bags under this directory')
    args = parser.parse_args()
    domain = claim_free_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    lines = []
    try:
        for processes in args.processes:
            out = Path(tempfile.mkdtemp(prefix=f'session_{processes}_', dir=args.keep))
            trials = args.multi_trials if processes == 'multi' and args.multi_trials \
                else args.trials
            result = run_session(trials, processes, out)
            analysed = analyse(out)
            line = report(result, processes, analysed)
            print(HEADER + '\n' + line)
            print(f'bring-up exit {result["exit"]}: {result["last_line"]}')
            bad = [(i + 1, f, r) for i, (f, r) in enumerate(result['finals']) if f != 'done']
            for number, final, reason in bad:
                print(f'trial {number}: {final}: {reason}')
            for line in result['refused']:
                print(f'not started (the start was not confirmed): {line}')
            lines.append(line)
    finally:
        release_domain(domain)
    if args.write:
        text = ('# A lab\'s day on the simulated rig\n\n'
                'Written by `bench/bench_session.py --write` (one `mantis bringup --backend sim '
                '--real-time-factor 0`, trials started over `/supervisor/start_trial` one after '
                'the other, every bag through `mantis analyze --table`, then Ctrl-C). Memory, '
                'descriptors and CPU are summed over the bring-up\'s process tree; shm files '
                'are Fast DDS\'s in /dev/shm.\n\n'
                f'{stamp()}\n\n{HEADER}\n' + '\n'.join(lines) + '\n')
        (REPO / 'docs' / 'session_benchmark.md').write_text(text, encoding='utf-8')
    return 0


if __name__ == '__main__':
    sys.exit(main())
