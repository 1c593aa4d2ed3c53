"""`mantis trial` and `mantis bringup`: the rig's node stack from the command line."""
from __future__ import annotations

import math
import os
from pathlib import Path
import re
import sys
import time

from mantis_rig.contract import START_TRIAL, SUPERVISOR_NODE, resolve
from mantis_rig.faults import RIG_FAULT, USAGE_ERROR
from mantis_rig.trial.supervisor_settings import (
    BACKENDS,
    PARAMETERS,
    ConditionError,
    TrialConditions,
    check_value,
)

PROCESSES = ('single', 'multi')
NAMESPACE = re.compile(r'(/[A-Za-z][A-Za-z0-9_]*)+')
STACK_EXIT_STATUSES = (
    f"exit status: 0 done; 1 the trial did not end 'done' (aborted: the reason is in its "
    f"bag); {USAGE_ERROR} bad input (an option, a scene, a parameter); {RIG_FAULT} a rig fault: "
    f"a device or the node stack failed (a node process died, the log could not be written), "
    f"named in one line, the stage stopped first; 130 / 143 interrupted by SIGINT / SIGTERM")


def add_commands(commands) -> None:
    trial = commands.add_parser('trial', help='run one trial on the node stack and log it',
                                epilog=STACK_EXIT_STATUSES)
    _stack_arguments(trial)
    trial.add_argument('--out', type=Path, required=True,
                       help='directory under which the trial gets its bag directory')
    trial.add_argument('--pull-speed', type=float, metavar='MM_PER_S',
                       help='pull speed, mm/s (default: the scene\'s)')
    trial.add_argument('--timeout', type=float, default=600.0,
                       help='give up after this many seconds of wall time (default 600)')
    trial.set_defaults(run=run_trial)

    bringup = commands.add_parser('bringup', help='start the node stack and wait for service '
                                  'calls (/supervisor/start_trial) until Ctrl-C',
                                  epilog=STACK_EXIT_STATUSES)
    _stack_arguments(bringup)
    bringup.add_argument('--out', type=Path, default=Path('trials'),
                         help='directory for the trials\' bags (default trials/)')
    bringup.set_defaults(run=run_bringup, pull_speed=None)


def _stack_arguments(parser) -> None:
    parser.add_argument('--backend', choices=BACKENDS, default='sim',
                        help='device backends (default sim)')
    parser.add_argument('--scene', default='air_23mm_rig',
                        help='simulated scene (default air_23mm_rig; see `mantis scenes`)')
    parser.add_argument('--set', dest='overrides', action='append', default=[],
                        metavar='KEY=VALUE',
                        help='a supervisor parameter (e.g. force_ceiling_n=12, operator_note=...) '
                        'or a scene parameter (e.g. loadcell.noise_N=0.02); repeatable')
    parser.add_argument('--processes', choices=PROCESSES, default='single',
                        help='single: all nodes in this process; multi: the supervisor in a '
                        'process and the rig in its own (sim: one sim_rig process; hardware: one '
                        'per device node)')
    parser.add_argument('--real-time-factor', type=float, default=1.0,
                        help='simulated seconds per wall second (sim backend; default 1; '
                        'simulated time slips when the machine cannot keep up; 0: as fast '
                        'as the stack keeps up, the world waiting for the load cell\'s stream)')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the simulated session (sim backend): sensor noise, and '
                             'the robots drawn from the scene\'s spread (docs/spread.md)')
    parser.add_argument('--namespace', default='', metavar='/NS',
                        help='the rig\'s ROS namespace, e.g. /rig2: every node, topic and '
                        'service under it, so that two rigs share a domain (default: none)')
    parser.add_argument('--log-dir', type=Path,
                        help='with --processes multi: write each node\'s output here')
    parser.add_argument('--live', metavar='[HOST:]PORT',
                        help='serve the trial\'s topics live to Foxglove over WebSocket '
                        '(foxglove-sdk; host 127.0.0.1 unless given; layout: '
                        'config/foxglove/trial_layout.json)')


def _typed(key: str, text: str):
    default = PARAMETERS[key].default
    if isinstance(default, bool):
        if text.lower() not in ('true', 'false', '1', '0', 'yes', 'no'):
            raise ConditionError(f'{key} = {text!r} is not a boolean')
        return text.lower() in ('true', '1', 'yes')
    if isinstance(default, float):
        try:
            return float(text)
        except ValueError:
            raise ConditionError(f'{key} = {text!r} is not a number') from None
    return text


