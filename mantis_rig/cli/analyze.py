"""`mantis replay`, `mantis import-tracking`, `mantis analyze`, `mantis recover`."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import sys
import threading

USAGE_ERROR = 2


def _err(command, text):
    print(f'mantis {command}: {text}', file=sys.stderr)


# ---------------------------------------------------------------------------------- replay
def run_replay(args) -> int:
    import rclpy

    from .replay import BagPlayer
    from .replay.schedule import raise_priority
    from .ros_env import claim_local_domain

    claim_local_domain()
    if args.realtime:
        # Before rclpy.init: the DDS threads started there inherit the class, so a publish
        # does not wait on a lock held by a preempted ordinary-priority DDS thread.
        try:
            raise_priority()
        except OSError as exc:
            _err('replay', f'warning: real-time scheduling refused ({exc}); playing at normal '
                           'priority')
    from rclpy.signals import SignalHandlerOptions

    from .nodes.lean_node import LeanNode
    from .nodes.stopping import StopRequested, StopSignals
    signals = StopSignals('mantis replay').install()    # 130 / 143, not rclpy's handler
    rclpy.init(args=None, signal_handler_options=SignalHandlerOptions.NO)
    node = LeanNode('mantis_replay')
    stop = threading.Event()
    relay = None
    try:
        if args.live:
            from .live import LiveRelay
            relay = LiveRelay(args.live)
            print(f'live view: {relay.url} (Foxglove: Open connection, Foxglove WebSocket)',
                  flush=True)
        player = BagPlayer(node, args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
                           clock_hz=args.clock, realtime=args.realtime,
                           time_jumps=args.time_jumps)
        for problem in player.report.problems:
            _err('replay', f'warning: {problem}; replaying the messages before the damage')
        if args.wait_for_subscribers > 0 and not player.wait_for_subscribers(
                args.wait_for_subscribers):
            _err('replay', f'warning: not every topic had a subscriber after '
                           f'{args.wait_for_subscribers} s; playing anyway')
        try:
            report = player.run(stop)
        except StopRequested:
            stop.set()
            report = player.report
            report.interrupted = True
        signals.shield()
        player.wait_for_delivery(timeout_s=2.0)
        print(report)
        if signals.first is not None:
            _err('replay', f'{signals.first.reason}')
            return signals.first.exit_status
        if not sum(report.published.values()):
            _err('replay', f'nothing was replayed from {args.bag}: no message to play'
                           f'{" on the topics asked for" if args.topics else ""}')
            return 1
        return 0
    except StopRequested as stop_requested:       # while setting up, before the playback
        return stop_requested.exit_status
    finally:
        signals.shield()
        if relay is not None:
            relay.close()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


# ------------------------------------------------------------- trial conditions, by hand
#: Trial conditions a tracking file does not carry, given on the command line (the rig's
#: bags carry them in ``trial_conditions``): trial condition -> option.
CONDITION_OPTIONS = {'d_t_mm': '--d-t-mm', 'contact_angle_deg': '--contact-angle-deg'}


def _add_condition_options(parser) -> None:
    parser.add_argument('--d-t-mm', type=float, metavar='MM',
                        help='tendon guide distance d_t of the trial (default: the bag\'s '
                             'trial conditions, else 23 mm)')
    parser.add_argument('--contact-angle-deg', type=float, metavar='DEG',
                        help='contact angle measured on the rig for this trial; sets θ3\'s '
                             'zero (default: the bag\'s trial conditions, else unknown: θ3 '
                             'counts from the latch)')


# ------------------------------------------------------- what a tracker export leaves out
def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'{text!r}: must be a positive number')
    return value


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a whole number') from None
    if value < 1:
        raise argparse.ArgumentTypeError(f'{text!r}: must be 1 or more')
    return value


#: analysis.tracker_export.LENGTH_UNITS, written out: building the parser imports no analysis.
LENGTH_UNITS = ('mm', 'um', 'px')


def _add_export_options(parser) -> None:
    parser.add_argument('--frame-rate', type=_positive_float, metavar='FPS',
                        help='frames per second of a tracker export whose Record Rate is N/A '
                             '(and whose trial name carries none, like "11kfps"); not for bags')
    parser.add_argument('--length-unit', choices=LENGTH_UNITS,
                        help='the unit the export\'s coordinates are really in, overriding its '
                             'Export Units (px: converted by the calibration\'s mm/pixel); '
                             'not for bags')


def export_options(args) -> dict:
    """--frame-rate and --length-unit as load_tracks's keyword arguments."""
    return {'frame_rate_hz': getattr(args, 'frame_rate', None),
            'length_unit': getattr(args, 'length_unit', None)}


