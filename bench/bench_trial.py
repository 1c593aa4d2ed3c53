"""What one simulated trial costs, per layout, and how fast an interrupted trial stops:

    .venv/bin/python bench/bench_trial.py [--scene air_23mm_rig] [--layouts single multi]
                                          [--stop]

For each layout it runs ``mantis trial --backend sim`` at real-time factor 1 in a new process
and prints the CPU seconds (user + system, the trial process and every node process it started)
per simulated second of the trial (rig time from the bag's first to last force sample) and the
wall time; then the same at --real-time-factor 0 (as fast as the stack keeps up).
With --stop it also interrupts a trial with SIGINT 3 s after its bag opens and prints the time
from the signal to the process's exit (issue 11 asks for at most 3 s).

With --against REV it runs one-process trials at real-time factor 1 of this checkout and of
REV (a git worktree of it, its bytecode written as the bootstrap writes this one's) in turn,
--pairs times, and prints each one's CPU per simulated s and the ratio pair by pair: this
machine's speed for this work drifts two- to three-fold within a day, unseen by the yardstick,
so only a pairing says what a change did.
"""
import argparse
import os
from pathlib import Path
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'test'))

from session_command import SessionCommand, mantis_argv  # noqa: E402

from mantis_rig.recording.trial_summary import summarize  # noqa: E402

TRIAL_START_WAIT_S = 300.0     # --stop: for the trial's bag to open


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def trial_command(scene: str, layout: str, out: Path, rtf: float = 1.0) -> list:
    return mantis_argv('trial', '--backend', 'sim', '--scene', scene, '--out', out,
                       '--processes', layout, '--real-time-factor', rtf)


def measure_trial(scene: str, layout: str, rtf: float = 1.0, checkout: Path = REPO):
    """(CPU s, wall s, the bag's summary) of one trial of ``checkout``'s code."""
    with tempfile.TemporaryDirectory() as out:
        cpu0, t0 = children_cpu_s(), time.perf_counter()
        done = subprocess.run(trial_command(scene, layout, Path(out), rtf), cwd=checkout,
                              capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, children_cpu_s() - cpu0
        if done.returncode != 0:
            raise SystemExit(f'{checkout}, {layout}: exit {done.returncode}\n'
                             f'{done.stderr[-2000:]}')
        return cpu, wall, summarize(next(Path(out).glob('trial_*')))


def run_trial(scene: str, layout: str, rtf: float = 1.0) -> None:
    cpu, wall, summary = measure_trial(scene, layout, rtf)
    rig_s = summary.force_duration_s
    print(f'{layout:6s} at {rtf:g}x: {rig_s:5.2f} s of rig time, wall {wall:5.1f} s (process '
          f'start and imports included), CPU {cpu:5.1f} s = {cpu / rig_s:4.2f} CPU s per '
          f'simulated s; outcome {summary.outcome.get("result")}, '
          f'{len(summary.force_gaps)} force gap(s)')


def paired_against(rev: str, scene: str, pairs: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        baseline = Path(tmp) / 'baseline'
        subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', str(baseline),
                        rev], check=True, capture_output=True)
        try:
            for checkout in (REPO, baseline):
                subprocess.run([sys.executable, '-m', 'compileall', '-q', 'mantis_rig',
                                'mantis_sim'], cwd=checkout, check=True)
            per_sim_s = {'this checkout': [], rev: []}
            ratios = []
            for pair in range(1, pairs + 1):
                for name, checkout in (('this checkout', REPO), (rev, baseline)):
                    cpu, _, summary = measure_trial(scene, 'single', checkout=checkout)
                    per_sim_s[name].append(cpu / summary.force_duration_s)
                ratios.append(per_sim_s['this checkout'][-1] / per_sim_s[rev][-1])
                print(f'pair {pair}: {per_sim_s["this checkout"][-1]:.2f} against '
                      f'{per_sim_s[rev][-1]:.2f} CPU s per simulated s', flush=True)
        finally:
            subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force',
                            str(baseline)], capture_output=True)
    for name, values in per_sim_s.items():
        print(f'{name}: median {statistics.median(values):.2f} CPU s per simulated s '
              f'({min(values):.2f}-{max(values):.2f})')
    print(f'this checkout / {rev}: median {statistics.median(ratios):.3f} '
          f'({min(ratios):.3f}-{max(ratios):.3f}) over {pairs} pairs')


def time_the_stop(scene: str, layout: str) -> None:
    with tempfile.TemporaryDirectory() as out, \
            SessionCommand(trial_command(scene, layout, Path(out))) as trial:
        trial.wait_for_line(lambda line: line.startswith('bag: '), TRIAL_START_WAIT_S)
        time.sleep(3.0)
        sent = trial.signal_group(signal.SIGINT)
        status = trial.wait()
        print(f'{layout:6s}: SIGINT 3 s into the trial: exit {status} after '
              f'{time.monotonic() - sent:.2f} s')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scene', default='air_23mm_rig')
    parser.add_argument('--layouts', nargs='+', default=['single', 'multi'],
                        choices=['single', 'multi'])
    parser.add_argument('--stop', action='store_true', help='also time an interrupted trial')
    parser.add_argument('--against', metavar='REV',
                        help='pair one-process trials at 1x with those of this git revision')
    parser.add_argument('--pairs', type=int, default=5, help='pairs with --against')
    args = parser.parse_args()
    print(f'machine: {os.cpu_count()} CPUs; scene {args.scene}')
    if args.against:
        paired_against(args.against, args.scene, args.pairs)
        return
    for rtf in (1.0, 0.0):
        for layout in args.layouts:
            run_trial(args.scene, layout, rtf)
    if args.stop:
        for layout in args.layouts:
            time_the_stop(args.scene, layout)


if __name__ == '__main__':
    main()
