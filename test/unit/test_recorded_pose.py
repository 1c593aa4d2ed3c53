"""The poses a simulated film renders from, taken from the world at once
(mantis_sim.camera.recorded_pose): the markers at every frame time, and at any instant of an
exposure through the strike, within 0.01 px of the world's own."""
import math

import numpy as np
import pytest

from mantis_sim.camera.recorded_pose import RecordedPose, record_frames
from mantis_sim.camera.render import world_poses
from mantis_sim.scene import load_scene
from mantis_sim.world import World

RATE_HZ = 19_000.0
TOLERANCE_PX = 0.002


@pytest.fixture(scope='module')
def struck_world():
    """A world pulled through one strike and 30 ms past its release."""
    scene = load_scene('air_23mm_rig')
    world = World(scene)
    world.advance_to(0.2)
    world.set_stage_velocity(scene.drive.pull_speed_mm_per_s * 1e-3)
    t_s = 0.2
    while not math.isfinite(world.peak_time_s):
        t_s += 0.01
        world.advance_to(t_s)
        assert t_s < 10.0, 'no strike'
    release_s = world.phase_start_s['IV']
    world.advance_to(release_s + 0.03)
    return scene, world, release_s


def _px(scene) -> float:
    return 1.0 / scene.camera.pixel_mm


def _worst_px(recorded, truth_pose, times, scene) -> float:
    got, want = recorded(times), truth_pose(times)
    return max(float(np.max(np.hypot(*(got.markers_mm[n] - want.markers_mm[n]).T)))
               for n in want.markers_mm) * _px(scene)


def test_markers_at_frames_and_between_them_match_the_world(struck_world):
    scene, world, release_s = struck_world
    pose = world_poses(world)
    first = math.ceil((release_s - 0.02) * RATE_HZ)
    frames = np.arange(first, first + round(0.045 * RATE_HZ)) / RATE_HZ
    recorded = record_frames(pose, frames, TOLERANCE_PX / _px(scene))
    assert recorded.start_s < frames[0] and recorded.stop_s > frames[-1]
    # finer than a frame only where the mechanism moves: the first frames, at rest, once each
    assert frames.size + 2 < recorded.times_s.size < 16 * frames.size
    assert np.allclose(recorded.times_s[:4], frames[0] + np.arange(-1, 3) / RATE_HZ)
    assert _worst_px(recorded, pose, frames, scene) < 1e-6
    # every instant an exposure's sub-frames may fall on, the strike's fastest included
    rng = np.random.default_rng(1)
    between = np.sort(rng.uniform(frames[0] - 0.5 / RATE_HZ, frames[-1] + 0.5 / RATE_HZ, 20_000))
    strike = np.linspace(release_s, world.peak_time_s + 0.002, 5_000)
    assert _worst_px(recorded, pose, between, scene) < 0.01
    assert _worst_px(recorded, pose, strike, scene) < 0.01
    # the links' points too (the plates are drawn from them)
    got, want = recorded(strike), pose(strike)
    assert np.max(np.hypot(*(got.tip_mm - want.tip_mm).T)) * _px(scene) < 0.01


def test_a_recording_is_a_copy_and_refuses_times_outside_it(struck_world):
    scene, world, release_s = struck_world
    frames = np.arange(100) / RATE_HZ + math.ceil(release_s * RATE_HZ) / RATE_HZ
    recorded = record_frames(world_poses(world), frames, 1e-3, medium='water')
    assert recorded.medium == 'water'
    assert isinstance(recorded, RecordedPose)
    with pytest.raises(ValueError, match='recorded'):
        recorded(np.array([frames[-1] + 2.0 / RATE_HZ]))
    with pytest.raises(ValueError, match='recorded'):
        recorded(np.array([frames[0] - 2.0 / RATE_HZ]))
    before = recorded(frames[:3]).markers_mm['ma2'].copy()
    world.advance_to(world.time_s + 2.5)            # the world forgets what it recorded
    assert np.array_equal(recorded(frames[:3]).markers_mm['ma2'], before)
