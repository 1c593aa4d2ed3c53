"""A recording day's own state (`mantis day-state`): it must recover the days' values of strikes
the model made itself, say what a day's value predicts for a strike it did not see, and write
today's robot as a scene that runs."""
import json

from conftest import data_file
import pytest

from mantis_rig.cli import main as mantis
from mantis_sim.model import kinetic_lever
from mantis_sim.parameters import ParameterError
from mantis_sim.scene import load_scene, load_scene_file
from mantis_sim.studies.real_strikes import day_state as ds
from mantis_sim.studies.real_strikes import fidelity
from mantis_sim.studies.real_strikes import identify as ident
from mantis_sim.studies.real_strikes.strikes import RealStrike

TABLE = 'real_trials/authors_summary_train.csv'
PROCESSED = 'real_trials/authors_processed'
HOLDS_MM = {'d1': 0.03, 'd2': 0.12}


def _serial(function, items):
    return [function(item) for item in items]


def _strikes_of_days(truths: dict):
    """Strikes 'measured' on the model, two a day, each day on its own scene (day -> scene)."""
    strikes = []
    for day, truth in truths.items():
        for k, (pull, angle) in enumerate(((2.3, 3.0), (1.0, 3.5))):
            strike = RealStrike(f'{day}_{k}', 'air', 23.0, angle, pull, day)
            sim = fidelity.simulate_strike(truth, strike, series=False)
            strikes.append(RealStrike(strike.trial, 'air', 23.0, angle, pull, day,
                                      peak_tip_speed_mps=sim.peak_tip_speed_mps,
                                      spring_energy_mJ=sim.spring_energy_mJ))
    return strikes


@pytest.mark.slow
def test_each_day_s_hold_is_recovered_and_predicts_its_other_strikes():
    base = load_scene('reference_air_23mm', [
        'effects=[joint_damping, hinge_stiffness, fluid_drag, tendon_slack, '
        'contact_restitution, pivot_friction]', 'hinge.friction_lever_mm=0.07',
        'hinge.kinetic_friction_ratio=0.3'])
    strikes = _strikes_of_days({day: ds.day_scene(base, ds.HOLD_KEY, hold)
                                for day, hold in HOLDS_MM.items()})
    param = ident.parse_free_parameter('hinge.friction_lever_mm=0:0.5', {'air_23mm': base})
    states = ds.DayStateFit({'air_23mm': base}, strikes, param, ident.Weights(), _serial)
    fitted = {s.day: s for s in states.fit()}
    for day, hold in HOLDS_MM.items():
        assert fitted[day].value == pytest.approx(hold, abs=2e-3)
        assert fitted[day].strikes == 2 and not fitted[day].at_bound
    left_out = states.leave_one_out()
    assert len(left_out) == 4
    summary = ds.left_out_summary(left_out)['air_23mm']
    assert summary['spring_energy_own_day'] < 0.2 * summary['spring_energy_shared']
    assert summary['tip_speed_own_day'] < summary['tip_speed_shared']


def test_a_day_s_hold_moves_the_hold_and_keeps_the_scene_s_braking():
    scene = load_scene('air_23mm')
    braking = kinetic_lever(scene)
    day = ds.day_scene(scene, ds.HOLD_KEY, 0.15)
    assert day.hinge.friction_lever_mm == 0.15 and kinetic_lever(day) == braking
    # a day that holds less than the scene brakes cannot brake more than it holds
    assert kinetic_lever(ds.day_scene(scene, ds.HOLD_KEY, 0.01)) == 0.01
    # the braking follows the hold when asked (mu_k / mu_s fixed)
    assert kinetic_lever(ds.day_scene(scene, ds.HOLD_KEY, 0.15, hold_braking=False)) == (
        pytest.approx(0.15 * scene.hinge.kinetic_friction_ratio))
    other = ds.day_scene(scene, 'geometry.L2_mm', 1.3)
    assert other.geometry.L2_mm == 1.3 and other.hinge == scene.hinge


@pytest.mark.slow
def test_day_state_writes_a_scene_per_day_that_runs(tmp_path, capsys):
    out = tmp_path / 'days'
    code = mantis(['day-state', '--strikes', str(data_file(TABLE)), '--processed',
                   str(data_file(PROCESSED)), '--group', 'water_23mm', '--out', str(out),
                   '--iterations', '1', '--weight', 'series=0', '--workers', '0',
                   '--cross-validate', '--json'])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert report['key'] == ds.LATCH_KEY
    assert {d['day'] for d in report['days']} == {'011620', '011720'}
    assert report['leave_one_strike_out']['water_23mm']['strikes'] == 6
    day = next(d for d in report['days'] if d['day'] == '011620')
    scene = load_scene_file(out / 'water_23mm_011620.yaml')
    assert scene.name == 'water_23mm_011620'
    assert scene.geometry.latch_offset_deg == pytest.approx(day['value'], rel=1e-5, abs=1e-6)
    assert scene.hinge == load_scene('water_23mm').hinge
    record = scene.provenance['day_state']
    assert record['day'] == '011620' and record['strikes'] == 3 and len(record['trials']) == 3
    assert scene.provenance['identified_by'] == 'mantis identify'
    run = fidelity.simulate_strike(scene, RealStrike('today', 'water', 23.0, 3.0, 2.3),
                                   series=False)
    assert run.status == 'strike'


