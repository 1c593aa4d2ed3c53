"""The simulated rig's physics: reference behaviour, invariants, hard cases, bad input."""
import math

import numpy as np
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
    """The rigid tendon's Jacobian loses its theta3 component at overcentering, where reduced
    dynamics divide by zero. Here the moment arm changes sign through the event, the tension
    passes it smoothly (no spike), the constraint holds, and afterwards the tendon drives the
    arm out: its speed keeps rising through phase III."""
    assert ('overcenter' in [n for n, _ in air['events']])
    assert air['max_constraint_drift_mm'] < 1e-4
    assert math.isfinite(air['peak_tendon_force_N'])
    r = simulate(load_scene('air_23mm'))
    tr, mech = r.trajectory, Mechanism(r.scene)
    t_oc = dict(r.metrics['events'])['overcenter'] * 1e3
    near = (tr.t_ms > t_oc - 1.0) & (tr.t_ms < t_oc + 1.0)
    arm = np.array([mech.tendon(a, b).d3 for a, b in zip(tr.theta1, tr.theta3)])
    assert np.all(arm[near & (tr.t_ms < t_oc)] > 0) and np.all(arm[near & (tr.t_ms > t_oc)] < 0)
    force = tr.tendon_force_N[near]
    assert np.all(np.isfinite(force)) and force.max() < 1.05 * force.min()
    assert np.all(np.diff(tr.omega3[tr.phase == 'III']) > 0)


def test_results_converge_as_tolerance_tightens():
    ref = run('air_23mm', 'integration.solver=DOP853', 'integration.rtol=1e-11')
    errors = [abs(run('air_23mm', 'integration.solver=RK45', f'integration.rtol={r!r}')
                  ['peak_tip_speed_mps'] - ref['peak_tip_speed_mps']) for r in (1e-4, 1e-7)]
    assert errors[1] < errors[0] / 10


def test_unlatches_once_without_chattering(air):
    """The latch lets go when the contact torque reaches zero, once, continuously: no
    chattering between latched and free, and the torque never had to pull."""
    assert [n for n, _ in air['events']].count('unlatch') == 1
    r = simulate(load_scene('air_23mm'))
    tr = r.trajectory
    latched = tr.phase == 'I'
    assert np.all(tr.contact_torque_Nmm[latched] >= -1e-9)
    assert abs(tr.contact_torque_Nmm[latched][-1]) < 1e-6
    assert tr.contact_torque_Nmm[latched].max() > 1.0
    assert np.all(tr.theta3[~latched] >= math.radians(3.0) - 1e-9)


def test_zero_pull_stays_latched_for_an_hour():
    m = run('air_23mm', 'drive.pull_speed_mm_per_s=0', 'integration.t_end_s=3600')
    assert m['phase_start_s']['II'] is None and not m['strike_reached']
    assert m['rhs_evals'] < 5000


def test_very_fast_pull_still_strikes():
    m = run('air_23mm', 'drive.pull_speed_mm_per_s=500')
    assert m['strike_reached'] and 20 < m['peak_tip_speed_mps'] < 40


def test_contact_angles_zero_to_ten_degrees(air):
    """A larger contact angle unlatches earlier and stores less energy, from 0 to 10 deg."""
    runs = [run('air_23mm', f'geometry.contact_angle_deg={a}') for a in (0.0, 3.0, 5.0, 10.0)]
    assert runs[1]['max_spring_energy_mJ'] == pytest.approx(air['max_spring_energy_mJ'])
    for m in runs:
        assert m['strike_reached'] and 20 < m['peak_tip_speed_mps'] < 40
        assert [n for n, _ in m['events']].count('unlatch') == 1
        assert m['energy_balance_residual_mJ'] < 1e-3
    energies = [m['max_spring_energy_mJ'] for m in runs]
    unlatch = [m['phase_start_s']['II'] for m in runs]
    assert energies == sorted(energies, reverse=True)
    assert unlatch == sorted(unlatch, reverse=True)


