"""`mantis import-tracking`: tracked video (CSV / .xlsx) -> trial bag."""
from __future__ import annotations

from mantis_sim.errors import InputError

from .options import (
    add_condition_options,
    add_export_options,
    err,
    export_options,
    given_conditions,
)


def run_import(args) -> int:
    from mantis_rig.analysis.one_trial import TrialRefused, analyse_trial

    from ..analysis.inputs import TrialInput, load_tracks
    from ..analysis.inputs.bag_writer import write_tracking_bag

    given = given_conditions(args)
    try:
        tracks = load_tracks(args.file, **export_options(args))
    except OSError as exc:
        raise InputError(f'{args.file}: {exc}') from exc
    analysis = None
    if not args.no_angles:
        try:
            analysis = analyse_trial(TrialInput(tracks=tracks), given)[0]   # as `analyze` does
        except TrialRefused as exc:    # the analysis refused the frames: keep the raw data
            err('import-tracking', f'warning: θ1/θ3 not derived ({exc}); writing the '
                                    'marker frames only')
    try:
        report = write_tracking_bag(tracks, args.out, analysis, conditions=given)
    except (FileExistsError, OSError) as exc:
        err('import-tracking', exc)
        return 1
    print(report)
    return 0


def add_commands(commands) -> None:
    imp = commands.add_parser(
        'import-tracking', help='tracked video (CSV / .xlsx) -> trial bag',
        description='Write marker tracks (the project\'s CSV, or the tracking software\'s '
                    '.xlsx or CSV export) and the derived θ1(t), θ3(t) into a bag.')
    imp.add_argument('file', help='.csv, .csv.gz or .xlsx')
    imp.add_argument('--out', required=True, help='new bag directory')
    add_condition_options(imp)
    add_export_options(imp)
    imp.add_argument('--no-angles', action='store_true',
                     help='write only the marker frames (no /analysis/joint_angles)')
    imp.set_defaults(run=run_import)
