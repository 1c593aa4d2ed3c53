"""The study's runner on a fake rig: every planned trial exactly once, aborts repeated at the end
of their block, a stop at any trial resumed with what is owed, a study killed mid-trial settled
from its bag, and a record that is rewritten whole after every change."""
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import pytest

from mantis_rig.recording import BagWriter
from mantis_rig.study_session.record import read_record
from mantis_rig.study_session.runner import StudyError, StudyRunner, StudySetup
from mantis_sim.scene import load_scene
from mantis_sim.studies.rig_study.plan import plan_from_mapping
from mantis_sim.studies.rig_study.quantities import QUANTITIES, SIMULATED_RIG_ERROR
from mantis_sim.studies.rig_study.twin_forecast import StudyForecaster, simulate_ensemble

PLAN = {'scene': 'air_23mm_rig', 'factors': {'d_t_mm': [19, 25], 'pull_speed_mm_s': [1.0, 2.3]},
        'repeats': 2, 'order': 'random', 'seed': 5, 'robots': 20}
_ENSEMBLES = {}
RIG_DEFAULTS = {'pull_speed_mm_s': 2.33, 'd_t_mm': 23.0, 'contact_angle_deg': 3.0,
                'medium': 'air'}


def _done(value) -> Future:
    future = Future()
    future.set_result(value)
    return future


def measured(conditions: dict) -> dict:
    """What the fake rig 'measures': plausible values of the guide's robot."""
    nineteen = conditions['d_t_mm'] == 19
    return {'peak_tendon_force_N': 17.0, 'loading_work_mJ': 48.0 if nineteen else 33.0,
            'release_time_s': 2.3 / conditions['pull_speed_mm_s'] * (1.0 if nineteen else 0.8),
            'peak_tip_speed_mps': 30.6 if nineteen else 28.4,
            'max_spring_energy_mJ': 105.0 if nineteen else 89.0}


class FakeAnalyst:
    def __init__(self):
        self.measured = []

    def ensemble(self, scene, overrides, conditions, robots, seed, slack):
        key = tuple(sorted(conditions.items()))
        if key not in _ENSEMBLES:
            _ENSEMBLES[key] = simulate_ensemble(load_scene(scene), conditions, robots, seed)
        return _done(_ENSEMBLES[key])

    def measure(self, bag):
        self.measured.append(Path(bag).name)
        return _done({**measured(FakeRig.conditions_of[Path(bag).name]), 'analysis_note': ''})


class Stop(BaseException):
    """Stands in for the person's Ctrl-C (StopRequested)."""


class FakeRig:
    conditions_of = {}

    def __init__(self, abort=(), stop_at=None, defaults=RIG_DEFAULTS):
        self.abort, self.stop_at, self.defaults = set(abort), stop_at, dict(defaults)
        self.started = []           # (trial's conditions) in the order they ran
        self._values = {}

    def set_conditions(self, values):
        self._values = dict(values)

    def conditions(self):
        return {**self.defaults, **{k: v for k, v in self._values.items() if k in self.defaults}}

    def backend(self):
        return 'sim'

    def start(self) -> Path:
        n = len(self.started) + 1
        bag = Path(self._values['out']) / f'trial_{n:03d}'
        bag.mkdir()
        self.started.append(dict(self._values))
        FakeRig.conditions_of[bag.name] = {**self.conditions(), **self._values}
        return bag

    def follow(self, on_state):
        n = len(self.started)
        on_state('pulling')
        if n == self.stop_at:
            raise Stop()
        if n in self.abort:
            return 'aborted', 'force ceiling 20 N reached'
        return 'done', ''


class Quiet:
    def before_trial(self, row, previous, total):
        pass

    def after_trial(self, row):
        pass


def _runner(tmp_path, rig, plan=PLAN):
    setup = StudySetup(plan_from_mapping(plan, 'plan'), tmp_path / 'study')
    return StudyRunner(setup, rig, Quiet(), FakeAnalyst(), say=lambda line: None,
                       progress=lambda line: None)


def _record(tmp_path):
    return read_record(tmp_path / 'study' / 'study.csv')


