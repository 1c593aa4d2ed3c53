"""mantis_sim.world: the simulated rig driven by stage commands in simulated time."""
import math

import numpy as np
import pytest

from mantis_sim.drive import CommandedPull
from mantis_sim.mechanism import Mechanism
from mantis_sim.model import SimulationError
from mantis_sim.results import simulate
from mantis_sim.scene import load_scene
from mantis_sim.trial_conditions import scene_for_conditions
from mantis_sim.world import SETTLE_AFTER_PEAK_MS, RobotInUse, World

STEP_S = 0.01


def run_world(scene, until_s, velocity=2.33e-3, command_at_s=0.0):
    world = World(scene)
    t = 0.0
    world.advance_to(command_at_s)
    world.set_stage_velocity(velocity)
    t = command_at_s
    while t < until_s:
        t = min(until_s, t + STEP_S)
        world.advance_to(t)
    return world


@pytest.fixture(scope='module')
def rig_world():
    return run_world(load_scene('air_23mm_rig'), 2.0)


def test_world_reproduces_the_batch_simulation(rig_world):
    """Same scene, same ramped pull from t = 0: the phases match simulate() to 1 us."""
    batch = simulate(load_scene('air_23mm_rig')).metrics
    for phase, start in batch['phase_start_s'].items():
        assert rig_world.phase_start_s[phase] == pytest.approx(start, abs=1e-6)
    assert rig_world.peak_time_s == pytest.approx(batch['peak_time_s'], abs=1e-6)


@pytest.mark.parametrize('name', ['air_19mm', 'air_23mm', 'water_23mm'])
def test_the_identified_robot_runs_on_the_rig_as_in_the_batch(name):
    """The shipped identified scenes (compliant tendon, the pivot's stick and slip) stepped in
    the rig's 10 ms chunks against simulate(). The release comes where the hold's margin
    crosses zero slowly, so the solver's rtol 1e-5, restarted every chunk, moves it by some
    microseconds (4-18 us measured): within a frame of the lab's fastest camera. The strike
    itself, from the release to the peak, agrees to within 1 us."""
    scene = load_scene(name)
    batch = simulate(scene).metrics
    world = run_world(scene, batch['peak_time_s'] + 0.05,
                      velocity=scene.drive.pull_speed_mm_per_s * 1e-3)
    frame_s = 1.0 / 19000.0
    for phase, start in batch['phase_start_s'].items():
        assert world.phase_start_s[phase] == pytest.approx(start, abs=frame_s), phase
    strike_s = batch['peak_time_s'] - batch['phase_start_s']['II']
    assert world.peak_time_s - world.phase_start_s['II'] == pytest.approx(strike_s, abs=2e-6)


def test_tension_matches_the_batch_trajectory(rig_world):
    result = simulate(load_scene('air_23mm_rig'), dense=True)
    traj = result.trajectory
    t_ms = np.linspace(1000.0, result.metrics['phase_start_s']['II'] * 1e3 - 1.0, 200)
    expected = result.tendon_force_at(t_ms)
    assert np.allclose(rig_world.tendon_force_N(t_ms * 1e-3), expected, atol=2e-3)
    strike = (traj.t_ms > result.metrics['phase_start_s']['II'] * 1e3) \
        & (traj.t_ms < result.metrics['peak_time_s'] * 1e3)
    peak = rig_world.tendon_force_N(traj.t_ms[strike] * 1e-3).max()
    assert peak == pytest.approx(traj.tendon_force_N[strike].max(), rel=1e-3)


