"""What `mantis identify`, `compare` and `day-state` share: the options naming the real strikes
and where they run, those options as the studies take them, the rig's analysis of a tracker
export handed to the studies, and the progress lines."""
from __future__ import annotations

from pathlib import Path
import sys

from mantis_sim.studies.real_strikes.strike_inputs import StrikeInputs

from .options import add_cluster_options


def add_strike_options(parser) -> None:
    """The real strikes (table, records, exports, scenes, groups), the cluster, --json."""
    parser.add_argument('--strikes', type=Path, required=True,
                        help='summary table (CSV): trial, medium, d_t_mm, contact_angle_deg, '
                             'pull_measured_mm_s, and v_max_mps, PE_max_mJ, ... as measured')
    parser.add_argument('--processed', type=Path,
                        help='folder of processed records <trial>_data.csv[.gz] (phase IV '
                             'from the table\'s t_z1_s)')
    parser.add_argument('--export', action='append', default=[], metavar='TRIAL=PATH',
                        help='a tracker export (.xlsx, .csv) of the table\'s strike TRIAL')
    parser.add_argument('--scene', action='append', default=[], metavar='GROUP=SCENE',
                        help='the scene of a group of strikes (default: the group\'s name, '
                             'e.g. air_23mm); repeatable')
    parser.add_argument('--group', action='append', default=[],
                        help='use only the strikes of this group (air_19mm, ...); repeatable')
    add_cluster_options(parser)
    parser.add_argument('--json', action='store_true', help='print the result as JSON')


def add_at_seat_option(parser) -> None:
    parser.add_argument('--at-seat', action='store_true',
                        help='latch each simulated arm where its strike\'s tracks show it at '
                             'overcentering (the table\'s seat_deg, or the processed record at '
                             'the table\'s t_oc_s) rather than at the recorded contact angle; '
                             'strikes without a seat stay at the contact angle and are listed')


def strike_inputs(args) -> StrikeInputs:
    """add_strike_options's options as the studies take them."""
    return StrikeInputs(strikes=args.strikes, processed=args.processed,
                        exports=tuple(args.export), scenes=tuple(args.scene),
                        groups=tuple(args.group), scheduler=args.scheduler,
                        workers=args.workers, progress=not args.json)


def export_series(path, strike):
    """A tracker export as its strike's motion (the studies' SeriesFromExport), by the rig's
    analysis (mantis_rig.analysis.strike_series), imported only when an export is given."""
    from mantis_rig.analysis.strike_series import export_series as analysed
    return analysed(path, strike)


def progress_line(message: str) -> None:
    """A line of the command's progress, on stderr."""
    print(message, file=sys.stderr, flush=True)
