"""Run a study's plan on a rig, trial after trial, each measured and judged against the twin's
forecast as it lands; resumable from its record after anything.

The runner knows the rig only as a :class:`RigPort` (set a trial's conditions, start it, follow
it to its end) and the person only as an :class:`Operator` (what to do before each trial). It
keeps ``DIR/study.csv`` (mantis_rig.study_session.record) and ``DIR/plan.yaml`` (the plan as run,
its repeats resolved) and rewrites the record after every change. Run again with the same
plan, it takes the trials still owed: a row left ``starting`` or ``running`` by a study that
died is settled from the bag first (recovered if its writer never closed it), so that no trial
runs twice and none is lost.
"""
from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from datetime import UTC, datetime
import math
from pathlib import Path
import pickle
from typing import Optional, Protocol

import yaml

from mantis_rig.recording import TRIAL_OUTCOME, BagReader
from mantis_rig.study_session.record import (
    ABORTED,
    DONE,
    INTERRUPTED,
    MAX_REPEATS_OF_AN_ABORT,
    NOT_STARTED,
    PENDING,
    RECORD_NAME,
    RUNNING,
    STARTING,
    StudyRecord,
    new_row,
    read_record,
    repeat_of,
    write_atomically,
)
from mantis_sim.errors import InputError
from mantis_sim.scene import load_scene
from mantis_sim.studies.rig_study.effects import auto_repeats
from mantis_sim.studies.rig_study.judge import judge
from mantis_sim.studies.rig_study.plan import CONDITION_KEYS, StudyPlan, plan_from_mapping
from mantis_sim.studies.rig_study.quantities import MEASUREMENT, QUANTITIES
from mantis_sim.studies.rig_study.twin_forecast import (
    DAY_QUANTITY,
    StudyForecaster,
    conditions_key,
)
from mantis_sim.trial_conditions import conditions_of_scene

PLAN_AS_RUN = 'plan.yaml'
BAGS = 'bags'
ENSEMBLES = 'forecast_ensembles.pkl'     # the twin's robots at each combination, simulated once
RIG = 'rig.yaml'            # the rig the study ran on: its backend, whose measuring chain it is
TRACKS = 'tracks'           # DIR/tracks/<video>.csv: each filmed trial's tracks (as attach's)


class StudyError(InputError):
    """A study directory that does not hold this plan's study, or a record it cannot use."""


class RigPort(Protocol):
    def set_conditions(self, values: dict) -> None: ...     # the supervisor's parameters
    def conditions(self) -> dict: ...               # its trial conditions (CONDITION_KEYS)
    def backend(self) -> str: ...                   # 'sim' or 'hardware' (its measuring chain)
    def start(self) -> Path: ...                            # the new trial's bag directory
    def follow(self, on_state: Callable[[str], None]) -> tuple[str, str]: ...  # (final, reason)


class Operator(Protocol):
    def before_trial(self, row: dict, previous: Optional[dict], total: int) -> None: ...
    def after_trial(self, row: dict) -> None: ...


@dataclass
class StudySetup:
    plan: StudyPlan
    directory: Path
    scene_overrides: tuple = ()
    slack_force_N: float = 0.3          # the supervisor's slack_force_n: where a pull starts


def day_of(when: datetime) -> str:
    return when.astimezone().strftime('%Y-%m-%d')


def video_name(directory: Path, row: dict) -> str:
    """The name the person saves a trial's tracked video (its export) under."""
    return f'{directory.name}_run{row["run"]:03d}_trial{row["trial"]:03d}'


