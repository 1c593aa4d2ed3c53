"""`mantis analyze`: phases, speeds and energies of a trial, or of many (--table)."""
from __future__ import annotations

import json
import math
from pathlib import Path
import sys

from mantis_rig.cli.track_command import add_video_options
from mantis_sim.errors import InputError

from .options import (
    add_condition_options,
    add_export_options,
    err,
    export_options,
    given_conditions,
    json_safe,
    positive_int,
)

#: Re-trackings of `mantis analyze --intervals` without N (each costs one analysis).
INTERVAL_REPLICAS = 40


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
        'phase starts     ' + ', '.join(f'{k} {_seconds(v)}' for k, v in phases.items())
        + f' (II: its {report["unlatch_method"]})',
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
    if 'intervals' in report:
        lines += _interval_lines(report['intervals'],
                                 report['unlatch_method'] == 'departure form')
    if report['input'].get('parameters'):
        lines.append('parameters       ' + '; '.join(report['input']['parameters']))
    if 'tendon_work_to_IV_mJ' in report:
        lines.append(f'tendon work to IV {report["tendon_work_to_IV_mJ"]:.1f} mJ')
    print('\n'.join(lines))


def _analyses_shown(stream=None):
    """On a terminal, a line counting the intervals' analyses (about a second each); on
    anything else (a log, a pipe) nothing."""
    stream = stream if stream is not None else sys.stderr
    if not stream.isatty():
        return None

    def show(done: int, total: int) -> None:
        stream.write(f'\ranalyze: intervals, analysis {done} of {total}'
                     + ('\n' if done == total else ''))
        stream.flush()
    return show


def _interval_lines(intervals: dict, by_departure: bool) -> list[str]:
    from ..analysis.intervals import QUANTITIES, UNLATCHING
    lines = [f'{100 * intervals["level"]:.0f} % intervals (tracking noise: '
             f'{intervals["replicas"]} replicas; the estimator\'s choices: '
             f'{intervals["choices"]}; docs/replay_analysis.md):']
    for key, unit in QUANTITIES.items():
        entry = intervals[key]
        if entry['low'] is None or not math.isfinite(entry['low']):
            lines.append(f'  {key:22s} not seen')
            continue
        digits = 4 if unit == 's' else 2
        before = 'at or before ' if key in intervals.get('open_below', ()) else ''
        lines.append(f'  {key:22s} {before}{entry["low"]:.{digits}f} .. '
                     f'{entry["high"]:.{digits}f} {unit}')
        if key == UNLATCHING and not by_departure:
            lines.append('  (unlatching: the interval of its level crossing; the arm leaves the '
                         'latch earlier, by less than the frames resolve)')
    return lines


def run_analyze(args) -> int:
    """One path without --table: that trial, reported in full. --table or several paths:
    the batch (directories searched for trials), one row per trial in the table."""
    if args.table is not None or len(args.paths) > 1:
        return run_analyze_batch(args)
    args.path = args.paths[0]
    return _analyze_one(args)


def _analyze_one(args) -> int:
    from ..analysis.inputs import is_bag_path, read_trial
    from ..video.to_csv import is_recording

    given = given_conditions(args)
    options = export_options(args)
    if is_recording(args.path):
        return _analyze_video(args, given, options)
    bag = is_bag_path(args.path)
    if bag and any(v is not None for v in options.values()):
        raise InputError(f'{args.path} is a bag: --frame-rate and --length-unit apply to '
                         'tracking files only (a bag states its own)')
    try:
        trial = read_trial(args.path, **options)
    except OSError as exc:
        raise InputError(f'{args.path}: {exc}') from exc
    return _analyze_trial(args, trial, given)


def _analyze_video(args, given, options) -> int:
    """Track the recording (as `mantis track`), then analyse its tracks as an export's."""
    import tempfile

    from mantis_rig.cli.track_command import track_video

    from ..analysis.inputs import read_trial
    if any(v is not None for v in options.values()):
        raise InputError(f'{args.path} is a recording: give its rate with --rate and its '
                         'scale with --calibration (--frame-rate and --length-unit are for '
                         'tracking files)')
    with tempfile.TemporaryDirectory(prefix='mantis_track_') as tmp:
        result = track_video(args, args.path, Path(tmp) / 'tracks.csv', label='analyze',
                             damage_ok=True)
        if result.calibration is None:
            raise InputError(f'{args.path}: the analysis needs millimetres: give '
                             '--calibration CAL.yaml or --marker-distance A,B=MM')
        trial = read_trial(result.csv)
    return _analyze_trial(args, trial, given)


