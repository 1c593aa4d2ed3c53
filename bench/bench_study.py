"""What a study costs beside its trials: `mantis study` against the same trials run bare.

    .venv/bin/python bench/bench_study.py [--repeats 15] [--rounds 1] [--write]

The plan: the guide distance (19, 25 mm) and the pull speed (1.0, 2.3 mm/s), `--repeats` each
(15: 60 trials), in a seeded random order, on the simulated rig at real-time factor 0 in one
process. Bare: `mantis bringup` and a client that sets each trial's conditions and starts it
once the one before has ended, in the study's own run order, until the last is done, then
Ctrl-C. Study: `mantis study PLAN --out DIR` from start to exit (the twin's forecasts, each
bag's measurement and judgement, the report). Both times run from the command's start to its
exit, bring-up and shutdown included. With --rounds N they alternate N times. With --write the
table goes into docs/performance.md ("A study") with the commit and the yardstick.
"""
import argparse
import os
from pathlib import Path
import re
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

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from session_command import mantis, mantis_argv  # noqa: E402

from bench.machine import stamp  # noqa: E402
from mantis_rig.nodes.trial_client import TrialClient  # noqa: E402
from mantis_rig.runtime.executors import Spinner  # noqa: E402
from mantis_rig.runtime.ros_env import claim_free_domain, release_domain  # noqa: E402
from mantis_rig.study_session.record import read_record  # noqa: E402
from mantis_sim.studies.rig_study.plan import plan_from_mapping  # noqa: E402

SECTION = '## A study'


def plan_mapping(repeats: int) -> dict:
    return {'scene': 'air_23mm_rig', 'factors': {'d_t_mm': [19, 25],
                                                 'pull_speed_mm_s': [1.0, 2.3]},
            'repeats': repeats, 'order': 'random', 'seed': 5}


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_bare(plan, out: Path) -> tuple[float, int, float]:
    """(wall s from the bring-up's start to its exit, trials done, CPU s of its processes)."""
    cpu0 = children_cpu_s()
    start = time.monotonic()
    with mantis('bringup', '--backend', 'sim', '--real-time-factor', '0', '--out', out) \
            as bringup:
        rclpy.init()
        client = TrialClient()
        executor = SingleThreadedExecutor()
        executor.add_node(client)
        spinner = Spinner(executor, 'bench')
        done = 0
        try:
            assert client.wait_for_supervisor(120.0), 'no supervisor:\n' + bringup.tail()
            for trial in plan.trials():
                ok, why = client.set_parameters({**trial.conditions, 'out': str(out)})
                assert ok, why
                started, message, final = client.run_trial(300.0)
                assert started, message
                done += final == 'done'
        finally:
            spinner.stop()
            client.destroy_node()
            rclpy.shutdown()
            bringup.signal_group(signal.SIGINT)
            bringup.finish(60)
    return time.monotonic() - start, done, children_cpu_s() - cpu0


def run_study(plan_path: Path, out: Path) -> tuple[float, int, float]:
    cpu0 = children_cpu_s()
    start = time.monotonic()
    status = subprocess.run(
        mantis_argv('study', plan_path, '--out', out, '--real-time-factor', '0'), cwd=REPO,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False).returncode
    wall = time.monotonic() - start
    assert status == 0, f'mantis study exited {status}'
    rows = read_record(out / 'study.csv').rows
    return wall, sum(r['status'] == 'done' for r in rows), children_cpu_s() - cpu0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=15)
    parser.add_argument('--rounds', type=int, default=1)
    parser.add_argument('--write', action='store_true')
    args = parser.parse_args()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    domain = claim_free_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    import yaml
    mapping = plan_mapping(args.repeats)
    plan = plan_from_mapping(mapping, 'bench')
    trials = len(plan.trials())
    bare, study = [], []
    try:
        with tempfile.TemporaryDirectory(prefix='bench_study_') as tmp:
            tmp = Path(tmp)
            plan_path = tmp / 'plan.yaml'
            plan_path.write_text(yaml.safe_dump(mapping))
            for k in range(args.rounds):
                for name, runs, run, args_ in (('bare', bare, run_bare, (plan, tmp / f'bare{k}')),
                                               ('study', study, run_study,
                                                (plan_path, tmp / f'study{k}'))):
                    wall, done, cpu = run(*args_)
                    runs.append((wall, done, cpu))
                    print(f'{name}: {trials} trials, {done} done, {wall:.1f} s '
                          f'({wall / trials:.2f} s a trial), CPU {cpu:.0f} s '
                          f'({cpu / trials:.2f} s a trial)', flush=True)
    finally:
        release_domain(domain)
    bare_s = statistics.median(w for w, *_ in bare)
    study_s = statistics.median(w for w, *_ in study)
    overhead = study_s / bare_s - 1.0
    print(f'overhead: {100 * overhead:+.1f} % of the bare trials\' wall time (goal: at most 10 %)')
    if args.write:
        write_doc(trials, bare, study, overhead)
    return 0


def write_doc(trials: int, bare: list, study: list, overhead: float) -> None:
    path = REPO / 'docs' / 'performance.md'
    text = path.read_text(encoding='utf-8')
    rows = '\n'.join(f'| {k + 1} | {b[0]:.1f} ({b[0] / trials:.2f}) | {b[2]:.0f} | {b[1]} | '
                     f'{s[0]:.1f} ({s[0] / trials:.2f}) | {s[2]:.0f} | {s[1]} |'
                     for k, (b, s) in enumerate(zip(bare, study)))
    section = (
        f'{SECTION}\n\nWritten by `bench/bench_study.py --write`: {trials} trials of the guide '
        f'distance (19, 25 mm) and the pull speed (1.0, 2.3 mm/s) in a seeded random order on '
        f'the simulated rig at real-time factor 0 in one process; bare (`mantis bringup` and a '
        f'client setting each trial\'s conditions and starting it in the same order) against '
        f'`mantis study` (the twin\'s forecasts, every bag measured and judged, the report), '
        f'each from its start to its exit. {stamp()}.\n\n'
        f'| round | bare: wall s (per trial) | CPU s | done | study: wall s (per trial) | '
        f'CPU s | done |\n|---|---|---|---|---|---|---|\n{rows}\n\n'
        f'The study\'s overhead: **{100 * overhead:+.1f} %** of the bare trials\' wall time '
        f'(goal: at most 10 %).\n')
    pattern = re.compile(rf'{re.escape(SECTION)}\n.*?(?=\n## |\Z)', re.S)
    text = pattern.sub(section.rstrip('\n'), text) if pattern.search(text) \
        else text.rstrip('\n') + '\n\n' + section
    path.write_text(text, encoding='utf-8')
    print(f'wrote {path}')


if __name__ == '__main__':
    sys.exit(main())
