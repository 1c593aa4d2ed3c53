"""The simulated backends driven by one simulated world (issue 3, items 3 and 4)."""
import numpy as np
import pytest

from mantis_rig.hardware.device_interfaces import CameraConfig, ConfigurationError, DaqConfig
from mantis_rig.simulated.local_world import LocalWorldPort, WorldRunner
from mantis_rig.simulated.sim_camera import SimCameraTrigger
from mantis_rig.simulated.sim_force import SimForceDaq
from mantis_rig.simulated.sim_stage import SimStage
from mantis_sim.results import simulate
from mantis_sim.scene import load_scene
from mantis_sim.sensors import LoadCellSensor
from mantis_sim.world import World

PULL_M_PER_S = 2.33e-3
RATE_HZ = 20_000.0
BLOCK = 1000


def make_rig(scene_name='air_23mm_rig', real_time_factor=2.0, overrides=()):
    scene = load_scene(scene_name, list(overrides))
    world = World(scene)
    runner = WorldRunner(world, real_time_factor=real_time_factor)
    port = LocalWorldPort(runner)
    return scene, world, runner, port


@pytest.fixture(scope='module')
def pulled_trial():
    """Pull at 2.33 mm/s until the force stream shows the release; trigger; stop."""
    scene, world, runner, port = make_rig()
    stage, daq, camera = SimStage(port), SimForceDaq(port, scene, seed=3), SimCameraTrigger(
        port, scene)
    blocks = []
    runner.start()
    try:
        with stage, daq, camera:
            daq.configure(DaqConfig(sample_rate_hz=RATE_HZ, block_size=BLOCK))
            daq.start()
            camera.arm(CameraConfig(frame_rate_hz=19_000.0, pre_trigger_s=0.3,
                                    post_trigger_s=0.03))
            stage.move_at(PULL_M_PER_S)
            released = False
            while not released:
                block = daq.read_block(timeout_s=10.0)
                blocks.append(block)
                released = _abrupt_change(np.concatenate([b.force_n for b in blocks[-2:]]))
                assert block.t0_s < 5.0, 'no release within 5 s of pulling'
            trigger_s = camera.trigger()
            stage.stop()
            for _ in range(4):
                blocks.append(daq.read_block(timeout_s=10.0))
            frames = camera.marker_frames(timeout_s=30.0)
            stage_state = stage.state()
    finally:
        runner.stop()
    return dict(scene=scene, world=world, blocks=blocks, trigger_s=trigger_s, frames=frames,
                stage_state=stage_state)