class StudyRunner:
    def __init__(self, setup: StudySetup, rig: RigPort, operator: Operator, analyst,
                 say: Callable[[str], None] = print, progress: Callable[[str], None] = print):
        self.setup = setup
        self.plan = setup.plan
        self.directory = setup.directory
        self.rig, self.operator, self.analyst = rig, operator, analyst
        self.say, self.progress = say, progress
        self.record: Optional[StudyRecord] = None
        self.forecaster: Optional[StudyForecaster] = None
        self._ensembles: dict = {}     # conditions key -> Future of its Ensemble, in order asked
        self._ensembles_saved = 0
        self._cached: dict = {}
        self._rig_conditions: dict = {}
        self._measuring: dict = {}      # id(row) -> (row, Future)
        self.current: Optional[dict] = None
        self._judged_all = False

    # ------------------------------------------------------------------ the record
    def open(self) -> StudyRecord:
        """The record: the study's own when DIR holds one of this plan, else a new one."""
        self._check_video()
        self.directory.mkdir(parents=True, exist_ok=True)
        (self.directory / BAGS).mkdir(exist_ok=True)
        path = self.directory / RECORD_NAME
        self._start_ensembles()
        if path.exists():
            self.plan = self._plan_as_run()
            self.record = read_record(path)
            self.say(f'resuming the study in {self.directory}: '
                     f'{sum(r["status"] == DONE for r in self.record.rows)} trial(s) done, '
                     f'{len(self.record.owed())} owed')
            self._settle_left_over()
        else:
            if self.plan.repeats is None:
                self._forecaster()
                repeats = auto_repeats(self.plan, self.forecaster)
                self.say(f'repeats: auto: {repeats} per combination resolve '
                         + ', '.join(f'{QUANTITIES[q].label} {d:g} {QUANTITIES[q].unit}'
                                     for q, d in self.plan.smallest_effect.items())
                         + ' (80 % power, 5 % level, the twin\'s scatter within a day)')
                self.plan = self.plan.with_repeats(repeats)
            write_atomically(self.directory / PLAN_AS_RUN,
                             yaml.safe_dump(self.plan.to_mapping(), sort_keys=False))
            self.record = StudyRecord(path, [new_row(t.trial, t.block, 1, t.conditions)
                                             for t in self.plan.trials()])
            self.record.renumber()
            self.record.save()
        self._measure_unmeasured()
        return self.record

    def _check_video(self) -> None:
        """A plan that says ``video: true`` needs the simulated rig's camera, which films."""
        if self.plan.video and self.rig is not None and self.rig.backend() != 'sim':
            raise StudyError(f'the plan says video: true, which the simulated camera films; the '
                             f'{self.rig.backend()} camera records the strike itself: leave '
                             f'video out and attach its recordings (mantis study attach)')

    def _plan_as_run(self) -> StudyPlan:
        stored, given = plan_as_run(self.directory), self.plan
        path = self.directory / PLAN_AS_RUN
        differ = [k for k in ('scene', 'factors', 'order', 'seed', 'fixed', 'hard_to_change',
                              'robots', 'video') if getattr(stored, k) != getattr(given, k)]
        if given.repeats is not None and given.repeats != stored.repeats:
            differ.append('repeats')
        if differ:
            raise StudyError(f'{self.directory} holds a study of another plan ({", ".join(differ)} '
                             f'differ from {path}); give a new --out for a new study')
        return stored

    def _settle_left_over(self) -> None:
        """Rows a study that died left starting or running: settled from their bags."""
        for row in list(self.record.rows):
            if row['status'] == STARTING:
                bag = self._unclaimed_bag(row)
                if bag is None:
                    row.update(status=PENDING, started_utc=None, day=None)
                    continue
                row['bag'] = str(bag)
                row['status'] = RUNNING
            if row['status'] == RUNNING:
                self._settle_from_bag(row)
        self.record.save()

    def _unclaimed_bag(self, row: dict) -> Optional[Path]:
        claimed = {Path(r['bag']).name for r in self.record.rows if r.get('bag')}
        started = datetime.fromisoformat(row['started_utc']).timestamp() \
            if row.get('started_utc') else 0.0
        bags = [p for p in (self.directory / BAGS).iterdir()
                if p.is_dir() and p.name not in claimed and p.stat().st_mtime >= started - 1.0]
        return max(bags, key=lambda p: p.stat().st_mtime) if bags else None

    def _settle_from_bag(self, row: dict) -> None:
        bag = self._bag_path(row)
        outcome = {}
        try:
            reader = BagReader(bag, warn=False)
            if not reader.complete:
                from mantis_rig.recording.recover import recover_bag
                report = recover_bag(bag)
                self.say(f'run {row["run"]}: its bag was left open; recovered '
                         f'{report.messages_recovered} messages into {report.output}')
                row['bag'] = _relative(report.output, self.directory)
                reader = BagReader(report.output, warn=False)
            outcome = reader.metadata(TRIAL_OUTCOME) or {}
        except (InputError, OSError) as exc:
            row['reason'] = f'its bag cannot be read: {exc}'
        if outcome.get('result') == 'completed':
            row.update(status=DONE, reason='')
        else:
            why = outcome.get('reason') or row.get('reason') or 'the study stopped during it'
            self._interrupted(row, f'the study stopped during it ({why})')

    def _interrupted(self, row: dict, reason: str) -> None:
        row.update(status=INTERRUPTED, reason=reason)
        self.record.insert_after(row, repeat_of(row))

    # ------------------------------------------------------------------ the forecasts
    def conditions_of(self, row: dict) -> dict:
        """The conditions a row ran at (the rig's for what the plan leaves open), or, for a row
        not yet run, those it will run at as far as the rig's now say."""
        return {**self._rig_conditions, **_conditions(row)}

    def _start_ensembles(self) -> None:
        scene = load_scene(self.plan.scene, list(self.setup.scene_overrides))
        self._rig_conditions = conditions_of_scene(scene)
        if self.rig is not None:
            self._rig_conditions.update(self.rig.conditions())
            write_atomically(self.directory / RIG,
                             yaml.safe_dump({'backend': self.rig.backend()}))
        self._cached = load_ensembles(self.directory)
        for cell in self.plan.cells:
            self._ask_ensemble({**self._rig_conditions, **self.plan.conditions_of(cell)})

    def _ask_ensemble(self, conditions: dict) -> None:
        key = conditions_key(conditions)
        if key in self._ensembles:
            return
        if key in self._cached:
            self._ensembles[key] = _done(self._cached[key])
        else:
            self._ensembles[key] = self.analyst.ensemble(
                self.plan.scene, list(self.setup.scene_overrides), conditions,
                self.plan.robots, self.plan.seed, self.setup.slack_force_N)

    def _forecaster(self, wait: bool = True) -> Optional[StudyForecaster]:
        """The forecaster, with every ensemble asked for so far (None, without ``wait``, while
        one is still being simulated)."""
        futures = list(self._ensembles.values())
        if not wait and not all(f.done() for f in futures):
            return None
        ensembles = [f.result() for f in futures]
        if self.forecaster is None:
            scene = load_scene(self.plan.scene, list(self.setup.scene_overrides))
            self.forecaster = StudyForecaster(scene, ensembles, self.plan.seed,
                                              measurement_of(self.directory))
        elif len(ensembles) > self._ensembles_saved:
            for ensemble in ensembles[self._ensembles_saved:]:
                self.forecaster.add(ensemble)
            self._judged_all = False         # the rows that waited for them are judged now
        if len(ensembles) > self._ensembles_saved:
            save_ensembles(self.directory, ensembles)
            self._ensembles_saved = len(ensembles)
        return self.forecaster

    def judge(self, arrived: list, every_row: bool) -> None:
        """Judge the rows whose measurements have just ``arrived`` (every row the first time
        the forecasts are there, and with ``every_row``): a trial's forecast depends only on
        the day's earlier ones, so judging each as it lands keeps a long study's cost per
        trial flat. A row that ran at conditions no ensemble was simulated at (the rig's,
        set outside the plan) gets one first."""
        for row in self.record.rows:
            self._ask_ensemble(self.conditions_of(row))
        forecaster = self._forecaster(wait=every_row)
        if forecaster is None:
            return
        if every_row or not self._judged_all:
            judge_rows(self.record.rows, forecaster, self.conditions_of)
            self._judged_all = True
        else:
            for row in arrived:
                judge_row(self.record.rows, row, forecaster, self.conditions_of)

    # ------------------------------------------------------------------ measuring
    def _measure_unmeasured(self) -> None:
        for row in self.record.rows:
            if row['status'] == DONE and row.get('analysed') != 'yes' and row.get('bag'):
                self._measure(row)

    def _measure(self, row: dict) -> None:
        """Ask the analyst for a done row's measurement: of its bag, and with the plan's
        ``video`` of its film, tracked into DIR/tracks/<its video name>.csv."""
        bag = self._bag_path(row)
        if self.plan.video:
            tracks = self.directory / TRACKS / f'{row["video"]}.csv'
            future = self.analyst.measure_filmed(bag, tracks)
        else:
            future = self.analyst.measure(bag)
        self._measuring[id(row)] = (row, future)

    def _bag_path(self, row: dict) -> Path:
        bag = Path(row['bag'])
        return bag if bag.is_absolute() else self.directory / bag

    def collect(self, wait: bool = False) -> None:
        """Fill the rows whose measurements are back (all of them with ``wait``)."""
        arrived = []
        for key, (row, future) in list(self._measuring.items()):
            if not wait and not future.done():
                continue
            values = future.result()
            note = values.pop('analysis_note', '')
            row.update({q: values.get(q) for q in QUANTITIES})
            row['analysed'] = 'yes'
            row['markers_from'] = values.get('markers_from') or None
            if note:
                row['reason'] = f'markers not analysed: {note}'
            del self._measuring[key]
            arrived.append(row)
            self._say_measured(row)
        if arrived or wait:
            self.judge(arrived, every_row=wait)
            self.record.save()

    def _say_measured(self, row: dict) -> None:
        parts = []
        for name, q in QUANTITIES.items():
            value = row.get(name)
            if value is not None and math.isfinite(value):
                parts.append(f'{q.label} {value:.4g} {q.unit}')
        self.say(f'run {row["run"]} measured: ' + ('; '.join(parts) or 'nothing'))

    # ------------------------------------------------------------------ running
    def run(self) -> StudyRecord:
        record = self.record or self.open()
        previous = None
        while True:
            owed = [r for r in record.rows if r['status'] == PENDING]
            if not owed:
                break
            row = owed[0]
            self.operator.before_trial(row, previous, len(record.rows))
            self._run_trial(row)
            self.operator.after_trial(row)
            previous = row
            self.collect()
        self.collect(wait=True)
        self._say_verdicts()
        return record

    def _run_trial(self, row: dict) -> None:
        conditions = {k: row[k] for k in CONDITION_KEYS if row.get(k) is not None}
        self.rig.set_conditions({**conditions, 'out': str((self.directory / BAGS).resolve()),
                                 'video': self.plan.video})
        row.update(self.rig.conditions())        # the rig's own for what the plan leaves open
        now = datetime.now(UTC)
        row.update(status=STARTING, started_utc=now.isoformat(timespec='seconds'),
                   day=day_of(now), video=video_name(self.directory, row))
        self.record.save()
        self.current = row
        try:
            bag = self.rig.start()
        except InputError as exc:        # the supervisor refused it: owed no more, said why
            row.update(status=NOT_STARTED, reason=str(exc))
            self.record.save()
            self.current = None
            raise
        row.update(status=RUNNING, bag=_relative(bag, self.directory))
        self.record.save()
        label = ', '.join(f'{k} {row[k]:g}' if isinstance(row[k], float) else f'{k} {row[k]}'
                          for k in self.plan.factors)
        self.progress(f'run {row["run"]}/{len(self.record.rows)} ({label}): starting')
        final, reason = self.rig.follow(
            lambda state: self.progress(f'run {row["run"]}/{len(self.record.rows)} '
                                        f'({label}): {state}'))
        self.current = None
        if final == 'done':
            row.update(status=DONE, reason='')
            self._measure(row)
        else:
            row.update(status=ABORTED, reason=reason)
            repeats = sum(1 for r in self.record.attempts_of(row['trial'])) - 1
            if repeats < MAX_REPEATS_OF_AN_ABORT:
                self.record.insert_after_block(repeat_of(row))
                self.say(f'run {row["run"]} aborted ({reason}); repeated at the end of its '
                         f'block')
            else:
                self.say(f'run {row["run"]} aborted ({reason}); repeated twice already: '
                         f'trial {row["trial"]} stays unmeasured')
        self.record.save()

    def interrupted(self, reason: str) -> None:
        """The person stopped the study (Ctrl-C, SIGTERM): the trial in progress is recorded
        as interrupted, with its bag, and owed again; nothing else changes."""
        row, self.current = self.current, None
        if row is not None and self.record is not None:
            if row['status'] == STARTING and not row.get('bag'):
                bag = self._unclaimed_bag(row)
                row['bag'] = _relative(bag, self.directory) if bag else None
            if row.get('bag'):
                self._interrupted(row, reason)
            else:
                row.update(status=PENDING, started_utc=None, day=None, video=None)
            self.record.save()

    def _say_verdicts(self) -> None:
        rows = self.record.rows
        done = [r for r in rows if r['status'] == DONE]
        flagged = [r for r in done if r.get('flags')]
        self.say(f'study: {len(done)} trial(s) done, {sum(r["status"] == ABORTED for r in rows)} '
                 f'aborted, {len(self.record.owed())} owed; {len(flagged)} outside their '
                 f'forecast\'s 95 % interval')
        for row in flagged:
            self.say(f'  run {row["run"]}: {row["cause"]}')


