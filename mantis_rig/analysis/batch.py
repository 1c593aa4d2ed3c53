"""Batch analysis: many trials (tracking files and bags), analysed in parallel, one row each.

``mantis analyze FILES_OR_DIRS... --table results.csv`` runs on it:

- :func:`expand_paths` turns the command line's paths into trials: a directory is searched
  recursively for tracking files (``*.xlsx``, ``*.csv``, ``*.csv.gz``) and bags (a directory
  holding ``metadata.yaml``, or ``.mcap`` files without it: a bag whose writer was killed); a
  bag is one trial, never searched further. Hidden entries (``.name``) and Excel's lock files
  (``~$name.xlsx``) found in a directory are not trials. A path named on the command line is
  always a trial, whatever its name (if it cannot be read, its row says why).
- :func:`analyse_one` reads one trial (:func:`.inputs.read_trial`), analyses it as ``mantis
  analyze PATH`` does (:func:`.trial.analyse_trial`) and returns its table row; it never
  raises: a trial that cannot be read or analysed is a ``refused`` row whose ``reason`` says
  why.
- :func:`run_batch` analyses the trials over a process pool and returns the rows in the
  order of the trials; :func:`write_table` writes them as CSV (:data:`COLUMNS`).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import BrokenExecutor, ProcessPoolExecutor, as_completed
import csv
import math
import multiprocessing
import os
from pathlib import Path, PureWindowsPath
import sys
from typing import TextIO
import warnings

import numpy as np

from mantis_rig.analysis.one_trial import TrialRefused, analyse_trial
from mantis_sim.errors import InputError

from ..recording import BagError
from .inputs import TrackFormatError, read_trial

TRACKING_SUFFIXES = ('.xlsx', '.csv', '.csv.gz')
PHASES = ('I', 'II', 'III', 'IV')
#: The table's columns: what the trial was, whether it was analysed, and its summary numbers.
COLUMNS = ('path', 'trial', 'status', 'reason', 'peak_tip_speed_mps',
           *(f'phase_{p}_start_s' for p in PHASES), 'overcentering_s',
           'peak_body_speed_radps', 'peak_arm_speed_radps', 'max_spring_energy_mJ', 'L1_mm',
           'contact_angle_deg', 'frame_rate_hz', 'n_frames', 'warnings')
OK, REFUSED = 'ok', 'refused'
#: Summary keys copied into the row as they are.
_SUMMARY_COLUMNS = ('peak_tip_speed_mps', 'overcentering_s', 'peak_body_speed_radps',
                    'peak_arm_speed_radps', 'max_spring_energy_mJ', 'L1_mm',
                    'contact_angle_deg')


# ------------------------------------------------------------------------------ the trials
def is_bag_dir(path) -> bool:
    """A directory holding a bag: its ``metadata.yaml``, or ``.mcap`` files without one."""
    path = Path(path)
    return path.is_dir() and ((path / 'metadata.yaml').is_file()
                              or any(p.is_file() for p in path.glob('*.mcap')))


def is_tracking_file(path) -> bool:
    return Path(path).name.lower().endswith(TRACKING_SUFFIXES)


def _not_a_trial(name: str) -> bool:
    return name.startswith(('.', '~$'))


def expand_paths(paths: Iterable, exclude: Iterable = ()) -> tuple[list[Path], list[str]]:
    """(the trials the paths name, each once: in the order of the paths, a directory's in the
    order of their paths; notes on directories that hold none).

    ``exclude``: files that are never trials (the table being written, if it lies among them).
    """
    excluded = {Path(p).resolve() for p in exclude}
    trials: list[Path] = []
    seen: set[Path] = set(excluded)
    notes = []

    def add(path: Path) -> None:
        key = path.resolve()
        if key not in seen:
            seen.add(key)
            trials.append(path)

    for path in map(Path, paths):
        if not path.is_dir() or is_bag_dir(path):
            add(path)                       # a file, a bag, or a missing path: its row says
            continue
        found = []
        for root, dirs, files in os.walk(path):
            root = Path(root)
            dirs[:] = [d for d in dirs if not _not_a_trial(d)]
            bags = [d for d in dirs if is_bag_dir(root / d)]
            dirs[:] = [d for d in dirs if d not in bags]
            found += [root / d for d in bags]
            found += [root / f for f in files if is_tracking_file(f) and not _not_a_trial(f)]
        if not found:
            notes.append(f'{path}: no tracking files ({", ".join(TRACKING_SUFFIXES)}) or bags '
                         'in it')
        for trial in sorted(found, key=lambda p: p.parts):
            add(trial)
    return trials, notes


def trial_name(path, source: dict | None = None) -> str:
    """The trial's name: the video's, as the tracker's export names it, else the file's or the
    bag's."""
    video = (source or {}).get('file name')
    if video:
        return PureWindowsPath(str(video)).stem
    path = Path(path)
    name = path.name
    for suffix in ('.csv.gz', '.xlsx', '.csv', '.mcap'):
        if name.lower().endswith(suffix):
            return name[:-len(suffix)]
    return name


