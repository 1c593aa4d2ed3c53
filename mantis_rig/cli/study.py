"""`mantis study`: run a plan of trials on a rig, each judged against the twin as it lands;
`mantis study attach` fills the rows' tip speed and energy from the videos (tracked here) or
their tracker exports; `mantis study report` writes the effects and figures (docs/study.md)."""
from __future__ import annotations

from pathlib import Path

from mantis_rig.cli.options import PROCESSES
from mantis_rig.cli.track_command import add_video_options
from mantis_rig.faults import RIG_FAULT, USAGE_ERROR
from mantis_sim.errors import InputError

USAGE = """mantis study PLAN --out DIR [options]     run (or resume) a study on a rig
       mantis study attach DIR FILES...        fill rows from the videos or their exports
       mantis study report DIR                 effects, repeats still needed, figures"""
EXIT_STATUSES = (
    f'exit status: 0 every planned trial is recorded; {USAGE_ERROR} bad input (the plan, '
    f'an export, a study directory of another plan); {RIG_FAULT} a rig fault (named in one '
    f'line, the stage stopped first; run the same command again to resume); 130 / 143 '
    f'interrupted by SIGINT / SIGTERM (the trial in progress is recorded as interrupted and '
    f'run again on resume)')


def add_commands(commands) -> None:
    study = commands.add_parser(
        'study', usage=USAGE, help='run a plan of trials, each judged against the twin\'s '
        'forecast; resumable (attach, report: see --help)', epilog=EXIT_STATUSES,
        description=__doc__)
    study.add_argument('plan', metavar='PLAN|attach|report',
                       help='the plan (YAML, docs/study.md), or attach / report')
    study.add_argument('rest', nargs='*', metavar='DIR FILES',
                       help='attach: the study directory and the videos (.cine, .avi: tracked '
                            'with --calibration, --rate ...) or their exports; report: the '
                            'study directory')
    study.add_argument('--out', type=Path, help='the study\'s directory (its record study.csv, '
                       'the plan as run, the bags under bags/, the report under report/)')
    study.add_argument('--connect', action='store_true',
                       help='run on a rig already up (`ros2 launch mantis_rig ...` or `mantis '
                            'bringup`) in this ROS domain, instead of bringing one up')
    study.add_argument('--backend', choices=('sim', 'hardware'), default='sim',
                       help='the rig this command brings up (default sim); hardware asks the '
                            'person before each trial')
    study.add_argument('--processes', choices=PROCESSES, default='single',
                       help='layout of the rig this command brings up (as `mantis trial`)')
    study.add_argument('--real-time-factor', type=float, default=1.0,
                       help='simulated seconds per wall second (sim; 0: as fast as it goes)')
    study.add_argument('--seed', type=int, default=0,
                       help='seed of the simulated session (sim): sensor noise and the robots')
    study.add_argument('--namespace', default='', metavar='/NS',
                       help='the rig\'s ROS namespace (as `mantis trial`)')
    study.add_argument('--set', dest='overrides', action='append', default=[],
                       metavar='KEY=VALUE', help='a supervisor or scene parameter for the rig '
                       'this command brings up (as `mantis trial`); repeatable')
    study.add_argument('--log-dir', type=Path, help='with --processes multi: node output here')
    study.add_argument('--ask', action='store_true',
                       help='ask the person before each trial also in simulation')
    add_video_options(study)
    study.set_defaults(run=run_study, live=None, pull_speed=None)


def run_study(args) -> int:
    if args.plan == 'attach':
        return _attach(args)
    if args.plan == 'report':
        return _report(args)
    if args.rest:
        raise InputError(f'mantis study PLAN takes one plan; got also {" ".join(args.rest)} '
                         f'(attach and report are `mantis study attach|report DIR`)')
    if args.out is None:
        raise InputError('mantis study PLAN needs --out DIR (the study\'s directory)')
    from mantis_rig.trial.supervisor_settings import check_value
    from mantis_sim.studies.rig_study.plan import load_plan
    plan = load_plan(args.plan, check_condition=check_value)
    if args.connect:
        from mantis_rig.study_session.session import run_connected
        return run_connected(plan, args)
    from mantis_rig.cli.trial_commands import stack_config
    from mantis_rig.study_session.runner import BAGS
    from mantis_rig.study_session.session import run_with_stack
    directory = Path(args.out).resolve()
    directory.mkdir(parents=True, exist_ok=True)
    args.scene, args.out = plan.scene, directory / BAGS     # the trials' bags, in the study's
    return run_with_stack(plan, stack_config(args), directory, log_dir=args.log_dir,
                          ask=args.ask)


def _directory(args) -> Path:
    if len(args.rest) < 1:
        raise InputError(f'mantis study {args.plan} needs the study directory')
    return Path(args.rest[0])


def _attach(args) -> int:
    from mantis_rig.study_session.attach import attach_exports
    directory = _directory(args)
    exports = [Path(p) for p in args.rest[1:]]
    if not exports:
        raise InputError('mantis study attach DIR FILES...: no video or export given')
    from mantis_rig.cli.track_command import track_video

    def tracked(video: Path, out: Path) -> Path:
        return track_video(args, video, out, label='study attach').csv
    filled = attach_exports(directory, exports, say=print, track_video=tracked)
    print(f'{filled} row(s) filled from {len(exports)} export(s); {directory / "study.csv"}')
    return 0


def _report(args) -> int:
    from mantis_rig.study_session.report import write_report
    directory = _directory(args)
    written = write_report(directory, say=print)
    print(f'report: {written}')
    return 0


__all__ = ['add_commands']