def test_the_held_arms_states_at_many_times_are_its_dynamics_at_each(rig_world):
    """Held on a taut rigid tendon, the pose follows from the stage alone: the states the
    camera and the load cell read at many times at once are the model's, state by state."""
    sim = rig_world._current.sim
    held = [seg for seg in sim.run_data.segments
            if seg.dense is not None and sim._constrained(seg.dense.mode)]
    assert len(held) > 10
    for seg in held[::10]:
        times_ms = np.linspace(seg.t[0], seg.t[-1], 5)
        one_by_one = np.array([seg.dense(t) for t in times_ms])
        tensions = [sim.dynamics_at(seg, t, s).tension_N for t, s in zip(times_ms, one_by_one)]
        guess = sim.model.theta1_guess
        assert np.allclose(seg.dense.states(times_ms), one_by_one, rtol=0, atol=1e-12)
        assert np.allclose(np.column_stack(seg.dense.angles(times_ms)), one_by_one[:, :2],
                           rtol=0, atol=1e-12)
        assert np.allclose(sim.tensions_at(seg, times_ms), tensions, rtol=1e-10, atol=0)
        assert sim.model.theta1_guess == guess     # the integrator's own guess is kept


def test_markers_move_as_two_rigid_bodies(rig_world):
    times = np.linspace(1.5, rig_world.peak_time_s + 0.005, 400)
    markers = rig_world.marker_positions_m(times)
    body = [markers[n] for n in ('mb1', 'mb2', 'mb3')]
    arm = [markers[n] for n in ('ma1', 'ma2')]
    for group in (body, arm):
        for i in range(len(group)):
            for j in range(i + 1, len(group)):
                d = np.linalg.norm(group[i] - group[j], axis=1)
                assert np.ptp(d) < 1e-9
    # the arm swings through a large angle relative to the body in the strike
    rel = arm[1] - arm[0]
    ref = body[1] - body[0]
    angle = np.unwrap(np.arctan2(rel[:, 1], rel[:, 0]) - np.arctan2(ref[:, 1], ref[:, 0]))
    assert np.ptp(angle) > math.radians(60)


def test_after_the_strike_the_arm_is_held_and_the_body_balances_spring_and_tendon(rig_world):
    """Held pose: the arm stays where it swung to; the body turns with the stage, the tension
    changes at the series stiffness of the tendon and of the spring as the linkage presents it
    (k_s + F d2l/dtheta1^2 over (dl/dtheta1)^2), and the tendon's stretch with the body's turn
    take up the stage's travel. Far below the tendon's own stiffness: the loaded spring yields."""
    assert rig_world.held
    assert rig_world.time_s * 1e3 > rig_world.peak_time_s * 1e3 + SETTLE_AFTER_PEAK_MS
    late = np.linspace(rig_world.time_s - 0.02, rig_world.time_s, 9)
    force = rig_world.tendon_force_N(late)
    th1, th3 = rig_world.joint_angles_rad(late)
    assert np.ptp(th3) == 0.0 and np.ptp(th1) > 1e-4
    scene = rig_world.scene
    hold_s = rig_world.peak_time_s + SETTLE_AFTER_PEAK_MS * 1e-3      # linearised about here
    (th1_hold,), _ = rig_world.joint_angles_rad([hold_s])
    geometry = Mechanism(scene).tendon(th1_hold, th3[0])
    k_t = scene.tendon.stiffness_N_per_mm
    linkage = (scene.spring.k_Nmm_per_rad
               + rig_world.tendon_force_N([hold_s])[0] * geometry.d11)
    expected = 1.0 / (1.0 / k_t + geometry.d1 ** 2 / linkage)           # N/mm
    pulled_mm = 2.33 * late                  # constant speed long before the strike
    slope = np.polyfit(pulled_mm, force, 1)[0]
    assert slope == pytest.approx(expected, rel=1e-3)
    assert abs(slope) < 0.05 * k_t
    turned_mm = -(th1 - th1[0]) * geometry.d1 + (force - force[0]) / k_t
    assert np.allclose(turned_mm, pulled_mm - pulled_mm[0], rtol=1e-3, atol=1e-9)


def test_times_outside_the_history_are_refused(rig_world):
    with pytest.raises(SimulationError, match='history'):
        rig_world.tendon_force_N([rig_world.time_s + 1.0])


