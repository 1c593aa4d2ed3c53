"""Fault injection on the rig's node stack (issue 41): one process of a `mantis bringup` killed
(SIGKILL) or frozen (SIGSTOP) while the trial takes up slack, pulls or returns; what became of
the stage, the trial's record, the bring-up and the next bring-up.

Used by test/system/test_faults.py (a representative set of cases) and bench/bench_faults.py
(the whole matrix, written to docs/reliability.md). Needs rclpy initialised by the caller (the
observer node lives in this process, in the caller's ROS domain, which the bring-up inherits).

A case: `Case(layout, process, signum, phase)`. Layouts: ``single`` (the whole stack in the
`mantis` process), ``multi`` (the simulated rig and the supervisor in processes of their own),
``hardware`` (a process per node on the hardware backends: the KDC101 emulator and the nidaqmx
fake, test/hardware_rig.py). Processes: ``mantis`` (the command itself) or a node process's
name. The observer hears the supervisor's state and the stage's joint state directly (not
through the bag, whose recorder may be the process under test); on the hardware layout the
stage is the emulator's, read in this process.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
import shutil
import signal
import tempfile
import threading
import time

from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState
from session_command import SessionCommand, mantis_argv

from mantis_rig import contract
from mantis_rig.nodes.trial_client import TrialClient
from mantis_rig.runtime.process_state import cmdline, running
from mantis_rig.stack.node_table import PROCESS_MODULES

SCENE = 'air_23mm_rig'
TRAVEL_MM = 8.0
INTO_PHASE_S = {'taking_up_slack': 0.15, 'pulling': 0.4, 'returning': 0.2}
FROZEN_HOLD_S = 20.0       # a frozen process is resumed after this long (if still there)
EXIT_WAIT_S = 40.0         # the bring-up must end within this of the fault
LEFT_RUNNING_WAIT_S = 15.0  # node processes whose bring-up was killed end by themselves
AT_REST_M_PER_S = 1e-6
PHASES = ('taking_up_slack', 'pulling', 'returning')
SIGNALS = {'SIGKILL': signal.SIGKILL, 'SIGSTOP': signal.SIGSTOP}


@dataclass(frozen=True)
class Case:
    layout: str            # 'single' or 'multi'
    process: str           # 'mantis' or a node process's name
    signal: str            # 'SIGKILL' or 'SIGSTOP'
    phase: str             # 'taking_up_slack', 'pulling' or 'returning'

    @property
    def id(self) -> str:
        return f'{self.layout}-{self.process}-{self.signal}-{self.phase}'


LAYOUTS = ('single', 'multi', 'hardware')


def processes_of(layout: str) -> list:
    if layout == 'hardware':
        return ['mantis', *contract.DEVICE_NODES, contract.SUPERVISOR_NODE]
    return ['mantis'] + (['sim_rig', contract.SUPERVISOR_NODE] if layout == 'multi' else [])


def matrix(layouts=LAYOUTS) -> list:
    """Every process of each layout, SIGKILL and SIGSTOP, in each phase."""
    return [Case(layout, process, sig, phase) for layout in layouts
            for process in processes_of(layout) for sig in SIGNALS for phase in PHASES]


@dataclass
class Result:
    case: Case
    bound_mm: float | None = None        # the phase's bound: start + travel (pulls), the start
    past_bound_mm: float | None = None   # how far the stage went past it (0: not past)
    stop_s: float | None = None          # from the fault to the stage at rest (wall time)
    stage_note: str = ''
    record: str = ''                     # the trial's bag: outcome and reason, or recoverable
    record_ok: bool = False
    exit_status: int | None = None
    line: str = ''
    left_running: list = field(default_factory=list)
    next_trial: str = ''                 # the next bring-up's trial: its end state
    wall_s: float = 0.0

    @property
    def ok(self) -> bool:
        return (self.past_bound_mm is not None and self.past_bound_mm <= 0.0
                and self.record_ok and not self.left_running and self.next_trial == 'done')


class Observer:
    """The stage's joint state and the supervisor's states, heard from this process."""

    def __init__(self):
        self.client = TrialClient(node_name='fault_observer')
        self.samples: list[tuple[float, float, float]] = []     # (wall, position m, velocity)
        self.phase_at: dict[str, float] = {}
        self._lock = threading.Lock()
        self.client.create_subscription(JointState, contract.JOINT_STATE.name, self._on_joint,
                                        contract.JOINT_STATE.qos.subscriber())
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.client)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _on_joint(self, msg) -> None:
        if msg.position:
            with self._lock:
                self.samples.append((time.monotonic(), msg.position[0],
                                     msg.velocity[0] if msg.velocity else 0.0))

    def position_at(self, t: float) -> float | None:
        with self._lock:
            before = [p for w, p, _ in self.samples if w <= t]
        return before[-1] if before else None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.executor.shutdown(timeout_sec=0)
        self.client.destroy_node()


class Bringup(SessionCommand):
    """`mantis bringup` in a session of its own, its output collected."""

    def __init__(self, layout: str, out: Path, extra=(), hardware=None):
        self.out = out
        common = ['--out', str(out), '--log-dir', str(out / 'logs'), *extra]
        if hardware is not None:
            from hardware_rig import START_MM
            super().__init__(hardware.command(['bringup', '--backend', 'hardware',
                                               '--processes', 'multi', '--set',
                                               f'start_position_mm={START_MM}', *common]),
                             env=hardware.env())
        else:
            super().__init__(mantis_argv('bringup', '--backend', 'sim', '--scene', SCENE,
                                         '--processes', layout, *common))

    def pid_of(self, name: str) -> int:
        if name == 'mantis':
            return self.pid
        for pid in self.children():
            if PROCESS_MODULES[name] in cmdline(pid):
                return pid
        raise LookupError(f'no {name} process under {self.pid}')

    def line(self) -> str:
        ours = [line for line in self.stderr if line.startswith('mantis bringup: ')]
        return ours[-1] if ours else ''


def run_trial_to_end(observer: Observer, timeout_s: float = 240.0) -> str:
    client = observer.client
    if not client.wait_for_supervisor(90.0):
        return 'no supervisor'
    ok, message = client.start_trial()
    if not ok:
        return f'refused: {message}'
    return client.wait_for_end(timeout_s) or 'no end'


def next_bringup_runs_a_trial(layout: str, out: Path, hardware=None) -> str:
    """A fresh bring-up of the layout runs one trial: its end state ('done' is the goal). In
    real time: at real-time factor 0 on a loaded machine (the suite's workers) the one process
    starved the stage's force subscription past its 0.5 s stale-force guard."""
    rig = Bringup(layout, out, hardware=hardware)
    observer = Observer()
    try:
        final = run_trial_to_end(observer)
        if final != 'done':
            final = f'{final}: {observer.client.reason}'
        rig.note_tree()
        rig.signal(signal.SIGINT)
        status = rig.wait(30.0)
        if status != 130:
            final += f' (the bring-up then exited {status})'
        return final
    finally:
        observer.close()
        rig.kill()


def run_case(case: Case, work: Path, next_trial: bool = True) -> Result:
    """Bring the stack up, start a trial, inject the fault in its phase, and look."""
    started = time.monotonic()
    result = Result(case)
    out = work / case.id
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    hardware = None
    if case.layout == 'hardware':
        from hardware_rig import HardwareRig
        hardware = HardwareRig(out)
    rig = Bringup(case.layout, out, hardware=hardware)
    observer = Observer()
    samples = hardware.samples if hardware is not None else observer.samples
    resumed = threading.Event()
    try:
        client = observer.client
        assert client.wait_for_supervisor(90.0), 'no supervisor:\n' + '\n'.join(rig.stderr)
        ok, message = client.start_trial()
        assert ok, message
        bag = Path(message.rsplit('logging to ', 1)[-1])
        trial_start_pos = None
        after = client.trial_start
        if case.phase == 'returning':    # the return after the pull, not a move to the start
            assert client.wait_for_state(('pulling',), after, 120.0) == 'pulling', \
                f'the trial never pulled: {client.states[after:]} {client.reason}'
            after = max(i for i, s in enumerate(client.states) if s == 'pulling')
        phase = client.wait_for_state((case.phase,), after, 120.0)
        assert phase == case.phase, f'the trial never reached {case.phase}: ' \
            f'{client.states[client.trial_start:]} {client.reason}'
        phase_start = time.monotonic()
        trial_start_pos = _trial_start(client, samples, hardware)
        time.sleep(INTO_PHASE_S[case.phase])
        rig.note_tree()
        target = rig.pid_of(case.process)
        phase_pos = _position_at(samples, phase_start)
        fault_at = time.monotonic()
        os.kill(target, SIGNALS[case.signal])
        if case.signal == 'SIGSTOP':
            def resume():       # a frozen process left alone by the stack is resumed later
                if not resumed.wait(FROZEN_HOLD_S):
                    try:
                        os.kill(target, signal.SIGCONT)
                    except ProcessLookupError:
                        pass
            threading.Thread(target=resume, daemon=True).start()
        if case.layout == 'single' and case.signal == 'SIGSTOP':
            # nothing is left to notice: the whole stack is frozen with its stage (simulated)
            status = rig.wait(FROZEN_HOLD_S + 5.0)
            if status is None:     # resumed: the trial goes on; end the bring-up as a user
                client.wait_for_end(120.0)
                rig.signal(signal.SIGINT)
                status = rig.wait(30.0)
        else:
            status = rig.wait(EXIT_WAIT_S)
        resumed.set()
        result.exit_status = status
        result.line = rig.line()
        if status is None:
            result.line = result.line or 'the bring-up did not end'
        rig.note_tree()
        deadline = time.monotonic() + LEFT_RUNNING_WAIT_S   # node processes ending on their own
        while any(running(pid) for pid in rig.tree) and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)                                     # the last joint states heard
        _stage_figures(result, list(samples), case, fault_at, phase_pos, trial_start_pos)
        result.left_running = [f'{pid} {cmdline(pid)[:60]}' for pid in rig.tree
                               if running(pid)] + (['mantis'] if rig.process.poll() is None
                                                   else [])
        result.record, result.record_ok = _record(bag, work)
        if result.past_bound_mm is None:      # this process heard nothing of the stage
            _bound_from_the_bag(result, bag, work, case)
    finally:
        resumed.set()
        observer.close()
        rig.kill()
        if hardware is not None and not next_trial:
            hardware.close()
    if next_trial:
        try:
            result.next_trial = next_bringup_runs_a_trial(case.layout, out / 'next', hardware)
        finally:
            if hardware is not None:
                hardware.close()
    result.wall_s = time.monotonic() - started
    return result


