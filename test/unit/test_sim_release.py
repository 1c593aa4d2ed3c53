"""When the simulated robot lets go (issue 24): the latch hold (effect pivot_friction) and runs with
no fixed time limit, each hard case numerically stable and located by events."""
import json

import numpy as np
import pytest

from mantis_rig.cli import main as mantis
from mantis_sim.parameters import ParameterError
from mantis_sim.results import simulate
from mantis_sim.scene import load_scene

REF = 'reference_air_23mm'
HOLD = ('effects=[joint_damping, hinge_stiffness, fluid_drag, tendon_slack, '
        'contact_restitution, pivot_friction]')


def sim(name, *overrides, dense=False):
    return simulate(load_scene(name, list(overrides)), dense=dense)


def release_state(result):
    return next(s for n, _, s in result.raw.events if n == 'unlatch')


def test_a_hold_of_zero_is_the_rigid_contact_to_the_last_digit():
    plain = sim(REF).metrics
    zero = sim(REF, HOLD, 'hinge.friction_lever_mm=0').metrics
    for key in ('peak_tip_speed_mps', 'deepest_body_angle_rad', 'phase_start_s', 'rhs_evals'):
        assert zero[key] == plain[key]
    assert 'pivot_friction' in zero['effects'] and 'pivot_friction' not in plain['effects']


@pytest.mark.parametrize('lever_mm', [0.1, 0.2, 0.4])
def test_the_latch_lets_go_past_overcentering_where_the_hold_is_spent(lever_mm):
    """The arm stays on the body past overcentering (the tendon's moment arm about the arm
    pivot, dl/dtheta3, negative, for a lever above the hinge's own ~0.05 mm x tension) until
    the contact would have to pull harder than lever x tension: released once, exactly there,
    and the run closes its energy balance."""
    r = sim(REF, HOLD, f'hinge.friction_lever_mm={lever_mm}')
    m = r.metrics
    assert [n for n, _ in m['events']].count('unlatch') == 1
    latched = r.raw.segments[0]
    assert latched.latched
    d = r.simulator.dynamics_at(latched, latched.t[-1], latched.states[-1])
    assert r.simulator.model.mech.tendon(d.th1, d.th3).d3 < 0          # past overcentering
    assert d.contact_torque_Nmm < 0                                    # the latch was pulling
    assert d.contact_torque_Nmm + lever_mm * d.tension_N == pytest.approx(0.0, abs=1e-6)
    assert m['energy_balance_residual_mJ'] < 1e-5
    assert m['strike_reached'] and 20 < m['peak_tip_speed_mps'] < 40


def test_a_larger_hold_loads_deeper_and_stores_more():
    energies = [sim(REF, HOLD, f'hinge.friction_lever_mm={h}').metrics['max_spring_energy_mJ']
                for h in (0.0, 0.1, 0.2, 0.3)]
    assert energies == sorted(energies) and energies[-1] > energies[0] + 20


def test_the_release_converges_as_the_tolerance_tightens():
    times = [sim(REF, HOLD, 'hinge.friction_lever_mm=0.2', f'integration.rtol={rtol}')
             .metrics['phase_start_s']['II'] for rtol in (1e-5, 1e-7, 1e-9)]
    assert abs(times[1] - times[2]) < abs(times[0] - times[2]) + 1e-12
    assert abs(times[1] - times[2]) < 1e-6


def test_a_compliant_tendon_with_a_hold_stays_stable_and_balanced():
    """The identified robot's combination: a compliant tendon (its tension a state) and the
    hold, on the implicit solver; one release, a strike, energy closed, no NaN."""
    r = sim(REF, HOLD, 'hinge.friction_lever_mm=0.25', 'tendon.model=compliant',
            'tendon.stiffness_N_per_mm=4', 'tendon.damping_N_ms_per_mm=0.05',
            'integration.solver=Radau', 'integration.rtol=1e-6')
    m, tr = r.metrics, r.trajectory
    assert [n for n, _ in m['events']].count('unlatch') == 1 and m['strike_reached']
    assert all(np.all(np.isfinite(c)) for k, c in vars(tr).items() if k != 'phase')
    assert m['energy_balance_residual_mJ'] < 1e-3


