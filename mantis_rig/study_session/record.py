"""A study's record, ``DIR/study.csv``: one row per trial in run order, rewritten whole and
atomically (a temporary file synced, then renamed over the old one) after every change, so that
a power cut leaves either the record before the change or the one after it, never a torn one.

A row's status: ``pending`` (owed), ``starting`` (its start was asked for: if the study died
here, the bag the supervisor may have opened is looked for), ``running`` (its bag is named),
``done``, ``aborted`` (the rig ended it; repeated at the end of its block, at most twice),
``interrupted`` (the person stopped the study during it; run again next), ``not started``
(the rig refused it). Aborted and interrupted rows stay in the record with their bags.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
import io
import math
from pathlib import Path

from mantis_sim.durable_files import write_atomically
from mantis_sim.errors import InputError
from mantis_sim.studies.rig_study.judge import forecast_columns
from mantis_sim.studies.rig_study.plan import CONDITION_KEYS
from mantis_sim.studies.rig_study.quantities import QUANTITIES

RECORD_NAME = 'study.csv'
PENDING, STARTING, RUNNING = 'pending', 'starting', 'running'
DONE, ABORTED, INTERRUPTED, NOT_STARTED = 'done', 'aborted', 'interrupted', 'not started'
STATUSES = (PENDING, STARTING, RUNNING, DONE, ABORTED, INTERRUPTED, NOT_STARTED)
OWED = (PENDING, STARTING, RUNNING)
#: How often an aborted trial is repeated at most.
MAX_REPEATS_OF_AN_ABORT = 2

LEADING = ('run', 'trial', 'block', 'attempt', *CONDITION_KEYS, 'status', 'reason', 'bag',
           'video', 'day', 'started_utc', 'analysed')
#: ``markers_from``: where the tip speed and spring energy came from (``bag``: the simulated
#: camera's marker frames in the bag; ``video``: the trial's film or its video attached, tracked;
#: ``export``: a tracker export attached; empty: neither)
TRAILING = ('flags', 'cause', 'day_strikes', 'markers_from')
INTEGER_COLUMNS = ('run', 'trial', 'block', 'attempt', 'day_strikes')
TEXT_COLUMNS = ('medium', 'status', 'reason', 'bag', 'video', 'day', 'started_utc', 'analysed',
                'flags', 'cause', 'markers_from') + tuple(f'{q}_flag' for q in QUANTITIES)


def columns() -> list[str]:
    out = list(LEADING)
    for name in QUANTITIES:
        out += [name, *forecast_columns(name)]
    return out + list(TRAILING)


class RecordError(InputError):
    """A study record that cannot be read (names the file, row and column)."""


@dataclass
class StudyRecord:
    path: Path
    rows: list          # dicts, in run order

    @property
    def directory(self) -> Path:
        return self.path.parent

    def save(self) -> None:
        text = io.StringIO()
        writer = csv.DictWriter(text, columns(), extrasaction='ignore', lineterminator='\n')
        writer.writeheader()
        for row in self.rows:
            writer.writerow({k: _cell(row.get(k)) for k in columns()})
        write_atomically(self.path, text.getvalue())

    def owed(self) -> list[dict]:
        return [r for r in self.rows if r['status'] in OWED]

    def renumber(self) -> None:
        for i, row in enumerate(self.rows, start=1):
            row['run'] = i

    def insert_after_block(self, row: dict) -> dict:
        """Insert ``row`` after the last row of its block (a repeat of an aborted trial)."""
        last = max(i for i, r in enumerate(self.rows) if r['block'] == row['block'])
        self.rows.insert(last + 1, row)
        self.renumber()
        return row

    def insert_after(self, before: dict, row: dict) -> dict:
        self.rows.insert(self.rows.index(before) + 1, row)
        self.renumber()
        return row

    def attempts_of(self, trial: int) -> list[dict]:
        return [r for r in self.rows if r['trial'] == trial]


def new_row(trial: int, block: int, attempt: int, conditions: dict) -> dict:
    row = dict.fromkeys(columns())
    row.update(trial=trial, block=block, attempt=attempt, status=PENDING, **conditions)
    return row


def repeat_of(row: dict) -> dict:
    return new_row(row['trial'], row['block'], row['attempt'] + 1,
                   {k: row[k] for k in CONDITION_KEYS if row.get(k) is not None})




def _cell(value) -> str:
    if value is None:
        return ''
    if isinstance(value, float):
        return '' if math.isnan(value) else repr(value)
    return str(value)


def read_record(path: Path) -> StudyRecord:
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as exc:
        raise RecordError(f'{path}: cannot read the study record: {exc.strerror or exc}') \
            from None
    reader = csv.DictReader(io.StringIO(text))
    missing = [c for c in ('run', 'trial', 'block', 'attempt', 'status', 'bag')
               if c not in (reader.fieldnames or [])]
    if missing:
        raise RecordError(f'{path}: not a study record: no column {", ".join(missing)}')
    rows = []
    for line, raw in enumerate(reader, start=2):
        row = dict.fromkeys(columns())
        for key, text_value in raw.items():
            if key is None:
                raise RecordError(f'{path}, line {line}: more cells than columns')
            row[key] = _parse(path, line, key, text_value)
        if row['status'] not in STATUSES:
            raise RecordError(f'{path}, line {line}: status {row["status"]!r} is not one of '
                              f'{", ".join(STATUSES)}')
        rows.append(row)
    return StudyRecord(path, rows)


def _parse(path: Path, line: int, key: str, text: str | None):
    if text is None or text == '':
        return None
    if key in TEXT_COLUMNS or key not in columns():
        return text
    try:
        return int(text) if key in INTEGER_COLUMNS else float(text)
    except ValueError:
        raise RecordError(f'{path}, line {line}, column {key}: {text!r} is not a number') \
            from None


__all__ = ['ABORTED', 'DONE', 'INTERRUPTED', 'MAX_REPEATS_OF_AN_ABORT', 'NOT_STARTED', 'OWED',
           'PENDING', 'RECORD_NAME', 'RUNNING', 'STARTING', 'StudyRecord', 'columns', 'new_row',
           'read_record', 'repeat_of', 'write_atomically']