def _analyze_trial(args, trial, given) -> int:
    from mantis_rig.analysis.one_trial import TrialRefused, analyse_trial
    if trial.problems:
        err('analyze', f'warning: {args.path} is damaged: {"; ".join(trial.problems)}')
        err('analyze', f'warning: analysing the {trial.tracks.n_frames} frames recorded '
                        f'before the damage (up to t = {float(trial.tracks.time_s[-1]):.4f} s)')
    try:
        analysis, warned, parameters = analyse_trial(trial, given)
    except TrialRefused as exc:
        raise TrialRefused(f'{args.path}: {exc}') from exc
    for text in warned:
        err('analyze', f'warning: {text}')
    report = analysis_report(analysis, trial, args.path, parameters)
    if args.intervals:
        from ..analysis.intervals import track_intervals
        report['intervals'] = track_intervals(trial.tracks, analysis, args.intervals,
                                              args.seed, _analyses_shown()).to_json()
    if args.plot:
        from mantis_rig.analysis.trial_figure import plot_trial
        plot_trial(analysis, args.plot, title=Path(args.path).name)
    if args.json:
        print(json.dumps(json_safe(report), indent=2))
    else:
        _print_text(report)
    return 0


def run_analyze_batch(args) -> int:
    """Every trial the paths name, analysed in parallel, one row each in the --table CSV."""
    from ..analysis.batch import Progress, expand_paths, is_bag_dir, run_batch, write_table

    if args.json or args.plot:
        raise InputError('--json and --plot apply to one trial; a batch (several paths or '
                         '--table) writes its table (--table FILE.csv, or - for stdout)')
    given = given_conditions(args)
    table = args.table if args.table is not None else '-'
    to_stdout = table == '-'
    if not to_stdout and not Path(table).resolve().parent.is_dir():
        raise InputError(f'--table {table}: no such directory {Path(table).parent}')
    if not to_stdout and Path(table).is_dir():
        raise InputError(f'--table {table} is a directory: name the CSV file to write')
    trials, notes = expand_paths(args.paths, exclude=() if to_stdout else (table,))
    for note in notes:
        err('analyze', f'warning: {note}')
    if not trials:
        raise InputError('no trials to analyse')
    options = export_options(args)
    if any(v is not None for v in options.values()):
        bags = [str(t) for t in trials if t.suffix == '.mcap' or is_bag_dir(t)]
        if bags:
            raise InputError(f'--frame-rate and --length-unit apply to tracking files only; '
                             f'these are bags (a bag states its own): {", ".join(bags)}')
    progress = Progress(len(trials))
    try:
        rows = run_batch(trials, given, jobs=args.jobs, on_done=progress, **options)
    except KeyboardInterrupt:
        progress.close()
        err('analyze', 'interrupted; no table written')
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
        err('analyze', f'--table {table}: {exc}')
        return 1
    refused = sum(row['status'] != 'ok' for row in rows)
    analysed = len(rows) - refused
    if refused:
        print(f'{analysed} of {len(rows)} trials analysed; {refused} refused: see the reason '
              f'column in {where}', file=sys.stderr)
        return 1
    print(f'{analysed} of {len(rows)} trials analysed: {where}', file=sys.stderr)
    return 0


def add_commands(commands) -> None:
    ana = commands.add_parser(
        'analyze', help='phases, speeds and energies of a trial, or of many (--table)',
        description='Analyse a trial bag (directory or .mcap), a tracking file, or a '
                    'recording (.cine, .avi, a folder of frames: tracked first as by `mantis '
                    'track`, then analysed as its export). With '
                    '--table or several paths: analyse every trial they name (directories are '
                    'searched recursively for tracking files *.xlsx, *.csv, *.csv.gz and for '
                    'bags) in parallel and write one row per trial to a CSV table; exit 1 if '
                    'any trial was refused (its row says why).')
    ana.add_argument('paths', nargs='+', metavar='BAG_TRACKING_FILE_RECORDING_OR_DIR')
    ana.add_argument('--json', action='store_true', help='print the summary as JSON')
    ana.add_argument('--plot', metavar='FILE.png', help='write the trial figure')
    ana.add_argument('--intervals', type=int, nargs='?', const=INTERVAL_REPLICAS, default=0,
                     metavar='N',
                     help='also give the peak tip speed, spring energy and phase starts their '
                          '80 %% intervals from the tracking noise (N re-trackings, default '
                          f'{INTERVAL_REPLICAS}) and the estimator\'s choices; costs about N + 6 '
                          'analyses')
    ana.add_argument('--seed', type=int, default=0, help='seed of --intervals (default 0)')
    ana.add_argument('--table', metavar='FILE.csv',
                     help='batch: write one row per trial to this CSV table (- for stdout, '
                          'the default when several paths are given without --table)')
    ana.add_argument('--jobs', type=positive_int, default=None, metavar='N',
                     help='batch: trials analysed at once (default: one per core)')
    add_condition_options(ana)
    add_export_options(ana)
    add_video_options(ana)
    ana.set_defaults(run=run_analyze)
