"""The simulated robot against real strikes: the readers of the lab's strike tables and
processed records, the comparison's statistics, the identification (it must recover parameters
of strikes the model made itself), and `mantis compare` / `mantis identify` end to end on the
project's copies of the real data (test/data/PROVENANCE.md)."""
import csv
import gzip
import json
import math

from conftest import data_file
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
import yaml

from mantis_rig.cli import main as mantis
from mantis_sim.results import LAB_THETA1_REST_RAD, lab_spring_energy_mJ
from mantis_sim.scene import load_scene, load_scene_file
from mantis_sim.studies.real_strikes import fidelity
from mantis_sim.studies.real_strikes import identify as ident
from mantis_sim.studies.real_strikes.day_state import DayStateFit
from mantis_sim.studies.real_strikes.strikes import (
    SEAT_MIN_INTO_RECORD_S,
    RealStrike,
    StrikeDataError,
    phase_iv_times,
    read_processed_record,
    read_strikes,
    read_summary_table,
    record_times,
    seat_in_record,
)

TABLE = 'real_trials/authors_summary_train.csv'
PROCESSED = 'real_trials/authors_processed'
AIR23 = '0801319_19kfps_T_2X_A_1_1_2p3_-6_4'
AIR19 = '111219_11kfps_T_2X_A_1_1_2p3_-10_5_1'
WATER = '011620_19kfps_T_2X_W_2_1_2p3_-8_7_2'


def record(trial):
    return data_file(f'{PROCESSED}/{trial}_data.csv.gz')


# --- readers -----------------------------------------------------------------------------------
def test_the_summary_table_gives_every_strike_with_its_conditions():
    strikes = read_summary_table(data_file(TABLE))
    assert len(strikes) == 32
    groups = {g: sum(s.group == g for s in strikes) for g in ('air_19mm', 'air_23mm',
                                                               'water_23mm')}
    assert groups == {'air_19mm': 8, 'air_23mm': 18, 'water_23mm': 6}
    pair = next(s for s in strikes if s.trial == '0828019_19kfps_T_2X_A_1_1_2p3_-3_2')
    # the measured pull speed, not the nominal 2.3 of the trial's name
    assert pair.pull_mm_per_s == pytest.approx(1.332)
    assert pair.peak_tip_speed_mps == pytest.approx(22.96)
    assert pair.recording_day == '0828019'


def _table_with(tmp_path, edit):
    rows = list(csv.DictReader(open(data_file(TABLE), newline='')))
    header = list(rows[0])
    header, rows = edit(header, rows)
    path = tmp_path / 'table.csv'
    with open(path, 'w', newline='') as handle:
        writer = csv.DictWriter(handle, fieldnames=header, extrasaction='ignore')
        writer.writeheader()
        writer.writerows(rows)
    return path


@pytest.mark.parametrize('edit, message', [
    (lambda h, r: ([c for c in h if c != 'd_t_mm'], r), r'missing column\(s\) d_t_mm'),
    (lambda h, r: (h, [{**r[0], 'medium': 'oil'}]), "medium 'oil' is not one of air, water"),
    (lambda h, r: (h, [{**r[0], 'contact_angle_deg': '0.0404'}, {**r[1],
                                                                 'contact_angle_deg': '150'}]),
     r'row 3 .*contact_angle_deg = 150 is outside \[0, 15\]'),
    (lambda h, r: (h, [{**r[0], 'v_max_mps': 'fast'}]), "column v_max_mps = 'fast' is not a "
                                                        'number'),
    (lambda h, r: ([c for c in h if not c.startswith('pull')], r), 'pull_measured_mm_s or '
                                                                   'pull_nominal_mm_s'),
    (lambda h, r: (h, []), 'no rows'),
    (lambda h, r: ([*h, 'seat_deg'], [{**r[0], 'seat_deg': '0.5'}, {**r[1], 'seat_deg': '95'}]),
     r'row 3 .*seat_deg = 95 is outside \[-5, 30\]'),
])
def test_a_broken_summary_table_is_refused_naming_row_and_column(tmp_path, edit, message):
    with pytest.raises(StrikeDataError, match=message):
        read_summary_table(_table_with(tmp_path, edit))