def test_without_stage_motion_the_rig_stays_in_phase_one():
    world = run_world(load_scene('reference_air_23mm'), 1.0, velocity=0.0)
    assert world.phase == 'I'
    force = world.tendon_force_N(np.linspace(0.1, 1.0, 10))
    assert np.ptp(force) < 1e-9 and force[0] > 1.0


def test_stopping_during_the_strike_keeps_the_simulation_consistent():
    """A stop on a free arm with a taut rigid tendon: the tendon goes slack (it cannot push),
    and the world runs on without chattering."""
    scene = load_scene('reference_air_23mm')
    world = World(scene)
    world.set_stage_velocity(2.33e-3)
    t = 0.0
    while world.phase_start_s.get('II') is None:
        t += STEP_S
        world.advance_to(t)
    world.set_stage_velocity(0.0)
    assert world.stage_velocity_m_per_s() == 0.0
    world.advance_to(t + 0.2)
    assert world.held
    assert np.all(np.isfinite(world.tendon_force_N(np.linspace(t, t + 0.2, 100))))


def test_a_move_to_a_position_ends_at_rest_on_the_target_at_most_at_the_asked_speed():
    world = World(load_scene('air_23mm_rig'))
    start = world.stage_position_m()
    target = start + 1.5e-3
    world.move_stage_to(target, 2.0e-3)
    speeds, t = [], 0.0
    while t < 3.0:
        t += STEP_S
        world.advance_to(t)
        speeds.append(world.stage_velocity_m_per_s())
    assert world.stage_position_m() == pytest.approx(target, abs=1e-12)
    assert world.stage_velocity_m_per_s() == 0.0
    assert 0.0 < max(speeds) <= 2.0e-3 + 1e-15
    # the phase I loading the move caused is the same as a pull's
    assert world.phase == 'I' and world.tendon_force_N([t])[0] > 0.0


def test_a_stop_ends_a_move_where_the_stage_is():
    world = World(load_scene('reference_air_23mm'))
    world.move_stage_to(world.stage_position_m() + 2e-3, 1e-3)
    world.advance_to(0.5)
    world.set_stage_velocity(0.0)
    stopped_at = world.stage_position_m()
    world.advance_to(1.5)
    assert world.stage_position_m() == stopped_at
    assert world.stage_velocity_m_per_s() == 0.0


def test_the_load_cell_filter_is_lfilter():
    """The amplifier's first-order low-pass, written out, against scipy.signal.lfilter over
    blocks of any size (the state carries over)."""
    from scipy.signal import lfilter

    from mantis_sim.sensors import first_order_lowpass
    rng = np.random.default_rng(5)
    x = rng.normal(10.0, 3.0, 5000)
    pole = math.exp(-2.0 * math.pi * 1000.0 / 20000.0)
    expected, _ = lfilter([1.0 - pole], [1.0, -pole], x, zi=[pole * x[0]])
    got, previous = [], float(x[0])
    for block in np.split(x, [1, 7, 7, 1000, 1001, 4096]):     # one of them empty
        y = first_order_lowpass(block, pole, previous)
        if y.size:
            previous = float(y[-1])
        got.append(y)
    assert np.allclose(np.concatenate(got), expected, rtol=1e-12, atol=1e-12)


def test_the_commanded_pull_at_many_times_is_its_pull_at_each():
    """pulled_mm (the load cell's stream asks for every sample while the world holds) against
    pulled() one time at a time, over ramps, a move, a stop and a reversal."""
    drive = CommandedPull(2e-6)
    drive.command(100.0, 2.3e-3)
    drive.move_to(3000.0, 1.0, 5e-3)
    drive.command(5000.0, 0.0)
    drive.command(5200.0, -1e-3)
    times_ms = np.concatenate([[-1.0, 0.0], np.linspace(0.0, 8000.0, 20001)])
    one_by_one = np.array([drive.pulled(t)[0] for t in times_ms])
    assert np.array_equal(drive.pulled_mm(times_ms), one_by_one)


