"""The simulated rig's physics: reference behaviour, invariants, hard cases, bad input.

Hard cases of physics.md ("Numerical demands") and their tests:
- rank loss at overcentering, rigid tendon ... test_overcentering_with_rigid_tendon_keeps_constraint
- latch release with lambda ~ 0 ............. test_unlatches_once_without_chattering,
                                               test_every_solver_releases_the_latch_once
- tendon slack and re-tension ............... test_tendon_going_slack_by_grazing_stays_slack,
                                               test_slack_and_retension_without_chattering,
                                               test_compliant_tendon_goes_slack_and_retensions
- very stiff compliant tendon ............... test_very_stiff_compliant_tendon_converges_to_rigid
- water added mass .......................... test_added_mass_is_a_consistent_inertia,
                                               test_energy_conserved_... [added mass]
- drag at zero speed ........................ test_drag_at_zero_speed_is_smooth_and_dissipative,
                                               test_release_from_rest_in_water
- impact on re-contact ...................... test_impact_on_recontact_rebounds_and_latches
- v = 0 stays latched; very fast pulls ...... test_zero_pull_stays_latched_for_an_hour,
                                               test_very_fast_pulls
- contact angles 0 to 10 deg ................ test_contact_angles_zero_to_ten_degrees
- hours of slow loading ..................... test_hours_of_slow_loading
Each also passes check_invariants (no NaN/inf, energy balance closes to the tolerance, bounded
constraint drift, unilateral contact and tendon respected); convergence as tolerances tighten:
test_results_converge_as_tolerance_tightens.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from mantis_rig.cli import main as mantis
from mantis_sim import drive, forces, mechanism
from mantis_sim.forces import FluidDrag
from mantis_sim.hybrid import HybridSimulator, Mode
from mantis_sim.mechanism import Mechanism
from mantis_sim.parameters import ParameterError
from mantis_sim.results import JSON_KEYS, simulate
from mantis_sim.scene import SceneError, available_scenes, load_scene

REPO = Path(__file__).resolve().parents[2]

PHASE_ORDER = ('I', 'II', 'III', 'IV')
# The published robot (rigid tendon): the engine's hard cases run on it.
REF_AIR, REF_AIR19, REF_WATER = 'reference_air_23mm', 'reference_air_19mm', 'reference_water_23mm'
NOMINAL_EVENTS = ['unlatch', 'overcenter', 'max_contraction', 'peak']
MECHANICAL = ('gravity, joint_damping, hinge_stiffness, fluid_drag, added_mass, tendon_slack, '
              'contact_restitution, stage_profile')
EVERYTHING_ON = f'effects=[{MECHANICAL}]'
# The stage's acceleration ramp and nothing else added to reference_air_23mm's effects.
RAMPED = ('effects=[joint_damping, hinge_stiffness, fluid_drag, tendon_slack, '
          'contact_restitution, stage_profile]')


def run(name=REF_AIR, *overrides):
    return simulate(load_scene(name, list(overrides))).metrics


def sim(name=REF_AIR, *overrides, dense=False):
    return simulate(load_scene(name, list(overrides)), dense=dense)


def check_invariants(result, residual_per_rtol=10.0):
    """No NaN/inf anywhere; the energy balance closes to the tolerance (relative to the energy
    that moved); a rigid tendon's length drift stays within what the tolerance allows; the
    arm never enters the body; a unilateral tendon never pushes; phases only advance."""
    tr, m, scene = result.trajectory, result.metrics, result.scene
    for name, column in vars(tr).items():
        if name != 'phase':
            assert np.all(np.isfinite(column)), name
    rtol = scene.integration.rtol
    scale = max(tr.spring_energy_mJ.max(), tr.kinetic_energy_mJ.max(), 1.0)
    assert m['energy_balance_residual_mJ'] <= residual_per_rtol * rtol * scale
    assert m['max_constraint_drift_mm'] <= 10.0 * rtol * scene.geometry.d_t_mm
    assert tr.theta3.min() >= math.radians(scene.geometry.contact_angle_deg) - 1e-8
    if scene.has('tendon_slack'):
        assert tr.tendon_force_N.min() >= -1e-9
    order = [PHASE_ORDER.index(p) for p in tr.phase]
    assert order == sorted(order)
    return result


@pytest.fixture(scope='module')
def air():
    return run(REF_AIR)


@pytest.fixture(scope='module')
def air_dense():
    return simulate(load_scene(REF_AIR), dense=True)


# --- what it must show (issue 2, item 1) --------------------------------------------------------

def test_air_23mm_reaches_all_four_phases_in_order(air_dense):
    m = check_invariants(air_dense).metrics
    starts = [m['phase_start_s'][p] for p in PHASE_ORDER]
    assert None not in starts and m['strike_reached']
    assert starts == sorted(starts) and len(set(starts)) == 4
    assert [n for n, _ in m['events']] == NOMINAL_EVENTS
    assert m['peak_time_s'] > starts[-1]


def test_air_23mm_peak_tip_speed_26_to_32_mps(air):
    assert 26.0 <= air['peak_tip_speed_mps'] <= 32.0


@pytest.mark.xfail(strict=True, reason=(
    'since the blade drag is the strip integral with flat-plate coefficients (water within '
    '10 % of the real robot), the arm swings faster and the raw tension peaks at 18.6 N at '
    'the peak tip speed; the published 18 N is the load cell\'s reading, and the simulated '
    'load cell (1 kHz amplifier) reads the spike lower (test_sim_backends)'))
def test_air_23mm_tendon_force_below_18N_throughout(air_dense):
    """Checked on the continuous solution (dense output, 2000 points per segment, plus every
    step), not only at the solver's steps, from the start to the peak tip speed."""
    r = air_dense
    forces_ = list(r.trajectory.tendon_force_N)
    for seg in r.raw.segments:
        forces_.extend(r.tendon_force_at(np.linspace(seg.t[0], seg.t[-1], 2000)))
    assert 0.0 < max(forces_) < 18.0
    assert max(forces_) == pytest.approx(r.metrics['peak_tendon_force_N'], rel=1e-6)