# --- where the arm sits on the latch -------------------------------------------------------------
def test_the_latch_offset_moves_the_latched_arm_as_a_larger_contact_angle_would():
    scene = load_scene('air_23mm')
    offset = fidelity.simulate_strike(scene.with_values({ds.LATCH_KEY: 2.0}),
                                      RealStrike('a', 'air', 23.0, 3.0, 2.3), series=False)
    wider = fidelity.simulate_strike(scene, RealStrike('b', 'air', 23.0, 5.0, 2.3), series=False)
    plain = fidelity.simulate_strike(scene, RealStrike('c', 'air', 23.0, 3.0, 2.3), series=False)
    assert offset.peak_tip_speed_mps == pytest.approx(wider.peak_tip_speed_mps, rel=1e-9)
    assert offset.spring_energy_mJ == pytest.approx(wider.spring_energy_mJ, rel=1e-9)
    assert offset.spring_energy_mJ < plain.spring_energy_mJ - 3.0     # overcentres earlier


def test_an_arm_latched_outside_its_range_is_refused_and_a_strike_there_fails_with_why():
    scene = load_scene('air_23mm')
    with pytest.raises(ParameterError, match='latch_offset_deg = -4.*latched arm at -1'):
        scene.with_values({ds.LATCH_KEY: -4.0})
    day = scene.with_values({ds.LATCH_KEY: -2.0})              # fine at 3 degrees ...
    sim = fidelity.simulate_strike(day, RealStrike('t', 'air', 23.0, 1.0, 2.3), series=False)
    assert sim.status == 'failed' and 'latched arm at -1' in sim.reason     # ... not at 1


@pytest.mark.slow
def test_each_day_s_latched_angle_is_recovered_from_its_peaks():
    base = load_scene('air_23mm')
    strikes = _strikes_of_days({day: base.with_values({ds.LATCH_KEY: offset})
                                for day, offset in (('d1', -1.0), ('d2', 4.0))})
    param = ident.parse_free_parameter(ds.DEFAULT_DAY_KEY, {'air_23mm': base})
    fitted = {s.day: s.value for s in ds.DayStateFit({'air_23mm': base}, strikes, param,
                                                     ident.Weights(), _serial).fit()}
    assert fitted['d1'] == pytest.approx(-1.0, abs=0.05)
    assert fitted['d2'] == pytest.approx(4.0, abs=0.05)


@pytest.mark.parametrize('extra, message', [
    (['--key', 'tendon.model'], "--key tendon.model: 'tendon.model' is not a numeric"),
    (['--iterations', '0'], 'must be >= 1'),
    (['--key', 'hinge.friction_lever_mm@oil_23mm'], 'no strikes of group'),
    (['--key', 'integration.t_end_s'], 'integration.t_end_s is unset'),
])
def test_day_state_refuses_bad_input_before_any_work(tmp_path, capsys, extra, message):
    code = mantis(['day-state', '--strikes', str(data_file(TABLE)), '--out',
                   str(tmp_path / 'o'), '--workers', '0', *extra])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()


def test_a_day_s_offset_is_taken_at_the_strike_s_own_angle_not_the_scene_s():
    """-4 degrees is outside what the scene's own 3 degrees can take, fine at a strike's 5."""
    scene = load_scene('air_23mm')
    strike = RealStrike('wide', 'air', 23.0, 5.0, 2.3)
    held = ident.simulate_task((scene, strike, False, {ds.LATCH_KEY: -4.0}))
    assert held.status == 'strike'
    inside = ident.simulate_task((scene, strike, False, {ds.LATCH_KEY: -6.0}))
    assert inside.status == 'failed' and 'latched arm at -1' in inside.reason


def test_a_day_its_mean_angle_cannot_take_is_not_written_and_says_why(tmp_path):
    from pathlib import Path

    from mantis_sim.scene import available_scenes
    from mantis_sim.studies.real_strikes.day_state_run import write_day_scenes
    scene = load_scene('water_23mm')
    strikes = [RealStrike(f'{day}_{k}', 'water', 23.0, 3.0, 2.3, day)
               for day in ('ok', 'bad') for k in range(2)]
    states = [ds.DayState('water_23mm', 'ok', 1.5, 0.1, 2, False),
              ds.DayState('water_23mm', 'bad', -4.0, 0.1, 2, False)]
    param = ident.parse_free_parameter(ds.DEFAULT_DAY_KEY, {'water_23mm': scene})
    written, refused = write_day_scenes(tmp_path, {'water_23mm': scene},
                                        {'water_23mm': Path(available_scenes()['water_23mm'])},
                                        param, states, strikes)
    assert [Path(p).name for p in written] == ['water_23mm_ok.yaml']
    assert load_scene_file(tmp_path / 'water_23mm_ok.yaml').geometry.latched_angle_deg == 4.5
    assert len(refused) == 1 and refused[0].startswith('water_23mm bad:')
    assert 'latched arm at -1' in refused[0]
    assert not (tmp_path / 'water_23mm_bad.yaml').exists()


def test_keys_that_constrain_each_other_are_varied_and_set_together():
    """A sweep of contact angle 5-8 with latch offset -4-0 holds only valid designs (1-8
    degrees): its ranges are accepted and each design runs, whichever key comes first; ranges
    with no valid design at all are refused before any work."""
    from mantis_sim.studies.design import designs
    scene = load_scene('air_23mm')
    ranges = [designs.parse_range('geometry.latch_offset_deg=-4:0:2'),
              designs.parse_range('geometry.contact_angle_deg=5:8:2')]
    designs.check_ranges(scene, ranges)
    row = designs.run_design(scene, {'geometry.latch_offset_deg': -4.0,
                                     'geometry.contact_angle_deg': 5.0})
    assert row['status'] == designs.STATUS_OK
    with pytest.raises(designs.DesignError, match='latched arm at'):
        designs.check_ranges(scene, [designs.parse_range('geometry.latch_offset_deg=-9:-8:2'),
                                     designs.parse_range('geometry.contact_angle_deg=1:2:2')])