def test_hours_of_slow_loading():
    """Pulled at 0.001 mm/s the rig loads for an hour before it fires: the release comes
    after the same pulled length as at 2.33 mm/s (loading is quasi-static), the strike is the
    same, and the cost does not grow with the simulated time."""
    slow = run('air_23mm', 'drive.pull_speed_mm_per_s=0.001', 'integration.t_end_s=1e5')
    nominal = run('air_23mm')
    assert slow['phase_start_s']['II'] > 3600
    assert slow['phase_start_s']['II'] * 0.001 == pytest.approx(
        nominal['phase_start_s']['II'] * 2.33, rel=1e-3)
    assert slow['peak_tip_speed_mps'] == pytest.approx(nominal['peak_tip_speed_mps'], rel=2e-3)
    assert slow['rhs_evals'] < 3 * nominal['rhs_evals']
    assert slow['energy_balance_residual_mJ'] < 1e-3


def _tendon_runs(solver, rtol, *overrides):
    return simulate(load_scene('air_23mm', ['initial.theta3_deg=30', 'integration.t_end_s=0.1',
                                            f'integration.solver={solver}',
                                            f'integration.rtol={rtol!r}', *overrides]))


# Solvers and tolerances whose integration noise differs: LSODA at 1e-6 drifts the stretch of
# a grazing tendon by ~1e-6 mm within microseconds, which once re-tensioned it spuriously.
GRAZING_SOLVERS = [('DOP853', 1e-7), ('LSODA', 1e-6), ('RK45', 1e-4), ('Radau', 1e-5)]


@pytest.mark.parametrize('solver, rtol', GRAZING_SOLVERS)
def test_tendon_going_slack_by_grazing_stays_slack(solver, rtol):
    """Arm released at 30 deg, stage at rest: the tension falls to zero smoothly (a grazing
    separation, stretch and its rate both zero), the tendon goes slack once and for good, and
    the free mechanism settles where its springs are at rest."""
    r = _tendon_runs(solver, rtol, 'drive.pull_speed_mm_per_s=0')
    assert [n for n, _, _ in r.raw.events] == ['slack']
    assert r.metrics['events'][0][1] == pytest.approx(2.76095e-3, abs=5e-7)
    tr = r.trajectory
    slack = tr.t_ms > r.metrics['events'][0][1] * 1e3
    assert np.all(tr.tendon_force_N[slack] == 0.0)
    stretch = tr.tendon_length_mm - tr.free_length_mm
    assert stretch[slack].max() < 1e-4 and stretch[-1] < -1.0
    assert tr.theta1[-1] == pytest.approx(math.pi + math.radians(50.63), abs=1e-3)
    assert math.degrees(tr.theta3[-1]) == pytest.approx(39.76, abs=0.1)
    # closes to the tolerance: ~57 mJ of spring energy at the start
    assert r.metrics['energy_balance_residual_mJ'] < 100.0 * rtol


def test_slack_and_retension_without_chattering():
    """Arm released at 30 deg while the stage pulls fast (100 mm/s): the start jerks the
    mechanism, the tendon goes slack, the stage takes up the slack and the tendon snaps taut
    twice (inelastic impacts), then the arm falls back on the body and re-latches. Every
    solver finds the same events at the same times; no energy is created at any snap."""
    runs = [_tendon_runs(solver, rtol, 'drive.pull_speed_mm_per_s=100')
            for solver, rtol in [('DOP853', 1e-9), ('DOP853', 1e-7), ('LSODA', 1e-6),
                                 ('Radau', 1e-5)]]
    ref = runs[0]
    names = [n for n, _, _ in ref.raw.events]
    assert names[:4] == ['slack', 'retension', 'slack', 'retension']
    assert 'recontact' in names and len(names) < 12
    for r in runs[1:]:
        assert [n for n, _, _ in r.raw.events] == names
        for (_, t, _), (_, t_ref, _) in zip(r.raw.events, ref.raw.events):
            assert t == pytest.approx(t_ref, abs=2e-3)          # ms
    for r in runs:
        tr = r.trajectory
        assert np.all(tr.tendon_force_N >= -1e-9)
        assert np.all(np.diff(tr.dissipated_mJ) >= -1e-9)         # snaps dissipate
        assert r.metrics['energy_balance_residual_mJ'] < 1e-3
    assert ref.metrics['energy_balance_residual_mJ'] < 1e-6
    assert ref.metrics['max_constraint_drift_mm'] < 1e-4


