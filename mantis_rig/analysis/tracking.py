"""Import of tracked marker positions (CSV or the tracking software's .xlsx export).

Marker naming: body markers start with ``mb``, arm markers with ``ma`` (``mb1``, ``ma2``, ...).
Positions are millimetres in the camera frame. The tracking software's frame is left-handed
(image y axis points down); :class:`MarkerTracks` records that in ``handedness`` and the
kinematics flip y once to work in a right-handed frame.

Accepted CSV layout (optionally gzipped, detected from the ``.gz`` suffix)::

    frame,time_s,mb1_x,mb1_y,...,ma2_x,ma2_y

Coordinate columns may also carry a unit suffix: ``mb1_x_mm``. Extra non-marker columns are
an error (they usually mean a mislabelled export), as is a marker with only x or only y.

Accepted .xlsx layout (first worksheet; rows are 1-based)::

    row 1..k   header block, one ``key | value`` pair per row, ended by the first empty row.
               Required keys (case-insensitive): ``record rate`` (frames/s) and
               ``calibration`` (mm per pixel, recorded in ``source``). Others are kept.
    row k+2    column labels: ``Frame | Time | mb1 | | mb2 | | ...`` (a marker label spans
               its x and y columns, the second cell may be empty or repeat the name);
               a label may be written ``Feature 1 (mb1)``: the name in brackets is used.
    row k+3    axis labels: ``| | x | y | x | y ...``
    row k+4..  data rows; an empty cell or -1/-1 marks a lost marker (NaN).

Times in the .xlsx are seconds; if the time column is empty, time = frame / record rate.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import gzip
from pathlib import Path
import re

import numpy as np

MIN_FRAMES = 50
_MARKER_RE = re.compile(r'^(m[ab]\w*?)_([xy])(?:_mm)?$')


class TrackFormatError(ValueError):
    """The file does not have the layout this module accepts."""


@dataclass
class MarkerTracks:
    """Marker positions over time (camera frame, millimetres)."""

    time_s: np.ndarray
    frames: np.ndarray
    markers_mm: dict[str, np.ndarray]
    handedness: str = 'left'
    source: dict = field(default_factory=dict)

    @property
    def body_markers(self) -> list[str]:
        return sorted(n for n in self.markers_mm if n.startswith('mb'))

    @property
    def arm_markers(self) -> list[str]:
        return sorted(n for n in self.markers_mm if n.startswith('ma'))

    @property
    def n_frames(self) -> int:
        return len(self.time_s)

    def validate(self) -> None:
        """Raise TrackFormatError unless the tracks can be analysed."""
        if self.n_frames < MIN_FRAMES:
            raise TrackFormatError(
                f'too few frames: {self.n_frames} (need at least {MIN_FRAMES})')
        if len(self.body_markers) < 2:
            raise TrackFormatError(
                f'need at least 2 body markers (mb*), found {self.body_markers}')
        if len(self.arm_markers) < 2:
            raise TrackFormatError(
                f'need at least 2 arm markers (ma*), found {self.arm_markers}')
        if np.any(np.diff(self.time_s) <= 0):
            raise TrackFormatError('time_s must increase strictly')
        for name, xy in self.markers_mm.items():
            if xy.shape != (self.n_frames, 2):
                raise TrackFormatError(f'marker {name}: shape {xy.shape}, expected (n, 2)')


def load_tracks(path: str | Path) -> MarkerTracks:
    """Read a marker file, choosing the reader from the suffix (.csv, .csv.gz, .xlsx)."""
    path = Path(path)
    if path.suffix.lower() == '.xlsx':
        return read_marker_xlsx(path)
    return read_marker_csv(path)


def read_marker_csv(path: str | Path) -> MarkerTracks:
    path = Path(path)
    opener = gzip.open if path.suffix == '.gz' else open
    with opener(path, 'rt') as f:
        header = [h.strip() for h in f.readline().strip().split(',')]
        try:
            data = np.loadtxt(f, delimiter=',', ndmin=2)
        except ValueError as exc:
            raise TrackFormatError(f'{path.name}: non-numeric data ({exc})') from exc
    if data.shape[1] != len(header):
        raise TrackFormatError(
            f'{path.name}: {len(header)} header columns but {data.shape[1]} data columns')
    missing = [c for c in ('frame', 'time_s') if c not in header]
    if missing:
        raise TrackFormatError(f'{path.name}: missing column(s) {missing}')
    coord_cols = {h: i for i, h in enumerate(header) if h not in ('frame', 'time_s')}
    markers = _markers_from_columns(coord_cols, data, path.name)
    tracks = MarkerTracks(
        time_s=data[:, header.index('time_s')].astype(float),
        frames=data[:, header.index('frame')].astype(np.int64),
        markers_mm=markers,
        source={'path': str(path), 'format': 'csv'},
    )
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


def read_marker_xlsx(path: str | Path) -> MarkerTracks:
    from openpyxl import load_workbook

    path = Path(path)
    wb = load_workbook(path, read_only=True, data_only=True)
    try:
        rows = list(wb.worksheets[0].iter_rows(values_only=True))
    finally:
        wb.close()
    meta, start = _read_header_block(rows, path.name)
    if len(rows) < start + 2:
        raise TrackFormatError(f'{path.name}: no column label rows after the header block')
    labels, axis_row = rows[start], rows[start + 1]
    cols = _xlsx_columns(labels, axis_row, path.name)
    body = [r for r in rows[start + 2:] if r and any(v is not None for v in r)]
    data = np.array([[_num(r[i]) if i < len(r) else np.nan for i in range(len(labels))]
                     for r in body], dtype=float).reshape(len(body), len(labels))
    frames = data[:, cols['frame']]
    time_s = data[:, cols['time']]
    if np.all(np.isnan(time_s)):
        time_s = frames / meta['record rate']
    markers = {}
    for name, (ix, iy) in cols['markers'].items():
        xy = data[:, [ix, iy]]
        xy[np.all(xy == -1, axis=1)] = np.nan
        markers[name] = xy
    tracks = MarkerTracks(
        time_s=time_s, frames=frames.astype(np.int64), markers_mm=markers,
        source={'path': str(path), 'format': 'xlsx', **meta},
    )
    tracks.validate()
    return tracks


def _num(v) -> float:
    if v is None or v == '':
        return np.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return np.nan


def _read_header_block(rows: list, fname: str) -> tuple[dict, int]:
    meta: dict = {}
    blank = [i for i, row in enumerate(rows) if not row or all(v is None for v in row)]
    if not blank:
        raise TrackFormatError(f'{fname}: header block is not ended by an empty row')
    end = blank[0]
    for row in rows[:end]:
        key = str(row[0]).strip().lower().rstrip(':')
        meta[key] = row[1] if len(row) > 1 else None
    missing = [k for k in ('record rate', 'calibration') if k not in meta]
    if missing:
        raise TrackFormatError(f'{fname}: header block lacks {missing}')
    for k in ('record rate', 'calibration'):
        try:
            meta[k] = float(meta[k])
        except (TypeError, ValueError) as exc:
            raise TrackFormatError(f'{fname}: header {k!r} is not a number') from exc
    return meta, end + 1


def _xlsx_columns(labels: tuple, axis_row: tuple, fname: str) -> dict:
    names = [str(v).strip() if v is not None else '' for v in labels]
    lower = [n.lower() for n in names]
    missing = [c for c in ('frame', 'time') if c not in lower]
    if missing:
        raise TrackFormatError(f'{fname}: missing column(s) {missing}')
    markers: dict[str, list] = {}
    current = None
    for i, label in enumerate(names):
        if lower[i] in ('frame', 'time'):
            current = None
            continue
        bracket = re.search(r'\((m[ab]\w*)\)', label)
        name = bracket.group(1) if bracket else label
        if name:
            if not re.fullmatch(r'm[ab]\w*', name):
                raise TrackFormatError(f'{fname}: unexpected column {label!r}')
            current = name
        if current is None:
            continue
        axis = str(axis_row[i]).strip().lower() if i < len(axis_row) and axis_row[i] else ''
        if axis in ('x', 'y'):
            markers.setdefault(current, [None, None])['xy'.index(axis)] = i
    incomplete = [f'{n}_{a}' for n, ix in markers.items() for a, j in zip('xy', ix, strict=True)
                  if j is None]
    if incomplete:
        raise TrackFormatError(f'{fname}: missing column(s) {sorted(incomplete)}')
    return {'frame': lower.index('frame'), 'time': lower.index('time'),
            'markers': {n: tuple(ix) for n, ix in sorted(markers.items())}}
