"""The analysis on the one real trial, against the authors' derived values
(test/data/PROVENANCE.md)."""
from conftest import data_file
import numpy as np
import pytest

from mantis_rig.analysis import analyze_tracks, load_tracks

pytestmark = pytest.mark.slow

DATA = data_file('air_23mm_2p3mmps_trial1_markers.csv.gz')


@pytest.fixture(scope='module')
def analysis():
    return analyze_tracks(load_tracks(DATA))


def test_file_loads_with_discovered_markers():
    tracks = load_tracks(DATA)
    assert tracks.n_frames == 65255
    assert tracks.body_markers == ['mb1', 'mb2', 'mb3']
    assert tracks.arm_markers == ['ma1', 'ma2']


def test_peak_tip_speed(analysis):
    assert analysis.summary()['peak_tip_speed_mps'] == pytest.approx(27.2, rel=0.05)


def test_start_of_phase_iv(analysis):
    assert abs(analysis.summary()['phase_start_s']['IV'] - 2.6177) < 1e-3


def test_peak_rates_timing(analysis):
    t = analysis.time_s
    assert abs(t[np.argmax(analysis.omega1_radps)] - 2.6257) < 0.5e-3
    assert abs(t[np.argmax(analysis.omega3_radps)] - 2.6259) < 0.5e-3
    s = analysis.summary()
    assert s['peak_arm_speed_radps'] / s['peak_body_speed_radps'] == pytest.approx(
        1766.9 / 184.6, rel=0.1)


def test_phase_order(analysis):
    p = analysis.summary()['phase_start_s']
    assert p['I'] < p['II'] < p['III'] < p['IV'] < analysis.phases.peak_tip_speed_s


def _body_arcs():
    tracks = load_tracks(DATA)
    return tracks.time_s, np.stack([tracks.markers_mm[n] for n in tracks.body_markers], axis=1)


def test_linkage_is_fitted_on_the_strike(analysis):
    """The strike (start of IV to the end of the body's rebound) is found, and the pivots
    fitted on it explain its frames to a quarter pixel (1 px = 0.17 mm; the strike frames are
    motion-blurred)."""
    fit = analysis.linkage
    assert fit.strike_fit
    start, stop = fit.fit_window_s
    assert abs(start - analysis.phases.max_contraction_s) < 2e-3
    assert analysis.phases.peak_tip_speed_s < stop < start + 0.02
    assert fit.body_fit_rms_mm < 0.05
    assert fit.arm_fit_rms_mm < 0.065


def test_the_body_turns_about_another_point_while_loading(analysis):
    """Joint play: 'rotation about one fixed point' with the loading pivot leaves 1.5x the
    residual of the strike pivot on the loading frames... and the strike pivot's on the strike
    frames is lower too; the two are ~0.5 mm apart. A common-centre circle fit on the loading
    frames (free radii) lands near the rigid loading pivot."""
    from mantis_rig.analysis.geometry import fit_common_centre, rotation_model_rms
    fit = analysis.linkage
    t, arcs = _body_arcs()
    strike = (t >= fit.fit_window_s[0]) & (t <= fit.fit_window_s[1])
    loading = t < fit.fit_window_s[0]
    strike_pivot, loading_pivot = fit.body_pivot_mm, fit.loading_pivot_mm
    assert 0.35 < np.linalg.norm(strike_pivot - loading_pivot) < 0.7
    assert (rotation_model_rms(arcs[loading], strike_pivot)
            > 1.4 * rotation_model_rms(arcs[loading], loading_pivot))
    assert (rotation_model_rms(arcs[strike], loading_pivot)
            > 1.1 * rotation_model_rms(arcs[strike], strike_pivot))
    circle, _, _ = fit_common_centre([arcs[loading][:, k] for k in range(arcs.shape[1])])
    assert np.linalg.norm(circle - loading_pivot) < 0.3


def test_body_angle_is_the_rigid_rotation_and_theta1_the_link():
    """The body angle turns as the pivot-free Kabsch pose does, in the loading and in the
    strike (about the loading pivot alone, the strike would come out 3 % too fast; about the
    strike pivot alone, the loading 2.7 % too slow). θ1, the direction of b seen from the
    strike pivot a (physics.md's link angle), turns as the body in the strike, where the body
    turns about a, and 2-3 % less over the loading, where it turns about the loading pivot."""
    from mantis_rig.analysis import fit_linkage
    from mantis_rig.analysis.geometry import rigid_poses
    from mantis_rig.analysis.kinematics import _right_handed
    tracks = load_tracks(DATA)
    _, angles = fit_linkage(tracks)
    _, kabsch, _ = rigid_poses(_right_handed(tracks, tracks.body_markers), iterations=2)

    def mean_at(x, t_s, k):
        i = int(np.searchsorted(tracks.time_s, t_s))
        return x[i - k:i + k + 1].mean()

    def turn(x, t0, t1, k):
        return mean_at(x, t1, k) - mean_at(x, t0, k)
    for t0, t1, k, rel in [(0.05, 2.60, 200, 0.003), (2.6188, 2.6263, 0, 0.01)]:
        assert turn(angles.body_angle_rad, t0, t1, k) == pytest.approx(
            turn(kabsch, t0, t1, k), rel=rel)
    loading = turn(angles.theta1_cam_rad, 0.05, 2.60, 200) / turn(kabsch, 0.05, 2.60, 200)
    assert 0.96 < loading < 0.985
    assert turn(angles.theta1_cam_rad, 2.6188, 2.6263, 0) == pytest.approx(
        turn(kabsch, 2.6188, 2.6263, 0), rel=0.01)