def _conditions(row: dict) -> dict:
    return {k: row[k] for k in CONDITION_KEYS if row.get(k) is not None}


def _day_strike(row: dict, conditions_of) -> Optional[tuple]:
    """(conditions, DAY_QUANTITY) of a row that measured it, else None."""
    value = row.get(DAY_QUANTITY)
    if row['status'] == DONE and value is not None and math.isfinite(value):
        return conditions_of(row), value
    return None


def recorded_conditions(rows: list, scene) -> Callable[[dict], dict]:
    """row -> the conditions it ran at, for a study read back from its record: its own, and for
    a row not yet run those the study's latest run row recorded for what the plan leaves
    open (the rig's), else the scene's."""
    ran = [r for r in rows if all(r.get(k) is not None for k in CONDITION_KEYS)]
    base = {k: ran[-1][k] for k in CONDITION_KEYS} if ran else conditions_of_scene(scene)
    return lambda row: {**base, **_conditions(row)}


def _judge(row: dict, earlier: list, forecaster: StudyForecaster, conditions_of) -> None:
    forecast = forecaster.forecast(conditions_of(row), earlier)
    verdict = judge(forecast, {q: row.get(q) for q in QUANTITIES})
    row.update(verdict.values)
    row.update(flags=' '.join(verdict.flagged), cause=verdict.cause,
               day_strikes=forecast.day_strikes)