def test_a_processed_record_is_timed_from_phase_iv_with_its_frames_rebuilt():
    t_iv = phase_iv_times(data_file(TABLE))[AIR23]
    series = read_processed_record(record(AIR23), t_iv)
    step = np.diff(series.t_s)
    assert step == pytest.approx(np.full(step.size, 1 / 19000), rel=1e-4)   # 19,000 frames/s
    assert series.t_s[0] < 0 < series.t_s[-1]
    # the lab's spring energy is its convention applied to the body angle at phase IV
    strikes = {s.trial: s for s in read_summary_table(data_file(TABLE))}
    for trial in (AIR23, AIR19, WATER):
        s = read_processed_record(record(trial), phase_iv_times(data_file(TABLE))[trial])
        theta1_iv = s.theta1_rad[np.argmin(np.abs(s.t_s))]
        assert lab_spring_energy_mJ(theta1_iv) == pytest.approx(
            strikes[trial].spring_energy_mJ, rel=2e-3)
    assert LAB_THETA1_REST_RAD == pytest.approx(4.0736)


def test_the_arm_s_seat_is_read_at_overcentering_and_not_before_the_recording():
    strikes = {s.trial: s for s in read_strikes(data_file(TABLE), data_file(PROCESSED))}
    t_oc = record_times(data_file(TABLE), 't_oc_s')[AIR23]
    raw = np.loadtxt(gzip.open(record(AIR23), 'rt'), delimiter=',')
    assert strikes[AIR23].seat_deg == pytest.approx(
        np.degrees(np.interp(t_oc, raw[:, 0], raw[:, 2])), abs=0.05)
    # a strike without a record has no seat, unless the table gives one
    assert strikes['0828019_19kfps_T_2X_A_1_1_2p3_-3_2'].seat_deg is None
    # the authors put overcentering before the recording at its first frames (their notes):
    # no seat is read there, nor outside the record
    t = np.arange(0.0, 2.0, 1e-3)
    theta2 = np.radians(3.0 + t)
    assert seat_in_record(t, theta2, 1.0) == pytest.approx(4.0)
    assert seat_in_record(t, theta2, SEAT_MIN_INTO_RECORD_S / 2) is None
    assert seat_in_record(t, theta2, 2.5) is None
    assert seat_in_record(t, theta2, None) is None


def test_a_seat_in_the_table_is_taken_before_the_record_s(tmp_path):
    table = _table_with(tmp_path, lambda h, r: ([*h, 'seat_deg'], [
        {**row, 'seat_deg': '7.5' if row['trial'] == AIR23 else ''} for row in r]))
    strikes = {s.trial: s for s in read_strikes(table, data_file(PROCESSED))}
    assert strikes[AIR23].seat_deg == 7.5
    assert strikes[WATER].seat_deg == pytest.approx(4.08, abs=0.05)    # from its record


def test_damaged_processed_records_are_refused(tmp_path):
    raw = gzip.open(record(AIR23), 'rb').read()
    packed = record(AIR23).read_bytes()
    cases = {'cut.csv.gz': packed[:len(packed) // 2],
             'lastline.csv': raw[:len(raw) // 2].rsplit(b'\n', 1)[0].rsplit(b',', 2)[0],
             'text.csv': b'time,theta\n1,2\n',
             'five.csv': b'\n'.join(b'%d,1,2,3,4' % i for i in range(20)),
             'nan.csv': raw.replace(b'\n', b'\nnan,nan,nan,0,0,0\n', 1),
             'notgzip.csv.gz': raw[:1000]}
    for name, content in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(StrikeDataError, match=name):
            read_processed_record(path, 1.0)
    with pytest.raises(StrikeDataError, match='phase IV at 99 s is outside the record'):
        read_processed_record(record(AIR23), 99.0)


# derandomized, as the fuzz suite's CI profile: the same examples every run (a new one found by
# chance would make CI flaky; the one found so far is the test below it)
@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 3000), flips=st.lists(st.tuples(st.integers(0, 2999),
                                                          st.integers(1, 255)), max_size=8))
def test_a_summary_table_damaged_anyhow_is_read_or_refused(tmp_path, cut, flips):
    content = bytearray(_table_with_seats()[:cut or None])
    for position, mask in flips:
        if position < len(content):
            content[position] ^= mask
    path = tmp_path / 'damaged.csv'
    path.write_bytes(bytes(content))
    try:
        strikes = read_summary_table(path)
    except StrikeDataError:
        return
    for s in strikes:
        assert s.medium in ('air', 'water') and 0 <= s.contact_angle_deg <= 15
        assert math.isfinite(s.pull_mm_per_s) and s.pull_mm_per_s > 0
        assert s.seat_deg is None or -5 <= s.seat_deg <= 30
    # the record times read beside the table (phase IV, overcentering): numbers or refused
    for column in ('t_z1_s', 't_oc_s'):
        try:
            times = record_times(path, column)
        except StrikeDataError:
            continue
        assert all(math.isfinite(t) for t in times.values())


