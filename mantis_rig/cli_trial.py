"""`mantis trial` and `mantis bringup`: the rig's node stack from the command line."""
from __future__ import annotations

import math
from pathlib import Path
import sys
import time

from .nodes.trial_conditions import (
    BACKENDS,
    PARAMETERS,
    ConditionError,
    TrialConditions,
    check_value,
)

USAGE_ERROR = 2
PROCESSES = ('single', 'multi')


def add_commands(commands) -> None:
    trial = commands.add_parser('trial', help='run one trial on the node stack and log it')
    _stack_arguments(trial)
    trial.add_argument('--out', type=Path, required=True,
                       help='directory under which the trial gets its bag directory')
    trial.add_argument('--pull-speed', type=float, metavar='MM_PER_S',
                       help='pull speed, mm/s (default: the scene\'s)')
    trial.add_argument('--timeout', type=float, default=600.0,
                       help='give up after this many seconds of wall time (default 600)')
    trial.set_defaults(run=run_trial)

    bringup = commands.add_parser('bringup', help='start the node stack and wait for service '
                                  'calls (/supervisor/start_trial) until Ctrl-C')
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
                        help='single: all nodes in this process; multi: one process per node')
    parser.add_argument('--real-time-factor', type=float, default=1.0,
                        help='simulated seconds per wall second (sim backend; default 1; '
                        'simulated time slips when the machine cannot keep up)')
    parser.add_argument('--seed', type=int, default=0, help='sensor noise seed (sim backend)')
    parser.add_argument('--log-dir', type=Path,
                        help='with --processes multi: write each node\'s output here')


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
    from .nodes.bringup import StackConfig

    if not (args.real_time_factor > 0 and math.isfinite(args.real_time_factor)):
        raise ConditionError(f'--real-time-factor {args.real_time_factor} must be > 0')
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
        scene = load_scene(args.scene, scene_overrides)   # SceneError, ParameterError
        conditions.update(pull_speed_mm_s=scene.drive.pull_speed_mm_per_s,
                          medium=scene.medium.name, d_t_mm=scene.geometry.d_t_mm,
                          contact_angle_deg=scene.geometry.contact_angle_deg)
    elif scene_overrides:
        raise ConditionError(f'unknown supervisor parameter(s) {scene_overrides} (scene '
                             f'parameters only apply to the sim backend)')
    conditions.update(supervisor)
    if args.pull_speed is not None:
        conditions['pull_speed_mm_s'] = args.pull_speed
    for key, value in conditions.items():
        check_value(key, value)
    TrialConditions.from_mapping(conditions).validate()
    return StackConfig(backend=args.backend, scene=args.scene, scene_overrides=scene_overrides,
                       seed=args.seed, real_time_factor=args.real_time_factor,
                       processes=args.processes, supervisor=conditions)


def _ros_session(run, args) -> int:
    try:
        config = stack_config(args)
    except ConditionError as exc:
        print(f'mantis {args.command}: {exc}', file=sys.stderr)
        return USAGE_ERROR
    import rclpy

    from .ros_env import claim_local_domain
    claim_local_domain()
    rclpy.init()
    try:
        return run(config, args)
    finally:
        if rclpy.ok():
            rclpy.shutdown()


def run_trial(args) -> int:
    return _ros_session(_trial, args)


def run_bringup(args) -> int:
    return _ros_session(_bringup, args)


def _trial(config, args) -> int:
    from .nodes.bringup import StackError

    try:
        return _run_stack_trial(config, args)
    except StackError as exc:
        print(f'mantis trial: {exc}', file=sys.stderr)
        return 1


def _run_stack_trial(config, args) -> int:
    from .nodes.bringup import Stack
    from .nodes.trial_client import TrialClient
    from .trial_summary import format_summary, summarize

    stack = Stack(config, log_dir=args.log_dir)
    client = TrialClient()
    stack.add_node(client)
    bag = None
    try:
        stack.start()
        if not client.wait_for_supervisor(60.0, stack.check_processes):
            print('mantis trial: the supervisor did not come up within 60 s', file=sys.stderr)
            return 1
        started, message, final = client.run_trial(timeout_s=args.timeout)
        if not started:
            print(f'mantis trial: the supervisor refused to start: {message}', file=sys.stderr)
            return 1
        bag = Path(message.rsplit('logging to ', 1)[-1])
        print(f'bag: {bag}', flush=True)
        if final is None:
            client.call('abort', timeout_s=5.0)
            print(f'mantis trial: no end of trial within {args.timeout} s; aborted',
                  file=sys.stderr)
        _wait_closed(bag, 30.0)
    finally:
        stack.stop()
        client.destroy_node()
    print(format_summary(summarize(bag), with_path=False))
    return 0 if final == 'done' else 1


def _wait_closed(bag: Path, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not (bag / 'metadata.yaml').exists():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def _bringup(config, args) -> int:
    from .nodes.bringup import Stack

    stack = Stack(config, log_dir=args.log_dir)
    try:
        stack.start()
        names = ', '.join(config.node_names())
        print(f'mantis bringup: {names} up ({config.processes} process'
              f'{"es" if config.processes == "multi" else ""}); call /supervisor/start_trial; '
              f'Ctrl-C to stop', flush=True)
        while True:
            dead = stack.dead_processes()
            if dead:
                print(f'mantis bringup: node process(es) ended: {dead}', file=sys.stderr)
                return 1
            time.sleep(0.5)
    except KeyboardInterrupt:
        return 0
    finally:
        stack.stop()


__all__ = ['add_commands', 'stack_config']
