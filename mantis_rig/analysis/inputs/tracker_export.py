"""The motion tracker's own export (``.xlsx``, or the same rows as CSV), in every variant the
lab's files show (``docs/tracking_export.md``).

Layout: an optional header block of ``Label: | value`` rows (``Record Rate:``, ``Calibration
1:``, ``Export Units:``, ``File Name:`` ... wherever the rows fall, blank rows between), then the
column header ``Frame | Time | Feature 1 (mb1) | | Feature 2 (mb2) | ...``, a row of ``x | y``
axis labels, and one row per frame. Markers are found by the name in brackets, in any order.

What the reader makes of it:
- lengths in millimetres, whatever ``Export Units`` says (Millimeters, Micrometers, or Pixels
  converted by the calibration's millimetres per pixel), or what the caller's ``length_unit``
  overrides it with (an export whose labels contradict its numbers);
- a lost marker, written as (-1, -1) or as blank cells, becomes NaN: a gap;
- ``Record Rate: N/A`` means the time column holds frame numbers: the rate then comes from the
  caller (``frame_rate_hz``) or from the trial's name (``..._11kfps_...``), or the file is
  refused; a header-less CSV's times are seconds;
- the calibration's tilt (degrees) and handedness are kept: the analysis turns the tracks back
  into the robot's frame with them (a header-less CSV states neither).

The .xlsx is read with python-calamine (Rust): 5-10x openpyxl's time on the lab's exports, with
the same rows (``test/system/test_tracker_export.py`` holds it to openpyxl's reading of every
shared export; ``docs/performance.md#reading-the-trackers-spreadsheets``).
"""
from __future__ import annotations

import datetime
import math
from pathlib import Path, PureWindowsPath
import re

import numpy as np

from .base import MarkerTracks, TrackFormatError, frame_numbers, lost_as_gaps

# Millimetres per unit of the tracker's ``Export Units`` / ``Calibration Units``.
UNIT_MM = {'millimeters': 1.0, 'millimetres': 1.0, 'mm': 1.0,
           'micrometers': 1e-3, 'micrometres': 1e-3, 'microns': 1e-3, 'um': 1e-3, 'µm': 1e-3,
           'centimeters': 10.0, 'cm': 10.0, 'meters': 1e3, 'm': 1e3}
LENGTH_UNITS = ('mm', 'um', 'px')
_RATE_IN_NAME = re.compile(r'(?<![0-9a-z])(\d+(?:[.p]\d+)?)\s*kfps', re.IGNORECASE)
_FEATURE = re.compile(r'\(([^()]*)\)\s*$')


def is_export_header(cells: list) -> bool:
    """True for the tracker's column header row: ``Frame | Time | ...``."""
    return (len(cells) >= 2 and _text(cells[0]).lower() == 'frame'
            and _text(cells[1]).lower() == 'time')


def looks_like_export(first_cells: list) -> bool:
    """True if a file starting with this row is the tracker's (not the project's) layout."""
    first = _text(first_cells[0]).lower() if first_cells else ''
    return is_export_header(first_cells) or first.startswith('motion analysis')


def parse_calibration(text: str) -> dict:
    """Fields of a ``Calibration 1:`` string (missing fields are left out).

    ``Name: Calibration1, Type: Normal, Scale: 5.89969 pixels/millimeter, 0.1695
    millimeters/pixel, Origin: 195.7, 293.5 pixels, Tilt: 0 degrees, System: Left-Handed
    Coordinate, Calibration Units: Millimeters``
    """
    out: dict = {}
    m = re.search(r'([-+\d.eE]+)\s*(\w+?)s?\s*/\s*pixel', text, re.IGNORECASE)
    if m:
        out['units_per_pixel'] = float(m.group(1))
    m = re.search(r'Scale:\s*([-+\d.eE]+)\s*pixels?\s*/\s*(\w+)', text, re.IGNORECASE)
    if m:
        out['pixels_per_unit'] = float(m.group(1))
    m = re.search(r'Origin:\s*([-+\d.eE]+)\s*,\s*([-+\d.eE]+)', text, re.IGNORECASE)
    if m:
        out['origin_px'] = (float(m.group(1)), float(m.group(2)))
    m = re.search(r'Tilt:\s*([-+\d.eE]+)', text, re.IGNORECASE)
    if m:
        out['tilt_deg'] = float(m.group(1))
    m = re.search(r'System:\s*(Left|Right)', text, re.IGNORECASE)
    if m:
        out['handedness'] = m.group(1).lower()
    m = re.search(r'Calibration Units:\s*([A-Za-zµ]+)', text, re.IGNORECASE)
    if m:
        out['units'] = m.group(1).lower()
    if 'units_per_pixel' not in out and out.get('pixels_per_unit'):
        out['units_per_pixel'] = 1.0 / out['pixels_per_unit']
    return out