def test_every_planned_trial_runs_once_with_its_forecast(tmp_path):
    rig = FakeRig()
    _runner(tmp_path, rig).run()
    rows = _record(tmp_path).rows
    assert [r['status'] for r in rows] == ['done'] * 8
    assert sorted(r['trial'] for r in rows) == list(range(1, 9))
    assert len(rig.started) == 8
    for row in rows:
        assert (tmp_path / 'study' / row['bag']).is_dir()
        assert rig.started[row['run'] - 1]['d_t_mm'] == row['d_t_mm']
        assert (row['contact_angle_deg'], row['medium']) == (3.0, 'air')   # the rig's own
        for name in QUANTITIES:
            assert row[name] == pytest.approx(measured(row)[name])
            qs = [row[f'{name}_q{k:02d}'] for k in range(5, 100, 5)]
            assert np.all(np.isfinite(qs)) and qs == sorted(qs)
            assert 0.0 <= row[f'{name}_pit'] <= 1.0
    assert [r['day_strikes'] for r in rows] == list(range(8))    # the day's earlier strikes
    assert (tmp_path / 'study' / 'plan.yaml').exists()


def test_a_trial_is_forecast_at_the_rigs_conditions_the_plan_left_open(tmp_path):
    """A rig whose guide distance was set to 19 mm outside the plan (`mantis start --set
    d_t_mm=19`), a plan of pull speeds only: every row records 19 mm and is forecast at it."""
    rig = FakeRig(defaults={**RIG_DEFAULTS, 'd_t_mm': 19.0})
    plan = {'scene': 'air_23mm_rig', 'factors': {'pull_speed_mm_s': [1.5, 2.3]}, 'repeats': 2,
            'order': 'as-listed', 'seed': 5, 'robots': 20}
    _runner(tmp_path, rig, plan).run()
    rows = _record(tmp_path).rows
    assert [r['d_t_mm'] for r in rows] == [19.0] * 4
    scene = load_scene('air_23mm_rig')
    at = {}
    for d_t in (19.0, 23.0):
        conditions = {**RIG_DEFAULTS, 'd_t_mm': d_t, 'pull_speed_mm_s': 1.5}
        forecaster = StudyForecaster(scene, [simulate_ensemble(scene, conditions, 20, 5)], 5,
                                     SIMULATED_RIG_ERROR)
        at[d_t] = forecaster.forecast(conditions).quantiles('loading_work_mJ')['q50']
    assert rows[0]['day_strikes'] == 0
    assert rows[0]['loading_work_mJ_q50'] == pytest.approx(at[19.0], rel=1e-9)
    assert abs(at[19.0] - at[23.0]) > 0.1 * at[23.0]         # the test tells them apart


def test_an_abort_is_repeated_at_the_end_of_its_block_twice_at_most(tmp_path):
    rig = FakeRig(abort={2, 9, 10})          # the 2nd trial, then both of its repeats
    _runner(tmp_path, rig).run()
    rows = _record(tmp_path).rows
    aborted = [r for r in rows if r['status'] == 'aborted']
    assert len(aborted) == 3 and len({r['trial'] for r in aborted}) == 1
    assert [r['attempt'] for r in aborted] == [1, 2, 3]
    assert rows[-1]['status'] == 'aborted'                # given up after two repeats
    assert all(r['reason'] == 'force ceiling 20 N reached' for r in aborted)
    assert sum(r['status'] == 'done' for r in rows) == 7
    assert [r['run'] for r in rows] == list(range(1, 11))


@pytest.mark.parametrize('stop_at', [1, 4, 8])
def test_a_stop_at_any_trial_resumes_with_every_trial_exactly_once(tmp_path, stop_at):
    first = FakeRig(stop_at=stop_at)
    runner = _runner(tmp_path, first)
    with pytest.raises(Stop):
        runner.run()
    runner.interrupted('interrupted by SIGINT (Ctrl-C)')
    rows = _record(tmp_path).rows
    assert sum(r['status'] == 'done' for r in rows) == stop_at - 1
    assert [r['status'] for r in rows].count('interrupted') == 1
    second = FakeRig()
    second.started = list(first.started)        # bag names go on
    _runner(tmp_path, second).run()
    rows = _record(tmp_path).rows
    done = [r['trial'] for r in rows if r['status'] == 'done']
    assert sorted(done) == list(range(1, 9))                 # each trial done exactly once
    assert len(second.started) - len(first.started) == 8 - (stop_at - 1)
    interrupted = [r for r in rows if r['status'] == 'interrupted']
    assert len(interrupted) == 1 and interrupted[0]['bag']   # kept, with its bag


def _bag(path: Path, result: str | None) -> None:
    writer = BagWriter(path, sync_period_s=0)
    writer.add_metadata('trial_conditions', {'d_t_mm': '19'})
    if result is None:
        return                    # left open: the process died
    writer.close(trial_outcome={'result': result, 'reason': ''})


