"""Import of tracked marker positions (CSV or the tracking software's .xlsx export).

Marker naming: body markers start with ``mb``, arm markers with ``ma`` (``mb1``, ``ma2``, ...).
Positions are millimetres in the camera frame. The tracking software's frame is left-handed
(image y axis points down) unless its calibration says otherwise; :class:`~.tracks.MarkerTracks`
records that in ``handedness`` (and the calibration's tilt in ``tilt_deg``), and the kinematics
turn the tracks once into the robot's right-handed frame.

Accepted CSV layout (optionally gzipped, detected from the ``.gz`` suffix)::

    frame,time_s,mb1_x,mb1_y,...,ma2_x,ma2_y

Coordinate columns may also carry a unit suffix: ``mb1_x_mm``. Extra non-marker columns are
an error (they usually mean a mislabelled export), as is a marker with only x or only y.

The tracker's own export, as .xlsx or as CSV (with or without its header block), in every
variant of ``docs/tracking_export.md``: :mod:`.tracker_export`. Lost markers ((-1, -1) or blank
cells) are NaN: gaps, never positions.
"""
from __future__ import annotations

import gzip
from pathlib import Path
import re
import zlib

import numpy as np

from . import tracker_export as te
from .tracks import MIN_FRAMES, MarkerTracks, TrackFormatError, frame_numbers

__all__ = ['MIN_FRAMES', 'MarkerTracks', 'TrackFormatError', 'load_tracks', 'read_marker_csv',
           'read_marker_xlsx']

_MARKER_RE = re.compile(r'^(m[ab]\w*?)_([xy])(?:_mm)?$')


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


def read_marker_csv(path: str | Path, frame_rate_hz: float | None = None,
                    length_unit: str | None = None) -> MarkerTracks:
    """The project's CSV (``frame,time_s,mb1_x,...``) or the tracker's CSV export."""
    path = Path(path)
    text = _read_text(path)
    rows = te.read_export_csv_rows(text, path.name)
    if rows and te.looks_like_export(rows[0]):
        return _from_export(rows, path, 'csv', frame_rate_hz, length_unit)
    if frame_rate_hz is not None or length_unit is not None:
        raise TrackFormatError(f'{path.name}: --frame-rate and --length-unit apply to the '
                               'tracker\'s exports; this file is the project\'s CSV')
    header = [h.strip() for h in (rows[0] if rows else [])]
    body = [r for r in rows[1:] if r]
    if not body:
        raise TrackFormatError(f'{path.name}: no data rows')
    ragged = next((k for k, r in enumerate(body) if len(r) != len(header)), None)
    if ragged is not None:
        raise TrackFormatError(f'{path.name}: row {ragged + 2} has {len(body[ragged])} columns, '
                               f'the header {len(header)}')
    try:
        data = np.array(body, dtype=np.float64)     # numpy parses the strings itself: fast
    except ValueError:                              # blank cells (lost markers) or damage
        try:
            data = np.array([[float(v) if v.strip() else np.nan for v in r] for r in body])
        except ValueError as exc:
            raise TrackFormatError(f'{path.name}: non-numeric data ({exc})') from exc
    missing = [c for c in ('frame', 'time_s') if c not in header]
    if missing:
        raise TrackFormatError(f'{path.name}: missing column(s) {missing}')
    coord_cols = {h: i for i, h in enumerate(header) if h not in ('frame', 'time_s')}
    markers = {name: te.lost_as_gaps(xy)
               for name, xy in _markers_from_columns(coord_cols, data, path.name).items()}
    tracks = MarkerTracks(
        time_s=data[:, header.index('time_s')].astype(float),
        frames=frame_numbers(data[:, header.index('frame')], path.name),
        markers_mm=markers,
        source={'path': str(path), 'format': 'csv'},
    )
    tracks.validate()
    return tracks


def read_marker_xlsx(path: str | Path, frame_rate_hz: float | None = None,
                     length_unit: str | None = None) -> MarkerTracks:
    """The tracker's .xlsx export (first worksheet), any of its variants."""
    path = Path(path)
    return _from_export(te.read_export_xlsx_rows(path), path, 'xlsx', frame_rate_hz,
                        length_unit)


def _from_export(rows: list, path: Path, fmt: str, frame_rate_hz: float | None,
                 length_unit: str | None) -> MarkerTracks:
    tracks = te.parse_export_rows(rows, path.name, frame_rate_hz, length_unit,
                                  source={'path': str(path), 'format': fmt})
    tracks.validate()
    return tracks


def _markers_from_columns(coord_cols: dict[str, int], data: np.ndarray,
                          fname: str) -> dict[str, np.ndarray]:
    axes: dict[str, dict[str, int]] = {}
    unknown = []
    for col, idx in coord_cols.items():
        m = _MARKER_RE.match(col)
        if m is None:
            unknown.append(col)
            continue
        axes.setdefault(m.group(1), {})[m.group(2)] = idx
    if unknown:
        raise TrackFormatError(f'{fname}: unexpected column(s) {unknown}')
    incomplete = [f'{n}_{a}' for n, ax in axes.items() for a in 'xy' if a not in ax]
    if incomplete:
        raise TrackFormatError(f'{fname}: missing column(s) {sorted(incomplete)}')
    return {n: np.column_stack([data[:, ax['x']], data[:, ax['y']]]).astype(float)
            for n, ax in sorted(axes.items())}
