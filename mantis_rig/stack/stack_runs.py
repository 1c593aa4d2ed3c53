"""The node stack run for a command: one trial on a stack brought up for it (`mantis trial`),
or the stack held up for service calls until Ctrl-C (`mantis bringup`). Each stops the stage
first on a node process's fault, closes the log and says what happened in one line."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import time

from mantis_rig.contract import START_TRIAL, SUPERVISOR_NODE, resolve
from mantis_rig.recording.bag_metadata import wait_closed


@dataclass(frozen=True)
class StackRunOptions:
    """How a command runs its stack: where node processes write their output (multi-process),
    the live view's [HOST:]PORT (or None), the rig's namespace, and how long a trial may take
    (wall time, s)."""

    log_dir: Path | None = None
    live: str | None = None
    namespace: str = ''
    timeout_s: float = 600.0


def run_one_trial(config, options: StackRunOptions, signals) -> int:
    """`mantis trial`: the stack up, one trial started and followed to its closed log, the
    stack down; the exit status (0 done, 1 not done; StackError for a rig fault)."""
    from mantis_rig.faults import StackError
    from mantis_rig.nodes.trial_client import TrialClient
    from mantis_rig.recording.trial_summary import format_summary, summarize
    from mantis_rig.runtime.stopping import StopRequested, say
    from mantis_rig.stack.bringup import Stack
    from mantis_rig.stack.watchdog import ProcessFault

    relay = _live_relay(options)
    stack = Stack(config, log_dir=options.log_dir)
    signals.emergency_stop = stack.emergency_stop
    client = TrialClient(namespace=config.namespace)
    stack.add_node(client)
    run = _TrialRun()
    try:
        stack.start()
        if relay is not None and stack.rig is not None:
            relay.follow_clock(stack.rig.clock)
        run.follow(client, stack, options.timeout_s, stopping=lambda: signals.first is not None)
    except StopRequested as stop:
        run.reason = stop.reason
    except ProcessFault as fault:     # a node process ended, froze or hung: stop the stage
        run.error, run.stage = fault, stack.fail_safe(fault)
    except StackError as exc:
        run.error = exc
        if run.started:
            client.call('abort', timeout_s=5.0)
            client.wait_for_end(10.0)
    finally:
        signals.shield()
        if run.bag is None and config.processes == 'single' and stack.nodes:
            run.bag = _supervisor_bag(stack)
        # a process fault: stop() gives its line to the supervisor, which aborts the trial
        # with it and closes the log
        stack.stop(reason=run.reason or 'trial ended', signum=_signum(signals))
        client.destroy_node()
        if relay is not None:
            relay.close()
    if signals.first is not None:
        where = f'log closed: {run.bag}' if run.bag else 'no trial had started'
        say(f'mantis trial: {signals.first.reason}: stage stopped; {where}')
        return signals.first.exit_status
    if isinstance(run.error, ProcessFault):
        raise StackError(fault_line(run.error, run.stage, [run.bag] if run.bag else []))
    if run.error is not None:
        raise run.error       # stage stopped, log closed: cli.main says it in one line, exit 3
    print(format_summary(summarize(run.bag), with_path=False))
    return 0 if run.final == 'done' else 1


def _live_relay(options: StackRunOptions):
    """The live view, if asked for (LiveError, before anything starts, if it cannot be)."""
    if not options.live:
        return None
    from mantis_rig.live import LiveRelay
    relay = LiveRelay(options.live, namespace=options.namespace or '/')
    print(f'live view: {relay.url} (Foxglove: Open connection, Foxglove WebSocket; layout '
          f'config/foxglove/trial_layout.json)', flush=True)
    return relay


class _TrialRun:
    """What `mantis trial` has learnt about its trial so far."""

    def __init__(self):
        self.started = False
        self.bag: Path | None = None
        self.final: str | None = None
        self.error: Exception | None = None      # the StackError that ended the trial
        self.stage = ''          # how the stage was stopped after a node process's fault
        self.reason = ''

    def follow(self, client, stack, timeout_s: float, stopping=lambda: False) -> None:
        from mantis_rig.faults import StackError
        from mantis_rig.nodes.supervisor_node import LOG_WRITE_FAILED
        from mantis_rig.stack.watchdog import WATCH_PERIOD_S

        def log_failed() -> bool:
            return client.reason.startswith(LOG_WRITE_FAILED)

        if not client.wait_for_supervisor(60.0, stack.check_processes):
            raise StackError('the supervisor did not come up within 60 s')
        self.started, message = client.start_trial()
        if not self.started:
            raise StackError(f'the supervisor refused to start: {message}')
        self.bag = Path(message.rsplit('logging to ', 1)[-1])
        print(f'bag: {self.bag}', flush=True)
        self.final = client.wait_for_end(timeout_s, alive=stack.check_processes,
                                         check_every_s=WATCH_PERIOD_S)
        if self.final not in (None, 'done') and not stopping():
            _name_a_dying_process(stack, lambda: client.reason)
        if self.final is None:
            client.call('abort', timeout_s=5.0)
            raise StackError(f'no end of trial within {timeout_s} s; aborted')
        if not wait_closed(self.bag, 30.0, failed=log_failed):
            if log_failed():
                raise StackError(client.reason)
            raise StackError(f'the trial ended ({self.final}) but its log {self.bag} was not '
                             f'closed within 30 s')


DYING_PROCESS_GRACE_S = 1.0     # how long an aborted multi-process trial watches its processes
# ... and how long, when the abort says a node process is on its way out (it stopped its stage
# on a signal, or a device node is shutting down): ending takes it longer than the grace on a
# loaded machine (seen: exit 1, the process unnamed)
SHUT_DOWN_NODE_EXIT_S = 15.0
SHUTTING_DOWN = ('shuttingdown', 'finalized')    # lifecycle states of a node going down


def _name_a_dying_process(stack, reason=lambda: '') -> None:
    """A trial aborted because a device node left the active state may have lost it to its
    process going down (killed by its own signal: the supervisor hears the node's transition
    before the process has exited). That is reported as the process's end, not as a device
    fault. Which it was shows only once the process has ended or not, so every aborted trial of
    a stack with node processes watches them for DYING_PROCESS_GRACE_S (an abort for another
    reason is reported that much later), or for up to SHUT_DOWN_NODE_EXIT_S while the abort's
    ``reason()`` (the supervisor's) says a node was shutting down; StackError names a process
    that ended."""
    from mantis_rig.nodes.supervisor_node import left_active
    from mantis_rig.runtime.stopping import PROCESS_STOPPING
    if not stack.processes:
        return
    marks = (*(left_active(state) for state in SHUTTING_DOWN), PROCESS_STOPPING)
    start = time.monotonic()
    while True:
        stack.check_processes()
        waited = time.monotonic() - start
        shutting_down = any(mark in reason() for mark in marks)
        if waited >= (SHUT_DOWN_NODE_EXIT_S if shutting_down else DYING_PROCESS_GRACE_S):
            return
        time.sleep(0.05)


def _supervisor_bag(stack) -> Path | None:
    try:
        return stack.node(SUPERVISOR_NODE).bag_path
    except StopIteration:
        return None


def _signum(signals) -> int:
    import signal
    return signals.first.signum if signals.first is not None else signal.SIGINT


def hold_bringup(config, options: StackRunOptions, signals) -> int:
    """`mantis bringup`: the stack up and watched until a stop signal or a node process's
    fault; the exit status."""
    from mantis_rig.faults import StackError
    from mantis_rig.runtime.stopping import StopRequested, say
    from mantis_rig.stack.bringup import Stack
    from mantis_rig.stack.watchdog import WATCH_PERIOD_S, ProcessFault

    relay = _live_relay(options)
    stack = Stack(config, log_dir=options.log_dir)
    signals.emergency_stop = stack.emergency_stop
    fault, stage, started = None, '', time.time()
    try:
        stack.start()
        if relay is not None and stack.rig is not None:
            relay.follow_clock(stack.rig.clock)
        names = ', '.join(config.node_names())
        start = resolve(START_TRIAL.name, config.namespace)
        print(f'mantis bringup: {names} up ({config.processes} process'
              f'{"es" if config.processes == "multi" else ""}); call {start}; '
              f'Ctrl-C to stop', flush=True)
        while True:
            stack.check_processes()     # ProcessFault: a node process ended, froze or hung
            time.sleep(WATCH_PERIOD_S)
    except StopRequested:
        pass
    except ProcessFault as found:       # stop the stage first, kill a frozen process
        fault, stage = found, stack.fail_safe(found)
    finally:
        signals.shield()
        reason = signals.first.reason if signals.first else 'a node process ended'
        # a process fault: stop() gives its line to the supervisor, which aborts a trial in
        # flight with it and closes the log
        stack.stop(reason=reason, signum=_signum(signals))
        if relay is not None:
            relay.close()
    if signals.first is not None:
        say(f'mantis bringup: {signals.first.reason}: stage stopped, nodes ended')
        return signals.first.exit_status
    if fault is not None:       # cli.main says it in one line, exit 3
        raise StackError(fault_line(fault, stage, _bags_since(config.supervisor.get('out'),
                                                              started)))
    return 0


def fault_line(fault, stage: str, bags) -> str:
    """The one line of a node process's fault: the process and how it ended, froze or hung,
    the stage stopped and the nodes ended, and what became of the trial in flight's bag (the
    last of ``bags``, the trials of this bring-up): closed with the fault as its abort reason,
    or not closed (its recorder, the supervisor, was killed) and recoverable."""
    line = f'{fault.line}; {stage or "stage stopped"}, nodes ended'
    bag = bags[-1] if bags else None
    if bag is None:
        return line
    if not (bag / 'metadata.yaml').exists():
        return (f'{line}; the trial\'s bag {bag} was not closed (its recorder went with '
                f'{fault.name}): recover it with `mantis recover {bag}`')
    outcome = _outcome(bag)
    if outcome.get('result') == 'aborted' and outcome.get('reason') == fault.line:
        return f'{line}; the trial in flight aborted with this reason in its bag {bag}'
    return line


def _outcome(bag: Path) -> dict:
    try:
        from mantis_rig.recording import BagReader
        return BagReader(bag).metadata('trial_outcome') or {}
    except Exception:        # noqa: BLE001 - the line goes out without it
        return {}


def _bags_since(out, since: float) -> list:
    """The trials' bag directories under ``out`` made since ``since`` (wall time), oldest
    first."""
    if not out or not Path(out).is_dir():
        return []
    bags = [p for p in Path(out).glob('trial_*') if p.is_dir() and p.stat().st_mtime >= since]
    return sorted(bags, key=lambda p: p.stat().st_mtime)


__all__ = ['StackRunOptions', 'fault_line', 'hold_bringup', 'run_one_trial']