def rate_from_name(name: str) -> float | None:
    """Frames per second from a trial name such as ``111319_11kfps_T_2X_A_2_1_2p3_-10_5_2``."""
    m = _RATE_IN_NAME.search(name or '')
    return float(m.group(1).replace('p', '.')) * 1000.0 if m else None


def parse_export_rows(rows: list[list], fname: str, frame_rate_hz: float | None = None,
                      length_unit: str | None = None,
                      source: dict | None = None) -> MarkerTracks:
    """The tracks of an export's rows (header block optional): millimetres, NaN where a
    marker is lost, the calibration's handedness and tilt, the frame rate and the unit the
    numbers were in as the tracks' fields; the header block (and how the rate and unit were
    found) in ``source``, after the caller's ``source`` (path, format). Not yet validated."""
    start = next((i for i, r in enumerate(rows) if is_export_header(r)), None)
    if start is None:
        raise TrackFormatError(f'{fname}: no column header row "Frame, Time, Feature 1 (...)"')
    meta = _header_block(rows[:start])
    if start + 1 >= len(rows):
        raise TrackFormatError(f'{fname}: no x/y row under the column header')
    columns, ignored = _marker_columns(rows[start], rows[start + 1], fname)
    table = _numeric_table(rows[start + 2:], fname, start + 3)
    if len(table) == 0:
        raise TrackFormatError(f'{fname}: no data rows under the column header')
    width = table.shape[1]
    needed = max(max(ix, iy) for ix, iy in columns.values())
    if needed >= width:
        raise TrackFormatError(f'{fname}: the data rows have {width} columns, the header '
                                f'names {needed + 1}')
    frames = table[:, 0]
    raw_time = table[:, 1]
    for what, col in (('Frame', frames), ('Time', raw_time)):
        bad = np.nonzero(~np.isfinite(col))[0]
        if len(bad):
            raise TrackFormatError(f'{fname}: row {start + 3 + int(bad[0])}: {what} is not a '
                                    'number')
    time_s, rate, rate_note = _time_base(meta, frames, raw_time, fname, frame_rate_hz)
    to_mm, unit, unit_note = _length_scale(meta, fname, length_unit)
    markers = {}
    for name, (ix, iy) in columns.items():
        markers[name] = lost_as_gaps(table[:, [ix, iy]]) * to_mm
    if ignored:
        meta['ignored_features'] = ','.join(ignored)
    return MarkerTracks(
        time_s=time_s, frames=frame_numbers(frames, fname), markers_mm=markers,
        handedness=meta.get('calibration_handedness', 'left'),
        tilt_deg=meta.get('calibration_tilt_deg'),
        source={**(source or {}), **meta, **rate_note, **unit_note},
        frame_rate_hz=rate, length_unit=unit)


def read_export(rows: list[list], path: Path, fmt: str, frame_rate_hz: float | None = None,
                length_unit: str | None = None) -> MarkerTracks:
    """The validated tracks of an export's rows read from ``path`` (``fmt``: 'xlsx', 'csv')."""
    tracks = parse_export_rows(rows, path.name, frame_rate_hz, length_unit,
                               source={'path': str(path), 'format': fmt})
    tracks.validate()
    return tracks


def read_xlsx_rows(path: Path) -> list[list]:
    """The first worksheet's rows, as lists, as openpyxl reads them (``data_only``, read-only)
    but for a blank cell (``''``, not None); damage is a TrackFormatError naming the file."""
    from python_calamine import CalamineError, CalamineWorkbook, SheetTypeEnum, XmlError
    try:
        wb = CalamineWorkbook.from_path(str(path))
    except XmlError as exc:
        raise TrackFormatError(f'{path.name}: damaged .xlsx ({type(exc).__name__}: '
                               f'{exc})') from exc
    except (CalamineError, OSError) as exc:   # not a zip, or none of a workbook's parts
        raise TrackFormatError(f'{path.name}: not a readable .xlsx workbook ({exc})') from exc
    except BaseException as exc:  # noqa: BLE001 - see _damage
        raise _damage(exc, f'{path.name}: damaged .xlsx') from exc
    try:
        try:
            sheets = [i for i, s in enumerate(wb.sheets_metadata)
                      if s.typ == SheetTypeEnum.WorkSheet]
            if not sheets:
                raise TrackFormatError(f'{path.name}: the workbook has no worksheet')
            rows = wb.get_sheet_by_index(sheets[0]).to_python(skip_empty_area=False)
        except TrackFormatError:
            raise
        except BaseException as exc:  # noqa: BLE001 - see _damage
            raise _damage(exc, f'{path.name}: damaged worksheet') from exc
    finally:
        wb.close()
    _as_openpyxl_reads(rows)
    return rows


