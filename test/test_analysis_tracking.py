"""The analysis on the one real trial, against the authors' derived values (data/README.md)."""
from pathlib import Path

import numpy as np
import pytest

from mantis_rig.analysis import analyze_tracks, load_tracks

DATA = (Path(__file__).resolve().parents[1] / '..' / 'shared' / 'data'
        / 'air_23mm_2p3mmps_trial1_markers.csv.gz').resolve()

pytestmark = pytest.mark.skipif(not DATA.exists(), reason=f'reference trial absent: {DATA}')


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


def test_body_angle_is_the_rigid_rotation():
    """The body angle turns as the pivot-free Kabsch pose does, in the loading and in the
    strike (about the loading pivot alone, the strike would come out 3 % too fast; about the
    strike pivot alone, the loading 2.7 % too slow)."""
    from mantis_rig.analysis import fit_linkage
    from mantis_rig.analysis.geometry import rigid_poses
    from mantis_rig.analysis.kinematics import _right_handed
    tracks = load_tracks(DATA)
    _, angles = fit_linkage(tracks)
    _, kabsch, _ = rigid_poses(_right_handed(tracks, tracks.body_markers), iterations=2)

    def mean_at(x, t_s, k):
        i = int(np.searchsorted(tracks.time_s, t_s))
        return x[i - k:i + k + 1].mean()
    for t0, t1, k, rel in [(0.05, 2.60, 200, 0.003), (2.6188, 2.6263, 0, 0.01)]:
        ours = mean_at(angles.theta1_cam_rad, t1, k) - mean_at(angles.theta1_cam_rad, t0, k)
        rigid = mean_at(kabsch, t1, k) - mean_at(kabsch, t0, k)
        assert ours == pytest.approx(rigid, rel=rel)


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
    'With the default axis (b -> outermost arm marker) the latched angle is 6.54 deg, '
    'authors 3.20 deg; AnalysisParams.contact_angle_rad takes a measured value'))
def test_contact_angle_matches_authors(analysis):
    assert abs(analysis.summary()['contact_angle_deg'] - 3.2) < 0.5


@pytest.mark.xfail(strict=True, reason=(
    'the published 2.1265 s is the zero of dl_t/dθ3 (physics.md geometry, L1 = 19, d_t = 23, '
    'beta = 140.24 deg) on the authors\' own angle series (data.csv: θ1 from the camera x '
    'axis, θ3 zero at the latch, i.e. without the 3.2 deg contact angle): their (θ1, θ3) = '
    '(1.9497, 0.0225) at 2.0407 s and (1.9341, 0.0262) at 2.1274 s give +0.40 and -0.04 mm, '
    'a zero at 2.1266 s. The same recipe on our angles gives 2.195 s: at 2.1265 s our θ1 is '
    '0.012 rad higher (their θ1 is the direction of b from one fixed pivot, which understates '
    'the loading rotation by 2.7 %, and their a->b reference differs from ours by 0.022 rad) '
    'and our θ3 0.007 rad lower; the zero moves ~4 ms per mrad of θ1 and ~7 ms per mrad of '
    'θ3, so no fit of the markers pins it to 20 ms. With physics.md\'s θ3 (contact angle '
    'included, default axis) it is 1.48 s; the (θ1, θ3) path knee is 2.111 s but moves over '
    '1.99-2.14 s with the fit window'))
def test_overcentering_matches_authors(analysis):
    assert abs(analysis.summary()['overcentering_s'] - 2.1265) < 0.02