def test_a_study_killed_mid_trial_is_settled_from_the_bag(tmp_path):
    rig = FakeRig()
    runner = _runner(tmp_path, rig)
    record = runner.open()
    first, second = record.rows[0], record.rows[1]
    bags = tmp_path / 'study' / 'bags'
    _bag(bags / 'closed', 'completed')
    _bag(bags / 'open', None)
    FakeRig.conditions_of.update(closed=dict(first), open=dict(second))
    first.update(status='running', bag='bags/closed', day='2026-11-28')
    second.update(status='running', bag='bags/open', day='2026-11-28')
    record.save()
    rig2 = FakeRig()
    rig2.started = [{}, {}]
    _runner(tmp_path, rig2).run()
    rows = _record(tmp_path).rows
    by_trial = {}
    for row in rows:
        by_trial.setdefault(row['trial'], []).append(row['status'])
    assert by_trial[first['trial']] == ['done']                  # not run again
    assert by_trial[second['trial']] == ['interrupted', 'done']  # run again, once
    assert len(rig2.started) - 2 == 7
    assert (bags / 'open_recovered').is_dir()


def test_a_directory_of_another_plan_is_refused(tmp_path):
    _runner(tmp_path, FakeRig()).open()
    other = {**PLAN, 'seed': 6}
    with pytest.raises(StudyError, match='seed'):
        _runner(tmp_path, FakeRig(), other).open()


def test_the_record_is_replaced_whole(tmp_path):
    runner = _runner(tmp_path, FakeRig())
    runner.open()
    directory = tmp_path / 'study'
    assert sorted(p.name for p in directory.iterdir() if p.name.startswith('.')) == []
    text = (directory / 'study.csv').read_text()
    header = text.splitlines()[0].split(',')
    for column in ('run', 'status', 'bag', 'd_t_mm', 'pull_speed_mm_s', 'peak_tip_speed_mps',
                   'max_spring_energy_mJ', 'peak_tip_speed_mps_q05', 'peak_tip_speed_mps_q95'):
        assert column in header


class FilmingAnalyst(FakeAnalyst):
    """The analyst of a study that films: the tip speed from each trial's film's tracks."""

    def __init__(self):
        super().__init__()
        self.filmed = []

    def measure(self, bag):
        raise AssertionError('a filmed trial is measured from its film, not its bag alone')

    def measure_filmed(self, bag, tracks_csv):
        self.filmed.append((Path(bag).name, Path(tracks_csv)))
        if len(self.filmed) == 2:
            return _done({'peak_tendon_force_N': 17.0, 'analysis_note': 'no film in '
                          f'{bag}/video within 300 s', 'markers_from': ''})
        return _done({**measured(FakeRig.conditions_of[Path(bag).name]), 'analysis_note': '',
                      'markers_from': 'video'})


def test_a_plan_with_video_films_each_trial_and_measures_it_from_the_film(tmp_path):
    rig = FakeRig()
    plan = {**PLAN, 'repeats': 1, 'video': True}
    setup = StudySetup(plan_from_mapping(plan, 'plan'), tmp_path / 'study')
    analyst = FilmingAnalyst()
    StudyRunner(setup, rig, Quiet(), analyst, say=lambda line: None,
                progress=lambda line: None).run()
    assert all(values['video'] is True for values in rig.started)
    rows = _record(tmp_path).rows
    assert [r['status'] for r in rows] == ['done'] * 4
    tracks = {name: csv for name, csv in analyst.filmed}
    for row in rows:
        assert tracks[Path(row['bag']).name] == tmp_path / 'study' / 'tracks' / \
            f'{row["video"]}.csv'
    lost = rows[1]                  # its film never came: said why, no tip speed
    assert lost['peak_tip_speed_mps'] is None and lost['markers_from'] is None
    assert 'markers not analysed: no film in' in lost['reason']
    assert all(r['markers_from'] == 'video' for r in rows if r is not lost)


def test_a_plan_with_video_is_refused_on_the_hardware_rig(tmp_path):
    class HardwareRig(FakeRig):
        def backend(self):
            return 'hardware'
    setup = StudySetup(plan_from_mapping({**PLAN, 'video': True}, 'plan'), tmp_path / 'study')
    runner = StudyRunner(setup, HardwareRig(), Quiet(), FakeAnalyst(), say=lambda line: None,
                         progress=lambda line: None)
    with pytest.raises(StudyError, match='the hardware camera records the strike itself'):
        runner.open()
    assert not (tmp_path / 'study').exists()
