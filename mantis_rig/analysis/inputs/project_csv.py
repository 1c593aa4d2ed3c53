"""The project's own CSV of marker tracks (a plain table, as ``test/data``'s
``air_23mm_2p3mmps_trial1_markers.csv.gz`` holds the real export's numbers; optionally gzipped)::

    frame,time_s,mb1_x,mb1_y,...,ma2_x,ma2_y

Marker naming: body markers start with ``mb``, arm markers with ``ma`` (``mb1``, ``ma2``, ...);
positions are millimetres in the camera frame, taken as the tracker's (left-handed: image y
down); times are seconds. Coordinate columns may also carry a unit suffix: ``mb1_x_mm``. Extra
non-marker columns are an error (they usually mean a mislabelled export), as is a marker with
only x or only y. Lost markers ((-1, -1) or blank cells) are NaN: gaps, never positions.
"""
from __future__ import annotations

from pathlib import Path
import re

import numpy as np

from .base import MarkerTracks, TrackFormatError, frame_numbers, lost_as_gaps

_MARKER_RE = re.compile(r'^(m[ab]\w*?)_([xy])(?:_mm)?$')


def read_project_csv(rows: list[list], path: Path) -> MarkerTracks:
    """The validated tracks of the project's CSV, its rows as read from ``path``."""
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
    markers = {name: lost_as_gaps(xy)
               for name, xy in _markers_from_columns(coord_cols, data, path.name).items()}
    tracks = MarkerTracks(
        time_s=data[:, header.index('time_s')].astype(float),
        frames=frame_numbers(data[:, header.index('frame')], path.name),
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