def _position_at(samples, t: float) -> float | None:
    before = [p for w, p, _ in list(samples) if w <= t]
    return before[-1] if before else None


def _trial_start(client, samples, hardware) -> float | None:
    """The trial's start position: where the stage is taken before the trial (hardware: the
    start_position_mm given), or where the first joint state heard had it."""
    if hardware is not None:
        from hardware_rig import START_MM
        return START_MM * 1e-3
    samples = list(samples)
    return samples[0][1] if samples else None


def _stage_figures(result, samples, case, fault_at, phase_pos, trial_start_pos) -> None:
    after = [(w, p, v) for w, p, v in samples if w >= fault_at]
    before = [(w, p, v) for w, p, v in samples if w < fault_at]
    if not samples:
        result.stage_note = 'not heard by the observer'
        return
    if phase_pos is None and before:
        phase_pos = before[-1][1]
    if case.phase == 'returning':
        bound = trial_start_pos
        positions = [p for _, p, _ in after] or [before[-1][1]]
        past = None if bound is None else max(0.0, (bound - min(positions)) * 1e3)
    else:
        bound = None if phase_pos is None else phase_pos + TRAVEL_MM * 1e-3
        positions = [p for _, p, _ in after] or [before[-1][1]]
        past = None if bound is None else max(0.0, (max(positions) - bound) * 1e3)
    result.bound_mm = None if bound is None else bound * 1e3
    result.past_bound_mm = None if past is None else round(past, 3)
    moving = [i for i, (_, _, v) in enumerate(after) if abs(v) >= AT_REST_M_PER_S]
    rest = None
    if after and (not moving or moving[-1] + 1 < len(after)):   # at rest from then on
        rest = after[moving[-1] + 1][0] if moving else after[0][0]
    if rest is not None:
        result.stop_s = rest - fault_at
        result.stage_note = f'at rest at {after[-1][1] * 1e3:.3f} mm'
    elif after:
        result.stop_s = after[-1][0] - fault_at
        result.stage_note = (f'last heard at {after[-1][1] * 1e3:.3f} mm, moving (simulated: '
                             f'it stopped with its process)')
    else:
        result.stop_s = 0.0
        last = before[-1][1] * 1e3 if before else float('nan')
        result.stage_note = f'not heard after the fault (stood at {last:.3f} mm, simulated ' \
                            f'with its process)'


