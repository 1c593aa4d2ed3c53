"""The simulated rig's physics: reference behaviour, invariants, hard cases, bad input."""
import math

import pytest

from mantis_rig.cli import main as mantis
from mantis_sim.forces import FluidDrag
from mantis_sim.mechanism import Mechanism
from mantis_sim.parameters import ParameterError
from mantis_sim.results import simulate
from mantis_sim.scene import SceneError, available_scenes, load_scene

PHASE_ORDER = ('I', 'II', 'III', 'IV')


def run(name='air_23mm', *overrides):
    return simulate(load_scene(name, list(overrides))).metrics


@pytest.fixture(scope='module')
def air():
    return run('air_23mm')


def test_air_23mm_reaches_all_phases_in_order(air):
    starts = [air['phase_start_s'][p] for p in PHASE_ORDER]
    assert None not in starts
    assert starts == sorted(starts) and len(set(starts)) == 4
    assert 26.0 <= air['peak_tip_speed_mps'] <= 32.0
    assert air['peak_tendon_force_N'] < 18.0
    assert air['peak_arm_speed_radps'] > 3 * air['peak_body_speed_radps']


def test_water_is_slow_and_short_guide_stores_more(air):
    assert 3.0 <= run('water_23mm')['peak_tip_speed_mps'] <= 8.0
    assert run('air_19mm')['max_spring_energy_mJ'] > air['max_spring_energy_mJ']
    shim = run('air_23mm_shim7deg')
    assert shim['max_spring_energy_mJ'] < air['max_spring_energy_mJ']
    assert shim['phase_start_s']['II'] < air['phase_start_s']['II']


def test_energy_conserved_without_damping_fluid_or_drive():
    m = run('air_23mm', 'effects=[hinge_stiffness]', 'drive.pull_speed_mm_per_s=0',
            'initial.theta3_deg=20', 'integration.solver=DOP853', 'integration.rtol=1e-11',
            'integration.t_end_s=0.05')
    spring0 = 0.5 * 47.7 * (2.4812 - math.pi - math.radians(50.63)) ** 2
    assert m['energy_balance_residual_mJ'] / spring0 < 1e-8


def test_energy_balance_closes_with_everything_on():
    m = run('air_23mm', 'effects=[gravity, joint_damping, hinge_stiffness, fluid_drag, '
            'tendon_slack, contact_restitution, stage_profile]', 'integration.rtol=1e-8')
    assert m['strike_reached']
    assert m['energy_balance_residual_mJ'] < 1e-3


def test_overcentering_with_rigid_tendon_keeps_constraint(air):
    assert ('overcenter' in [n for n, _ in air['events']])
    assert air['max_constraint_drift_mm'] < 1e-4
    assert math.isfinite(air['peak_tendon_force_N'])


def test_results_converge_as_tolerance_tightens():
    ref = run('air_23mm', 'integration.solver=DOP853', 'integration.rtol=1e-11')
    errors = [abs(run('air_23mm', 'integration.solver=RK45', f'integration.rtol={r!r}')
                  ['peak_tip_speed_mps'] - ref['peak_tip_speed_mps']) for r in (1e-4, 1e-7)]
    assert errors[1] < errors[0] / 10


def test_unlatches_once_without_chattering(air):
    assert [n for n, _ in air['events']].count('unlatch') == 1


def test_zero_pull_stays_latched_for_an_hour():
    m = run('air_23mm', 'drive.pull_speed_mm_per_s=0', 'integration.t_end_s=3600')
    assert m['phase_start_s']['II'] is None and not m['strike_reached']
    assert m['rhs_evals'] < 5000


def test_very_fast_pull_still_strikes():
    m = run('air_23mm', 'drive.pull_speed_mm_per_s=500')
    assert m['strike_reached'] and 20 < m['peak_tip_speed_mps'] < 40


@pytest.mark.parametrize('angle', [0.0, 5.0, 10.0])
def test_contact_angles_zero_to_ten_degrees(angle):
    m = run('air_23mm', f'geometry.contact_angle_deg={angle}')
    assert m['strike_reached'] and math.isfinite(m['peak_tip_speed_mps'])