def judge_rows(rows: list, forecaster: StudyForecaster, conditions_of=None) -> None:
    """Every row's forecast at its conditions (``conditions_of(row)``; default: those it
    records), from the day's earlier measured strikes, and its judgement (rows in run order; a
    row not yet run is forecast as of today)."""
    conditions_of = conditions_of or recorded_conditions(rows, forecaster.scene)
    today = day_of(datetime.now(UTC))
    by_day: dict = {}
    for row in rows:
        earlier = by_day.setdefault(row.get('day') or today, [])
        _judge(row, list(earlier), forecaster, conditions_of)
        strike = _day_strike(row, conditions_of)
        if strike is not None:
            earlier.append(strike)


def judge_row(rows: list, row: dict, forecaster: StudyForecaster, conditions_of) -> None:
    """One row's forecast and judgement, from the earlier rows of its day (what a trial that
    has just been measured needs: the rows after it are judged at the study's end)."""
    earlier = [strike for r in rows[:rows.index(row)] if r.get('day') == row.get('day')
               for strike in [_day_strike(r, conditions_of)] if strike is not None]
    _judge(row, earlier, forecaster, conditions_of)


def plan_as_run(directory: Path) -> StudyPlan:
    """The plan a study directory was run with (its repeats resolved)."""
    path = Path(directory) / PLAN_AS_RUN
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as exc:
        raise StudyError(f'{path}: the study\'s plan as run cannot be read '
                         f'({exc.strerror or exc}): is {directory} a study directory?') from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise StudyError(f'{path}: not YAML: {str(exc).splitlines()[0]}') from None
    return plan_from_mapping(data, str(path))