def stack_config(args):
    """A StackConfig from the command line; ConditionError / SceneError say what is wrong."""
    from mantis_rig.stack.bringup import StackConfig

    if not (args.real_time_factor >= 0 and math.isfinite(args.real_time_factor)):
        raise ConditionError(f'--real-time-factor {args.real_time_factor} must be >= 0 (0: as '
                             f'fast as the stack keeps up)')
    supervisor, scene_overrides = {}, []
    for item in args.overrides:
        key, sep, value = item.partition('=')
        if not sep or not key:
            raise ConditionError(f'--set {item!r}: expected KEY=VALUE')
        if key in PARAMETERS:
            supervisor[key] = _typed(key, value)
        else:
            scene_overrides.append(item)
    conditions = {'out': str(args.out), 'backend': args.backend, 'scene': args.scene}
    if args.backend == 'sim':
        from mantis_sim.scene import load_scene
        from mantis_sim.trial_conditions import conditions_of_scene
        scene = load_scene(args.scene, scene_overrides)   # SceneError, ParameterError
        # the trial's conditions are the scene's (the contact angle as recorded: the arm sits
        # at it + the latch offset the robots are drawn with); each set here (--set d_t_mm=19)
        # the supervisor has the simulated world build its robot at (mantis_sim.trial_conditions)
        conditions.update(conditions_of_scene(scene))
    elif scene_overrides:
        raise ConditionError(f'unknown supervisor parameter(s) {scene_overrides} (scene '
                             f'parameters only apply to the sim backend)')
    conditions.update(supervisor)
    if args.pull_speed is not None:
        conditions['pull_speed_mm_s'] = args.pull_speed
    for key, value in conditions.items():
        check_value(key, value)
    TrialConditions.from_mapping(conditions).validate()
    if args.backend == 'sim':
        # conditions the simulated world could not build its robot at are bad input here,
        # before anything starts (ParameterError, naming the condition and why)
        from mantis_sim.trial_conditions import scene_for_conditions
        scene_for_conditions(scene, conditions)
    if args.namespace and not NAMESPACE.fullmatch(args.namespace):
        raise ConditionError(f'--namespace {args.namespace!r}: expected an absolute ROS '
                             f'namespace such as /rig2 (/-separated names of letters, digits '
                             f'and _, each starting with a letter)')
    return StackConfig(backend=args.backend, scene=args.scene, scene_overrides=scene_overrides,
                       seed=args.seed, real_time_factor=args.real_time_factor,
                       processes=args.processes, supervisor=conditions,
                       namespace=args.namespace)


def _ros_session(run, args) -> int:
    config = stack_config(args)      # InputError: cli.main says what is wrong, exit 2
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from mantis_rig.runtime.ros_env import claim_local_domain
    from mantis_rig.runtime.stopping import StopSignals
    claim_local_domain()
    # our handlers, not rclpy's: its handler shuts the context down before the stage's stop and
    # the trial's end could be published
    signals = StopSignals(f'mantis {args.command}').install()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        status = run(config, args, signals)
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    if signals.first is not None:
        # Everything is stopped and closed; the interpreter's own teardown (DDS participants)
        # takes seconds more, which an interrupted operator should not wait for.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


def run_trial(args) -> int:
    return _ros_session(_trial, args)


def run_bringup(args) -> int:
    return _ros_session(_bringup, args)


def _trial(config, args, signals) -> int:
    from mantis_rig.nodes.trial_client import TrialClient
    from mantis_rig.recording.trial_summary import format_summary, summarize
    from mantis_rig.runtime.stopping import StopRequested, say
    from mantis_rig.stack.bringup import Stack, StackError
    from mantis_rig.stack.watchdog import ProcessFault

    relay = _live_relay(args)
    stack = Stack(config, log_dir=args.log_dir)
    signals.emergency_stop = stack.emergency_stop
    client = TrialClient(namespace=config.namespace)
    stack.add_node(client)
    run = _TrialRun()
    try:
        stack.start()
        if relay is not None and stack.rig is not None:
            relay.follow_clock(stack.rig.clock)
        run.follow(client, stack, args.timeout, stopping=lambda: signals.first is not None)
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


def _live_relay(args):
    """The live view, if asked for (LiveError, before anything starts, if it cannot be)."""
    if not args.live:
        return None
    from mantis_rig.live import LiveRelay
    relay = LiveRelay(args.live, namespace=args.namespace or '/')
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
        from mantis_rig.nodes.supervisor_node import LOG_WRITE_FAILED
        from mantis_rig.stack.bringup import StackError
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
        if not _wait_closed(self.bag, 30.0, failed=log_failed):
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


def _wait_closed(bag: Path, timeout_s: float, failed=lambda: False) -> bool:
    deadline = time.monotonic() + timeout_s
    while not (bag / 'metadata.yaml').exists():
        if time.monotonic() > deadline or failed():
            return False
        time.sleep(0.05)
    return True


def _bringup(config, args, signals) -> int:
    from mantis_rig.runtime.stopping import StopRequested, say
    from mantis_rig.stack.bringup import Stack, StackError
    from mantis_rig.stack.watchdog import WATCH_PERIOD_S, ProcessFault

    relay = _live_relay(args)
    stack = Stack(config, log_dir=args.log_dir)
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


__all__ = ['add_commands', 'stack_config']