def test_air_23mm_arm_peak_angular_speed_several_times_the_body(air):
    assert air['peak_arm_speed_radps'] > 3.0 * air['peak_body_speed_radps']


def test_water_23mm_peak_tip_speed_3_to_8_mps():
    m = check_invariants(sim(REF_WATER)).metrics
    assert 3.0 <= m['peak_tip_speed_mps'] <= 8.0
    assert m['peak_arm_speed_radps'] > 3.0 * m['peak_body_speed_radps']


def test_short_tendon_guide_stores_more_spring_energy(air):
    assert run(REF_AIR19)['max_spring_energy_mJ'] > air['max_spring_energy_mJ']


def test_larger_contact_angle_unlatches_earlier_and_stores_less(air):
    shim = run('air_23mm_shim7deg')
    assert shim['max_spring_energy_mJ'] < air['max_spring_energy_mJ']
    assert shim['phase_start_s']['II'] < air['phase_start_s']['II']


# --- invariants (item 2 and the invariants of item 3) -------------------------------------------

CONSERVATIVE = {
    # the arm swings free on a taut rigid tendon, no contact on the way
    'rigid': ['effects=[hinge_stiffness]', 'initial.theta3_deg=100'],
    # M(theta3) with the water's added mass, and gravity: tests their velocity terms
    'added mass and gravity': ['effects=[hinge_stiffness, gravity, added_mass]',
                               'medium.density_g_per_mm3=9.1875e-4', 'initial.theta3_deg=100'],
    # the arm hits the body five times, elastically, and swings through overcentering
    'elastic impacts': ['effects=[hinge_stiffness, contact_restitution]', 'contact.restitution=1',
                        'contact.latch_speed_rad_per_s=0', 'initial.theta3_deg=20'],
    # a bilateral compliant tendon (50 N/mm) stores energy too
    'compliant tendon': ['effects=[hinge_stiffness]', 'tendon.model=compliant',
                         'initial.theta3_deg=20', 'integration.t_end_s=0.005'],
}


@pytest.mark.parametrize('case', CONSERVATIVE)
def test_energy_conserved_without_damping_fluid_or_drive(case):
    """Drive at rest, no damping, no fluid, no tendon slack: the total mechanical energy stays
    what it was to better than 1e-8 of itself at tight tolerance, while the mechanism moves
    (tens of mJ change between spring and kinetic energy)."""
    r = sim(REF_AIR, 'drive.pull_speed_mm_per_s=0', 'integration.solver=DOP853',
            'integration.rtol=1e-11', 'integration.t_end_s=0.05',
            'integration.post_peak_ms=50', *CONSERVATIVE[case])
    tr = r.trajectory
    assert np.all(tr.drive_work_mJ == 0.0)
    energy = r.raw.energy0_mJ + tr.balance_residual_mJ + tr.drive_work_mJ - tr.dissipated_mJ
    assert np.all(np.isfinite(energy))
    assert np.abs(energy - energy[0]).max() / energy[0] < 1e-8
    assert tr.kinetic_energy_mJ.max() > 10.0
    if case == 'elastic impacts':
        assert [n for n, _, _ in r.raw.events].count('recontact') >= 2


@pytest.mark.parametrize('scene, solver', [(REF_AIR, 'DOP853'), (REF_WATER, 'DOP853'),
                                           ('air_23mm_compliant', 'Radau')])
def test_energy_balance_closes_to_the_tolerance_with_everything_on(scene, solver):
    """Every mechanical effect on (gravity, damping, hinge, drag, added mass, slack,
    restitution, stage ramp): dKE + dV = W_tendon - dissipated closes to about rtol times the
    energy, at every tolerance, and so converges as the tolerance tightens."""
    residuals = []
    for rtol in (1e-5, 1e-7, 1e-9):
        r = check_invariants(sim(scene, EVERYTHING_ON, f'integration.solver={solver}',
                                 f'integration.rtol={rtol!r}', 'integration.post_peak_ms=2'))
        assert [n for n, _ in r.metrics['events']][:4] == NOMINAL_EVENTS
        assert r.metrics['effects'] == MECHANICAL.split(', ')
        residuals.append(r.metrics['energy_balance_residual_mJ'])
    assert residuals[2] < residuals[0] / 100


CONVERGENCE_CASES = [
    (REF_AIR, []), (REF_WATER, []), (REF_AIR, ['geometry.contact_angle_deg=0']),
    (REF_WATER, ['geometry.contact_angle_deg=10']),
    (REF_AIR, ['drive.pull_speed_mm_per_s=500']),
]


