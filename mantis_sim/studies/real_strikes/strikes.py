"""Real strikes of the robot, as the identification and the comparison see them.

A `RealStrike` is one strike at its own conditions (medium, guide distance, contact angle,
measured pull speed), with what was measured of it: the lab's summary values (peak tip speed,
spring energy, peak angular speeds) and, where recorded, the motion and tendon force around the
strike (`StrikeSeries`, time from the start of phase IV). Readers here take the lab's two
plain-text forms: a summary table (CSV, one row per strike) and a processed record (the
authors' six columns per camera frame). Tracker exports are read by the rig package's analysis,
which builds the same `StrikeSeries`.

Where the arm sat on the latch (`RealStrike.seat_deg`: the arm's angle relative to the body at
the lab's overcentering) decides most of a strike's stored energy and is not among the
conditions (docs/fidelity.md); a table may give it (column `seat_deg`), or a processed record
shows it at the table's overcentering time `t_oc_s`.

The lab's spring energy (`spring_energy_mJ`) is the lab's convention of the body angle at
phase IV (mantis_sim.results.lab_spring_energy_mJ), which a simulated strike's deepest body turn
is given too, so that both sides use one formula whatever spring a model has.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field, replace
import gzip
import math
from pathlib import Path
from typing import Optional

import numpy as np

from mantis_sim.errors import InputError

MEDIA = ('air', 'water')
# What is kept of a record around phase IV (s): the strike and its approach, not the seconds of
# loading (a record holds up to 65,000 frames; the comparison needs the strike's few hundred).
RECORD_WINDOW_S = (-0.05, 0.1)
SUMMARY_REQUIRED = ('trial', 'medium', 'd_t_mm', 'contact_angle_deg')
PULL_COLUMNS = ('pull_measured_mm_s', 'pull_nominal_mm_s')   # the measured one first
SUMMARY_VALUES = {            # column -> RealStrike field
    'v_max_mps': 'peak_tip_speed_mps',
    'PE_max_mJ': 'spring_energy_mJ',
    'peak_body_radps': 'peak_body_speed_radps',
    'peak_arm_radps': 'peak_arm_speed_radps',
}
# Plausible ranges of the conditions: a value outside is a unit mix-up or a typo, refused.
CONDITION_RANGES = {'d_t_mm': (5.0, 60.0), 'contact_angle_deg': (0.0, 15.0),
                    'pull_mm_per_s': (0.01, 50.0), 'seat_deg': (-5.0, 30.0)}
# An overcentering time within a record's first this many seconds marks overcentering before
# the recording began (the table's notes: "F_oc at the recording start"): no seat is read there.
SEAT_MIN_INTO_RECORD_S = 0.05


class StrikeDataError(InputError):
    """A strike table or record cannot be used; the message names the file, row and column."""


@dataclass(frozen=True)
class StrikeSeries:
    """Motion (and tendon force, where recorded) around a strike; t = 0 at phase IV (the body's
    deepest turn). Angles in rad; theta3 is the arm's angle relative to the body."""

    t_s: np.ndarray
    theta1_rad: np.ndarray
    theta3_rad: np.ndarray
    tendon_force_N: Optional[np.ndarray] = None

    def window(self, start_s: float, stop_s: float) -> StrikeSeries:
        keep = (self.t_s >= start_s) & (self.t_s <= stop_s)
        force = None if self.tendon_force_N is None else self.tendon_force_N[keep]
        return StrikeSeries(self.t_s[keep], self.theta1_rad[keep], self.theta3_rad[keep], force)


@dataclass(frozen=True)
class RealStrike:
    trial: str
    medium: str
    d_t_mm: float
    contact_angle_deg: float
    pull_mm_per_s: float
    recording_day: str = ''
    peak_tip_speed_mps: Optional[float] = None
    spring_energy_mJ: Optional[float] = None
    peak_body_speed_radps: Optional[float] = None
    peak_arm_speed_radps: Optional[float] = None
    series: Optional[StrikeSeries] = field(default=None, compare=False)
    source: str = ''
    seat_deg: Optional[float] = None    # the arm's angle on the body at overcentering, tracked

    @property
    def group(self) -> str:
        """The lab's configuration: medium and guide distance, e.g. 'air_23mm'."""
        return f'{self.medium}_{self.d_t_mm:g}mm'

    def with_series(self, series: StrikeSeries, source: str) -> RealStrike:
        return replace(self, series=series,
                       source=f'{self.source}; {source}' if self.source else source)