# --------------------------------------------------------------------------- one trial
def _row(path, trial: str, status: str, reason: str = '', **values) -> dict:
    row = dict.fromkeys(COLUMNS, None)
    row.update(path=str(path), trial=trial, status=status, reason=reason, **values)
    return row


def _frame_rate(tracks) -> float | None:
    """The frame rate the tracks state, else the one of the median step of the times."""
    rate = tracks.frame_rate_hz
    if rate is not None and math.isfinite(rate) and rate > 0:
        return float(rate)
    steps = np.diff(tracks.time_s)
    return float(1.0 / np.median(steps)) if len(steps) and np.median(steps) > 0 else None


def analyse_one(path, given: dict | None = None, frame_rate_hz: float | None = None,
                length_unit: str | None = None) -> dict:
    """The table row of one trial, analysed as ``mantis analyze PATH`` analyses it (``given``:
    the trial conditions stated on the command line). Never raises: any exception, expected
    (TrackFormatError, ValueError, OSError, BagError ...) or not, is a refused row. Python
    warnings raised on the way land in the row's ``warnings``, not on stderr."""
    path = Path(path)
    with warnings.catch_warnings(record=True) as caught:    # the filters in force decide
        trial, notes = None, []
        stage = 'reading'
        try:
            trial = read_trial(path, frame_rate_hz, length_unit)
            stage = 'analysis'
            row = _analyse(path, trial, given or {}, notes)
        except Exception as exc:  # noqa: BLE001 - the batch's boundary: a trial's failure, whatever it is, is its row (named), never the batch's end
            row = _row(path, status=REFUSED, reason=_reason(exc, stage),
                       **_what_was_read(path, trial))
    for w in caught:
        text = f'{w.category.__name__}: {w.message}'
        if text not in notes:
            notes.append(text)
    row['warnings'] = '; '.join(notes)
    return row


def _what_was_read(path: Path, trial) -> dict:
    if trial is None:
        return {'trial': trial_name(path)}
    tracks = trial.tracks
    return {'trial': trial_name(path, tracks.source), 'frame_rate_hz': _frame_rate(tracks),
            'n_frames': tracks.n_frames}


def _analyse(path: Path, trial, given: dict, notes: list) -> dict:
    """The row of a trial that was read; ``notes`` collects its warnings."""
    tracks = trial.tracks
    known = _what_was_read(path, trial)
    if trial.problems:
        notes.append(f'damaged: {"; ".join(trial.problems)}; analysed the {tracks.n_frames} '
                     f'frames before the damage (to t = {float(tracks.time_s[-1]):.4f} s)')
    try:
        analysis, warned, _ = analyse_trial(trial, given)
    except TrialRefused as exc:
        return _row(path, status=REFUSED, reason=str(exc), **known)
    notes.extend(warned)
    summary = analysis.summary()
    values = {k: summary[k] for k in _SUMMARY_COLUMNS}
    values.update({f'phase_{p}_start_s': summary['phase_start_s'][p] for p in PHASES})
    return _row(path, status=OK, **known, **values)


def _reason(exc: Exception, stage: str) -> str:
    text = str(exc) or type(exc).__name__
    if isinstance(exc, (TrackFormatError, BagError, OSError)):
        return text
    if isinstance(exc, (InputError, ValueError)):
        return f'{stage}: {text}'
    return f'unexpected {type(exc).__name__} in {stage}: {text}'