def test_retension_and_slack_at_the_same_instant():
    """Events at coincident times: the second snap leaves a tendon that would have to push,
    so it is slack again at the same instant; the simulation goes on from there."""
    r = _tendon_runs('DOP853', 1e-7, 'drive.pull_speed_mm_per_s=100')
    events = r.raw.events
    same = [(a[0], b[0]) for a, b in zip(events, events[1:]) if a[1] == b[1]]
    assert ('retension', 'slack') in same
    assert r.trajectory.t_ms[-1] == pytest.approx(100.0)


def test_advancing_to_just_before_or_after_an_event_finds_the_same_events():
    """Events at near-coincident times: a segment ending within rounding of an event root
    (the simulated rig advances in steps) must neither miss the event nor trip the root
    finder."""
    from mantis_sim.hybrid import HybridSimulator
    scene = load_scene('air_23mm')
    ref = HybridSimulator(scene)
    ref.run()
    names = [n for n, _, _ in ref.run_data.events]
    for _, t_event, _ in ref.run_data.events:
        for offset in (-1e-9, -1e-12, 0.0, 1e-12):
            sim = HybridSimulator(scene)
            sim.start()
            sim.advance(t_event + offset)
            sim.advance(ref.t_end, stop_after_peak=True)
            assert [n for n, _, _ in sim.run_data.events] == names
            for (_, t, _), (_, t_ref, _) in zip(sim.run_data.events, ref.run_data.events):
                assert t == pytest.approx(t_ref, abs=1e-5)


def test_impact_on_recontact_rebounds_and_latches():
    """The hinge throws the arm back on the body: each impact reverses the arm at about the
    restitution coefficient (0.3), the bounces shrink geometrically, every impact dissipates,
    and the arm ends latched on the body (no endless re-contact chattering)."""
    r = simulate(load_scene('air_23mm', ['initial.theta3_deg=20', 'drive.pull_speed_mm_per_s=0',
                                         'integration.t_end_s=0.2', 'hinge.rest_angle_deg=0',
                                         'hinge.k_Nmm_per_rad=5']))
    impacts = [s for n, _, s in r.raw.events if n == 'recontact']
    assert 2 <= len(impacts) < 12
    speeds = [-s[3] for s in impacts]
    assert all(v > 0 for v in speeds)
    ratios = [b / a for a, b in zip(speeds, speeds[1:])]
    assert all(0.2 < q < 0.35 for q in ratios)
    assert r.raw.segments[-1].latched
    tr = r.trajectory
    assert tr.theta3[-1] == pytest.approx(math.radians(3.0), abs=1e-12)
    assert np.all(np.diff(tr.dissipated_mJ) >= -1e-9)
    assert r.metrics['energy_balance_residual_mJ'] < 1e-4


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


def test_shipped_compliant_scene_is_stable_with_its_implicit_solver():
    """air_23mm_compliant (50 N/mm, stiff on gram-scale inertia) with its scene's solver:
    all four phases in order, the tendon never pushes, the energy balance closes, and an
    explicit method agrees on the peak tip speed."""
    m = run('air_23mm_compliant')
    assert m['solver'] == 'Radau'
    starts = [m['phase_start_s'][p] for p in PHASE_ORDER]
    assert None not in starts and starts == sorted(starts)
    assert 0.0 < m['peak_tendon_force_N'] < 18.0
    assert m['energy_balance_residual_mJ'] < 1e-4
    explicit = run('air_23mm_compliant', 'integration.solver=DOP853', 'integration.rtol=1e-6')
    assert m['peak_tip_speed_mps'] == pytest.approx(explicit['peak_tip_speed_mps'], rel=1e-5)


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
