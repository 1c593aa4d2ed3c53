"""The analysis's inputs, one module per form a trial comes in, and one way in for all of them.

- :func:`read_trial` (:mod:`.read`): any trial (a bag, the tracker's export as .xlsx or CSV,
  the project's CSV) as a :class:`TrialInput`, whichever it is; :func:`load_tracks` the tracks
  of a tracking file;
- :mod:`.base`: what each becomes (:class:`MarkerTracks`, :class:`TrialInput`) and the readers'
  one error, :class:`TrackFormatError`;
- one module per form: :mod:`.bag` (a trial bag), :mod:`.tracker_export` (the tracker's export,
  both forms, ``docs/tracking_export.md``), :mod:`.project_csv` (the project's CSV);
- :mod:`.bag_writer`: the way back, tracks written into a bag (``mantis import-tracking``;
  it imports rclpy, so it is not imported here).
"""
from .base import MIN_FRAMES, MarkerTracks, TrackFormatError, TrialInput
from .read import is_bag_path, load_tracks, read_marker_csv, read_marker_xlsx, read_trial

__all__ = ['MIN_FRAMES', 'MarkerTracks', 'TrackFormatError', 'TrialInput', 'is_bag_path',
           'load_tracks', 'read_marker_csv', 'read_marker_xlsx', 'read_trial']