def given_conditions(args) -> dict:
    """The trial conditions given as options, checked against their ranges (ConditionError)."""
    from .nodes.trial_conditions import ConditionError, check_value

    given = {}
    for name, option in CONDITION_OPTIONS.items():
        value = getattr(args, name, None)
        if value is not None:
            try:
                check_value(name, value)
            except ConditionError as exc:
                raise ConditionError(f'{option}: {exc}') from None
            given[name] = value
    return given


# ------------------------------------------------------------------------- import-tracking
def run_import(args) -> int:
    from .analysis import analyze_tracks, load_tracks
    from .analysis.conditions import params_for_trial
    from .analysis.tracking_import import write_tracking_bag

    given = given_conditions(args)
    try:
        tracks = load_tracks(args.file, **export_options(args))
    except OSError as exc:
        _err('import-tracking', f'{args.file}: {exc}')
        return USAGE_ERROR
    analysis = None
    if not args.no_angles:
        try:
            analysis = analyze_tracks(tracks, params_for_trial({}, given=given)[0])
        except (ValueError, IndexError) as exc:
            _err('import-tracking', f'warning: θ1/θ3 not derived ({exc}); writing the '
                                    'marker frames only')
    try:
        report = write_tracking_bag(tracks, args.out, analysis, conditions=given)
    except (FileExistsError, OSError) as exc:
        _err('import-tracking', exc)
        return 1
    print(report)
    return 0


