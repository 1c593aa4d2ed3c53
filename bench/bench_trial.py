"""What one simulated trial costs, per layout, and how fast an interrupted trial stops:

    .venv/bin/python bench/bench_trial.py [--scene air_23mm] [--layouts single multi] [--stop]
                                          [--baseline DIR | --against REV] [--pairs N]
                                          [--write]

For each layout it runs ``mantis trial --backend sim`` at real-time factor 1 in a new process
and prints the CPU seconds (user + system, the trial process and every node process it started)
per simulated second of the trial (rig time from the bag's first to last force sample) and the
wall time; then the same at --real-time-factor 0 (as fast as the stack keeps up).
With --stop it also interrupts a trial with SIGINT 3 s after its bag opens and prints the time
from the signal to the process's exit (issue 11 asks for at most 3 s).

With --baseline DIR (a clean copy of another revision, e.g. `git -C . archive HEAD | tar -x -C
DIR`) or --against REV (a git worktree of REV) it runs trials at real-time factor 1 of this
checkout and of the baseline in turn, for each of --layouts, --pairs times (the first of a pair
alternates), and prints each one's CPU per simulated s and the ratio pair by pair: this
machine's speed for this work drifts two- to three-fold within a day, unseen by the yardstick,
so only a pairing says what a change did. Both checkouts' bytecode and numba cache are written
first (as scripts/bootstrap.sh writes them), and each checkout's processes run with its own
directory first on PYTHONPATH (the package each imports is checked). With --write the paired
figures replace the section "A simulated trial" of docs/performance.md, stamped with the commit
and the yardstick (bench/machine.py).
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

from bench.machine import replace_section, stamp, yardstick_s  # noqa: E402
from mantis_rig.recording.trial_summary import summarize  # noqa: E402

TRIAL_START_WAIT_S = 300.0     # --stop: for the trial's bag to open


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def trial_command(scene: str, layout: str, out: Path, rtf: float = 1.0) -> list:
    return mantis_argv('trial', '--backend', 'sim', '--scene', scene, '--out', out,
                       '--processes', layout, '--real-time-factor', rtf)


def checkout_env(checkout: Path) -> dict:
    """The environment a checkout's trial runs in: its directory first on PYTHONPATH (its node
    processes inherit it), so that its own package is imported, not the installed one."""
    return {**os.environ, 'PYTHONPATH': os.pathsep.join(
        [str(checkout), *filter(None, os.environ.get('PYTHONPATH', '').split(os.pathsep))])}


def check_imports(checkout: Path) -> None:
    """SystemExit unless ``checkout``'s trial imports its own mantis_rig and mantis_sim."""
    where = subprocess.run(
        [sys.executable, '-c', 'import mantis_rig, mantis_sim; '
         'print(mantis_rig.__file__); print(mantis_sim.__file__)'],
        cwd=checkout, env=checkout_env(checkout), capture_output=True, text=True, check=True)
    for line in where.stdout.split():
        if not Path(line).resolve().is_relative_to(checkout.resolve()):
            raise SystemExit(f'{checkout}: its trial would import {line}')


def prepare(checkout: Path) -> None:
    """Its bytecode and numba cache written, as scripts/bootstrap.sh writes a checkout's (with
    PYTHONDONTWRITEBYTECODE set, a module without them is compiled in every process)."""
    env = checkout_env(checkout)
    subprocess.run([sys.executable, '-m', 'compileall', '-q', 'mantis_rig', 'mantis_sim'],
                   cwd=checkout, env=env, check=True)
    subprocess.run([sys.executable, '-m', 'mantis_sim.fast'], cwd=checkout, env=env,
                   check=True, capture_output=True)
    check_imports(checkout)


def measure_trial(scene: str, layout: str, rtf: float = 1.0, checkout: Path = REPO):
    """(CPU s, wall s, the bag's summary) of one trial of ``checkout``'s code."""
    with tempfile.TemporaryDirectory() as out:
        cpu0, t0 = children_cpu_s(), time.perf_counter()
        done = subprocess.run(trial_command(scene, layout, Path(out), rtf), cwd=checkout,
                              env=checkout_env(checkout), capture_output=True, text=True)
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


LAYOUT_NAMES = {'single': 'one process', 'multi': 'supervisor and `sim_rig` apart'}


def paired(baseline: Path, label: str, scene: str, layouts, pairs: int) -> dict:
    """Trials at real-time factor 1 of this checkout and of ``baseline`` in turn, ``pairs``
    times for each layout; layout -> {'this': [...], 'baseline': [...], 'ratio': [...], 'wall':
    {...}} (CPU s per simulated s; wall s)."""
    for checkout in (REPO, baseline):
        prepare(checkout)
    figures = {layout: {'this': [], 'baseline': [], 'ratio': [],
                        'wall': {'this': [], 'baseline': []}} for layout in layouts}
    for pair in range(1, pairs + 1):
        for layout in layouts:
            turn = [('this', REPO), ('baseline', baseline)]
            if pair % 2 == 0:
                turn.reverse()
            got = figures[layout]
            for name, checkout in turn:
                cpu, wall, summary = measure_trial(scene, layout, checkout=checkout)
                got[name].append(cpu / summary.force_duration_s)
                got['wall'][name].append(wall)
            got['ratio'].append(got['this'][-1] / got['baseline'][-1])
            print(f'pair {pair}, {layout:6s}: {got["this"][-1]:.3f} against {label} '
                  f'{got["baseline"][-1]:.3f} CPU s per simulated s', flush=True)
    return figures


