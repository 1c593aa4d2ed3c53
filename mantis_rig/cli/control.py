"""`mantis start`, `mantis abort`, `mantis state`: drive a rig that is already running (brought
up by `mantis bringup`, the launch file or `ros2 run`) over its supervisor's services and topics.

The rig is reached in the ROS domain of the environment: a ROS_DOMAIN_ID already set (by
`. scripts/ros_env.sh`, or by hand) is kept, as `claim_local_domain` keeps it, so run these in
the shell that brought the rig up, or with its ROS_DOMAIN_ID. Without one, the command claims a
free domain of its own like every mantis command, where no rig runs: it then says so, with the
other unreachable cases, in one line (exit 3).
"""
from __future__ import annotations

import json
from pathlib import Path
import sys
import time

from mantis_rig.cli.options import ROS_NAMESPACE, supervisor_value
from mantis_rig.faults import RIG_FAULT, USAGE_ERROR, StackError
from mantis_rig.trial.supervisor_settings import (
    PARAMETERS,
    ConditionError,
    TrialConditions,
    check_value,
)

REACH_TIMEOUT_S = 10.0        # default: how long the supervisor has to answer
STATUS_WAIT_S = 5.0           # how long the supervisor's status may lag behind its state
EXIT_STATUSES = (
    f"exit status: 0 done (start: started, without --wait); 1 the trial ended aborted, or the "
    f"supervisor refused (a trial in progress; no trial to abort); {USAGE_ERROR} bad input (an "
    f"unknown parameter, a value out of range); {RIG_FAULT} no supervisor answered (the rig is "
    f"not up, another namespace, another ROS_DOMAIN_ID)")


def add_commands(commands) -> None:
    start = commands.add_parser(
        'start', help='start a trial on a running rig (mantis bringup) and print its bag',
        epilog=EXIT_STATUSES)
    _rig_arguments(start)
    start.add_argument('--set', dest='overrides', action='append', default=[],
                       metavar='KEY=VALUE',
                       help='set a supervisor parameter first (e.g. d_t_mm=19, '
                       'pull_speed_mm_s=1.0, out=DIR: a relative DIR is taken from here); it '
                       'stays set for the trials after; repeatable')
    start.add_argument('--wait', action='store_true',
                       help='follow the trial to its end; print its final state and reason')
    start.add_argument('--timeout', type=float, default=600.0,
                       help='with --wait: abort the trial after this many seconds of wall '
                       'time (default 600)')
    start.set_defaults(run=run_start)

    abort = commands.add_parser('abort', help='abort the trial running on a rig',
                                epilog=EXIT_STATUSES)
    _rig_arguments(abort)
    abort.set_defaults(run=run_abort)

    state = commands.add_parser(
        'state', help="a rig's supervisor state, its reason, its trials and last bag",
        epilog=EXIT_STATUSES)
    _rig_arguments(state)
    state.add_argument('--json', action='store_true', help='one JSON object (a line each with '
                       '--watch)')
    state.add_argument('--watch', action='store_true',
                       help='print every state as it comes, until Ctrl-C')
    state.set_defaults(run=run_state)


def _rig_arguments(parser) -> None:
    parser.add_argument('--namespace', default='', metavar='/NS',
                        help='the rig\'s ROS namespace, as given to mantis bringup '
                        '(default: none)')
    parser.add_argument('--reach-timeout', type=float, default=REACH_TIMEOUT_S, metavar='S',
                        help=f'how long the supervisor has to answer (default '
                        f'{REACH_TIMEOUT_S:g} s)')


# ------------------------------------------------------------------------ the commands
def run_start(args) -> int:
    values = supervisor_values(args.overrides)       # ConditionError: exit 2, nothing sent
    with rig_client(args) as client:
        if values:
            _check_together(client, values)
            ok, why = client.set_parameters(values)
            if not ok:
                _say(f'mantis start: the supervisor refused {why}')
                return 1
        ok, message = client.start_trial()
        if not ok:
            _say(f'mantis start: the supervisor refused to start: {message}')
            return 1
        bag = message.rsplit('logging to ', 1)[-1]
        print(f'bag: {bag}', flush=True)
        if not args.wait:
            return 0
        final = client.wait_for_end(args.timeout)
        if final is None:
            client.call('abort', timeout_s=5.0)
            raise StackError(f'no end of trial within {args.timeout} s; aborted')
        reason = client.reason_of(bag, final, STATUS_WAIT_S) or ''
        print(final + (f': {reason}' if reason else ''), flush=True)
        return 0 if final == 'done' else 1