def _number(text: str, where: str, column: str, required: bool) -> Optional[float]:
    text = (text or '').strip()
    if not text:
        if required:
            raise StrikeDataError(f'{where}: column {column} is empty')
        return None
    try:
        value = float(text)
    except ValueError:
        raise StrikeDataError(f'{where}: column {column} = {text!r} is not a number') from None
    if not math.isfinite(value):
        raise StrikeDataError(f'{where}: column {column} = {text!r} is not a finite number')
    return value


def _check_range(value: float, name: str, where: str) -> float:
    lo, hi = CONDITION_RANGES[name]
    if not lo <= value <= hi:
        raise StrikeDataError(f'{where}: {name} = {value:g} is outside [{lo:g}, {hi:g}] '
                              f'(a unit mix-up?)')
    return value


def read_summary_table(path: Path) -> list[RealStrike]:
    """One RealStrike per row of a summary table (columns of authors_summary_train.csv:
    trial, medium, d_t_mm, contact_angle_deg, pull_measured_mm_s or pull_nominal_mm_s, and any of
    v_max_mps, PE_max_mJ, peak_body_radps, peak_arm_radps, recording_day, seat_deg)."""
    path = Path(path)
    try:
        with open(path, newline='', encoding='utf-8') as handle:
            reader = csv.DictReader(handle)
            rows = list(reader)
            header = [str(c) for c in reader.fieldnames or []]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise StrikeDataError(f'{path}: cannot read the summary table ({exc})') from None
    if not rows:
        raise StrikeDataError(f'{path}: no rows')
    missing = [c for c in SUMMARY_REQUIRED if c not in header]
    if not any(c in header for c in PULL_COLUMNS):
        missing.append(' or '.join(PULL_COLUMNS))
    if missing:
        raise StrikeDataError(f'{path}: missing column(s) {", ".join(missing)}; found '
                              f'{", ".join(header)}')
    strikes = []
    for number, row in enumerate(rows, start=2):
        if None in row:         # more fields than the header names: a damaged line
            raise StrikeDataError(f'{path} row {number}: {len(header) + len(row[None])} fields '
                                  f'where the header names {len(header)}')
        trial = (row.get('trial') or '').strip()
        where = f'{path} row {number} ({trial or "no trial name"})'
        if not trial:
            raise StrikeDataError(f'{where}: column trial is empty')
        medium = (row.get('medium') or '').strip()
        if medium not in MEDIA:
            raise StrikeDataError(f'{where}: medium {medium!r} is not one of {", ".join(MEDIA)}')
        pull = next((v for v in (_number(row.get(c, ''), where, c, False) for c in PULL_COLUMNS
                                 if c in row) if v is not None), None)
        if pull is None:
            raise StrikeDataError(f'{where}: no pull speed (columns {", ".join(PULL_COLUMNS)})')
        values = {attr: _number(row.get(col, ''), where, col, False)
                  for col, attr in SUMMARY_VALUES.items()}
        seat = _number(row.get('seat_deg', ''), where, 'seat_deg', False)
        strikes.append(RealStrike(
            trial=trial, medium=medium,
            d_t_mm=_check_range(_number(row['d_t_mm'], where, 'd_t_mm', True), 'd_t_mm', where),
            contact_angle_deg=_check_range(
                _number(row['contact_angle_deg'], where, 'contact_angle_deg', True),
                'contact_angle_deg', where),
            pull_mm_per_s=_check_range(pull, 'pull_mm_per_s', where),
            recording_day=(row.get('recording_day') or '').strip(), source=str(path),
            seat_deg=None if seat is None else _check_range(seat, 'seat_deg', where),
            **values))
    return strikes


def read_processed_record(path: Path, phase_iv_s: float) -> StrikeSeries:
    """The authors' processed record of one strike (CSV, optionally gzipped, no header: time
    s, theta1 rad, theta2 rad (the arm relative to the body), their rates, tendon force N),
    re-timed so that t = 0 at phase IV (``phase_iv_s``, in the record's time)."""
    return _strike_series(*_load_processed(path), phase_iv_s)


