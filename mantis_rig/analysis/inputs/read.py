"""The analysis's one way in: :func:`read_trial` reads any input a trial comes as, and says
nothing of which one it read; :func:`load_tracks` the tracks of a tracking file.

What the path is decides the reader:

- a bag (a directory, or an ``.mcap`` file: a bag whose writer was killed): :mod:`.bag`, with
  the tendon force it recorded;
- ``.xlsx`` (``.xlsm``): the tracker's export, :mod:`.tracker_export`;
- ``.csv`` (``.csv.gz``, gzipped): the tracker's export as CSV (:mod:`.tracker_export`: its
  first row is its header block or its column header ``Frame, Time, ...``), else the project's
  CSV (:mod:`.project_csv`).

Each becomes a :class:`~.base.TrialInput` (:class:`~.base.MarkerTracks` in mm, and for a bag
the force samples); a file that does not read as its kind is a :class:`~.base.TrackFormatError`
naming the file and what was wrong.
"""
from __future__ import annotations

import csv
import gzip
import io
from pathlib import Path
import zlib

from . import tracker_export as te
from .base import MarkerTracks, TrackFormatError, TrialInput
from .project_csv import read_project_csv

__all__ = ['is_bag_path', 'load_tracks', 'read_marker_csv', 'read_marker_xlsx', 'read_trial']


def is_bag_path(path) -> bool:
    """A bag directory or an .mcap file (anything else is taken for a tracking file)."""
    path = Path(path)
    return path.is_dir() or path.suffix == '.mcap'


def read_trial(path, frame_rate_hz: float | None = None,
               length_unit: str | None = None) -> TrialInput:
    """A trial bag (directory or .mcap) or a tracking file (.csv, .csv.gz, .xlsx).

    ``frame_rate_hz`` and ``length_unit`` go to :func:`load_tracks` (what a tracker export
    leaves out or gets wrong); a bag states both itself, so with a bag they are a ValueError.
    """
    if is_bag_path(path):
        if frame_rate_hz is not None or length_unit is not None:
            raise ValueError(f'{path}: the frame rate and length unit apply to tracking files; '
                             'a bag states its own')
        from .bag import read_trial_bag  # ROS messages: imported when a bag is read
        return read_trial_bag(path)
    return TrialInput(tracks=load_tracks(path, frame_rate_hz, length_unit))


def load_tracks(path: str | Path, frame_rate_hz: float | None = None,
                length_unit: str | None = None) -> MarkerTracks:
    """Read a marker file, choosing the reader from the suffix (.csv, .csv.gz, .xlsx).

    ``frame_rate_hz`` and ``length_unit`` ('mm', 'um' or 'px') state what a tracker export
    leaves out (``Record Rate: N/A``) or gets wrong (units that contradict the numbers).
    """
    path = Path(path)
    try:
        if path.suffix.lower() in ('.xlsx', '.xlsm'):
            return read_marker_xlsx(path, frame_rate_hz, length_unit)
        return read_marker_csv(path, frame_rate_hz, length_unit)
    except TrackFormatError as exc:
        if path.name in str(exc):
            raise
        raise TrackFormatError(f'{path}: {exc}') from exc


def read_marker_xlsx(path: str | Path, frame_rate_hz: float | None = None,
                     length_unit: str | None = None) -> MarkerTracks:
    """The tracker's .xlsx export (first worksheet), any of its variants."""
    path = Path(path)
    return te.read_export(te.read_xlsx_rows(path), path, 'xlsx', frame_rate_hz, length_unit)


def read_marker_csv(path: str | Path, frame_rate_hz: float | None = None,
                    length_unit: str | None = None) -> MarkerTracks:
    """The project's CSV (``frame,time_s,mb1_x,...``) or the tracker's CSV export."""
    path = Path(path)
    rows = _csv_rows(_read_text(path), path.name)
    if rows and te.looks_like_export(rows[0]):
        return te.read_export(rows, path, 'csv', frame_rate_hz, length_unit)
    if frame_rate_hz is not None or length_unit is not None:
        raise TrackFormatError(f'{path.name}: --frame-rate and --length-unit apply to the '
                               'tracker\'s exports; this file is the project\'s CSV')
    return read_project_csv(rows, path)


def _read_text(path: Path) -> str:
    opener = gzip.open if path.suffix == '.gz' else open
    try:
        with opener(path, 'rb') as f:
            raw = f.read()
    except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
        raise TrackFormatError(f'{path.name}: damaged gzip file ({exc})') from exc
    try:
        return raw.decode('utf-8-sig')
    except UnicodeDecodeError as exc:
        raise TrackFormatError(f'{path.name}: not UTF-8 text (byte {exc.start}: '
                               f'{exc.reason})') from None


def _csv_rows(text: str, fname: str) -> list[list]:
    """The rows of a CSV text (any line endings); a malformed one is a TrackFormatError."""
    reader = csv.reader(io.StringIO(text, newline=''))
    try:
        return list(reader)
    except csv.Error as exc:
        raise TrackFormatError(f'{fname}: not a readable CSV at line {reader.line_num} '
                               f'({exc})') from None
