"""The motion tracker's CSV form, written: its header block, then the column header and one row
per frame (``docs/tracking_export.md``, "The CSV form"), so that the analysis
(its one way in for a trial) and other tools read it as they read the lab's exports.

Positions are given in image pixels (x right, y down, (0, 0) the top-left pixel's centre) and
written in millimetres through a :class:`~.calibration.Calibration` (``Export Units:
Millimeters``), or as pixels without one (``Export Units: Pixels``, no calibration: the
analysis cannot turn those into millimetres and says so). A lost marker (NaN) is written as the
tracker writes it, ``-1,-1``; values at 10 significant digits, CRLF line endings.

Streamed: :class:`TrackerCsvWriter` writes each frame as it comes (``write_frame``), or blocks of
frames (``write_frames``); nothing is held.
"""
from __future__ import annotations

import csv
import datetime
import math
from pathlib import Path

import numpy as np

from .calibration import Calibration

__all__ = ['TrackerCsvWriter', 'write_tracker_csv']

LOST = -1


class TrackerCsvWriter:
    """A tracker CSV being written (a context manager; ``close()`` otherwise).

    ``marker_names``: the features in column order (``mb1``, ``ma2``, ...). ``rate_hz``: the
    recording's rate (``Record Rate:``); None writes ``N/A`` and then the time column must hold
    frame numbers, as the tracker writes it. ``video_name``: the ``File Name:`` row (the trial's
    name carries its rate for a reader that needs it)."""

    def __init__(self, path, marker_names, rate_hz: float | None = None,
                 calibration: Calibration | None = None, video_name: str = '',
                 recorded_at: datetime.datetime | None = None):
        self.path = Path(path)
        self.marker_names = [str(n) for n in marker_names]
        if not self.marker_names or len(set(self.marker_names)) != len(self.marker_names):
            raise ValueError(f'marker names {self.marker_names}: need distinct names')
        self.calibration = calibration
        self.rate_hz = rate_hz
        self._file = open(self.path, 'w', newline='', encoding='utf-8')  # noqa: SIM115
        self._csv = csv.writer(self._file, lineterminator='\r\n')
        self._header(video_name, recorded_at or datetime.datetime.now())

    def _header(self, video_name: str, when: datetime.datetime) -> None:
        rate = 'N/A' if self.rate_hz is None else _number(self.rate_hz)
        cal = self.calibration
        rows = [['Motion Analysis Data Sheet', ''], [], ['Test Data'],
                ['Date:', when.strftime('%Y-%m-%d'), '', 'Time:', when.strftime('%H:%M:%S')],
                ['File Name:', video_name], ['Record Rate:', rate], [], ['Calibration(s)']]
        if cal is not None:
            rows.append(['Calibration 1:', cal.tracker_string()])
        rows += [['Export Units:', 'Millimeters' if cal is not None else 'Pixels'], [],
                 ['Tracking Data']]
        names = ['Frame', 'Time']
        for k, name in enumerate(self.marker_names, start=1):
            names += [f'Feature {k} ({name})', '']
        rows += [names, ['', ''] + ['x', 'y'] * len(self.marker_names)]
        self._csv.writerows(rows)

    def write_frame(self, frame: int, time_s: float, positions_px) -> None:
        """One row: ``positions_px`` maps each marker name to (x, y) pixels (NaN, or absent:
        lost). ``time_s`` is written as it is (frame numbers where the rate is N/A)."""
        xy = np.full((len(self.marker_names), 2), np.nan)
        for k, name in enumerate(self.marker_names):
            if name in positions_px:
                xy[k] = positions_px[name]
        self._rows(np.array([frame]), np.array([time_s], float), xy[None])

    def write_frames(self, frames, times_s, positions_px) -> None:
        """Many rows: ``positions_px`` maps each marker name to an (n, 2) array of pixels."""
        frames = np.asarray(frames)
        xy = np.full((len(frames), len(self.marker_names), 2), np.nan)
        for k, name in enumerate(self.marker_names):
            if name in positions_px:
                xy[:, k] = positions_px[name]
        self._rows(frames, np.asarray(times_s, float), xy)

    def _rows(self, frames: np.ndarray, times_s: np.ndarray, xy_px: np.ndarray) -> None:
        out = xy_px if self.calibration is None else self.calibration.px_to_mm(xy_px)
        lost = ~np.all(np.isfinite(out), axis=-1)
        out = np.where(lost[..., None], LOST, out)
        for frame, t, row in zip(frames, times_s, out.reshape(len(frames), -1)):
            self._csv.writerow([int(frame), _number(t)] + [_number(v) for v in row])

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> TrackerCsvWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_tracker_csv(path, frames, times_s, positions_px: dict, rate_hz: float | None = None,
                      calibration: Calibration | None = None, video_name: str = '') -> Path:
    """The whole file at once (see :class:`TrackerCsvWriter`)."""
    with TrackerCsvWriter(path, list(positions_px), rate_hz, calibration, video_name) as w:
        w.write_frames(frames, times_s, positions_px)
    return Path(path)


def _number(value: float) -> str:
    """10 significant digits, as the tracker writes; whole numbers without a point."""
    value = float(value)
    if math.isfinite(value) and value == int(value) and abs(value) < 1e15:
        return str(int(value))
    return f'{value:.10g}'
