"""`mantis trial` and `mantis bringup`: the rig's node stack from the command line."""
from __future__ import annotations

import math
from pathlib import Path

from mantis_rig.cli.options import PROCESSES, ROS_NAMESPACE, supervisor_value
from mantis_rig.faults import RIG_FAULT, USAGE_ERROR
from mantis_rig.trial.supervisor_settings import (
    BACKENDS,
    PARAMETERS,
    ConditionError,
    TrialConditions,
    check_value,
)

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
    # end_process: the command line's process ends by os._exit once all is closed (cli.main)
    trial.set_defaults(run=run_trial, end_process=True)

    bringup = commands.add_parser('bringup', help='start the node stack and wait for service '
                                  'calls (/supervisor/start_trial) until Ctrl-C',
                                  epilog=STACK_EXIT_STATUSES)
    _stack_arguments(bringup)
    bringup.add_argument('--out', type=Path, default=Path('trials'),
                         help='directory for the trials\' bags (default trials/)')
    bringup.set_defaults(run=run_bringup, pull_speed=None, end_process=True)


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
            supervisor[key] = supervisor_value(key, value)
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
    if args.namespace and not ROS_NAMESPACE.fullmatch(args.namespace):
        raise ConditionError(f'--namespace {args.namespace!r}: expected an absolute ROS '
                             f'namespace such as /rig2 (/-separated names of letters, digits '
                             f'and _, each starting with a letter)')
    return StackConfig(backend=args.backend, scene=args.scene, scene_overrides=scene_overrides,
                       seed=args.seed, real_time_factor=args.real_time_factor,
                       processes=args.processes, supervisor=conditions,
                       namespace=args.namespace)


def _options(args):
    from mantis_rig.stack.stack_runs import StackRunOptions
    return StackRunOptions(log_dir=args.log_dir, live=args.live, namespace=args.namespace,
                           timeout_s=getattr(args, 'timeout', 600.0))


def run_trial(args) -> int:
    from mantis_rig.stack.command_session import ros_session
    from mantis_rig.stack.stack_runs import run_one_trial
    config, options = stack_config(args), _options(args)
    return ros_session(args.command, lambda signals: run_one_trial(config, options, signals))


def run_bringup(args) -> int:
    from mantis_rig.stack.command_session import ros_session
    from mantis_rig.stack.stack_runs import hold_bringup
    config, options = stack_config(args), _options(args)
    return ros_session(args.command, lambda signals: hold_bringup(config, options, signals))


__all__ = ['add_commands', 'stack_config']