def _table_with_seats() -> bytes:
    """The training table with a seat_deg column (4.5 degrees on every row)."""
    lines = data_file(TABLE).read_text().splitlines()
    return '\n'.join([lines[0] + ',seat_deg'] + [line + ',4.5' for line in lines[1:]]).encode()


def test_the_undamaged_table_is_read_by_the_fuzzed_reader(tmp_path):
    """The property above is not vacuous: the table it damages is read whole when intact."""
    assert len(read_summary_table(data_file(TABLE))) == 32
    path = tmp_path / 'seated.csv'
    path.write_bytes(_table_with_seats())
    strikes = read_summary_table(path)
    assert len(strikes) == 32 and {s.seat_deg for s in strikes} == {4.5}
    assert len(record_times(path, 't_oc_s')) == 32


# --- statistics ----------------------------------------------------------------------------------
def test_a_slope_within_days_removes_each_day_s_level():
    rng = np.random.default_rng(3)
    days = [d for d in 'abcd' for _ in range(6)]
    level = {'a': 0.0, 'b': 5.0, 'c': -3.0, 'd': 9.0}
    x = rng.uniform(0.3, 2.4, len(days))
    y = 0.9 * x + np.array([level[d] for d in days]) + rng.normal(0, 0.2, len(days))
    within = fidelity.fit_slope(x, y, days)
    assert abs(within.value - 0.9) < 3 * within.std_error < 0.5
    pooled = fidelity.fit_slope(x, y)          # the day levels swamp a pooled fit
    assert pooled.std_error > 3 * within.std_error


# --- identification ------------------------------------------------------------------------------
def _made_up_strikes(scene, conditions):
    """Strikes 'measured' on the model itself, at the given (pull, contact angle, day)."""
    strikes = []
    for i, (pull, angle, day) in enumerate(conditions):
        strike = RealStrike(f'synthetic_{i}', 'air', 23.0, angle, pull, day)
        sim = fidelity.simulate_strike(scene, strike, series=False)
        assert sim.status == 'strike'
        strikes.append(RealStrike(strike.trial, 'air', 23.0, angle, pull, day,
                                  peak_tip_speed_mps=sim.peak_tip_speed_mps,
                                  spring_energy_mJ=sim.spring_energy_mJ))
    return strikes


def test_identification_recovers_a_hold_it_did_not_know():
    base = load_scene('reference_air_23mm', [
        'effects=[joint_damping, hinge_stiffness, fluid_drag, tendon_slack, '
        'contact_restitution, pivot_friction]'])
    truth = base.with_values({'hinge.friction_lever_mm': 0.12})
    strikes = _made_up_strikes(truth, [(2.3, 3.0, 'd1'), (1.0, 2.0, 'd1'), (0.5, 4.0, 'd2')])
    param = ident.parse_free_parameter('hinge.friction_lever_mm=0:0.5', {'air_23mm': base})
    model = ident.StrikeModel({'air_23mm': base}, strikes, [param], ident.Weights(),
                              lambda f, items: [f(i) for i in items])
    fit = ident.identify(model, [0.03], max_iterations=10)
    assert fit.values[0] == pytest.approx(0.12, abs=2e-3)
    assert fit.cost < 1e-6 and np.isfinite(fit.std_errors[0])
    summary = ident.error_summary(fit.strikes, fit.simulated)
    assert summary['air_23mm']['spring_energy_median_abs_error'] < 1e-3
    for folds in (ident.cross_validate(model, fit.values), ident.cross_validate_one_step(model,
                                                                                         fit)):
        assert [f.left_out for f in folds] == ['d1', 'd2']
        assert all(abs(f.values[0] - 0.12) < 5e-3 for f in folds)
        assert all(s.status == 'strike' for f in folds for s in f.simulated)


