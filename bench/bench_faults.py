"""Fault injection, the whole matrix (issue 41): every process of the stack, SIGKILL and
SIGSTOP, while the trial takes up slack, pulls and returns: both layouts of the simulated rig,
and the hardware layout on the KDC101 emulator and the nidaqmx fake (test/hardware_rig.py).

    .venv/bin/python bench/bench_faults.py [--layouts single multi hardware] [--processes ...]
                                           [--signals SIGKILL SIGSTOP] [--phases ...]
                                           [--no-next] [--write] [--keep DIR]

Each case brings `mantis bringup` up (sim: real time, scene air_23mm_rig), starts a
trial, sends the signal to the process in the phase (test/fault_injection.py: 0.15 s into
taking up slack, 0.4 s into the pull, 0.2 s into the return), and reports: the stage's travel
past its bound (the pull's start + travel_mm; the start for a return), the time from the fault
to the stage at rest, the trial's record (its bag's outcome, or what `mantis recover` makes of
it), the bring-up's exit status and line, what is left running, and the end of a trial on the
next bring-up (`--real-time-factor 0`). A frozen process the stack leaves alone is resumed
after 20 s. With --write the table goes into docs/reliability.md with the commit and the
yardstick (bench/machine.py).
"""
import argparse
import os
from pathlib import Path
import sys
import tempfile

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'test'))
# as the test suite does (test/conftest.py): shared-memory ports of killed processes can leave
# a later participant matched but deaf
os.environ['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'

from fault_injection import LAYOUTS, PHASES, SIGNALS, matrix, run_case  # noqa: E402
import rclpy  # noqa: E402

from bench.machine import stamp  # noqa: E402
from mantis_rig.runtime.ros_env import claim_free_domain, release_domain  # noqa: E402

DOC = REPO / 'docs' / 'reliability.md'
BEGIN, END = '<!-- bench_faults: begin -->', '<!-- bench_faults: end -->'
HEADER = ('| layout | process | signal | phase | past bound (mm) | stop (s) | stage | trial record '
          '| exit | line | left running | next trial | ok |\n'
          '|---|---|---|---|---:|---:|---|---|---:|---|---|---|---|')


def row(result) -> str:
    c = result.case

    def cell(text) -> str:
        return str(text).replace('|', '\\|').replace('\n', ' ') or '-'
    past = '-' if result.past_bound_mm is None else f'{result.past_bound_mm:.3f}'
    stop = '-' if result.stop_s is None else f'{result.stop_s:.2f}'
    return (f'| {c.layout} | {c.process} | {c.signal} | {c.phase} | {past} | {stop} | '
            f'{cell(result.stage_note)} | {cell(result.record)} | {result.exit_status} | '
            f'{cell(result.line)} | {cell(", ".join(result.left_running) or "nothing")} | '
            f'{cell(result.next_trial)} | {"yes" if result.ok else "**no**"} |')


def write(rows: list) -> None:
    table = f'{stamp()}\n\n{HEADER}\n' + '\n'.join(rows) + '\n'
    text = DOC.read_text(encoding='utf-8')
    head, _, rest = text.partition(BEGIN)
    _, _, tail = rest.partition(END)
    DOC.write_text(f'{head}{BEGIN}\n{table}{END}{tail}', encoding='utf-8')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--layouts', nargs='+', choices=LAYOUTS, default=list(LAYOUTS))
    parser.add_argument('--processes', nargs='+', help='only these processes (default: all)')
    parser.add_argument('--signals', nargs='+', default=list(SIGNALS))
    parser.add_argument('--phases', nargs='+', default=list(PHASES))
    parser.add_argument('--no-next', action='store_true',
                        help='skip the next bring-up\'s trial')
    parser.add_argument('--write', action='store_true', help='write docs/reliability.md')
    parser.add_argument('--keep', type=Path, help='keep the bags under this directory')
    parser.add_argument('--rows-from', type=Path, help='an earlier run\'s output: its table rows '
                        'go first, and its cases are not run again')
    args = parser.parse_args()
    earlier = [line.split('  (')[0] for line in args.rows_from.read_text().splitlines()
               if line.startswith('| ') and not line.startswith('| layout')] \
        if args.rows_from else []
    done = {tuple(cell.strip() for cell in line.split('|')[1:5]) for line in earlier}
    cases = [c for c in matrix() if c.layout in args.layouts and c.signal in args.signals
             and c.phase in args.phases
             and (not args.processes or c.process in args.processes)
             and (c.layout, c.process, c.signal, c.phase) not in done]
    domain = claim_free_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    work = Path(tempfile.mkdtemp(prefix='faults_', dir=args.keep))
    rclpy.init()
    rows, failed = list(earlier), sum('**no**' in line for line in earlier)
    try:
        print(HEADER, flush=True)
        for case in cases:
            try:
                result = run_case(case, work, next_trial=not args.no_next)
            except Exception as exc:       # noqa: BLE001 - the next case runs all the same
                print(f'{case.id}: could not be run: {exc!r}', flush=True)
                failed += 1
                continue
            rows.append(row(result))
            failed += not result.ok
            print(rows[-1] + f'  ({result.wall_s:.0f} s)', flush=True)
    finally:
        rclpy.try_shutdown()
        release_domain(domain)
    if args.write:
        write(rows)
    print(f'{len(rows) - failed} of {len(rows)} cases ok; bags under {work}')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
