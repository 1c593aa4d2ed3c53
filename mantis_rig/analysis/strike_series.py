"""A tracker export as the motion of a real strike (mantis_sim's `StrikeSeries`), by the rig's
own analysis: what `mantis identify`, `compare` and `day-state` hand the studies for
`--export TRIAL=PATH` (mantis_sim.studies.real_strikes.strike_inputs.SeriesFromExport)."""
from __future__ import annotations

import math
from pathlib import Path

from mantis_sim.studies.real_strikes.strikes import (
    RECORD_WINDOW_S,
    RealStrike,
    StrikeDataError,
    StrikeSeries,
)

from .inputs import load_tracks
from .pipeline import AnalysisParams, analyze_tracks


def export_series(path: Path, strike: RealStrike) -> StrikeSeries:
    """The strike's motion from a tracker export, timed from its own phase IV, cut to the
    record's window."""
    if not path.exists():
        raise StrikeDataError(f'--export {path}: no such file')
    analysis = analyze_tracks(load_tracks(path), AnalysisParams(
        d_t_mm=strike.d_t_mm, contact_angle_rad=math.radians(strike.contact_angle_deg)))
    t_iv = analysis.phases.max_contraction_s
    return StrikeSeries(analysis.time_s - t_iv, analysis.theta1_rad,
                        analysis.theta3_rad).window(*RECORD_WINDOW_S)