@pytest.mark.parametrize('scene, overrides', CONVERGENCE_CASES)
def test_results_converge_as_tolerance_tightens(scene, overrides):
    """Two different high-order methods agree at tight tolerance; against them, the peak tip
    speed and the phase-IV start of an explicit and a multistep solver converge."""
    ref = run(scene, *overrides, 'integration.solver=DOP853', 'integration.rtol=1e-11')
    other = run(scene, *overrides, 'integration.solver=Radau', 'integration.rtol=1e-10')
    v_ref, t_ref = ref['peak_tip_speed_mps'], ref['phase_start_s']['IV']
    assert other['peak_tip_speed_mps'] == pytest.approx(v_ref, rel=1e-9)
    assert other['phase_start_s']['IV'] == pytest.approx(t_ref, abs=1e-9)
    for solver in ('RK45', 'LSODA'):
        loose, tight = (run(scene, *overrides, f'integration.solver={solver}',
                            f'integration.rtol={rtol!r}') for rtol in (1e-4, 1e-8))
        for key in ('peak_tip_speed_mps',):
            errors = [abs(m[key] - v_ref) / v_ref for m in (loose, tight)]
            assert errors[1] < errors[0] / 10 and errors[1] < 1e-6
        errors = [abs(m['phase_start_s']['IV'] - t_ref) for m in (loose, tight)]
        assert errors[1] < errors[0] / 10 and errors[1] < 1e-8       # s


# --- hard cases (item 3) ----------------------------------------------------------------------

def test_overcentering_with_rigid_tendon_keeps_constraint(air):
    """The rigid tendon's Jacobian loses its theta3 component at overcentering, where reduced
    dynamics divide by zero. Here the moment arm changes sign through the event, the tension
    passes it smoothly (no spike), the constraint holds, and afterwards the tendon drives the
    arm out: its speed keeps rising through phase III."""
    r = check_invariants(sim(REF_AIR))
    tr, mech = r.trajectory, Mechanism(r.scene)
    assert r.metrics['max_constraint_drift_mm'] < 1e-5
    t_oc = dict(r.metrics['events'])['overcenter'] * 1e3
    near = (tr.t_ms > t_oc - 1.0) & (tr.t_ms < t_oc + 1.0)
    arm = np.array([mech.tendon(a, b).d3 for a, b in zip(tr.theta1, tr.theta3)])
    # The samples at the event itself (the arm is zero there, to roundoff; their times differ
    # from the event's by roundoff of the ms conversion) belong to neither side.
    off_event = ~np.isclose(tr.t_ms, t_oc, rtol=0.0, atol=1e-9)
    before, after = near & off_event & (tr.t_ms < t_oc), near & off_event & (tr.t_ms > t_oc)
    assert before.any() and after.any()
    assert np.all(arm[before] > 0) and np.all(arm[after] < 0)
    assert np.all(np.abs(arm[near & ~off_event]) < 1e-9)
    force = tr.tendon_force_N[near]
    assert np.all(np.isfinite(force)) and force.max() < 1.05 * force.min()
    assert np.all(np.diff(tr.omega3[tr.phase == 'III']) > 0)


def test_unlatches_once_without_chattering(air):
    """The latch lets go when the contact torque reaches zero, once, continuously: no
    chattering between latched and free, and the torque never had to pull."""
    assert [n for n, _ in air['events']].count('unlatch') == 1
    tr = sim(REF_AIR).trajectory
    latched = tr.phase == 'I'
    assert np.all(tr.contact_torque_Nmm[latched] >= -1e-9)
    assert abs(tr.contact_torque_Nmm[latched][-1]) < 1e-6
    assert tr.contact_torque_Nmm[latched].max() > 1.0
    assert np.all(tr.theta3[~latched] >= math.radians(3.0) - 1e-9)


@pytest.mark.parametrize('solver', ['RK23', 'RK45', 'DOP853', 'LSODA', 'Radau', 'BDF'])
def test_every_solver_releases_the_latch_once(solver):
    """At lambda = 0 the arm leaves the body with zero relative speed; integration noise of a
    loose tolerance must not read as a re-contact (latch, unlatch, latch, ...)."""
    r = check_invariants(sim(REF_AIR, f'integration.solver={solver}', 'integration.rtol=1e-3'),
                         residual_per_rtol=30.0)
    assert [n for n, _ in r.metrics['events']] == NOMINAL_EVENTS