def test_a_hold_that_never_gives_is_a_run_without_a_strike_that_says_why():
    r = sim(REF, HOLD, 'hinge.friction_lever_mm=5', 'drive.start_position_mm=20')
    m = r.metrics
    assert m['status'] == 'no strike' and not m['strike_reached']
    assert m['reason'].startswith('the stage used up its travel (5 mm from '
                                  'drive.start_position_mm = 20 to drive.travel_mm = 25')
    assert r.trajectory.t_ms[-1] == pytest.approx(5.0 / 2.33 * 1e3)


# --- no fixed time limit -------------------------------------------------------------------------
def test_a_slow_pull_on_the_short_guide_strikes_however_long_it_loads():
    """0.5 mm/s with the 19 mm guide and a small contact angle releases after more than the
    10 s the simulator used to give up at."""
    m = sim('reference_air_19mm', 'drive.pull_speed_mm_per_s=0.5',
            'geometry.contact_angle_deg=2').metrics
    assert m['status'] == 'strike' and m['reason'] == ''
    assert m['phase_start_s']['II'] > 10.0


def test_a_still_stage_never_releases_and_says_so():
    m = sim(REF, 'drive.pull_speed_mm_per_s=0').metrics
    assert m['status'] == 'no strike' and m['phase_start_s']['II'] is None
    assert 'the stage does not pull (drive.pull_speed_mm_per_s = 0)' in m['reason']


def test_a_given_time_limit_is_named_when_it_cuts_a_run_short():
    m = sim(REF, 'integration.t_end_s=0.5').metrics
    assert m['status'] == 'no strike'
    assert m['reason'] == 'no strike within integration.t_end_s = 0.5 s'


def test_a_start_beyond_the_travel_is_refused():
    with pytest.raises(ParameterError, match='drive.start_position_mm = 25.0 leaves no travel'):
        load_scene(REF, ['drive.start_position_mm=25'])


def test_mantis_sim_reports_a_non_strike_in_json_and_in_one_line(capsys):
    assert mantis(['sim', '--scene', REF, '--set', 'drive.start_position_mm=24.9',
                   '--json']) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data['status'] == 'no strike' and 'used up its travel' in data['reason']
    assert captured.err.startswith('no strike: the stage used up its travel')


# --- kinetic friction and sticking ------------------------------------------------------------
FRICTION = HOLD.replace('contact_restitution, ', '')


@pytest.mark.parametrize('lever_mm, sticks', [(0.6, True), (0.1, False)])
def test_a_free_arm_sticks_where_friction_can_hold_it_and_slips_where_not(lever_mm, sticks):
    """The arm let go at 20 deg with the stage still: the hinge (rest 0 deg, 5 N mm/rad) pushes
    it closed with ~1.7 N mm; the pivot holds up to lever x the tendon's ~5 N. Above that it
    stays put for good; below, it slips and closes onto the body."""
    r = sim(REF, FRICTION, f'hinge.friction_lever_mm={lever_mm}', 'initial.theta3_deg=20',
            'drive.pull_speed_mm_per_s=0', 'integration.t_end_s=0.05',
            'hinge.rest_angle_deg=0', 'hinge.k_Nmm_per_rad=5')
    tr = r.trajectory
    last = r.raw.segments[-1]
    if sticks:
        assert np.ptp(tr.theta3) < 1e-9 and last.latched
        assert last.stuck_at == pytest.approx(np.radians(20.0))
    else:
        assert tr.theta3[-1] == pytest.approx(np.radians(3.0), abs=1e-9)
        assert last.latched and last.stuck_at is None
    assert len(r.raw.events) < 10
    assert r.metrics['energy_balance_residual_mJ'] < 1e-6


def test_the_pivot_friction_brakes_the_strike_and_books_what_it_takes():
    """Through the strike and 40 ms after it: the friction takes energy (booked, the balance
    closes), the arm comes to rest stuck or on the body without chattering, and a larger
    lever strikes slower from the same release."""
    base = [HOLD, 'tendon.model=compliant', 'tendon.stiffness_N_per_mm=4',
            'integration.solver=Radau', 'integration.rtol=1e-6', 'integration.post_peak_ms=40']
    runs = [sim(REF, *base, f'hinge.friction_lever_mm={h}') for h in (0.06, 0.3)]
    for r in runs:
        m = r.metrics
        assert m['strike_reached'] and m['energy_balance_residual_mJ'] < 1e-3
        assert len(m['events']) < 15
        assert r.raw.segments[-1].latched
        assert np.all(np.diff(r.trajectory.dissipated_mJ) >= -1e-9)
    assert runs[1].metrics['peak_arm_speed_radps'] < runs[0].metrics['peak_arm_speed_radps']