def test_a_free_parameter_must_name_a_numeric_key_and_known_groups():
    scenes = {'air_23mm': load_scene('reference_air_23mm')}
    p = ident.parse_free_parameter('hinge.friction_lever_mm@air_23mm=0:1', scenes)
    assert (p.label, p.lower, p.upper) == ('hinge.friction_lever_mm@air_23mm', 0.0, 1.0)
    for text, message in (('tendon.model', 'not a numeric scene parameter'),
                          ('geometry.nope', 'not a numeric scene parameter'),
                          ('geometry.L2_mm@water_23mm', 'no strikes of group'),
                          ('geometry.L2_mm=0:500', 'must lie within the valid range'),
                          ('geometry.L2_mm=1', 'bounds must be LO:HI')):
        with pytest.raises(ident.IdentificationError, match=message):
            ident.parse_free_parameter(text, scenes)


# --- the commands ---------------------------------------------------------------------------------
def _no_nan_in_json(constant):
    raise ValueError(f'{constant} is not JSON')


@pytest.mark.slow
def test_compare_writes_errors_parity_and_a_trial_figure(tmp_path, capsys):
    out = tmp_path / 'cmp'
    code = mantis(['compare', '--strikes', str(data_file(TABLE)), '--processed',
                   str(data_file(PROCESSED)), '--out', str(out), '--workers', '0', '--json',
                   '--figure', WATER, '--group', 'air_19mm', '--group', 'water_23mm'])
    assert code == 0
    report = json.loads(capsys.readouterr().out, parse_constant=_no_nan_in_json)
    rows = list(csv.DictReader(open(out / 'errors.csv')))
    assert len(rows) == 14 and {r['group'] for r in rows} == {'air_19mm', 'water_23mm'}
    assert (out / 'parity.png').stat().st_size > 10_000
    assert (out / f'trial_{WATER}.png').stat().st_size > 10_000
    speed = report['groups']['peak_tip_speed_mps']
    assert speed['air_19mm']['strikes'] == 8 and speed['water_23mm']['strikes'] == 6
    assert [e['effect'] for e in report['effects']][1].startswith('peak tip speed per mm/s')
    # no air 23 mm strikes here: that effect cannot be estimated, and says so as null
    assert report['effects'][1]['real'] is None
    assert all(r['status'] == 'strike' for r in rows)


def test_compare_at_the_tracked_seats_latches_each_arm_where_its_tracks_show_it(tmp_path,
                                                                                capsys):
    far_out = '0828019_19kfps_T_2X_A_1_1_2p3_-3_2'      # tracked 12.2 degrees out, recorded 2.8
    table = _table_with(tmp_path, lambda h, r: ([*h, 'seat_deg'], [
        {**row, 'seat_deg': {far_out: '12.2', AIR23: '25'}.get(row['trial'], '')}
        for row in r if row['trial'] in (far_out, AIR23, '111419_8kfps_T_2X_A_16_1_0p5_-10_5_1')]))
    runs = {}
    for name, extra in (('recorded', []), ('seated', ['--at-seat'])):
        code = mantis(['compare', '--strikes', str(table), '--processed', str(data_file(PROCESSED)),
                       '--out', str(tmp_path / name), '--workers', '0', *extra])
        assert code == 0
        runs[name] = {r['trial']: r for r in csv.DictReader(open(tmp_path / name / 'errors.csv'))}
        runs[name + '_text'] = capsys.readouterr().out
    recorded, seated = runs['recorded'][far_out], runs['seated'][far_out]
    assert float(seated['seat_deg']) == pytest.approx(12.2, abs=0.1)
    # seated further out, the arm overcentres earlier: less stored, as measured
    assert abs(float(seated['error_spring_energy_mJ'])) < 0.1 < abs(
        float(recorded['error_spring_energy_mJ']))
    # a seat the latch cannot take is a failed strike with the reason, not a silent default
    assert runs['seated'][AIR23]['status'] == 'failed'
    assert 'latch_offset_deg' in runs['seated'][AIR23]['reason']
    assert runs['recorded'][AIR23]['status'] == 'strike'
    # no seat (no record here, none in the table): simulated at the contact angle and listed
    assert 'no seat, at the contact angle: 111419_8kfps_T_2X_A_16_1_0p5_-10_5_1' in \
        runs['seated_text']