def _tendon_runs(solver, rtol, *overrides):
    return simulate(load_scene(REF_AIR, ['initial.theta3_deg=30', 'integration.t_end_s=0.1',
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
    r = check_invariants(_tendon_runs(solver, rtol, 'drive.pull_speed_mm_per_s=0'))
    assert [n for n, _, _ in r.raw.events] == ['slack']
    # converged (DOP853 at 1e-11): 2.7296014 ms; RK45 at 1e-4 is 0.56 us off it
    assert r.metrics['events'][0][1] == pytest.approx(2.72960e-3, abs=1e-6)
    tr = r.trajectory
    slack = tr.t_ms > r.metrics['events'][0][1] * 1e3
    assert np.all(tr.tendon_force_N[slack] == 0.0)
    stretch = tr.tendon_length_mm - tr.free_length_mm
    assert stretch[slack].max() < 1e-4 and stretch[-1] < -1.0
    assert tr.theta1[-1] == pytest.approx(math.pi + math.radians(50.63), abs=1e-3)
    assert math.degrees(tr.theta3[-1]) == pytest.approx(39.76, abs=0.1)


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
        check_invariants(r)
        assert np.all(np.diff(r.trajectory.dissipated_mJ) >= -1e-9)      # snaps dissipate


def test_retension_and_slack_at_the_same_instant():
    """Events at coincident times: the second snap leaves a tendon that would have to push,
    so it is slack again at the same instant; the simulation goes on from there."""
    r = check_invariants(_tendon_runs('DOP853', 1e-7, 'drive.pull_speed_mm_per_s=100'))
    events = r.raw.events
    same = [(a[0], b[0]) for a, b in zip(events, events[1:]) if a[1] == b[1]]
    assert ('retension', 'slack') in same
    assert r.trajectory.t_ms[-1] == pytest.approx(100.0)


def test_compliant_tendon_goes_slack_and_retensions():
    """air_23mm_compliant after the strike: the arm swings on and unloads the tendon, which
    goes slack (no tension, stretch <= 0) and is taken up again by the stage (stretch > 0);
    the tension is continuous through both events, as it must be for a spring."""
    r = check_invariants(sim('air_23mm_compliant', 'integration.post_peak_ms=5'))
    names = [n for n, _ in r.metrics['events']]
    assert names[:4] == NOMINAL_EVENTS and names[4:] == ['slack', 'retension']
    tr = r.trajectory
    stretch = tr.tendon_length_mm - tr.free_length_mm
    t_slack, t_taut = (t * 1e3 for _, t in r.metrics['events'][4:])
    slack = (tr.t_ms > t_slack) & (tr.t_ms < t_taut)
    assert slack.sum() >= 2
    assert np.all(tr.tendon_force_N[slack] == 0.0) and np.all(stretch[slack] < 0.0)
    assert np.all(stretch[tr.t_ms > t_taut] > 0.0)
    at_events = [tr.tendon_force_N[np.isclose(tr.t_ms, t, rtol=0, atol=1e-12)]
                 for t in (t_slack, t_taut)]
    assert all(np.abs(f).max() < 1e-6 for f in at_events)


def test_very_stiff_compliant_tendon_converges_to_rigid():
    """A compliant tendon of 1e4 and 1e6 N/mm (oscillation periods of ~0.1 ms and ~10 us
    against a trial of 1.9 s) on the implicit Radau: the strike converges to the rigid
    tendon's as the stiffness grows (error ~ 1/k), and the cost grows far slower than the
    stiffness (an explicit method would step at the tendon's period). The stage ramps up
    (stage_profile): an ideal jump to full speed would ring the stiff, lightly damped tendon
    mode, which any method has to resolve until it decays."""
    rigid = run(REF_AIR, RAMPED)
    runs = [check_invariants(sim(REF_AIR, RAMPED, 'tendon.model=compliant',
                                 f'tendon.stiffness_N_per_mm={k}', 'integration.solver=Radau',
                                 'integration.rtol=1e-6')).metrics for k in (1e4, 1e6)]
    errors = [abs(m['peak_tip_speed_mps'] / rigid['peak_tip_speed_mps'] - 1) for m in runs]
    assert errors[0] < 1e-3 and errors[1] < errors[0] / 30
    for m in runs:
        assert [n for n, _ in m['events']] == NOMINAL_EVENTS
        assert m['peak_tendon_force_N'] == pytest.approx(rigid['peak_tendon_force_N'], rel=0.01)
    assert runs[1]['rhs_evals'] < 5 * runs[0]['rhs_evals'] < 50_000


def test_added_mass_is_a_consistent_inertia():
    """Water's entrained fluid: M stays symmetric positive definite at every arm angle, the
    arm's inertia grows many times, dM/dtheta3 (which the velocity terms use) matches M's
    finite difference, and energy is conserved with it (test_energy_conserved_...)."""
    water = load_scene(REF_WATER)
    wet, dry = Mechanism(water), Mechanism(water.with_values({'effects': ['fluid_drag']}))
    for th3 in np.linspace(0.0, math.pi, 13):
        m = wet.mass(th3)
        assert m.m11 > 0 and m.m11 * m.m22 - m.m12 ** 2 > 0
        h = 1e-6
        plus, minus = wet.mass(th3 + h), wet.mass(th3 - h)
        for name in ('m11', 'm12', 'm22'):
            fd = (getattr(plus, name) - getattr(minus, name)) / (2 * h)
            assert getattr(m, 'd' + name) == pytest.approx(fd, rel=1e-6, abs=1e-8)
        assert m.m22 > 5 * dry.mass(th3).m22


def test_added_mass_slows_the_strike_and_keeps_balance():
    """In water the strike is several times slower than in air; the arm still outruns the
    body; added mass alone (without drag) also slows it."""
    water = check_invariants(sim(REF_WATER)).metrics
    air = run(REF_AIR)
    assert water['peak_tip_speed_mps'] < air['peak_tip_speed_mps'] / 3
    no_drag = run(REF_WATER, 'effects=[joint_damping, hinge_stiffness, added_mass, '
                  'tendon_slack, contact_restitution]')
    no_fluid = run(REF_WATER, 'effects=[joint_damping, hinge_stiffness, tendon_slack, '
                   'contact_restitution]')
    assert no_drag['peak_tip_speed_mps'] < no_fluid['peak_tip_speed_mps']
    assert no_drag['phase_duration_s']['IV'] > no_fluid['phase_duration_s']['IV']


REAL_WATER_TIP_SPEED_MPS = 4.62     # the real robot in water, 23 mm guide (issue 14)


def test_water_strike_within_10_percent_of_the_real_robot():
    """The blade's strip-theory drag with flat-plate section coefficients: the strike in water
    comes within 10 % of the real robot's 4.62 m/s (it was 3.03 with the revolving-wing
    coefficients and one centre of pressure)."""
    tip = run(REF_WATER)['peak_tip_speed_mps']
    assert abs(tip / REAL_WATER_TIP_SPEED_MPS - 1) < 0.10, tip


def test_blade_drag_is_the_strip_integral():
    """Three Gauss strips against a 64-strip sum over random states: within 0.1 % wherever the
    flow keeps one direction along the blade (the strike), and exact for pure rotation about
    the arm pivot (force ~ r^2, moment ~ r^3)."""
    scene = load_scene(REF_WATER)
    mech = Mechanism(scene)
    drag, fine = FluidDrag(mech, scene), FluidDrag(mech, scene)
    g, rho = scene.geometry, scene.medium.density_g_per_mm3
    n, chord = 64, scene.arm.blade_area_mm2 / (g.L3_mm - g.L5_mm)
    width = (g.L3_mm - g.L5_mm) / n
    fine.strips = [(g.L5_mm + (k + 0.5) * width, 0.5 * rho * chord * width) for k in range(n)]
    rng = np.random.default_rng(3)
    checked = 0
    while checked < 300:
        th3 = rng.uniform(0.0, math.pi)
        w1, w3 = rng.normal(size=2) * 0.3
        v_root, v_tip = (mech.arm_point_velocity(r, th3, w1, w3)[1] for r in (g.L5_mm, g.L3_mm))
        if v_root * v_tip <= 0:
            continue
        q, q_fine = np.array(drag(2.4, th3, w1, w3)), np.array(fine(2.4, th3, w1, w3))
        assert np.max(np.abs(q - q_fine)) < 1e-3 * np.max(np.abs(q_fine))
        checked += 1
    # pure rotation about b (w1 = 0), broadside: Q3 = -rho/2 C_D chord w3^2 int r^3 dr
    w3 = 0.2
    q3 = drag(2.4, 1.0, 0.0, w3)[1]
    exact = -0.5 * rho * scene.arm.blade_drag_broadside * chord * w3 * abs(w3) \
        * (g.L3_mm ** 4 - g.L5_mm ** 4) / 4
    assert q3 == pytest.approx(exact, rel=1e-6)


def test_drag_at_zero_speed_is_smooth_and_dissipative():
    """At rest the angle of attack is undefined: the regularised drag is exactly zero there,
    goes to zero continuously (bounded force per unit speed), and never adds energy."""
    scene = load_scene(REF_WATER)
    drag = FluidDrag(Mechanism(scene), scene)
    assert drag(2.4, 0.1, 0.0, 0.0) == (0.0, 0.0, 0.0)
    rng = np.random.default_rng(1)
    for scale in (1e-12, 1e-9, 1e-6, 1e-3, 1.0):
        for _ in range(50):
            th3 = rng.uniform(0.0, math.pi)
            w1, w3 = rng.normal(size=2) * scale
            q1, q3, loss = drag(2.4, th3, w1, w3)
            assert all(math.isfinite(v) for v in (q1, q3, loss))
            assert loss >= 0.0 and loss == pytest.approx(-(q1 * w1 + q3 * w3), rel=1e-9,
                                                         abs=1e-30)
            if scale <= 1e-6:       # well below the regularisation speed: linear in speed
                assert math.hypot(q1, q3) < 1e-2 * math.hypot(w1, w3)


def test_release_from_rest_in_water():
    """The arm is let go from rest at 20 deg, in water, stage at rest: drag starts at zero
    speed, where its regularisation acts. The integrator starts with steps as long as without
    fluid and needs no more evaluations over all; the water slows the swing several times and
    only ever takes energy out."""
    base = ['drive.pull_speed_mm_per_s=0', 'initial.theta3_deg=20', 'integration.t_end_s=0.02',
            'integration.post_peak_ms=20']
    wet = check_invariants(sim(REF_WATER, *base))
    dry = check_invariants(sim(REF_WATER, *base, 'effects=[joint_damping, hinge_stiffness, '
                               'tendon_slack, contact_restitution]'))
    assert wet.trajectory.tip_speed_mps.max() < dry.trajectory.tip_speed_mps.max() / 3
    assert np.all(np.diff(wet.trajectory.dissipated_mJ) >= 0.0)
    first_steps = [np.diff(r.trajectory.t_ms[:3]) for r in (wet, dry)]
    assert np.all(first_steps[0] >= 0.5 * first_steps[1])
    assert wet.metrics['rhs_evals'] <= dry.metrics['rhs_evals']


def test_impact_on_recontact_rebounds_and_latches():
    """The hinge throws the arm back on the body: each impact reverses the arm at about the
    restitution coefficient (0.3), the bounces shrink geometrically, every impact dissipates,
    and the arm ends latched on the body (no endless re-contact chattering)."""
    r = check_invariants(sim(REF_AIR, 'initial.theta3_deg=20', 'drive.pull_speed_mm_per_s=0',
                             'integration.t_end_s=0.2', 'hinge.rest_angle_deg=0',
                             'hinge.k_Nmm_per_rad=5'))
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


def test_plastic_recontact_without_restitution_latches_at_once():
    """contact_restitution off: re-contact is plastic, the first impact latches the arm."""
    r = check_invariants(sim(REF_AIR, 'effects=[joint_damping, hinge_stiffness, '
                             'tendon_slack]', 'initial.theta3_deg=20',
                             'drive.pull_speed_mm_per_s=0', 'integration.t_end_s=0.2',
                             'hinge.rest_angle_deg=0', 'hinge.k_Nmm_per_rad=5'))
    assert [n for n, _, _ in r.raw.events].count('recontact') == 1
    assert r.raw.segments[-1].latched


def test_zero_pull_stays_latched_for_an_hour():
    """v = 0: the start pose is a static equilibrium held by tendon and latch; it stays
    exactly so for an hour of simulated time, at a cost independent of that hour."""
    r = check_invariants(sim(REF_AIR, 'drive.pull_speed_mm_per_s=0',
                             'integration.t_end_s=3600'))
    m, tr = r.metrics, r.trajectory
    assert m['phase_start_s']['II'] is None and not m['strike_reached']
    assert tr.t_ms[-1] == pytest.approx(3.6e6)
    assert np.ptp(tr.theta1) < 1e-12 and np.all(tr.omega1 == 0.0)
    assert np.ptp(tr.tendon_force_N) < 1e-9 and tr.contact_torque_Nmm.min() > 1.0
    ten_seconds = run(REF_AIR, 'drive.pull_speed_mm_per_s=0', 'integration.t_end_s=10')
    assert m['rhs_evals'] < 1.5 * ten_seconds['rhs_evals']


def test_very_fast_pulls():
    """From 2.33 to 500 mm/s (x200): loading stays quasi-static (the latch lets go after the
    same pulled length), but the faster stage does more work during the strike itself, so
    the tip is faster; every run reaches all four phases and closes its balance."""
    speeds = (2.33, 100.0, 500.0)
    runs = [check_invariants(sim(REF_AIR, f'drive.pull_speed_mm_per_s={v}')).metrics
            for v in speeds]
    pulled = [m['phase_start_s']['II'] * v for m, v in zip(runs, speeds)]
    assert max(pulled) == pytest.approx(min(pulled), rel=0.01)
    work = [m['tendon_work_phase_IV_mJ'] for m in runs]
    tip = [m['peak_tip_speed_mps'] for m in runs]
    assert work == sorted(work) and work[-1] > 50 * work[0]
    assert tip == sorted(tip) and tip[-1] < 40.0
    for m in runs:
        assert [n for n, _ in m['events']] == NOMINAL_EVENTS


def test_contact_angles_zero_to_ten_degrees(air):
    """A larger contact angle unlatches earlier and stores less energy, from 0 to 10 deg."""
    runs = [check_invariants(sim(REF_AIR, f'geometry.contact_angle_deg={a}')).metrics
            for a in (0.0, 3.0, 5.0, 10.0)]
    assert runs[1]['max_spring_energy_mJ'] == pytest.approx(air['max_spring_energy_mJ'])
    for m in runs:
        assert [n for n, _ in m['events']] == NOMINAL_EVENTS
        assert 20 < m['peak_tip_speed_mps'] < 40
    energies = [m['max_spring_energy_mJ'] for m in runs]
    unlatch = [m['phase_start_s']['II'] for m in runs]
    assert energies == sorted(energies, reverse=True)
    assert unlatch == sorted(unlatch, reverse=True)


def test_hours_of_slow_loading():
    """Pulled at 0.001 mm/s the rig loads for an hour before it fires: the release comes
    after the same pulled length as at 2.33 mm/s (loading is quasi-static), the strike is the
    same, and the cost does not grow with the simulated time."""
    slow = check_invariants(sim(REF_AIR, 'drive.pull_speed_mm_per_s=0.001',
                                'integration.t_end_s=1e5')).metrics
    nominal = run(REF_AIR)
    assert slow['phase_start_s']['II'] > 3600
    assert slow['phase_start_s']['II'] * 0.001 == pytest.approx(
        nominal['phase_start_s']['II'] * 2.33, rel=1e-3)
    assert slow['peak_tip_speed_mps'] == pytest.approx(nominal['peak_tip_speed_mps'], rel=2e-3)
    assert slow['rhs_evals'] < 3 * nominal['rhs_evals']


def test_advancing_to_just_before_or_after_an_event_finds_the_same_events():
    """Events at near-coincident times: a segment ending within rounding of an event root
    (the simulated rig advances in steps) must neither miss the event nor trip the root
    finder."""
    scene = load_scene(REF_AIR)
    ref = HybridSimulator(scene)
    ref.run()
    names = [n for n, _, _ in ref.run_data.events]
    for _, t_event, _ in ref.run_data.events:
        for offset in (-1e-9, -1e-12, 0.0, 1e-12):
            s = HybridSimulator(scene)
            s.start()
            s.advance(t_event + offset)
            s.advance(ref.t_end, stop_after_peak=True)
            assert [n for n, _, _ in s.run_data.events] == names
            for (_, t, _), (_, t_ref, _) in zip(s.run_data.events, ref.run_data.events):
                assert t == pytest.approx(t_ref, abs=1e-5)


def test_shipped_compliant_scene_is_stable_with_its_implicit_solver():
    """air_23mm_compliant (50 N/mm, stiff on gram-scale inertia) with its scene's solver:
    all four phases in order, the tendon never pushes, the energy balance closes, and an
    explicit method agrees on the peak tip speed."""
    r = check_invariants(sim('air_23mm_compliant'))
    m = r.metrics
    assert m['solver'] == 'fast'
    assert [n for n, _ in m['events']] == NOMINAL_EVENTS
    assert 0.0 < m['peak_tendon_force_N'] < 18.0
    explicit = run('air_23mm_compliant', 'integration.solver=DOP853', 'integration.rtol=1e-6')
    assert m['peak_tip_speed_mps'] == pytest.approx(explicit['peak_tip_speed_mps'], rel=1e-5)


# --- a disabled effect costs nothing -----------------------------------------------------------

COUNTED_TERMS = {
    'gravity': (forces.Gravity, '__call__'),
    'joint_damping': (forces.JointDamping, '__call__'),
    'hinge_stiffness': (forces.HingeStiffness, '__call__'),
    'fluid_drag': (forces.FluidDrag, '__call__'),
    'added_mass': (mechanism._AddedMass, 'matrix'),
    'stage_profile': (drive.RampedPull, 'pulled'),
}


@pytest.mark.parametrize('effect', COUNTED_TERMS)
def test_a_disabled_effect_is_never_evaluated(effect, monkeypatch):
    """The right-hand side evaluates an effect's term on every call when the scene enables
    it, and not once when it does not (everything else on)."""
    cls, method = COUNTED_TERMS[effect]
    calls = []
    original = getattr(cls, method)

    def counted(self, *args):
        calls.append(1)
        return original(self, *args)

    monkeypatch.setattr(cls, method, counted)
    everything = MECHANICAL.split(', ')
    for enabled in (everything, [e for e in everything if e != effect]):
        calls.clear()
        m = run(REF_WATER, f'effects=[{", ".join(enabled)}]', 'integration.solver=DOP853')
        assert m['strike_reached'] and (effect in m['effects']) == (effect in enabled)
        if effect in enabled:
            assert len(calls) >= m['rhs_evals']
        else:
            assert calls == []


def test_tendon_slack_off_means_no_slack_events():
    """Without tendon_slack the tendon is bilateral: no slack event is even looked for."""
    on = HybridSimulator(load_scene(REF_AIR))
    off = HybridSimulator(load_scene(REF_AIR, ['effects=[joint_damping, hinge_stiffness]']))
    for s in (on, off):
        s.start()
    names = [[spec[0] for spec in s._event_specs(Mode(False, True), 'II', False, 0.0)]
             for s in (on, off)]
    assert 'slack' in names[0] and 'slack' not in names[1]


# --- scenes, command line, bad input (item 6) --------------------------------------------------

def test_every_shipped_scene_loads():
    scenes = available_scenes()
    assert {REF_AIR, REF_AIR19, REF_WATER, 'air_23mm_shim7deg'} <= set(scenes)
    for name in scenes:
        load_scene(name)


@pytest.mark.parametrize('override, words', [
    ('body.mass_g=-1', ['body.mass_g', '-1', '(0, 100] g']),
    ('geometry.contact_angle_deg=20', ['contact_angle_deg', '20', '[0, 15]']),
    ('effects=[warp_drive]', ['effects', 'warp_drive', 'valid effects']),
    ('geometry.nope=1', ['geometry.nope', '1', 'valid keys']),
])
def test_bad_parameters_name_key_value_and_range(override, words):
    with pytest.raises(ParameterError) as info:
        load_scene(REF_AIR, [override])
    assert all(w in str(info.value) for w in words)


def test_unknown_and_malformed_scenes(tmp_path):
    with pytest.raises(SceneError, match='unknown scene'):
        load_scene('no_such_scene')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('geometry: {L1_mm: [1\n')
    with pytest.raises(SceneError, match='not valid YAML at line 2, column 1'):
        load_scene(str(bad))


def test_damaged_scene_files_are_refused_with_the_reason(tmp_path):
    text = (REPO / 'mantis_sim' / 'scenes' / 'reference_air_23mm.yaml').read_text()
    huge = tmp_path / 'huge.yaml'
    huge.write_text(text.replace('d_t_mm: 23.0', 'd_t_mm: ' + '9' * 400))
    with pytest.raises(ParameterError, match=r'geometry.d_t_mm = 9+\.\.\. \(400 characters\) '
                                             r'is out of range'):
        load_scene(str(huge))
    latin1 = tmp_path / 'latin1.yaml'
    latin1.write_bytes(text.encode() + b'# caf\xe9\n')
    with pytest.raises(SceneError, match='not UTF-8 text'):
        load_scene(str(latin1))
    cut = tmp_path / 'cut.yaml'
    cut.write_text(text[:58])
    with pytest.raises(SceneError, match='missing required key.*effects, geometry, medium, '
                                         'tendon, drive'):
        load_scene(str(cut))


def _bad_files(tmp_path):
    malformed = tmp_path / 'malformed.yaml'
    malformed.write_text('name: x\ngeometry: {L1_mm: [1\n')
    out_of_range = tmp_path / 'shim20.yaml'
    out_of_range.write_text('name: shim20\ngeometry: {contact_angle_deg: 20.0}\n')
    return malformed, out_of_range


@pytest.mark.parametrize('args, words', [
    (['--scene', 'no_such_scene'], ['unknown scene', 'no_such_scene', REF_AIR]),
    (['--set', 'geometry.nope=1'], ['geometry.nope', '1', 'valid keys', 'L1_mm']),
    (['--set', 'nope=1'], ["'nope'", '1', 'geometry']),
    (['--set', 'body.mass_g=-1'], ['body.mass_g', '-1', '(0, 100] g']),
    (['--set', 'arm.mass_g=-0.1'], ['arm.mass_g', '-0.1', '(0, 100] g']),
    (['--set', 'geometry.contact_angle_deg=20'], ['geometry.contact_angle_deg', '20',
                                                  '[0, 15] deg']),
    (['--set', 'geometry.contact_angle_deg=-1'], ['geometry.contact_angle_deg', '-1',
                                                  '[0, 15] deg']),
    (['--set', 'effects=[gravity, warp_drive]'], ['effects', 'warp_drive', 'valid effects',
                                                  'fluid_drag']),
    (['--set', 'body.mass_g=heavy'], ['body.mass_g', 'heavy', '(0, 100] g']),
    (['--solver', 'Euler'], ['integration.solver', 'Euler', 'DOP853']),
    (['--scene', 'MALFORMED'], ['malformed.yaml', 'not valid YAML', 'line 3, column 1']),
    (['--scene', 'OUT_OF_RANGE'], ['shim20.yaml', 'geometry.contact_angle_deg', '20',
                                   '[0, 15] deg']),
])
def test_cli_bad_input_exits_2_naming_key_value_and_range(args, words, tmp_path, capsys):
    malformed, out_of_range = _bad_files(tmp_path)
    args = [{'MALFORMED': str(malformed), 'OUT_OF_RANGE': str(out_of_range)}.get(a, a)
            for a in args]
    if '--scene' not in args:
        args = ['--scene', REF_AIR] + args
    assert mantis(['sim', *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == ''
    assert all(w in captured.err for w in words), captured.err


@pytest.mark.parametrize('argv', [['sim'], ['sim', '--scene', REF_AIR, '--rtol', 'tight'],
                                  ['sim', '--scene', REF_AIR, '--bogus']])
def test_cli_usage_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        mantis(argv)
    assert info.value.code == 2
    assert 'usage:' in capsys.readouterr().err


def test_cli_json_keys_are_exactly_the_issues(capsys):
    assert mantis(['sim', '--scene', REF_AIR, '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {'peak_tip_speed_mps', 'max_spring_energy_mJ', 'peak_tendon_force_N',
                         'phase_start_s', 'phase_duration_s', 'energy_balance_residual_mJ',
                         'wall_time_s', 'rhs_evals', 'effects', 'solver', 'rtol',
                         # issue 24: a run's outcome and the body's deepest turn
                         'status', 'reason', 'deepest_body_angle_rad',
                         # issue 30: loads beyond the rig's load cell or force ceiling
                         'warnings'}
    assert data['status'] == 'strike' and data['reason'] == '' and data['warnings'] == []
    assert set(data) == {*JSON_KEYS, 'warnings'}
    assert set(data['phase_start_s']) == set(PHASE_ORDER) == set(data['phase_duration_s'])
    assert data['effects'] == ['joint_damping', 'hinge_stiffness', 'fluid_drag', 'tendon_slack',
                               'contact_restitution']
    assert data['solver'] == 'fast' and data['rtol'] == 1e-7 and data['rhs_evals'] > 0


def test_ramped_pull_with_a_following_error_is_continuous_at_the_ramps_end(capsys):
    """Issue 25: with stage_profile and a following error (tau > 0), RampedPull found the state
    at the ramp's end by calling itself at that time, which came back to the same branch: every
    pull at or after the ramp's end was a RecursionError, and `mantis sim` ended in it."""
    pull = drive.RampedPull(2.33e-3, 4e-6, 5.0)
    tr = pull.t_ramp
    before, at, after = pull.pulled(tr * (1 - 1e-12)), pull.pulled(tr), pull.pulled(tr + 1.0)
    assert at == pytest.approx(before, rel=1e-9)
    assert after[0] > at[0] and 0 < after[1] < 2.33e-3
    assert mantis(['sim', '--scene', 'air_23mm_rig', '--json',
                   '--set', 'drive.following_time_constant_ms=5']) == 0
    assert json.loads(capsys.readouterr().out)['peak_tip_speed_mps'] > 0