def _strike_then_return(world, velocity=2.33e-3, speed=2.0e-3, t=None):
    """Pull until the arm is held after its strike, stop, move back to the start; return the
    world time at the end and the strike's (peak time, peak force) relative to the pull."""
    t = world.time_s if t is None else t
    start = world.stage_position_m()
    pull_at = t
    world.set_stage_velocity(velocity)
    while not world.held:
        t += STEP_S
        world.advance_to(t)
    peak_s = world.peak_time_s - pull_at
    peak_force = world.tendon_force_N(np.linspace(pull_at + 1.0, world.peak_time_s, 500)).max()
    world.set_stage_velocity(0.0)
    world.move_stage_to(start, speed)
    while world.stage_velocity_m_per_s() != 0.0 or world.stage_position_m() != start:
        t += STEP_S
        world.advance_to(t)
    t += STEP_S
    world.advance_to(t)
    return t, peak_s, peak_force


def test_the_robot_is_relatched_when_the_stage_is_back_at_its_start():
    """As the operator re-latches the robot between strikes: the next pull strikes again, as
    the first did; the force stays continuous across the re-latch."""
    world = World(load_scene('air_23mm_rig'))
    t, first_peak_s, first_force = _strike_then_return(world)
    assert world.strikes == 2 and world.phase == 'I' and not world.held
    t2, second_peak_s, second_force = _strike_then_return(world, t=t)
    assert world.strikes == 3
    assert second_peak_s == pytest.approx(first_peak_s, abs=2e-4)
    assert second_force == pytest.approx(first_force, rel=1e-3)
    # no jump where the robot was re-latched: the tendon is slack there (stage at its start)
    span = np.linspace(t2 - 1.5, t2, 3000)
    assert np.all(np.isfinite(world.tendon_force_N(span)))


def test_a_stage_that_does_not_return_leaves_the_robot_unlatched():
    world = World(load_scene('reference_air_23mm'))
    world.set_stage_velocity(2.33e-3)
    t = 0.0
    while not world.held:
        t += STEP_S
        world.advance_to(t)
    world.set_stage_velocity(0.0)
    world.move_stage_to(world.stage_position_m() - 1e-3, 2e-3)
    world.advance_to(t + 2.0)
    assert world.strikes == 1 and world.held


def test_each_relatch_may_draw_its_own_robot():
    drawn = []

    def relatch_scene(n):
        drawn.append(n)
        return load_scene('air_23mm_rig', overrides=['spring.k_Nmm_per_rad=40'])

    world = World(load_scene('air_23mm_rig'), relatch_scene=relatch_scene)
    t, first_peak_s, _ = _strike_then_return(world)
    _, second_peak_s, _ = _strike_then_return(world, t=t)
    assert drawn[0] == 2 and second_peak_s != pytest.approx(first_peak_s, abs=1e-3)


def test_a_robot_left_unlatched_holds_no_tension_on_the_next_pull():
    """The operator forgot to re-latch: the tendon only swings the free arm."""
    world = World(load_scene('air_23mm_rig'), operator_relatches=False)
    t, _, peak_force = _strike_then_return(world)
    assert world.strikes == 1 and not world.latched and peak_force > 5.0
    world.set_stage_velocity(0.2e-3)
    times = t + np.arange(1, 101) * 0.05                # 1 mm of take-up
    for time_s in times:
        world.advance_to(time_s)
    assert np.all(world.tendon_force_N(times) == 0.0)
    th1, th3 = world.joint_angles_rad(times)
    assert np.ptp(th1) == 0.0 and np.ptp(th3) == 0.0


def test_the_last_strikes_truth_stays_readable_after_the_relatch():
    world = World(load_scene('air_23mm_rig'))
    assert world.last_strike is None
    t, peak_s, _ = _strike_then_return(world)
    struck = world.last_strike
    assert world.strikes == 2 and struck.number == 1
    assert 'IV' in struck.phase_start_s and 'II' not in world.phase_start_s
    assert struck.peak_time_s == pytest.approx(peak_s, abs=1e-9)


