"""Where the test suite's time goes, per test module:

    .venv/bin/python bench/bench_suite_time.py [--workers 2] [--out FILE.md] [--json FILE.json]
                                               [--raw-dir DIR] [-- PYTEST ARGS...]
    .venv/bin/python bench/bench_suite_time.py --from-raw DIR [--out FILE.md] [--json FILE.json]

Runs the suite as scripts/test.sh does (`python -m pytest -q -n 2 --dist loadfile
--no-loadscope-reorder`, in the environment of scripts/ros_env.sh; not the bootstrap, ruff or
`mantis doctor`), with this file loaded as a pytest plugin (``-p bench_suite_time``) in every
xdist worker. ``--workers 0``: one process, no xdist (e.g. ``--workers 0 -- test/unit``, the
inner loop). Arguments after ``--`` go to pytest (default: the whole suite).

Per test the plugin writes one JSON line to ``<raw dir>/<worker>.jsonl`` (a worker that dies
leaves what it wrote); this script merges them and prints, per module, sorted by wall time:

* **wall**: from its first test's start to its last test's end, in the worker that ran it
  (``--dist loadfile`` runs a module whole in one worker); module fixtures set up in the first
  test and torn down in the last are inside it;
* **CPU**: user + system of the worker process (all its threads: rclpy executors, node
  threads of the tests' stacks) plus that of its children reaped meanwhile
  (``resource.getrusage`` SELF and CHILDREN deltas around each test). A child still running at
  a test's end is counted in the test during which it is reaped; one never reaped (and the
  work of processes that are not the worker's children) is not counted at all;
* **tests**, and the sum of pytest's per-phase durations (setup / call / teardown);
* **waits on**: inferred where the module mostly waits (CPU / wall < 0.5) from what the plugin
  measured in the test's own thread: wall time in ``subprocess.Popen.wait`` / ``communicate``
  (child processes) and in ``time.sleep`` (polls, timed waits; a module that bound ``sleep``
  before the plugin loaded escapes it), and from the ``ros`` marker (DDS discovery, executors,
  callbacks on other threads); a '?' where what it waits on was not measured; empty where the
  module is CPU-bound.

``--out FILE`` writes the Markdown table (its caption: bench/machine.py's stamp(), the commit
and the yardstick); ``--write HEADING`` puts it in docs/testing.md under ``## HEADING``;
``--json FILE`` the merged records and every test's line.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
from pathlib import Path
import resource
import shlex
import subprocess
import sys
import tempfile
import threading
import time

REPO = Path(__file__).resolve().parents[1]
RAW_DIR_ENV = 'MANTIS_SUITE_TIME_DIR'      # set for the workers: where they write their lines
LAYERS = ('unit', 'ros', 'system')
MOSTLY_WAITS = 0.5                         # CPU / wall below this: the module mostly waits
SHOWN_SHARE = 0.10                         # a wait named in 'waits on' takes this much of wall


# ============================================================================ the pytest plugin
class _Waits(threading.local):
    depth = 0


_waits = _Waits()
_waited = {'sleep': 0.0, 'subprocess': 0.0}     # wall s, in the main (test) thread
_main_thread = threading.main_thread()


def _timed(kind: str, function):
    """``function``, with the wall time of its outermost calls from the main thread added to
    _waited[kind] (communicate calls wait: counted once)."""
    def timed(*args, **kwargs):
        if threading.current_thread() is not _main_thread or _waits.depth:
            return function(*args, **kwargs)
        _waits.depth += 1
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            _waited[kind] += time.perf_counter() - start
            _waits.depth -= 1
    timed.__wrapped__ = function
    return timed


def _cpu_s(who: int) -> float:
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


class _Recorder:
    """Writes one JSON line per test (this worker's file in the raw directory)."""

    def __init__(self, directory: Path):
        self.worker = os.environ.get('PYTEST_XDIST_WORKER', 'main')
        directory.mkdir(parents=True, exist_ok=True)
        self._file = open(directory / f'{self.worker}.jsonl', 'a', encoding='utf-8')
        self._phases: dict[str, dict] = {}
        self._outcomes: dict[str, list] = {}

    def around(self, item):
        """Generator for the runtest_protocol hookwrapper."""
        waited = dict(_waited)
        self_cpu, children_cpu = _cpu_s(resource.RUSAGE_SELF), _cpu_s(resource.RUSAGE_CHILDREN)
        start, perf = time.time(), time.perf_counter()
        yield
        wall = time.perf_counter() - perf
        path = item.nodeid.split('::', 1)[0]
        parts = Path(path).parts
        self._write({
            'worker': self.worker, 'module': path, 'nodeid': item.nodeid,
            'layer': parts[1] if len(parts) > 2 and parts[1] in LAYERS else '',
            'start': start, 'end': start + wall, 'wall_s': wall,
            'cpu_self_s': _cpu_s(resource.RUSAGE_SELF) - self_cpu,
            'cpu_children_s': _cpu_s(resource.RUSAGE_CHILDREN) - children_cpu,
            'phases_s': self._phases.pop(item.nodeid, {}),
            'outcome': self._outcome(self._outcomes.pop(item.nodeid, [])),
            'markers': sorted({mark.name for mark in item.iter_markers()}),
            'sleep_s': _waited['sleep'] - waited['sleep'],
            'subprocess_wait_s': _waited['subprocess'] - waited['subprocess'],
        })

    def logreport(self, report) -> None:
        phases = self._phases.setdefault(report.nodeid, {})
        phases[report.when] = phases.get(report.when, 0.0) + report.duration
        self._outcomes.setdefault(report.nodeid, []).append((report.when, report.outcome))

    @staticmethod
    def _outcome(reports) -> str:
        outcomes = [outcome for _, outcome in reports]
        if 'failed' in outcomes:
            return 'error' if ('call', 'failed') not in reports else 'failed'
        return 'skipped' if 'skipped' in outcomes else 'passed'

    def _write(self, record: dict) -> None:
        self._file.write(json.dumps(record) + '\n')
        self._file.flush()

    def close(self) -> None:
        self._file.close()


_recorder: _Recorder | None = None


def pytest_configure(config):
    global _recorder
    directory = os.environ.get(RAW_DIR_ENV)
    if not directory or _recorder is not None:
        return
    if getattr(config, 'workerinput', None) is None and config.getoption('numprocesses', None):
        return            # the xdist controller runs no tests: its workers record them
    _recorder = _Recorder(Path(directory))
    time.sleep = _timed('sleep', time.sleep)
    subprocess.Popen.wait = _timed('subprocess', subprocess.Popen.wait)
    subprocess.Popen.communicate = _timed('subprocess', subprocess.Popen.communicate)


def pytest_unconfigure(config):
    if _recorder is not None:
        _recorder.close()


def _hookwrapper(function):
    import pytest
    return pytest.hookimpl(hookwrapper=True)(function)


@_hookwrapper
def pytest_runtest_protocol(item, nextitem):
    if _recorder is None:
        yield
        return
    yield from _recorder.around(item)


def pytest_runtest_logreport(report):
    if _recorder is not None:
        _recorder.logreport(report)


# ============================================================================ merging
def read_raw(directory: Path) -> list[dict]:
    tests = []
    for path in sorted(directory.glob('*.jsonl')):
        for line in path.read_text(encoding='utf-8').splitlines():
            if line.strip():
                tests.append(json.loads(line))
    return tests


def per_module(tests: list[dict]) -> list[dict]:
    by_module: dict[str, list[dict]] = collections.defaultdict(list)
    for test in tests:
        by_module[test['module']].append(test)
    modules = []
    for name, rows in by_module.items():
        phases = collections.Counter()
        for row in rows:
            phases.update(row['phases_s'])
        outcomes = collections.Counter(row['outcome'] for row in rows)
        modules.append({
            'module': name, 'layer': rows[0]['layer'],
            'workers': sorted({row['worker'] for row in rows}),
            'tests': len(rows),
            'wall_s': max(row['end'] for row in rows) - min(row['start'] for row in rows),
            'tests_wall_s': sum(row['wall_s'] for row in rows),
            'cpu_s': sum(row['cpu_self_s'] + row['cpu_children_s'] for row in rows),
            'cpu_children_s': sum(row['cpu_children_s'] for row in rows),
            'phases_s': {phase: phases.get(phase, 0.0) for phase in ('setup', 'call', 'teardown')},
            'sleep_s': sum(row['sleep_s'] for row in rows),
            'subprocess_wait_s': sum(row['subprocess_wait_s'] for row in rows),
            'markers': sorted({mark for row in rows for mark in row['markers']}),
            'outcomes': dict(outcomes),
        })
    modules.sort(key=lambda m: -m['wall_s'])
    for module in modules:
        module['waits_on'] = waits_on(module)
    return modules


def waits_on(module: dict) -> str:
    """What a module that mostly waits waits on, from what was measured; '' if CPU-bound."""
    wall = module['wall_s']
    if wall <= 0 or module['cpu_s'] / wall >= MOSTLY_WAITS:
        return ''
    parts = []
    for key, what in (('subprocess_wait_s', 'child processes'), ('sleep_s', 'sleeps/polls')):
        if module[key] >= SHOWN_SHARE * wall:
            parts.append(f'{what} {module[key] / wall:.0%}')
    # what neither explains (the worker's own CPU overlaps its waits; its children's, the
    # wait for them): other threads' results, DDS, a timeout
    rest = (wall - module['subprocess_wait_s'] - module['sleep_s']
            - (module['cpu_s'] - module['cpu_children_s']))
    if rest >= SHOWN_SHARE * wall:
        ros = 'ros' in module['markers'] or module['layer'] == 'ros'
        parts.append(f'{"ROS (DDS, executors)?" if ros else "?"} {rest / wall:.0%}')
    return ', '.join(parts)


def markdown(modules: list[dict], caption: str, limit: int | None = None) -> str:
    lines = [caption, '',
             '| module | layer | tests | wall (s) | CPU (s) | CPU / wall | setup / call / '
             'teardown (s) | waits on |',
             '|---|---|---:|---:|---:|---:|---|---|']
    for m in modules[:limit]:
        phases = ' / '.join(f'{m["phases_s"][p]:.1f}' for p in ('setup', 'call', 'teardown'))
        name = m['module'].removeprefix('test/')
        failed = sum(n for outcome, n in m['outcomes'].items() if outcome in ('failed', 'error'))
        tests = f'{m["tests"]}' + (f' ({failed} failed)' if failed else '')
        lines.append(f'| `{name}` | {m["layer"] or "-"} | {tests} | {m["wall_s"]:.1f} | '
                     f'{m["cpu_s"]:.1f} | {m["cpu_s"] / m["wall_s"] if m["wall_s"] else 0:.2f} | '
                     f'{phases} | {m["waits_on"]} |')
    return '\n'.join(lines) + '\n'


def layer_totals(modules: list[dict]) -> str:
    lines = []
    for layer in (*LAYERS, ''):
        chosen = [m for m in modules if m['layer'] == layer]
        if chosen:
            lines.append(f'{layer or "(no layer)"}: {len(chosen)} modules, '
                         f'{sum(m["tests"] for m in chosen)} tests, '
                         f'{sum(m["wall_s"] for m in chosen):.1f} s of module wall, '
                         f'{sum(m["cpu_s"] for m in chosen):.1f} CPU s')
    return '\n'.join(lines)


# ============================================================================ the run
def run_suite(workers: int, pytest_args: list[str], raw_dir: Path) -> tuple[int, float, str]:
    """(pytest's exit status, wall s, the command) of the suite run with the plugin."""
    xdist = ['-n', str(workers), '--dist', 'loadfile', '--no-loadscope-reorder'] if workers \
        else []
    pytest = [sys.executable, '-m', 'pytest', '-q', *xdist, '-p', Path(__file__).stem,
              *pytest_args]
    command = f'. scripts/ros_env.sh && exec {shlex.join(pytest)}'
    env = {**os.environ, RAW_DIR_ENV: str(raw_dir),
           'PYTHONPATH': os.pathsep.join(filter(None, [str(Path(__file__).resolve().parent),
                                                       os.environ.get('PYTHONPATH')]))}
    start = time.perf_counter()
    status = subprocess.run(['bash', '-c', command], cwd=REPO, env=env).returncode
    return status, time.perf_counter() - start, shlex.join(pytest)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workers', type=int,
                        default=int(os.environ.get('MANTIS_TEST_WORKERS', '2')),
                        help='xdist workers as scripts/test.sh (default 2); 0: no xdist')
    parser.add_argument('--raw-dir', type=Path,
                        help='where the workers write their JSON lines (default: a new '
                             'temporary directory)')
    parser.add_argument('--from-raw', type=Path, metavar='DIR',
                        help='do not run: merge the lines a run left in DIR')
    parser.add_argument('--out', type=Path, help='write the Markdown table here')
    parser.add_argument('--json', type=Path, help='write the merged records here')
    parser.add_argument('--top', type=int, help='print only the first N modules')
    parser.add_argument('--write', metavar='HEADING',
                        help="also put the table in docs/testing.md under '## HEADING'")
    parser.add_argument('pytest_args', nargs='*', help='after --: arguments for pytest')
    args = parser.parse_args()
    sys.path.insert(0, str(REPO))
    from bench.machine import stamp, yardstick_s

    run = {}
    if args.from_raw:
        raw_dir = args.from_raw
    else:
        raw_dir = args.raw_dir or Path(tempfile.mkdtemp(prefix='suite_time_'))
        if any(raw_dir.glob('*.jsonl')):
            parser.error(f'{raw_dir} already holds a run\'s lines (--from-raw to merge them)')
        yardstick_before = yardstick_s()
        status, wall, command = run_suite(args.workers, args.pytest_args, raw_dir)
        run = {'command': command, 'workers': args.workers, 'exit_status': status,
               'wall_s': wall, 'yardstick_before_s': yardstick_before}
    tests = read_raw(raw_dir)
    if not tests:
        print(f'no test recorded in {raw_dir}', file=sys.stderr)
        return 1
    modules = per_module(tests)
    caption = stamp()
    if run:
        caption = (f'{caption} (before the run {run["yardstick_before_s"]:.2f} s); '
                   f'`{run["command"]}` with scripts/ros_env.sh: {run["wall_s"]:.0f} s wall, '
                   f'exit status {run["exit_status"]}; {len(tests)} tests in {len(modules)} '
                   f'modules')
    table = markdown(modules, caption)
    print(markdown(modules, caption, args.top), end='')
    print()
    print(layer_totals(modules))
    print(f'raw lines: {raw_dir}')
    if args.out:
        args.out.write_text(table + '\n' + layer_totals(modules) + '\n', encoding='utf-8')
    if args.write:
        from bench.machine import replace_section
        replace_section(REPO / 'docs' / 'testing.md', f'## {args.write}',
                        table + '\n' + layer_totals(modules) + '\n')
    if args.json:
        args.json.write_text(json.dumps({'caption': caption, **run, 'raw_dir': str(raw_dir),
                                         'modules': modules, 'tests': tests}, indent=1),
                             encoding='utf-8')
    return run.get('exit_status', 0)


if __name__ == '__main__':
    sys.exit(main())