@pytest.mark.slow
def test_identify_at_the_tracked_seats_fits_seated_strikes_and_says_so(tmp_path, capsys):
    table = _table_with(tmp_path, lambda h, r: ([*h, 'seat_deg'], [
        {**row, 'seat_deg': '5.0'} for row in r if row['trial'] in (
            WATER, '011720_11kfps_T_2X_W_1_1_1p5_-7_7_3', '011720_6kfps_T_2X_W_3_1_0p5_-7_7_2')]))
    out = tmp_path / 'scenes'
    code = mantis(['identify', '--strikes', str(table), '--out', str(out), '--at-seat',
                   '--fit', 'arm.blade_drag_broadside=0.5:6', '--iterations', '1',
                   '--workers', '0', '--cross-validate'])
    assert code == 0
    assert 'arms latched at their tracked seats (3 strikes)' in capsys.readouterr().err
    provenance = load_scene_file(out / 'water_23mm.yaml').provenance
    assert 'tracked seat' in provenance['at_seat']
    assert set(provenance['cross_validation_by_day']) == {'011620', '011720'}


def test_a_seated_model_stays_seated_for_the_left_out_days_and_the_days_own_starts():
    scene = load_scene('air_23mm')
    strikes = [RealStrike(f'seated{day}', 'air', 23.0, 3.0, 2.3, recording_day=day,
                          peak_tip_speed_mps=26.0, spring_energy_mJ=90.0, seat_deg=7.0)
               for day in ('d1', 'd2')]
    seen = []

    def recording_mapper(function, tasks):
        seen.extend(values for _, _, _, values in tasks)
        return [function(t) for t in tasks]
    params = [ident.parse_free_parameter('arm.blade_drag_broadside=0.5:6', {'air_23mm': scene})]
    model = ident.StrikeModel({'air_23mm': scene}, strikes, params, ident.Weights(series=0.0),
                              recording_mapper, at_seat=True)
    fit = ident.identify(model, max_iterations=1)
    folds = ident.cross_validate_one_step(model, fit)
    hold = ident.parse_free_parameter('hinge.friction_lever_mm=0:1', {'air_23mm': scene})
    DayStateFit({'air_23mm': scene}, strikes, hold, ident.Weights(series=0.0), recording_mapper,
                at_seat=True).fit(1)
    assert {f.left_out for f in folds} == {'d1', 'd2'} and fit.at_seat
    assert seen and all(v[fidelity.LATCH_KEY] == pytest.approx(4.0) for v in seen)


@pytest.mark.slow
def test_identify_writes_a_calibrated_scene_with_its_provenance(tmp_path, capsys):
    out = tmp_path / 'scenes'
    code = mantis(['identify', '--strikes', str(data_file(TABLE)), '--processed',
                   str(data_file(PROCESSED)), '--group', 'water_23mm', '--out', str(out),
                   '--fit', 'arm.blade_drag_broadside=0.5:6', '--iterations', '1',
                   '--weight', 'series=0.2', '--workers', '0', '--cross-validate', '--json',
                   '--loss', 'huber:0.05'])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report['cross_validation_by_day']) == {'011620', '011720'}
    written = load_scene_file(out / 'water_23mm.yaml')
    fitted = report['parameters']['arm.blade_drag_broadside']['value']
    assert written.arm.blade_drag_broadside == pytest.approx(fitted, rel=1e-5)
    provenance = written.provenance
    assert provenance['strikes'] == 6 and provenance['recording_days'] == ['011620', '011720']
    assert WATER in provenance['trials']
    assert provenance['parameters']['arm.blade_drag_broadside']['std_error'] > 0
    assert 'water_23mm' in provenance['cross_validated_errors']
    assert provenance['weights']['series'] == 0.2 and provenance['weights']['tip_speed'] == 1
    assert provenance['loss'] == 'huber:0.05'
    # the shipped scene was fitted in three stages; what this fit held stays on record as theirs
    fitted = provenance['parameters']
    assert 'held_from_stage' not in fitted['arm.blade_drag_broadside']
    assert fitted['tendon.stiffness_N_per_mm']['held_from_stage'] == 1
    assert fitted['hinge.kinetic_friction_ratio']['held_from_stage'] == 3
    stages = provenance['earlier_stages']
    assert [s['stage'] for s in stages] == [1, 2, 3]
    assert stages[1]['parameters'] == ['hinge.kinetic_friction_ratio']
    assert stages[1]['weights']['series'] == 0.0 and stages[1]['loss'] == 'soft_l1:0.01'
    assert 'damping.arm_Nmm_ms_per_rad' in stages[2]['parameters']
    doc = yaml.safe_load((out / 'water_23mm.yaml').read_text())
    assert doc['name'] == 'water_23mm' and doc['medium']['name'] == 'water'
    # the shipped spread was fitted about the parameters this fit replaced: not carried over
    assert 'spread' not in doc and load_scene('water_23mm').spread is not None


