"""What one simulated trial costs, per layout, and how fast an interrupted trial stops:

    .venv/bin/python bench/bench_trial.py [--scene air_23mm_rig] [--layouts single multi]
                                          [--stop]

For each layout it runs ``mantis trial --backend sim`` at real-time factor 1 in a new process
and prints the CPU seconds (user + system, the trial process and every node process it started)
per simulated second of the trial (rig time from the bag's first to last force sample) and the
wall time; then the same at --real-time-factor 0 (as fast as the stack keeps up).
With --stop it also interrupts a trial with SIGINT 3 s after its bag opens and prints the time
from the signal to the process's exit (issue 11 asks for at most 3 s).
"""
import argparse
import os
from pathlib import Path
import resource
import signal
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mantis_rig.recording.trial_summary import summarize  # noqa: E402


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def trial_command(scene: str, layout: str, out: Path, rtf: float = 1.0) -> list:
    return [sys.executable, '-m', 'mantis_rig.cli', 'trial', '--backend', 'sim', '--scene', scene,
            '--out', str(out), '--processes', layout, '--real-time-factor', str(rtf)]


def run_trial(scene: str, layout: str, rtf: float = 1.0) -> None:
    with tempfile.TemporaryDirectory() as out:
        cpu0, t0 = children_cpu_s(), time.perf_counter()
        done = subprocess.run(trial_command(scene, layout, Path(out), rtf), cwd=REPO,
                              capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, children_cpu_s() - cpu0
        if done.returncode != 0:
            print(f'{layout}: exit {done.returncode}\n{done.stderr[-2000:]}')
            return
        bag = next(Path(out).glob('trial_*'))
        summary = summarize(bag)
        rig_s = summary.force_duration_s
    print(f'{layout:6s} at {rtf:g}x: {rig_s:5.2f} s of rig time, wall {wall:5.1f} s (process '
          f'start and imports included), CPU {cpu:5.1f} s = {cpu / rig_s:4.2f} CPU s per '
          f'simulated s; outcome {summary.outcome.get("result")}, '
          f'{len(summary.force_gaps)} force gap(s)')


def time_the_stop(scene: str, layout: str) -> None:
    with tempfile.TemporaryDirectory() as out:
        process = subprocess.Popen(trial_command(scene, layout, Path(out)), cwd=REPO,
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                   start_new_session=True)
        for line in process.stdout:
            if line.startswith('bag: '):
                break
        time.sleep(3.0)
        sent = time.perf_counter()
        os.killpg(process.pid, signal.SIGINT)
        status = process.wait()
        print(f'{layout:6s}: SIGINT 3 s into the trial: exit {status} after '
              f'{time.perf_counter() - sent:.2f} s')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='air_23mm_rig')
    parser.add_argument('--layouts', nargs='+', default=['single', 'multi'],
                        choices=['single', 'multi'])
    parser.add_argument('--stop', action='store_true', help='also time an interrupted trial')
    args = parser.parse_args()
    print(f'machine: {os.cpu_count()} CPUs; scene {args.scene}')
    for rtf in (1.0, 0.0):
        for layout in args.layouts:
            run_trial(args.scene, layout, rtf)
    if args.stop:
        for layout in args.layouts:
            time_the_stop(args.scene, layout)


if __name__ == '__main__':
    main()
