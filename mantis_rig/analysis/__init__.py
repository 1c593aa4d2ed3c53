"""Analysis of strike trials: marker import, linkage fit, phases, energies, speeds, plots.

Pure numpy/scipy (matplotlib only in :mod:`.plots`); functions take arrays, not ROS messages.
"""
from .energy import InertiaParams
from .kinematics import LinkageFit, fit_linkage, tip_speed_mps
from .report import AnalysisParams, TrialAnalysis, analyze_angles, analyze_tracks
from .tracking import MarkerTracks, TrackFormatError, load_tracks, read_marker_csv, read_marker_xlsx

__all__ = [
    'AnalysisParams', 'InertiaParams', 'LinkageFit', 'MarkerTracks', 'TrackFormatError',
    'TrialAnalysis', 'analyze_angles', 'analyze_tracks', 'fit_linkage', 'load_tracks',
    'read_marker_csv', 'read_marker_xlsx', 'tip_speed_mps',
]