@pytest.mark.parametrize('extra, message', [
    (['--fit', 'geometry.nope'], 'not a numeric scene parameter'),
    (['--fit', 'geometry.L2_mm', '--export', 'nosuchtrial=x.xlsx'], 'expected TRIAL=PATH'),
    (['--fit', 'geometry.L2_mm', '--group', 'oil_23mm'], 'no such strikes'),
    (['--fit', 'geometry.L2_mm', '--iterations', '0'], 'must be >= 1'),
    (['--fit', 'geometry.L2_mm', '--weight', 'series=-1'], 'must be a finite number >= 0'),
    (['--fit', 'geometry.L2_mm', '--weight', 'speed=1'], 'expected NAME=VALUE'),
    (['--fit', 'geometry.L2_mm', '--loss', 'l1'], 'NAME must be one of'),
    (['--fit', 'geometry.L2_mm', '--per-day', 'geometry.latch_offset_deg=-5:5', '--at-seat'],
     'use one or the other'),
])
def test_identify_refuses_bad_input_before_any_work(tmp_path, capsys, extra, message):
    code = mantis(['identify', '--strikes', str(data_file(TABLE)), '--out',
                   str(tmp_path / 'o'), '--workers', '0', *extra])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()


@pytest.mark.slow
def test_a_tracker_export_gives_the_strike_s_motion_through_the_rig_s_analysis():
    """`--export TRIAL=PATH`: the export analysed, timed from its own phase IV, cut to the
    strike: the body turns back and the arm swings out, as in the authors' record."""
    from mantis_rig.analysis.strike_series import export_series
    strike = next(s for s in read_summary_table(data_file(TABLE)) if s.trial == AIR23)
    series = export_series(data_file('real_trials/air_23mm_19kfps_ma3.xlsx'), strike)
    assert series.t_s[0] < -0.01 and series.t_s[-1] > 0.01
    at = {t: np.interp(t, series.t_s, series.theta1_rad) for t in (0.0, 5e-3)}
    arm = {t: np.interp(t, series.t_s, series.theta3_rad) for t in (0.0, 5e-3)}
    assert 0.1 < at[5e-3] - at[0.0] < 0.4
    assert arm[5e-3] - arm[0.0] > 1.5


@pytest.mark.parametrize('group', ['air_19mm', 'air_23mm', 'water_23mm'])
def test_the_shipped_scenes_are_the_identified_robot_with_their_provenance(group):
    scene = load_scene(group)
    provenance = scene.provenance
    assert provenance['identified_by'] == 'mantis identify' and provenance['strikes'] == 32
    assert len(provenance['recording_days']) >= 10
    fitted = provenance['parameters']
    assert all(entry['std_error'] >= 0 for entry in fitted.values())
    assert scene.tendon.model == 'compliant' and scene.has('pivot_friction')
    assert fitted['tendon.stiffness_N_per_mm']['value'] == scene.tendon.stiffness_N_per_mm
    assert group in provenance['cross_validated_errors']
    m = fidelity.simulate_strike(scene, RealStrike('nominal', scene.medium.name,
                                                   scene.geometry.d_t_mm, 3.0, 2.3),
                                 series=False)
    assert m.status == 'strike' and m.spring_energy_mJ > 60


def test_a_header_damaged_into_an_extra_field_is_refused_not_a_crash(tmp_path):
    """The fuzzed table above found it: a flipped byte in the header made a line longer than
    the header, and the refusal itself crashed on the extra fields' missing name."""
    content = bytearray(data_file(TABLE).read_bytes())
    content[19] ^= 1                        # ',' -> '-' joins two header names
    path = tmp_path / 'flipped.csv'
    path.write_bytes(bytes(content))
    with pytest.raises(StrikeDataError, match='fields where the header names|missing column'):
        read_summary_table(path)