def test_authors_pivot_is_the_strike_pivot_with_x_mirrored(analysis):
    """Evidence for the pivot_frame convention. Residual of 'rotation about this pivot'
    (offsets and angles optimised) on the strike frames: the published (0.927, -0.262) as
    recorded leaves 4x the residual of the fit; with x negated it fits as well as the fit
    itself (and 1.4x worse on the loading frames, like the strike pivot)."""
    from mantis_rig.analysis.geometry import rotation_model_rms
    fit = analysis.linkage
    t, arcs = _body_arcs()
    strike = (t >= fit.fit_window_s[0]) & (t <= fit.fit_window_s[1])
    best = rotation_model_rms(arcs[strike], fit.body_pivot_mm)
    assert rotation_model_rms(arcs[strike], np.array([0.927, -0.262])) > 3 * best
    assert rotation_model_rms(arcs[strike], np.array([-0.927, -0.262])) < 1.02 * best
    assert np.linalg.norm(np.array([0.927, -0.262]) - fit.loading_pivot_mm) > 1.5


def test_pivot_and_L1_match_authors(analysis):
    s = analysis.summary()
    assert np.allclose(s['body_pivot_mm'], [0.927, -0.262], atol=0.2)
    assert abs(s['L1_mm'] - 19.57) < 0.3


@pytest.mark.xfail(strict=True, reason=(
    'θ3 is measured from the arm axis b->tip (physics.md); neither the tip nor c is tracked, '
    'so the axis direction in the arm-marker frame is an arm constant the markers cannot '
    'reveal (test_analysis_rigid.test_contact_angle_needs_the_arm_axis). The authors do not '
    'derive it from the tracks either: their θ3 series for this trial (repository '
    'csv files/031320_..._1_data.csv) starts at exactly 0, and their per-trial contact angle '
    'is a separate input (th2i.csv, one number per trial, e.g. 3.367 for 091319_..._1). '
    'By default θ3 counts from the latch and the contact angle is reported unknown (NaN); '
    'taking the outermost arm marker for the axis (arm_axis_offset_rad=0) gives 5.9 deg, '
    'authors 3.20 deg; AnalysisParams.contact_angle_rad (or a bag\'s trial conditions) '
    'takes a measured value'))
def test_contact_angle_matches_authors(analysis):
    assert abs(analysis.summary()['contact_angle_deg'] - 3.2) < 0.5


def test_overcentering_matches_authors(analysis):
    """The published 2.1265 s is the zero of dl_t/dθ3 with physics.md's geometry (L1 = 19,
    d_t = 23, β = 140.24°) on the link angles: θ1 the direction a -> b from the camera's x axis
    (b seen from the fixed body pivot a, which with the joint's play turns 2-3 % less than the
    body while loading), θ3 the arm from the line b -> a, counted from the latch (no contact
    angle is known for this trial). Measured: 2.144 s. How firmly: the pivots' fit window
    (STRIKE_SPEED_SHARE 0.02-0.5) moves it over 2.095-2.155 s, the fitted L1 (19.64 mm) in
    place of the design's 2.201 s, θ3 including the authors' 3.2° contact angle 1.77 s (the
    zero moves ~4 ms per mrad of θ1 and ~7 ms per mrad of θ3)."""
    assert abs(analysis.summary()['overcentering_s'] - 2.1265) < 0.02


def arm_lost(tracks, first, last):
    """A copy of the tracks with every arm marker lost (NaN) over frames first..last-1."""
    import copy
    lost = copy.deepcopy(tracks)
    for name in lost.arm_markers:
        lost.markers_mm[name][first:last] = np.nan
    return lost


@pytest.mark.parametrize('around', [(-3, 3), (-10, 10), (-40, -20)],
                         ids=['at the peak', 'over the peak', 'before the peak'])
def test_markers_lost_inside_the_strike_are_refused_not_guessed(analysis, around):
    from mantis_rig.analysis.pipeline import StrikeLost
    tracks = load_tracks(DATA)
    peak = int(np.searchsorted(tracks.time_s, analysis.phases.peak_tip_speed_s))
    with pytest.raises(StrikeLost, match='the markers were lost inside the strike'):
        analyze_tracks(arm_lost(tracks, peak + around[0], peak + around[1]))


def test_tracking_that_ends_in_the_strike_is_counted(analysis):
    tracks = load_tracks(DATA)
    peak = int(np.searchsorted(tracks.time_s, analysis.phases.peak_tip_speed_s))
    ended = analyze_tracks(arm_lost(tracks, peak + 2, tracks.n_frames))
    assert ended.summary()['lost_frames_in_strike'] > 0
    assert analysis.summary()['lost_frames_in_strike'] == 0