def _load_processed(path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """(path, frame times s, the record's columns) of a processed record, checked."""
    path = Path(path)
    opener = gzip.open if path.suffix == '.gz' else open
    try:
        with opener(path, 'rt', encoding='utf-8') as handle:
            data = np.loadtxt(handle, delimiter=',', ndmin=2)
    except (OSError, ValueError, EOFError, UnicodeDecodeError) as exc:
        raise StrikeDataError(f'{path}: not a processed record of six numeric columns '
                              f'({type(exc).__name__}: {exc})') from None
    if data.shape[1] != 6 or data.shape[0] < 10:
        raise StrikeDataError(f'{path}: expected six columns and at least 10 frames, got '
                              f'{data.shape[1]} columns and {data.shape[0]} frames')
    if not np.all(np.isfinite(data[:, :3])):
        raise StrikeDataError(f'{path}: the times and angles must be finite numbers')
    return path, _frame_times(data[:, 0], path), data


def _strike_series(path: Path, t: np.ndarray, data: np.ndarray, phase_iv_s: float) -> StrikeSeries:
    theta1, theta3, force = data[:, 1], data[:, 2], data[:, 5]
    if not t[0] <= phase_iv_s <= t[-1]:
        raise StrikeDataError(f'{path}: phase IV at {phase_iv_s:g} s is outside the record '
                              f'({t[0]:g} to {t[-1]:g} s)')
    return StrikeSeries(t - phase_iv_s, theta1, theta3, force).window(*RECORD_WINDOW_S)


def _frame_times(recorded: np.ndarray, path: Path) -> np.ndarray:
    """The frames' times: the records print time to 5 significant digits, so past 1 s
    neighbouring frames share a printed time; frames are evenly spaced, so the times are
    rebuilt from the first, the last and the frame count, and checked against the printed ones."""
    n = recorded.size
    step = (recorded[-1] - recorded[0]) / (n - 1)
    rebuilt = recorded[0] + step * np.arange(n)
    worst = float(np.max(np.abs(rebuilt - recorded)))
    if not step > 0 or worst > max(2.0 * step, 1e-4):
        raise StrikeDataError(f'{path}: the time column is not evenly spaced frames (rebuilt '
                              f'times differ from the printed ones by up to {worst:.3g} s)')
    return rebuilt


def seat_in_record(t: np.ndarray, theta2_rad: np.ndarray,
                   overcentering_s: Optional[float]) -> Optional[float]:
    """The arm's angle relative to the body (deg) at the lab's overcentering time, or None where
    that time is unknown, outside the record or within its first SEAT_MIN_INTO_RECORD_S."""
    if overcentering_s is None or not t[0] + SEAT_MIN_INTO_RECORD_S <= overcentering_s <= t[-1]:
        return None
    return float(np.degrees(np.interp(overcentering_s, t, theta2_rad)))


def attach_processed_records(strikes: list[RealStrike], folder: Path,
                             phase_iv_column: dict[str, float],
                             overcentering_column: Optional[dict[str, float]] = None
                             ) -> list[RealStrike]:
    """Each strike with its processed record `<trial>_data.csv.gz` (or .csv) from folder, where
    there is one; ``phase_iv_column`` maps trial -> phase IV time in its record, and
    ``overcentering_column`` trial -> the lab's overcentering time, where the arm's seat is
    read (unless the table gave the seat)."""
    out = []
    for strike in strikes:
        candidates = [Path(folder) / f'{strike.trial}_data.csv{ext}' for ext in ('.gz', '')]
        found = next((p for p in candidates if p.exists()), None)
        if found is None or strike.trial not in phase_iv_column:
            out.append(strike)
            continue
        path, t, data = _load_processed(found)
        with_record = strike.with_series(
            _strike_series(path, t, data, phase_iv_column[strike.trial]), str(found))
        if strike.seat_deg is None:
            with_record = replace(with_record, seat_deg=seat_in_record(
                t, data[:, 2], (overcentering_column or {}).get(strike.trial)))
        out.append(with_record)
    return out


def read_strikes(table: Path, processed: Optional[Path] = None) -> list[RealStrike]:
    """The strikes of a summary table, each with its processed record from the folder
    ``processed`` where it has one (timed by the table's t_z1_s), and the arm's seat read
    there at the table's t_oc_s where the table gives no seat_deg."""
    strikes = read_summary_table(table)
    if processed is None:
        return strikes
    if not Path(processed).is_dir():
        raise StrikeDataError(f'{processed}: no such folder of processed records')
    return attach_processed_records(strikes, processed, phase_iv_times(table),
                                    record_times(table, 't_oc_s'))


def phase_iv_times(path: Path) -> dict[str, float]:
    """trial -> t_z1_s (phase IV in the record's time) from a summary table that has it."""
    return record_times(path, 't_z1_s')


def record_times(path: Path, column: str) -> dict[str, float]:
    """trial -> a time in the trial's record (s) from a summary table's column, where given."""
    with open(path, newline='', encoding='utf-8') as handle:
        rows = list(csv.DictReader(handle))
    out = {}
    for number, row in enumerate(rows, start=2):
        if (row.get(column) or '').strip():
            trial = (row.get('trial') or '').strip()
            out[trial] = _number(row[column], f'{path} row {number} ({trial})', column, True)
    return out


__all__ = ['RealStrike', 'StrikeDataError', 'StrikeSeries', 'attach_processed_records',
           'phase_iv_times', 'read_processed_record', 'read_strikes', 'read_summary_table',
           'record_times', 'seat_in_record']