def test_slack_and_retension_without_chattering():
    m = run('air_23mm', 'initial.theta3_deg=30', 'drive.pull_speed_mm_per_s=0',
            'integration.t_end_s=0.1')
    names = [n for n, _ in m['events']]
    assert 'slack' in names and 'retension' in names
    assert len(names) < 100
    assert m['energy_balance_residual_mJ'] < 1e-3


def test_impact_on_recontact_rebounds_and_latches():
    m = run('air_23mm', 'initial.theta3_deg=20', 'drive.pull_speed_mm_per_s=0',
            'integration.t_end_s=0.2', 'hinge.rest_angle_deg=0', 'hinge.k_Nmm_per_rad=5')
    assert [n for n, _ in m['events']].count('recontact') >= 2
    assert m['energy_balance_residual_mJ'] < 1e-4


def test_drag_at_zero_speed_is_finite_and_zero():
    scene = load_scene('water_23mm')
    drag = FluidDrag(Mechanism(scene), scene)
    q1, q3, loss = drag(2.4, 0.1, 0.0, 0.0)
    assert (q1, q3, loss) == (0.0, 0.0, 0.0)
    assert all(math.isfinite(v) for v in drag(2.4, 0.1, 1e-12, -1e-12))


def test_added_mass_raises_inertia_and_keeps_balance():
    water = load_scene('water_23mm')
    dry = Mechanism(water.with_values({'effects': ['fluid_drag']})).mass(0.3)
    wet = Mechanism(water).mass(0.3)
    assert wet.m22 > 5 * dry.m22
    assert run('water_23mm')['energy_balance_residual_mJ'] < 1e-3


def test_stiff_compliant_tendon_matches_rigid(air):
    m = run('air_23mm', 'tendon.model=compliant', 'tendon.stiffness_N_per_mm=1e4',
            'integration.solver=Radau', 'integration.rtol=1e-6')
    assert m['strike_reached']
    assert abs(m['peak_tip_speed_mps'] - air['peak_tip_speed_mps']) < 0.05 * 27


def test_every_shipped_scene_loads():
    assert {'air_23mm', 'air_19mm', 'water_23mm', 'air_23mm_shim7deg'} <= set(available_scenes())


@pytest.mark.parametrize('override, words', [
    ('body.mass_g=-1', ['body.mass_g', '-1', 'range']),
    ('geometry.contact_angle_deg=20', ['contact_angle_deg', '20', '[0, 15]']),
    ('effects=[warp_drive]', ['warp_drive', 'valid effects']),
    ('geometry.nope=1', ['geometry.nope', 'valid keys']),
])
def test_bad_parameters_name_key_value_and_range(override, words):
    with pytest.raises(ParameterError) as info:
        load_scene('air_23mm', [override])
    assert all(w in str(info.value) for w in words)


def test_unknown_and_malformed_scenes(tmp_path):
    with pytest.raises(SceneError, match='unknown scene'):
        load_scene('no_such_scene')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('geometry: {L1_mm: [1\n')
    with pytest.raises(SceneError, match='not valid YAML'):
        load_scene(str(bad))


def test_cli_usage_errors_exit_2(capsys):
    assert mantis(['sim', '--scene', 'no_such_scene']) == 2
    assert mantis(['sim', '--scene', 'air_23mm', '--set', 'body.mass_g=-1']) == 2
    assert 'body.mass_g' in capsys.readouterr().err


def test_cli_json_keys(capsys):
    import json
    assert mantis(['sim', '--scene', 'air_23mm', '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    for key in ('peak_tip_speed_mps', 'max_spring_energy_mJ', 'peak_tendon_force_N',
                'phase_start_s', 'phase_duration_s', 'energy_balance_residual_mJ', 'wall_time_s',
                'rhs_evals', 'effects', 'solver', 'rtol'):
        assert key in data
    assert set(data['phase_start_s']) == set(PHASE_ORDER)
