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


def test_pivot_fit_is_at_noise_level(analysis):
    """Rotation about one fixed pivot explains the body markers to ~0.2 pixel (1 px = 0.17 mm) and
    the arm markers, in the body frame, likewise; L1 is near its design 19 mm."""
    fit = analysis.linkage
    assert fit.body_fit_rms_mm < 0.05
    assert fit.arm_fit_rms_mm < 0.05
    assert analysis.L1_mm == pytest.approx(19.0, abs=0.3)


def _body_arcs():
    tracks = load_tracks(DATA)
    return np.stack([tracks.markers_mm[n] for n in tracks.body_markers], axis=1)


def test_rigid_and_circle_fits_agree_authors_pivot_does_not(analysis):
    """Two independent estimators of the pivot (rigid rotation about a fixed point, and a
    common-centre circle fit with free radii) agree to 0.3 mm; the published pivot is 2 mm
    from both."""
    from mantis_rig.analysis.geometry import fit_common_centre
    ours = analysis.linkage.body_pivot_mm
    arcs = _body_arcs()
    circle, _, _ = fit_common_centre([arcs[:, k] for k in range(arcs.shape[1])])
    assert np.linalg.norm(circle - ours) < 0.3
    assert np.linalg.norm(np.array([0.927, -0.262]) - ours) > 1.5


def test_authors_pivot_fits_only_with_x_mirrored(analysis):
    """Evidence for the xfail below. Residual of 'rotation about this pivot' (offsets and
    angles optimised): the published (0.927, -0.262) is >5x worse than the fit; the same
    numbers with x negated, (-0.927, -0.262), fit within 1.6x of it. So the published value
    is probably in an x-mirrored frame; even so it lies 0.6 mm from the fitted pivot."""
    from mantis_rig.analysis.geometry import rotation_model_rms
    arcs = _body_arcs()
    best = rotation_model_rms(arcs, analysis.linkage.body_pivot_mm)
    assert rotation_model_rms(arcs, np.array([0.927, -0.262])) > 5 * best
    assert rotation_model_rms(arcs, np.array([-0.927, -0.262])) < 1.6 * best


@pytest.mark.xfail(strict=True, reason=(
    'published pivot (0.927,-0.262) leaves 7x the residual of the fit on these tracks; the '
    'ML rigid-rotation fit gives (-1.167,-0.790), L1 19.17 (circle fit: (-1.226,-0.958), '
    '19.01). With x negated the published pivot fits (1.4x) but is still 0.58 mm away: the '
    'body markers\' mutual distances drift ~0.1 mm with angle (image non-rigidity), which '
    'moves any centre estimate by ~0.5 mm along the radius'))
def test_pivot_and_L1_match_authors(analysis):
    s = analysis.summary()
    assert np.allclose(s['body_pivot_mm'], [0.927, -0.262], atol=0.2)
    assert abs(s['L1_mm'] - 19.57) < 0.3


@pytest.mark.xfail(strict=True, reason=(
    'θ3 is measured from the arm axis b->tip (physics.md), and neither the tip nor c is '
    'tracked: the arm-axis direction in the arm-marker frame is an arm constant '
    '(AnalysisParams.arm_axis_offset_rad) that markers cannot reveal (see '
    'test_analysis_rigid.test_contact_angle_needs_the_arm_axis). With the axis taken as '
    'b->outermost marker the latched angle is 6.07 deg, authors 3.20 deg'))
def test_contact_angle_matches_authors(analysis):
    assert abs(analysis.summary()['contact_angle_deg'] - 3.2) < 0.5


@pytest.mark.xfail(strict=True, reason=(
    'geometric overcentering needs the absolute θ1 (guide-hole direction) and θ3 (arm axis) '
    'to ~0.3 deg (~0.07 s per deg here); neither is visible to the camera. With the default '
    'conventions it is 2.077 s, authors 2.1265; with θ3 shifted to the authors\' 3.20 deg '
    'contact it is 2.356 s, so their θ1 reference differs too. The kinematic knee of the path '
    '(θ1, θ3) (TrialAnalysis.overcentering_trajectory_s) is 2.105 s but moves over 1.99-2.14 s '
    'with the fit window, and the path shows no sharp event at overcentering'))
def test_overcentering_matches_authors(analysis):
    assert abs(analysis.summary()['overcentering_s'] - 2.1265) < 0.02