# ---------------------------------------------------------------------------- the batch
def _size(path: Path) -> int:
    try:
        if path.is_dir():
            return sum(p.stat().st_size for p in path.glob('*.mcap'))
        return path.stat().st_size
    except OSError:
        return 0


def run_batch(trials: list, given: dict | None = None, frame_rate_hz: float | None = None,
              length_unit: str | None = None, jobs: int | None = None,
              on_done: Callable[[dict], None] | None = None) -> list[dict]:
    """The rows of ``trials`` (in their order), analysed by up to ``jobs`` processes (default:
    one per core); ``on_done(row)`` as each trial finishes (in the order they finish)."""
    trials = [Path(t) for t in trials]
    jobs = min(jobs or os.cpu_count() or 1, len(trials))
    rows: list = [None] * len(trials)
    done = on_done or (lambda row: None)
    if jobs <= 1:
        for i, path in enumerate(trials):
            rows[i] = analyse_one(path, given, frame_rate_hz, length_unit)
            done(rows[i])
        return rows
    # Largest first: the long trials start early and the short ones fill in the end.
    order = sorted(range(len(trials)), key=lambda i: -_size(trials[i]))
    # forkserver, not fork: the caller may run threads (rclpy's, a live relay's, a test runner's)
    # and a child forked from a threaded process can inherit a lock held mid-way or crash; one
    # CI run saw a worker die of a segmentation fault and refuse every trial.
    pool = ProcessPoolExecutor(max_workers=jobs,
                               mp_context=multiprocessing.get_context('forkserver'))
    try:
        futures = {pool.submit(analyse_one, str(trials[i]), given, frame_rate_hz,
                               length_unit): i for i in order}
        for future in as_completed(futures):
            i = futures[future]
            try:
                rows[i] = future.result()
            except BrokenExecutor as exc:  # the worker process itself died (BrokenProcessPool)
                rows[i] = _row(trials[i], trial_name(trials[i]), REFUSED,
                               f'the analysing process died ({type(exc).__name__}: {exc})')
            done(rows[i])
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return rows


# ------------------------------------------------------------------------------ output
def _cell(value) -> str:
    if value is None:
        return ''
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f'{value:.10g}' if math.isfinite(value) else ''
    return str(value)


def write_table(rows: list[dict], stream: TextIO) -> None:
    """The rows as CSV, :data:`COLUMNS` in order (a number that is not finite: empty)."""
    writer = csv.writer(stream, lineterminator='\n')
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in COLUMNS])


class Progress:
    """A one-line progress bar on a terminal (``\\r[#####     ] 3/6 trial``, refused trials
    printed above it); one line per finished trial on anything else (a log, a pipe)."""

    def __init__(self, total: int, stream: TextIO | None = None, width: int = 20):
        self.total, self.width, self.done = total, width, 0
        self.stream = stream if stream is not None else sys.stderr
        try:
            self.tty = self.stream.isatty()
        except (AttributeError, ValueError):
            self.tty = False
        self._shown = 0

    def __call__(self, row: dict) -> None:
        self.done += 1
        refused = row['status'] != OK
        if not self.tty:
            line = f'[{self.done}/{self.total}] {row["status"]} {row["path"]}'
            self.stream.write(line + (f': {row["reason"]}' if refused else '') + '\n')
            self.stream.flush()
            return
        if refused:
            self._clear()
            self.stream.write(f'refused {row["path"]}: {row["reason"]}\n')
        filled = round(self.width * self.done / max(self.total, 1))
        bar = f'[{"#" * filled}{" " * (self.width - filled)}] {self.done}/{self.total} ' \
              f'{row["trial"]}'
        self.stream.write('\r' + bar + ' ' * max(0, self._shown - len(bar)))
        self._shown = len(bar)
        self.stream.flush()

    def _clear(self) -> None:
        if self._shown:
            self.stream.write('\r' + ' ' * self._shown + '\r')
            self._shown = 0

    def close(self) -> None:
        if self.tty and self._shown:
            self.stream.write('\n')
            self.stream.flush()
            self._shown = 0
