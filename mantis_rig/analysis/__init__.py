"""Analysis of strike trials: marker import, linkage fit, phases, energies, speeds, plots.

Pure numpy/scipy (matplotlib only in :mod:`.plots`); functions take arrays, not ROS messages.
The layers, as ``docs/architecture.md`` lays them out:

- :mod:`.inputs`: every form a trial comes in (a bag, the tracker's export as .xlsx or CSV,
  the project's CSV), one module each, and one way in, :func:`read_trial`;
- :mod:`.pipeline`: one trial's tracks through the fit, phases, speeds and energies
  (:func:`analyze_tracks`), on the modules beside it (``kinematics``, ``smoothing``,
  ``phases``, ``onset``, ``energy``, ``geometry``);
- :mod:`.trial`: one trial's analysis as ``mantis analyze`` runs it (:func:`analyse_trial`:
  its conditions, the pipeline, refused or analysed with warnings);
- :mod:`.batch`: many trials, one table row each; :mod:`.intervals`, :mod:`.plots` on top.
"""
from mantis_rig.analysis.one_trial import TrialRefused, analyse_trial

from .energy import InertiaParams
from .inputs import (
    MarkerTracks,
    TrackFormatError,
    TrialInput,
    load_tracks,
    read_marker_csv,
    read_marker_xlsx,
    read_trial,
)
from .kinematics import LinkageFit, fit_linkage, tip_speed_mps
from .pipeline import AnalysisParams, TrialAnalysis, analyze_angles, analyze_tracks

__all__ = [
    'AnalysisParams', 'InertiaParams', 'LinkageFit', 'MarkerTracks', 'TrackFormatError',
    'TrialAnalysis', 'TrialInput', 'TrialRefused', 'analyse_trial', 'analyze_angles',
    'analyze_tracks', 'fit_linkage', 'load_tracks', 'read_marker_csv', 'read_marker_xlsx',
    'read_trial', 'tip_speed_mps',
]
