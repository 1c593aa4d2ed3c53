"""The analysis of the simulated camera over the frame phase (no ROS).

test_analysis_sim_trial analyses one simulated trial; its stage starts on the world's 10 ms
grid, which holds a whole number of frames, so every such trial sees the strike at the same
frame phase: one draw of the quantisation errors. Here one strike of air_23mm_rig is filmed
at eight frame phases and each film analysed as `mantis analyze` analyses the trial's bag.
Bounds from `bench/bench_sim_camera.py` (48 phases at 19,000 frames/s: peak tip speed -0.59 ..
+0.02 %, its time -0.28 .. -0.01 frames, overcentering -0.33 .. +0.01 frames; README).
"""
import numpy as np
import pytest

from mantis_rig.analysis.sim_camera_study import study

pytestmark = [pytest.mark.timeout(120), pytest.mark.slow]


@pytest.fixture(scope='module')
def films():
    _, errors = study('air_23mm_rig', n_phases=8)
    return errors


def test_peak_tip_speed_over_the_frame_phase(films):
    """Within 1 % in the median film, and within 3 % in every one: the pixel quantisation
    of the arm markers (about 3 mrad of arm angle per frame) against a peak that is a few
    frames wide."""
    errors = np.array([f.peak_tip_speed_rel for f in films])
    assert abs(np.median(errors)) < 0.01, errors
    assert np.max(np.abs(errors)) < 0.03, errors


def test_peak_time_over_the_frame_phase(films):
    errors = np.array([f.peak_time_frames for f in films])
    assert np.max(np.abs(errors)) < 2.5, errors


def test_overcentering_over_the_frame_phase(films):
    """Within a third of a frame at every phase at the tracker's 0.1-pixel resolution (it was
    about one frame early when the simulated camera gave whole pixels)."""
    errors = np.array([f.phase_frames['III'] for f in films])
    assert np.max(np.abs(errors)) < 1.5, errors


def test_unlatching_fitted_back_to_its_start_over_the_frame_phase(films):
    """The arm leaves the latch below the tracking noise for ~2 ms, so its level crossing is
    +42 .. +49 frames late; fitted by the departure's form (analysis.onset) the start is within
    a millisecond or so, early or late (bench_sim_camera: -41 .. +19 frames over 48 phases,
    median -0.9)."""
    errors = np.array([f.phase_frames['II'] for f in films])
    assert np.median(np.abs(errors)) < 15.0, errors
    assert np.max(np.abs(errors)) < 45.0, errors


@pytest.mark.xfail(strict=True, reason=(
    'issue 13 goal not met: the start of IV is -1.4 .. +9.0 frames over 48 phases (the body '
    'turns round while moving less than the tracking noise; its time is extrapolated from '
    'the rise), unlatching -41 .. +19 (the arm leaves the latch below the noise for ~2 ms; '
    'its departure\'s form puts the start back only as far as the noise lets it)'))
def test_phase_starts_within_two_frames_at_every_frame_phase(films):
    for phase in ('II', 'III', 'IV'):
        errors = np.array([f.phase_frames[phase] for f in films])
        assert np.max(np.abs(errors)) < 2.0, (phase, errors)