def test_the_instant_of_the_relatch_is_readable():
    """The load cell asks for the world up to now, which may be the re-latch's own instant."""
    world = World(load_scene('air_23mm_rig'))
    t, _, _ = _strike_then_return(world)
    while world.strikes == 2:                        # one more step: re-latched at its end
        _strike_then_return(world, t=t)
        break
    now = world.time_s
    relatched = [s.t0_ms * 1e-3 for s in world._strikes[1:]]
    times = np.array(relatched + [now])
    assert np.all(np.isfinite(world.tendon_force_N(times)))
    assert np.all(np.isfinite(world.joint_angles_rad(times)[0]))


# ------------------------------------------------------------------ rebuilding the latched robot
def _pull_until_held(world, t, velocity=2.33e-3):
    world.set_stage_velocity(velocity)
    while not world.held:
        t += STEP_S
        world.advance_to(t)
    return t


def _at_rest_N(scene):
    """The tension of a latched robot the stage has not pulled on."""
    world = World(scene)
    world.advance_to(0.1)
    return world.tendon_force_N([0.05])[0]


def test_the_latched_robot_is_rebuilt_while_unloaded_and_strikes_as_its_scene():
    """Before a trial pulls, the robot on the latch may be set up anew (the trial's
    conditions): the same latching, the new robot from its start pose; the time before stays
    the old robot's. The rebuilt robot strikes as the batch simulation of its scene."""
    scene = load_scene('air_23mm_rig')
    other = scene_for_conditions(scene, {'d_t_mm': 19.0})
    world = World(scene)
    world.rebuild_latched(other)                      # at t = 0: nothing of the old one kept
    assert len(world._strikes) == 1 and world.robot is other and world.strikes == 1
    world.rebuild_latched(scene)
    world.advance_to(0.5)
    world.set_stage_velocity(0.0)                     # a stop is no motion
    assert world.rebuild_problem() is None
    world.rebuild_latched(other)
    assert world.strikes == 1 and world.robot is other and world.scene is scene
    world.advance_to(0.6)
    before, after = world.tendon_force_N([0.25, 0.55])
    assert before == pytest.approx(_at_rest_N(scene), rel=1e-6)
    assert after == pytest.approx(_at_rest_N(other), rel=1e-6)
    assert after != pytest.approx(before, rel=1e-3)      # d_t moves the preload
    _pull_until_held(world, 0.6)
    batch = simulate(other).metrics
    strike = world.last_strike
    assert strike.number == 1
    assert strike.peak_time_s - 0.6 == pytest.approx(batch['peak_time_s'], abs=1e-5)
    assert batch['peak_time_s'] != pytest.approx(simulate(scene).metrics['peak_time_s'],
                                                 abs=1e-2)


def test_a_loaded_or_struck_robot_is_not_rebuilt_and_a_relatched_one_is():
    scene = load_scene('air_23mm_rig')
    other = scene_for_conditions(scene, {'d_t_mm': 19.0})
    world = World(scene)
    start = world.stage_position_m()
    world.advance_to(0.2)
    world.set_stage_velocity(2.33e-3)                 # a trial pulls on it
    assert 'is loaded: the stage has moved since it was latched' in world.rebuild_problem()
    world.advance_to(0.3)
    world.set_stage_velocity(0.0)                     # stopped again: still loaded
    with pytest.raises(RobotInUse, match='cannot rebuild the latched robot: the robot of '
                                         'latching 1 is loaded'):
        world.rebuild_latched(other)
    assert world.robot is scene
    t = _pull_until_held(world, 0.3)
    with pytest.raises(RobotInUse, match='has struck and is not latched again yet'):
        world.rebuild_latched(other)
    world.set_stage_velocity(0.0)
    world.move_stage_to(start, 2.0e-3)
    while world.strikes == 1:                          # back at its start: re-latched
        t += STEP_S
        world.advance_to(t)
    assert world.rebuild_problem() is None
    world.rebuild_latched(other)
    assert world.strikes == 2 and world.robot is other