def test_a_pivot_that_slides_more_easily_than_it_sticks_brakes_less():
    """mu_kinetic < mu_static: the same hold (the same release), a faster swing."""
    base = [HOLD, 'hinge.friction_lever_mm=0.3']
    sticky = sim(REF, *base).metrics
    sliding = sim(REF, *base, 'hinge.kinetic_friction_ratio=0.3').metrics
    assert sliding['phase_start_s']['II'] == sticky['phase_start_s']['II']
    assert sliding['peak_arm_speed_radps'] > sticky['peak_arm_speed_radps']
    assert sliding['energy_balance_residual_mJ'] < 1e-5


def test_a_braking_lever_of_its_own_keeps_the_braking_where_the_hold_moves():
    """hinge.kinetic_friction_lever_mm: at ratio x lever it is the same pivot to the last digit;
    with it held, a stronger hold stores more and strikes faster, where raising the one
    friction (the ratio's form) brakes the faster strike away."""
    base = [HOLD, 'hinge.friction_lever_mm=0.1', 'hinge.kinetic_friction_ratio=0.5']
    by_ratio = sim(REF, *base).metrics
    by_lever = sim(REF, *base, 'hinge.kinetic_friction_lever_mm=0.05').metrics
    for key in ('peak_tip_speed_mps', 'max_spring_energy_mJ', 'phase_start_s'):
        assert by_lever[key] == by_ratio[key]
    held = sim(REF, HOLD, 'hinge.friction_lever_mm=0.3',
               'hinge.kinetic_friction_lever_mm=0.05').metrics
    both = sim(REF, HOLD, 'hinge.friction_lever_mm=0.3',
               'hinge.kinetic_friction_ratio=0.5').metrics
    # the same hold; only the arm's slow slide in phases II-III is braked differently
    assert held['max_spring_energy_mJ'] == pytest.approx(both['max_spring_energy_mJ'], rel=1e-4)
    assert held['max_spring_energy_mJ'] > by_ratio['max_spring_energy_mJ']
    assert held['peak_tip_speed_mps'] > by_ratio['peak_tip_speed_mps'] > \
        both['peak_tip_speed_mps']
    assert held['energy_balance_residual_mJ'] < 1e-5


def test_a_pivot_cannot_brake_more_than_it_holds():
    with pytest.raises(ParameterError, match='kinetic_friction_lever_mm = 0.2 exceeds '
                                             'hinge.friction_lever_mm = 0.1'):
        load_scene(REF, [HOLD, 'hinge.friction_lever_mm=0.1',
                         'hinge.kinetic_friction_lever_mm=0.2'])


def test_the_physics_package_never_names_the_rig_package():
    """mantis_sim stands alone (issue 25): no import of, nor reference to, mantis_rig."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[2] / 'mantis_sim'
    sources = [p for p in root.rglob('*') if p.is_file() and p.suffix in ('.py', '.yaml')]
    assert len(sources) > 20, f'no physics package at {root}'
    naming = [str(p.relative_to(root)) for p in sources if 'mantis_rig' in p.read_text()]
    assert naming == []


@pytest.mark.parametrize('solver', ['RK23', 'LSODA', 'Radau'])
def test_a_loose_tolerance_does_not_chatter_at_the_release(solver):
    """At the release the friction just balances and w3 starts at zero: at rtol 1e-3 its
    rounding noise about zero once read as the arm stopping, stuck it, let it slip, at one
    instant until the simulator gave up. The identified robot, every solver family, strikes."""
    m = sim('air_23mm', f'integration.solver={solver}', 'integration.rtol=1e-3').metrics
    assert m['strike_reached'] and len(m['events']) <= 8
    tight = sim('air_23mm', 'integration.rtol=1e-7').metrics
    assert m['peak_tip_speed_mps'] == pytest.approx(tight['peak_tip_speed_mps'], rel=0.01)


def test_ctrl_c_in_a_command_without_a_stage_is_one_line_and_130(monkeypatch, capsys):
    from mantis_rig.cli import sim as sim_cli

    def interrupted(args):
        raise KeyboardInterrupt
    monkeypatch.setattr(sim_cli, 'run_sim', interrupted)
    assert mantis(['sim', '--scene', REF]) == 130
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('mantis sim: interrupted')