def _record(bag: Path, work: Path) -> tuple[str, bool]:
    """The trial's record: the outcome in its closed bag, or what `mantis recover` makes of an
    unclosed one (its messages, the last trial state in them)."""
    from mantis_rig.recording import BagReader
    from mantis_rig.recording.recover import recover_bag
    if not bag.exists():
        return 'no bag', False
    if (bag / 'metadata.yaml').exists():
        outcome = BagReader(bag).metadata('trial_outcome') or {}
        result = outcome.get('result', '?')
        return f'{result}: {outcome.get("reason", "")}', result in ('aborted', 'completed')
    output = Path(tempfile.mkdtemp(dir=work, prefix='recovered_')) / bag.name
    try:
        report = recover_bag(bag, output)
    except Exception as exc:          # noqa: BLE001 - the table says so
        return f'not closed; mantis recover failed: {exc}', False
    states = [m.message.data for m in BagReader(output).messages(
        [contract.resolve(contract.SUPERVISOR_STATE)])]
    return (f'not closed; mantis recover: {report.messages_recovered} messages, last state '
            f'{states[-1] if states else "?"}', report.messages_recovered > 0)


def _bound_from_the_bag(result, bag: Path, work: Path, case: Case) -> None:
    """The travel past the bound from the trial's own bag (its joint states, rig time), when
    the observer heard none: the bound from where the stage was when the phase began."""
    from mantis_rig.recording import BagReader
    readable = bag if (bag / 'metadata.yaml').exists() else \
        next(iter(sorted(work.glob(f'recovered_*/{bag.name}'))), None)
    if readable is None:
        return
    reader = BagReader(readable)
    joints = [(m.log_time_ns, m.message.position[0]) for m in
              reader.messages([contract.resolve(contract.JOINT_STATE)]) if m.message.position]
    states = [(m.log_time_ns, m.message.data) for m in
              reader.messages([contract.resolve(contract.SUPERVISOR_STATE)])]
    began = next((t for t, state in states if state == case.phase), None)
    if began is None or not joints:
        return
    at = [p for t, p in joints if t <= began] or [joints[0][1]]
    later = [p for t, p in joints if t >= began] or [at[-1]]
    if case.phase == 'returning':
        bound = joints[0][1]
        past = max(0.0, (bound - min(later)) * 1e3)
    else:
        bound = at[-1] + TRAVEL_MM * 1e-3
        past = max(0.0, (max(later) - bound) * 1e3)
    result.bound_mm, result.past_bound_mm = bound * 1e3, round(past, 3)
    result.stage_note += f'; from its bag: at most {max(later) * 1e3:.3f} mm after the phase began'