def test_a_refit_of_one_key_for_some_groups_supersedes_the_earlier_fit_of_that_key():
    """The earlier stage's entry is held only where no label of this fit sets the same key for
    a group in common: KEY@air_19mm supersedes KEY, not KEY@water_23mm or another key."""
    first = {'stage': 1, 'parameters': ['geometry.L2_mm'], 'date': 'first'}
    earlier = {'identified_by': 'mantis identify', 'date': 'then', 'weights': {'series': 0.05},
               'earlier_stages': [first],
               'parameters': {
                   'hinge.kinetic_friction_ratio': {'value': 0.8},
                   'hinge.friction_lever_mm@water_23mm': {'value': 0.06},
                   'geometry.L2_mm': {'value': 1.2, 'held_from_stage': 1}}}
    refitted = {'hinge.kinetic_friction_ratio@air_19mm': {},
                'hinge.friction_lever_mm@air_19mm': {}}
    held, stages = ident._held_from_earlier_stages(earlier, refitted)
    assert set(held) == {'hinge.friction_lever_mm@water_23mm', 'geometry.L2_mm'}
    assert held['hinge.friction_lever_mm@water_23mm']['held_from_stage'] == 2
    assert held['geometry.L2_mm']['held_from_stage'] == 1
    assert stages == [first, {'stage': 2, 'parameters': ['hinge.friction_lever_mm@water_23mm',
                                                         'hinge.kinetic_friction_ratio'],
                              'date': 'then', 'weights': {'series': 0.05}}]
    assert ident._held_from_earlier_stages(earlier, dict.fromkeys(earlier['parameters'])) == (
        {}, [])
    assert ident._held_from_earlier_stages({'identified_by': 'hand'}, {}) == ({}, [])


def test_a_fit_of_a_key_the_scene_leaves_unset_starts_from_what_the_model_uses():
    """hinge.kinetic_friction_lever_mm is unset in the shipped scenes (the ratio x the static
    lever is used): a fit of it starts there; a key with no such rule is refused by name."""
    from mantis_sim.model import kinetic_lever
    scene = load_scene('air_23mm')
    assert scene.hinge.kinetic_friction_lever_mm is None
    param = ident.parse_free_parameter('hinge.kinetic_friction_lever_mm=0:0.05',
                                       {'air_23mm': scene})
    assert ident.default_value({'air_23mm': scene}, param) == kinetic_lever(scene)
    with pytest.raises(ident.IdentificationError, match='integration.t_end_s is unset'):
        ident.scene_value(scene, 'integration.t_end_s')


@pytest.mark.slow
def test_a_global_parameter_is_identified_beside_each_day_s_own_state():
    """Strikes made on the model with a blade drag it did not know and the arm sitting
    differently on the latch each day: --per-day fits each day's offset as a nuisance, the
    drag as the robot's; a left-out day is predicted at the scene's offset, and the calibrated
    scene keeps the day states in its provenance, not in its values."""
    base = load_scene('air_23mm')
    truth = {'d1': 2.0, 'd2': -1.0}
    strikes = []
    for day, offset in truth.items():
        scene = base.with_values({'arm.blade_drag_broadside': 1.6,
                                  'geometry.latch_offset_deg': offset})
        strikes += [s for s in _made_up_strikes(scene, [(2.3, 3.0, day), (1.0, 3.5, day)])]
    scenes = {'air_23mm': base}
    params = [ident.parse_free_parameter('arm.blade_drag_broadside=0.5:4', scenes)]
    params += ident.per_day_parameters(
        ident.parse_free_parameter('geometry.latch_offset_deg=-5:12', scenes), strikes)
    assert [p.label for p in params[1:]] == ['geometry.latch_offset_deg@air_23mm#d1',
                                             'geometry.latch_offset_deg@air_23mm#d2']
    model = ident.StrikeModel(scenes, strikes, params, ident.Weights(),
                              lambda f, items: [f(i) for i in items])
    fit = ident.identify(model, max_iterations=12)
    assert fit.values == pytest.approx([1.6, 2.0, -1.0], abs=0.03)
    folds = {f.left_out: f for f in ident.cross_validate_one_step(model, fit)}
    assert folds['d1'].values[1] == 0.0 and folds['d2'].values[2] == 0.0
    doc = ident.calibrated_scene({'name': 'air_23mm', 'effects': []}, fit, 'air_23mm')
    assert doc['arm']['blade_drag_broadside'] == pytest.approx(1.6, abs=0.03)
    assert 'geometry' not in doc
    states = doc['provenance']['day_states']
    assert states['geometry.latch_offset_deg@air_23mm#d1']['value'] == pytest.approx(2.0,
                                                                                      abs=0.03)
    assert set(doc['provenance']['parameters']) == {'arm.blade_drag_broadside'}