def spread(values, digits: int = 2) -> str:
    return (f'{statistics.median(values):.{digits}f} ({min(values):.{digits}f}-'
            f'{max(values):.{digits}f})')


def paired_table(figures: dict, label: str) -> str:
    rows = ['| layout | this checkout | ' + label + ' | this / ' + label + ' | wall s, this / '
            + label + ' | pairs |', '|---|---|---|---|---|---|']
    for layout, got in figures.items():
        rows.append(f'| {LAYOUT_NAMES[layout]} | {spread(got["this"])} | '
                    f'{spread(got["baseline"])} | {spread(got["ratio"], 3)} | '
                    f'{statistics.median(got["wall"]["this"]):.1f} / '
                    f'{statistics.median(got["wall"]["baseline"]):.1f} | '
                    f'{len(got["ratio"])} |')
    return '\n'.join(rows)


def paired_against(rev: str, scene: str, layouts, pairs: int) -> dict:
    """paired() against a git worktree of ``rev``."""
    with tempfile.TemporaryDirectory() as tmp:
        baseline = Path(tmp) / 'baseline'
        subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', str(baseline),
                        rev], check=True, capture_output=True)
        try:
            return paired(baseline, rev, scene, layouts, pairs)
        finally:
            subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force',
                            str(baseline)], capture_output=True)


SECTION = '## A simulated trial'
SECTION_TEXT = """`bench/bench_trial.py`: a whole `{scene}` trial, `mantis trial --backend sim` at
real-time factor 1 in a new process (start, imports and exit included), for each layout: one
process, and the supervisor and the simulated rig (`sim_rig`) in processes of their own. CPU s
per simulated s is user + system of the trial's process and every node process it started (the
bench's children), over the rig time from the bag's first to last force sample. This machine's
speed for this work drifts two- to three-fold within a day, unseen by the yardstick, so a change
is measured paired: this checkout's trials and the baseline's (`--baseline DIR`, a clean copy
made with `git archive`, or `--against REV`) in turn, the first of a pair alternating. Goal
(issue 45): at most 0.4 CPU s per simulated s in one process on `air_23mm`.

{stamp}; yardstick at the start {yardstick:.2f} s.

{table}

Where a trial's CPU goes and what was done about it, and the figures before these:
[below](#a-simulated-trial-earlier-figures).
"""


def write_docs(scene: str, table: str, stamped: str, yardstick: float) -> None:
    replace_section(REPO / 'docs' / 'performance.md', SECTION,
                    SECTION_TEXT.format(scene=scene, stamp=stamped, yardstick=yardstick,
                                        table=table))


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
    parser.add_argument('--scene', default='air_23mm')
    parser.add_argument('--layouts', nargs='+', default=['single', 'multi'],
                        choices=['single', 'multi'])
    parser.add_argument('--stop', action='store_true', help='also time an interrupted trial')
    baseline = parser.add_mutually_exclusive_group()
    baseline.add_argument('--baseline', type=Path, metavar='DIR',
                          help='pair trials at 1x with those of this clean copy of another '
                               'revision')
    baseline.add_argument('--against', metavar='REV',
                          help='pair trials at 1x with those of this git revision (a worktree)')
    parser.add_argument('--label', help='what the baseline is called in the table (default: '
                                        'its revision or directory)')
    parser.add_argument('--pairs', type=int, default=5, help='pairs per layout')
    parser.add_argument('--write', action='store_true',
                        help='with --baseline or --against: write the paired figures into '
                             'docs/performance.md')
    args = parser.parse_args()
    if args.write and not (args.baseline or args.against):
        parser.error('--write needs --baseline or --against')
    print(f'machine: {os.cpu_count()} CPUs; scene {args.scene}')
    if args.baseline or args.against:
        yardstick = yardstick_s()
        print(f'yardstick {yardstick:.2f} s', flush=True)
        if args.baseline:
            label = args.label or str(args.baseline)
            figures = paired(args.baseline.resolve(), label, args.scene, args.layouts,
                             args.pairs)
        else:
            label = args.label or args.against
            figures = paired_against(args.against, args.scene, args.layouts, args.pairs)
        table, stamped = paired_table(figures, label), stamp()
        print(table)
        print(stamped)
        if args.write:
            write_docs(args.scene, table, stamped, yardstick)
        return
    for rtf in (1.0, 0.0):
        for layout in args.layouts:
            run_trial(args.scene, layout, rtf)
    if args.stop:
        for layout in args.layouts:
            time_the_stop(args.scene, layout)


if __name__ == '__main__':
    main()