def _damage(exc: BaseException, what: str) -> TrackFormatError:
    """What the parser raised on a damaged file, as a TrackFormatError: any exception, and a
    panic of its Rust code (pyo3's PanicException, a BaseException); an interrupt or an exit
    goes on as it is."""
    if isinstance(exc, (KeyboardInterrupt, SystemExit, GeneratorExit, MemoryError)):
        raise exc
    return TrackFormatError(f'{what} ({type(exc).__name__}: {exc})')


def _as_openpyxl_reads(rows: list[list]) -> None:
    """Cells above the data as openpyxl reads them, in place: a whole number is an int (the
    file writes '19000', calamine reads every number as a float), a date a datetime. Only the
    header block's text depends on it; the numbers below the column header become floats."""
    end = next((i for i, r in enumerate(rows) if is_export_header(r)), len(rows) - 2) + 2
    for row in rows[:end]:
        for k, v in enumerate(row):
            if isinstance(v, float) and v.is_integer() and abs(v) < 2 ** 53:
                row[k] = int(v)
            elif type(v) is datetime.date:
                row[k] = datetime.datetime.combine(v, datetime.time())


# ------------------------------------------------------------------------------- internals
def _text(v) -> str:
    return '' if v is None else str(v).strip()


def _header_block(rows: list[list]) -> dict:
    meta: dict = {}
    for row in rows:
        if not row:
            continue
        label = _text(row[0])
        values = [v for v in row[1:] if _text(v)]
        if not label or (not label.endswith(':') and not values):
            continue                      # a section title ("Test Data", "Calibration(s)")
        key = label.rstrip(':').strip().lower()
        if key == 'date':                 # "Date: | d | | Time: | t"
            meta['date'] = _text(values[0]) if values else ''
            if len(values) >= 3 and _text(values[1]).lower().startswith('time'):
                meta['time_of_day'] = _text(values[2])
            continue
        meta[key] = _text(values[0]) if values else ''
    calibration = next((v for k, v in meta.items() if k.startswith('calibration')
                        and k != 'calibration units'), None)
    if calibration:
        meta['calibration'] = calibration
        meta.update({f'calibration_{k}': v for k, v in parse_calibration(calibration).items()})
    return meta


def _marker_columns(labels: list, axes: list, fname: str) -> tuple[dict, list[str]]:
    """{marker name: (x column, y column)} from the header rows, and ignored feature names."""
    columns: dict[str, list] = {}
    ignored = []
    current = None
    for i in range(2, len(labels)):
        label = _text(labels[i])
        if label:
            m = _FEATURE.search(label)
            name = (m.group(1) if m else label).strip()
            if re.fullmatch(r'm[ab]\w*', name, re.IGNORECASE):
                current = name.lower()
                if current in columns:
                    raise TrackFormatError(f'{fname}: marker {current} appears twice')
                columns[current] = [None, None]
            else:
                current = None
                ignored.append(name)
        if current is None:
            continue
        axis = _text(axes[i]).lower() if i < len(axes) else ''
        if axis in ('x', 'y'):
            columns[current]['xy'.index(axis)] = i
    incomplete = sorted(f'{n} {a}' for n, ix in columns.items()
                        for a, j in zip('xy', ix, strict=True) if j is None)
    if incomplete:
        raise TrackFormatError(f'{fname}: no column for {incomplete} (the row under the column '
                                'header must label each marker\'s x and y)')
    return {n: (ix[0], ix[1]) for n, ix in sorted(columns.items())}, ignored


def _cell_number(v) -> float:
    if v is None:
        return math.nan
    if isinstance(v, (int, float)):
        return float(v)
    s = str(v).strip()
    if not s:
        return math.nan
    return float(s)


def _numeric_table(rows: list[list], fname: str, first_row: int) -> np.ndarray:
    table = _numeric_table_at_once(rows)
    if table is not None:
        return table
    body = []
    for k, row in enumerate(rows):
        if not row or all(not _text(v) for v in row):
            continue
        try:
            body.append([_cell_number(v) for v in row])
        except (TypeError, ValueError):
            bad = next(v for v in row if not _is_number(v))
            raise TrackFormatError(f'{fname}: row {first_row + k}: {bad!r} is not a '
                                    'number') from None
    if not body:
        return np.empty((0, 0))
    width = max(len(r) for r in body)
    table = np.full((len(body), width), np.nan)
    for k, r in enumerate(body):
        table[k, :len(r)] = r
    # A trailing empty column (a trailing comma) carries nothing.
    return table