def run_abort(args) -> int:
    with rig_client(args) as client:
        ok, message = client.call('abort', timeout_s=args.reach_timeout)
    if not ok:
        _say(f'mantis abort: {message}')
        return 1
    print(message, flush=True)
    return 0


def run_state(args) -> int:
    with rig_client(args) as client:
        if not client.states:          # transient local: the current state comes at once
            deadline = time.monotonic() + args.reach_timeout
            while not client.states and time.monotonic() < deadline:
                time.sleep(0.05)
        if not args.watch:
            _print_state(_state(client, len(client.states) - 1), args.json)
            return 0
        shown = 0
        try:
            while True:
                while shown < len(client.states):
                    _print_state(_state(client, shown), args.json)
                    shown += 1
                time.sleep(0.05)
        except KeyboardInterrupt:
            return 0


# ------------------------------------------------------------------------ parts
def supervisor_values(overrides) -> dict:
    """``--set KEY=VALUE`` items as the supervisor's typed parameters; ConditionError names an
    unknown key or a value out of range. A relative ``out`` is made absolute (the supervisor
    runs elsewhere)."""
    values = {}
    for item in overrides:
        key, sep, text = item.partition('=')
        if not sep or not key:
            raise ConditionError(f'--set {item!r}: expected KEY=VALUE')
        if key not in PARAMETERS:
            raise ConditionError(f'--set {item!r}: unknown supervisor parameter {key!r}; '
                                 f'known: {", ".join(PARAMETERS)}')
        value = supervisor_value(key, text)
        if key == 'out':
            value = str(Path(value).expanduser().absolute())
        check_value(key, value)
        values[key] = value
    return values


def _check_together(client, values: dict) -> None:
    """Refuse (ConditionError) values that do not go with the supervisor's others (the camera's
    window), before any is set."""
    current = {k: v for k, v in client.get_parameters(PARAMETERS).items() if v is not None}
    TrialConditions.from_mapping({**current, **values}).validate()


def rig_client(args):
    """The running rig's TrialClient for ``args`` (its namespace, --reach-timeout)."""
    from mantis_rig.stack.command_session import rig_client as client_of_rig

    if args.namespace and not ROS_NAMESPACE.fullmatch(args.namespace):
        raise ConditionError(f'--namespace {args.namespace!r}: expected an absolute ROS '
                             f'namespace such as /rig2')
    return client_of_rig(args.command, args.namespace, args.reach_timeout)


def _state(client, index: int) -> dict:
    """State ``index`` of those heard (-1 with none heard: the status's), with the status
    (trials, bag) heard since and its reason (the status follows each state by a moment)."""
    state = client.states[index] if index >= 0 else client.supervisor_status.get('state', '')
    deadline = time.monotonic() + STATUS_WAIT_S
    while client.supervisor_status.get('state') != state and \
            index == len(client.states) - 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    status = dict(client.supervisor_status)
    return {'namespace': client.get_namespace(), 'state': state,
            'reason': client.reasons.get((status.get('bag', ''), state), ''),
            'trials': int(status.get('trials') or 0), 'bag': status.get('bag', ''),
            'last_abort_reason': status.get('last_abort_reason', '')}


def _print_state(state: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(state), flush=True)
        return
    line = f'{state["state"]}' + (f': {state["reason"]}' if state['reason'] else '')
    print(f'{line} (trials {state["trials"]}' +
          (f', bag {state["bag"]})' if state['bag'] else ')'), flush=True)


def _say(line: str) -> None:
    sys.stderr.write(line + '\n')
    sys.stderr.flush()


__all__ = ['add_commands', 'rig_client', 'supervisor_values']