def _abrupt_change(force_n, window=20, jump_n=1.0):
    """The release: the mean force over 1 ms moves by more than 1 N from the previous 1 ms."""
    means = force_n[:force_n.size // window * window].reshape(-1, window).mean(axis=1)
    return bool(np.any(np.abs(np.diff(means)) > jump_n))


def test_force_stream_is_gap_free_and_counts_rate_times_duration(pulled_trial):
    blocks = pulled_trial['blocks']
    assert not any(b.overrun for b in blocks)
    for before, after in zip(blocks, blocks[1:]):
        assert after.first_index == before.first_index + BLOCK
        assert after.t0_s == pytest.approx(before.t0_s + BLOCK / RATE_HZ, abs=1e-9)
    duration_s = blocks[-1].t0_s + BLOCK / RATE_HZ - blocks[0].t0_s
    samples = sum(b.force_n.size for b in blocks)
    assert samples == round(duration_s * RATE_HZ)


def _samples(blocks):
    t = np.concatenate([b.t0_s + b.period_s * np.arange(b.force_n.size) for b in blocks])
    return t, np.concatenate([b.force_n for b in blocks])


def test_force_follows_the_phases_and_changes_abruptly_at_release(pulled_trial):
    world = pulled_trial['world']
    t, force = _samples(pulled_trial['blocks'])
    starts = world.phase_start_s
    assert set(starts) == {'I', 'II', 'III', 'IV'}
    at_unlatch = force[(t > starts['II'] - 0.002) & (t < starts['II'])].mean()
    strike = (t > starts['II']) & (t < world.peak_time_s + 0.002)
    # The model's phase I unloads the tendon slowly as the moment arm grows (see README);
    # once the arm unlatches, the four-bar snaps and the tendon force spikes within ms.
    assert force[strike].max() > at_unlatch + 5.0
    true_peak = world.tendon_force_N(t[strike]).max()
    assert true_peak == pytest.approx(
        simulate(pulled_trial['scene']).metrics['peak_tendon_force_N'], rel=0.02)
    # a sub-millisecond spike through the 1 kHz amplifier: lower, never higher
    assert 0.8 * true_peak < force[strike].max() < true_peak + 0.05
    assert t[strike][np.argmax(force[strike])] - starts['II'] < 0.01


def test_force_samples_follow_the_simulated_tension(pulled_trial):
    world = pulled_trial['world']
    assert pulled_trial['scene'].has('loadcell_dynamics')
    t, force = _samples(pulled_trial['blocks'])
    slow = (t > world.time_s - world.history_s + 0.01) & (t < world.phase_start_s['II'] - 0.01)
    assert slow.sum() > 2000
    truth = world.tendon_force_N(t[slow])
    residual = force[slow] - truth
    # 1 kHz amplifier on a slowly changing force, 0.01 N rms noise, 16-bit ADC (3.4 mN steps)
    assert abs(residual.mean()) < 0.01
    assert 0.005 < residual.std() < 0.02


def test_camera_frames_cover_the_strike(pulled_trial):
    frames, world = pulled_trial['frames'], pulled_trial['world']
    assert frames is not None and len(frames.time_s) > 1000
    assert frames.time_s[0] < world.phase_start_s['II'] < world.peak_time_s < frames.time_s[-1]
    assert np.allclose(np.diff(frames.time_s), 1 / 19_000.0)
    assert sorted(frames.markers_m) == ['ma1', 'ma2', 'mb1', 'mb2', 'mb3']
    camera = pulled_trial['scene'].camera
    step = camera.pixel_mm * camera.tracker_resolution_px
    xy = frames.markers_m['ma2'] * 1e3                                  # metres, SI
    assert np.allclose(xy / step, np.round(xy / step), atol=1e-6)   # the tracker's 0.1 px
    assert not np.allclose(xy / camera.pixel_mm, np.round(xy / camera.pixel_mm), atol=1e-6)
    arm_travel = np.linalg.norm(xy[-1] - xy[0])
    assert arm_travel > 5.0                                             # the arm struck


def test_stage_stopped_after_trial(pulled_trial):
    state = pulled_trial['stage_state']
    assert not state.moving and state.velocity_m_per_s == 0.0
    assert state.homed


def test_loadcell_noise_is_reproducible_from_its_seed():
    scene = load_scene('air_23mm_rig')
    force = np.linspace(0, 10, 500)
    a = LoadCellSensor(scene, RATE_HZ, seed=7).measure_volts(force)
    b = LoadCellSensor(scene, RATE_HZ, seed=7).measure_volts(force)
    c = LoadCellSensor(scene, RATE_HZ, seed=8).measure_volts(force)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_without_loadcell_effect_the_daq_reads_the_truth():
    scene = load_scene('reference_air_23mm')                   # no loadcell_dynamics
    force = np.linspace(0, 10, 50)
    volts = LoadCellSensor(scene, RATE_HZ).measure_volts(force)
    assert np.allclose(volts * scene.loadcell.newtons_per_volt, force)


@pytest.mark.parametrize('config, words', [
    (DaqConfig(sample_rate_hz=3e6), ['3000000', '2000000']),
    (DaqConfig(channel='Dev1/aio'), ['Dev1/aio']),
])
def test_daq_refuses_bad_configuration(config, words):
    scene, world, runner, port = make_rig()
    daq = SimForceDaq(port, scene)
    with pytest.raises(ConfigurationError) as info:
        daq.configure(config)
    for word in words:
        assert word in str(info.value)


def test_stage_refuses_speed_and_travel_outside_limits():
    scene, world, runner, port = make_rig()
    with SimStage(port) as stage:
        with pytest.raises(ConfigurationError, match=r'3\.0000 mm/s exceeds the ceiling 2\.400'):
            stage.move_at(3.0e-3)
        with pytest.raises(ConfigurationError, match=r'30\.0000 mm is outside .*24\.500'):
            stage.move_to(30e-3, 1e-3)


def test_camera_refuses_frame_rate_above_limit():
    scene, world, runner, port = make_rig()
    with SimCameraTrigger(port, scene) as camera:
        with pytest.raises(ConfigurationError,
                           match=r'40000 frames/s exceeds the camera ceiling 37000'):
            camera.arm(CameraConfig(frame_rate_hz=40_000.0))


def test_velocity_move_stops_at_the_soft_limit():
    scene, world, runner, port = make_rig(real_time_factor=1.0,
                                          overrides=['drive.start_position_mm=24.0'])
    runner.start()
    try:
        with SimStage(port) as stage:
            stage.move_at(2.4e-3)
            port.wait_until(port.now_s() + 1.0, timeout_s=60)
            state = stage.state()
    finally:
        runner.stop()
    assert not state.moving and state.forward_limit
    # it stops within a world step (10 ms at 2.4 mm/s = 24 um) of the limit, never far beyond
    assert 24.47e-3 < state.position_m <= 24.5e-3 + 30e-6


def test_a_move_ends_the_velocity_watchdog_and_arrives_exactly():
    """A stop, then a move to a position: the soft-limit watchdog of the velocity move is gone
    (a move's own stop flag must not keep it polling), and the move ends on its target."""
    import threading
    scene, world, runner, port = make_rig(real_time_factor=0.0)
    runner.start()
    try:
        with SimStage(port) as stage:
            start = stage.state().position_m
            stage.move_at(2.0e-3)
            port.wait_until(port.now_s() + 0.2, timeout_s=60)
            stage.stop()
            stage.move_to(start - 0.5e-3, 2.0e-3, timeout_s=60)
            watchdogs = [t for t in threading.enumerate() if t.name == 'sim-stage-limits']
            state = stage.state()
    finally:
        runner.stop()
    assert all(not t.is_alive() for t in watchdogs)
    assert state.position_m == pytest.approx(start - 0.5e-3, abs=1e-9) and not state.moving


def test_a_bounded_pull_ends_at_rest_on_its_bound_with_nobody_commanding():
    """The simulated stage obeys a pull's bound as the controller does: the world takes the
    stage there at the pull speed and stops it, at rest, with no stop ever sent (whoever
    commanded the pull is gone), and never past it."""
    scene, world, runner, port = make_rig(real_time_factor=0.0)
    runner.start()
    try:
        stage = SimStage(port)
        stage.open()
        start = stage.state().position_m
        bound = start + 2.0e-3       # long enough to reach the pull speed (4 mm/s² ramps)
        stage.move_at(PULL_M_PER_S, bound_m=bound)
        furthest, speeds = start, []
        for _ in range(200):                      # 2 s of simulated time, in 10 ms steps
            port.wait_until(port.now_s() + 0.01, timeout_s=60)
            position, velocity = port.stage_state()
            furthest = max(furthest, position)
            speeds.append(velocity)
        position, velocity = port.stage_state()
        with pytest.raises(ConfigurationError, match='not ahead of the stage'):
            stage.move_at(PULL_M_PER_S, bound_m=start)
    finally:
        runner.stop()
    assert max(speeds) == pytest.approx(PULL_M_PER_S, rel=1e-9)     # the pull speed, capped
    assert position == pytest.approx(bound, abs=1e-9) and velocity == 0.0
    assert furthest <= bound + 1e-12