def _numeric_table_at_once(rows: list[list]) -> np.ndarray | None:
    """The table of rows of one width, converted by numpy at once (blank cells NaN, blank
    rows dropped), as the cell-by-cell conversion makes it; None if they are ragged or hold
    anything numpy does not turn into the same number (text, blanks of spaces, dates): then the
    cell-by-cell conversion names the row."""
    rows = [r for r in rows if r]
    if not rows or any(len(r) != len(rows[0]) for r in rows):
        return None
    cells = np.array(rows, dtype=object)
    if cells.ndim != 2:
        return None
    blank = np.equal(cells, '') | np.equal(cells, None)
    cells[blank] = math.nan
    try:
        table = cells.astype(np.float64)
    except (TypeError, ValueError, OverflowError):
        return None
    return table[~blank.all(axis=1)] if blank.any() else table


def _is_number(v) -> bool:
    try:
        _cell_number(v)
        return True
    except (TypeError, ValueError):
        return False


def _trial_name(meta: dict, fname: str) -> str:
    path = meta.get('file name') or ''
    return PureWindowsPath(path).stem if path else Path(fname).name


def _time_base(meta: dict, frames: np.ndarray, raw_time: np.ndarray, fname: str,
               frame_rate_hz: float | None) -> tuple[np.ndarray, float | None, dict]:
    stated = meta.get('record rate')
    rate = None
    if stated not in (None, '') and stated.strip().upper() != 'N/A':
        try:
            rate = float(stated)
        except ValueError:
            raise TrackFormatError(f'{fname}: Record Rate {stated!r} is not a number') from None
        if not (math.isfinite(rate) and rate > 0):
            raise TrackFormatError(f'{fname}: Record Rate {stated!r} is not a positive rate')
    frame_numbers = stated is not None and rate is None      # "N/A": Time holds frame numbers
    if frame_rate_hz is not None:
        if rate is not None and abs(rate - frame_rate_hz) > 1e-6 * rate:
            raise TrackFormatError(f'{fname}: --frame-rate {frame_rate_hz:g} contradicts the '
                                    f'file\'s Record Rate {rate:g} frames/s')
        rate, source = float(frame_rate_hz), 'given'
    elif rate is not None:
        source = 'record rate'
    else:
        source = 'trial name'
        rate = rate_from_name(_trial_name(meta, fname))
    if frame_numbers or (stated is None and np.array_equal(raw_time, frames)):
        if rate is None:
            raise TrackFormatError(
                f'{fname}: the frame rate is not stated (Record Rate: N/A, the Time column '
                'holds frame numbers) and the trial name carries none (like "11kfps"): give '
                'it with --frame-rate FPS')
        time_s = raw_time / rate
        return time_s, rate, {'frame_rate_source': source}
    if stated is None:          # a header-less CSV: the times are seconds
        steps = np.diff(raw_time)
        if len(steps) and np.median(steps) > 0:
            measured = 1.0 / float(np.median(steps))
            return raw_time, rate or measured, {
                'frame_rate_source': source if rate else 'time column'}
    return raw_time, rate, {'frame_rate_source': source}


def _length_scale(meta: dict, fname: str, length_unit: str | None,
                  ) -> tuple[float, str, dict]:
    """(millimetres per exported unit, the unit, what it came from)."""
    per_pixel = meta.get('calibration_units_per_pixel')
    cal_units = meta.get('calibration_units', 'millimeters')
    if length_unit is not None:
        if length_unit not in LENGTH_UNITS:
            raise TrackFormatError(f'length unit {length_unit!r}: expected one of '
                                    f'{LENGTH_UNITS}')
        if length_unit == 'px':
            if per_pixel is None:
                raise TrackFormatError(f'{fname}: --length-unit px needs the calibration\'s '
                                        'millimetres per pixel, and the file states none')
            scale = per_pixel * UNIT_MM.get(cal_units, 1.0)
        else:
            scale = {'mm': 1.0, 'um': 1e-3}[length_unit]
        return scale, length_unit, {'length_unit_source': 'given'}
    unit = (meta.get('export units') or '').strip().lower()
    if not unit:
        return 1.0, 'mm', {'length_unit_source': 'default (no Export Units)'}
    if unit in ('pixels', 'pixel', 'px'):
        if per_pixel is None:
            raise TrackFormatError(f'{fname}: Export Units are Pixels but no calibration '
                                    'states the millimetres per pixel')
        cal_scale = UNIT_MM.get(cal_units)
        if cal_scale is None:
            raise TrackFormatError(f'{fname}: unknown Calibration Units {cal_units!r}')
        return per_pixel * cal_scale, 'px', {'length_unit_source': 'Export Units'}
    scale = UNIT_MM.get(unit)
    if scale is None:
        raise TrackFormatError(f'{fname}: unknown Export Units {meta.get("export units")!r} '
                                '(expected Millimeters, Micrometers or Pixels)')
    return scale, unit, {'length_unit_source': 'Export Units'}