# --------------------------------------------------------------------------------- analyze
def _json_safe(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def analysis_report(analysis, trial, path, parameters=()) -> dict:
    """summary() plus what the input was and the tendon's work (if force was recorded).
    ``parameters``: where the analysis took its model parameters from (trial conditions)."""
    report = analysis.summary()
    report['arm_ke_share_at_peak'] = analysis.arm_ke_share_at_peak
    if analysis.tendon_work_mJ is not None:
        report['tendon_work_to_IV_mJ'] = float(
            analysis.tendon_work_mJ[analysis.phases.index_max_contraction])
    report['input'] = {'path': str(path), 'frames': trial.tracks.n_frames,
                       'last_frame_s': float(trial.tracks.time_s[-1]),
                       'truncated': trial.truncated, 'problems': list(trial.problems),
                       'parameters': list(parameters)}
    return report


def _seconds(value) -> str:
    return f'{value:.4f} s' if value is not None and math.isfinite(value) else 'not seen'


def _print_text(report):
    phases = report['phase_start_s']
    pivot = report['body_pivot_mm']
    lines = [
        f'input            {report["input"]["path"]} ({report["input"]["frames"]} frames)',
        f'peak tip speed   {report["peak_tip_speed_mps"]:.2f} m/s',
        'phase starts     ' + ', '.join(f'{k} {_seconds(v)}' for k, v in phases.items()),
        f'overcentering    {_seconds(report["overcentering_s"])}',
        f'peak body speed  {report["peak_body_speed_radps"]:.1f} rad/s',
        f'peak arm speed   {report["peak_arm_speed_radps"]:.1f} rad/s (relative to the body)',
        f'max spring energy {report["max_spring_energy_mJ"]:.1f} mJ',
        f'arm share of KE at peak {report["arm_ke_share_at_peak"]:.2f}',
        ('contact angle    unknown: θ3 counts from the latch'
         if report['contact_angle_deg'] is None or not math.isfinite(report['contact_angle_deg'])
         else f'contact angle    {report["contact_angle_deg"]:.2f} deg'),
        f'body pivot       ({pivot[0]:.3f}, {pivot[1]:.3f}) mm (camera frame, x mirrored '
        'as the authors publish it)',
        f'L1               {report["L1_mm"]:.2f} mm',
    ]
    if report['input'].get('parameters'):
        lines.append('parameters       ' + '; '.join(report['input']['parameters']))
    if 'tendon_work_to_IV_mJ' in report:
        lines.append(f'tendon work to IV {report["tendon_work_to_IV_mJ"]:.1f} mJ')
    print('\n'.join(lines))


def run_analyze(args) -> int:
    """One path without --table: that trial, reported in full. --table or several paths:
    the batch (directories searched for trials), one row per trial in the table."""
    if args.table is not None or len(args.paths) > 1:
        return run_analyze_batch(args)
    args.path = args.paths[0]
    return _analyze_one(args)


def _analyze_one(args) -> int:
    from .analysis.bag_input import is_bag_path, load_trial_input
    from .analysis.batch import TrialRefused, analyse_trial

    given = given_conditions(args)
    bag = is_bag_path(args.path)
    options = export_options(args)
    if bag and any(v is not None for v in options.values()):
        _err('analyze', f'{args.path} is a bag: --frame-rate and --length-unit apply to '
                        'tracking files only (a bag states its own)')
        return USAGE_ERROR
    try:
        trial = load_trial_input(args.path, **options)
    except OSError as exc:
        _err('analyze', exc)
        return USAGE_ERROR
    if trial.problems:
        _err('analyze', f'warning: {args.path} is damaged: {"; ".join(trial.problems)}')
        _err('analyze', f'warning: analysing the {trial.tracks.n_frames} frames recorded '
                        f'before the damage (up to t = {float(trial.tracks.time_s[-1]):.4f} s)')
    try:
        analysis, warned, parameters = analyse_trial(trial, given)
    except TrialRefused as exc:
        raise TrialRefused(f'{args.path}: {exc}') from exc
    for text in warned:
        _err('analyze', f'warning: {text}')
    report = analysis_report(analysis, trial, args.path, parameters)
    if args.plot:
        from .analysis.plots import plot_trial
        plot_trial(analysis, args.plot, title=Path(args.path).name)
    if args.json:
        print(json.dumps(_json_safe(report), indent=2))
    else:
        _print_text(report)
    return 0


def run_analyze_batch(args) -> int:
    """Every trial the paths name, analysed in parallel, one row each in the --table CSV."""
    from .analysis.batch import Progress, expand_paths, is_bag_dir, run_batch, write_table

    if args.json or args.plot:
        _err('analyze', '--json and --plot apply to one trial; a batch (several paths or '
                        '--table) writes its table (--table FILE.csv, or - for stdout)')
        return USAGE_ERROR
    given = given_conditions(args)
    table = args.table if args.table is not None else '-'
    to_stdout = table == '-'
    if not to_stdout and not Path(table).resolve().parent.is_dir():
        _err('analyze', f'--table {table}: no such directory {Path(table).parent}')
        return USAGE_ERROR
    if not to_stdout and Path(table).is_dir():
        _err('analyze', f'--table {table} is a directory: name the CSV file to write')
        return USAGE_ERROR
    trials, notes = expand_paths(args.paths, exclude=() if to_stdout else (table,))
    for note in notes:
        _err('analyze', f'warning: {note}')
    if not trials:
        _err('analyze', 'no trials to analyse')
        return USAGE_ERROR
    options = export_options(args)
    if any(v is not None for v in options.values()):
        bags = [str(t) for t in trials if t.suffix == '.mcap' or is_bag_dir(t)]
        if bags:
            _err('analyze', f'--frame-rate and --length-unit apply to tracking files only; '
                            f'these are bags (a bag states its own): {", ".join(bags)}')
            return USAGE_ERROR
    progress = Progress(len(trials))
    try:
        rows = run_batch(trials, given, jobs=args.jobs, on_done=progress, **options)
    except KeyboardInterrupt:
        progress.close()
        _err('analyze', 'interrupted; no table written')
        return 130
    progress.close()
    where = 'the table on stdout' if to_stdout else table
    try:
        if to_stdout:
            write_table(rows, sys.stdout)
            sys.stdout.flush()
        else:
            with open(table, 'w', newline='', encoding='utf-8') as f:
                write_table(rows, f)
    except OSError as exc:
        _err('analyze', f'--table {table}: {exc}')
        return 1
    refused = sum(row['status'] != 'ok' for row in rows)
    analysed = len(rows) - refused
    if refused:
        print(f'{analysed} of {len(rows)} trials analysed; {refused} refused: see the reason '
              f'column in {where}', file=sys.stderr)
        return 1
    print(f'{analysed} of {len(rows)} trials analysed: {where}', file=sys.stderr)
    return 0


# --------------------------------------------------------------------------------- recover
def run_recover(args) -> int:
    from .recording import main_recover

    return main_recover([args.bag] + (['-o', args.output] if args.output else []))


# ---------------------------------------------------------------------------------- parser
def add_commands(commands) -> None:
    replay = commands.add_parser(
        'replay', help='republish a trial bag with its original timing',
        description='Republish a recorded trial (loopback DDS, own domain unless '
                    'ROS_DOMAIN_ID is set) with its original relative timing.')
    replay.add_argument('bag', help='bag directory or .mcap file')
    replay.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1)')
    replay.add_argument('--loop', action='store_true', help='start again at the end')
    replay.add_argument('--live', metavar='[HOST:]PORT',
                        help='also serve the replayed topics to Foxglove over WebSocket '
                        '(foxglove-sdk; host 127.0.0.1 unless given)')
    replay.add_argument('--time-jumps', choices=('refuse', 'skip'), default='refuse',
                        help="a message whose log time lies outside the span the bag's "
                        'metadata.yaml states (a damaged time stamp): refuse the replay, naming '
                        'it (default), or skip such messages and list them in the report')
    replay.add_argument('--topics', nargs='+', metavar='TOPIC', help='only these topics')
    replay.add_argument('--clock', type=float, nargs='?', const=100.0, default=None,
                        metavar='HZ', help='publish /clock from the log times (default 100 Hz)')
    replay.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='SECONDS',
                        help='wait up to this long for a subscriber on every topic')
    replay.add_argument('--realtime', action='store_true',
                        help='play from a SCHED_FIFO thread (needs root or CAP_SYS_NICE): '
                             'keeps timing within ~1 ms on a busy machine')
    replay.set_defaults(run=run_replay)

    imp = commands.add_parser(
        'import-tracking', help='tracked video (CSV / .xlsx) -> trial bag',
        description='Write marker tracks (the project\'s CSV, or the tracking software\'s '
                    '.xlsx or CSV export) and the derived θ1(t), θ3(t) into a bag.')
    imp.add_argument('file', help='.csv, .csv.gz or .xlsx')
    imp.add_argument('--out', required=True, help='new bag directory')
    _add_condition_options(imp)
    _add_export_options(imp)
    imp.add_argument('--no-angles', action='store_true',
                     help='write only the marker frames (no /analysis/joint_angles)')
    imp.set_defaults(run=run_import)

    ana = commands.add_parser(
        'analyze', help='phases, speeds and energies of a trial, or of many (--table)',
        description='Analyse a trial bag (directory or .mcap) or a tracking file. With '
                    '--table or several paths: analyse every trial they name (directories are '
                    'searched recursively for tracking files *.xlsx, *.csv, *.csv.gz and for '
                    'bags) in parallel and write one row per trial to a CSV table; exit 1 if '
                    'any trial was refused (its row says why).')
    ana.add_argument('paths', nargs='+', metavar='BAG_OR_TRACKING_FILE_OR_DIR')
    ana.add_argument('--json', action='store_true', help='print the summary as JSON')
    ana.add_argument('--plot', metavar='FILE.png', help='write the trial figure')
    ana.add_argument('--table', metavar='FILE.csv',
                     help='batch: write one row per trial to this CSV table (- for stdout, '
                          'the default when several paths are given without --table)')
    ana.add_argument('--jobs', type=_positive_int, default=None, metavar='N',
                     help='batch: trials analysed at once (default: one per core)')
    _add_condition_options(ana)
    _add_export_options(ana)
    ana.set_defaults(run=run_analyze)

    rec = commands.add_parser(
        'recover', help='rewrite a crashed/truncated bag into a valid one',
        description='Rewrite a crashed/truncated trial bag into a valid rosbag2 MCAP bag.')
    rec.add_argument('bag', help='bag directory (or its .mcap file)')
    rec.add_argument('-o', '--output', help='new bag directory (default: <bag>_recovered)')
    rec.set_defaults(run=run_recover)