def load_ensembles(directory: Path) -> dict:
    """The study's forecast ensembles saved by an earlier run (conditions key -> Ensemble);
    none if there are none or they cannot be read (they are then simulated again)."""
    path = directory / ENSEMBLES
    try:
        with open(path, 'rb') as handle:
            ensembles = pickle.load(handle)
        return {conditions_key(e.conditions): e for e in ensembles}
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, TypeError):
        return {}


def save_ensembles(directory: Path, ensembles: list) -> None:
    write_atomically(directory / ENSEMBLES, pickle.dumps(list(ensembles)))


def study_forecaster(directory: Path, plan: StudyPlan, rows: list, scene_overrides=(),
                     slack_force_N: float = 0.3, say=print) -> StudyForecaster:
    """The forecaster of a study's directory: an ensemble at each combination of the plan and
    at the conditions of each of its record's ``rows``, the saved ones, any missing
    simulated."""
    from mantis_sim.studies.rig_study.twin_forecast import simulate_ensemble
    cached = load_ensembles(directory)
    scene = load_scene(plan.scene, list(scene_overrides))
    conditions_of = recorded_conditions(rows, scene)
    wanted = {}
    for conditions in [conditions_of(plan.conditions_of(c)) for c in plan.cells] + \
            [conditions_of(r) for r in rows]:
        wanted.setdefault(conditions_key(conditions), conditions)
    ensembles = []
    for key, conditions in wanted.items():
        ensemble = cached.get(key)
        if ensemble is None:
            say(f'simulating the twin\'s {plan.robots} robots at {conditions}')
            ensemble = simulate_ensemble(scene, conditions, plan.robots, plan.seed,
                                         slack_force_N=slack_force_N)
        ensembles.append(ensemble)
    save_ensembles(directory, ensembles)
    return StudyForecaster(scene, ensembles, plan.seed, measurement_of(directory))


def measurement_of(directory: Path) -> dict:
    """The measuring chain of the rig a study ran on (quantities.MEASUREMENT), from DIR/rig.yaml
    (the real rig's where it is missing or unreadable: the wider)."""
    try:
        backend = (yaml.safe_load((directory / RIG).read_text(encoding='utf-8')) or {}).get(
            'backend')
    except (OSError, yaml.YAMLError, AttributeError):
        backend = None
    return MEASUREMENT.get(backend, MEASUREMENT['hardware'])


def _done(value) -> Future:
    future = Future()
    future.set_result(value)
    return future


def _relative(path: Optional[Path], directory: Path) -> Optional[str]:
    if path is None:
        return None
    try:
        return str(Path(path).resolve().relative_to(directory.resolve()))
    except ValueError:
        return str(path)



__all__ = ['BAGS', 'Operator', 'PLAN_AS_RUN', 'RigPort', 'StudyError', 'StudyRunner',
           'StudySetup', 'judge_row', 'judge_rows', 'plan_as_run', 'recorded_conditions',
           'study_forecaster', 'video_name']
