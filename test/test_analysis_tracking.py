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
    """The common-centre fit explains the body arcs to ~1/6 pixel; L1 is near its design 19 mm."""
    fit = analysis.linkage
    assert fit.body_fit_rms_mm < 0.05
    assert fit.arm_fit_rms_mm < 0.05
    assert analysis.L1_mm == pytest.approx(19.0, abs=0.3)


def test_authors_pivot_leaves_larger_residuals():
    """Evidence for the xfail below: the authors' pivot fits these arcs ~9x worse than ours."""
    from mantis_rig.analysis.geometry import fit_common_centre
    tracks = load_tracks(DATA)
    arcs = [tracks.markers_mm[n] for n in tracks.body_markers]
    centre, _, rms = fit_common_centre(arcs)
    authors = np.array([0.927, -0.262])
    rms_authors = np.sqrt(np.mean(np.concatenate(
        [(np.linalg.norm(a - authors, axis=1) - np.linalg.norm(a - authors, axis=1).mean()) ** 2
         for a in arcs])))
    assert rms_authors > 5 * rms


@pytest.mark.xfail(strict=True, reason='authors pivot (0.927,-0.262)/L1 19.57 do not fit these '
                   'tracks: least squares gives (-1.23,-0.96), L1 19.01 (see test above)')
def test_pivot_and_L1_match_authors(analysis):
    s = analysis.summary()
    assert np.allclose(s['body_pivot_mm'], [0.927, -0.262], atol=0.2)
    assert abs(s['L1_mm'] - 19.57) < 0.3


@pytest.mark.xfail(strict=True, reason='arm tip direction is not tracked; with the arm axis '
                   'b->outermost marker the latched angle is 6.2 deg, authors 3.20 deg')
def test_contact_angle_matches_authors(analysis):
    assert abs(analysis.summary()['contact_angle_deg'] - 3.2) < 0.5


@pytest.mark.xfail(strict=True, reason='geometric overcentering needs absolute angles to ~0.2 deg '
                   '(about 0.12 s per deg); with default conventions it is 2.054 s, authors 2.1265')
def test_overcentering_matches_authors(analysis):
    assert abs(analysis.summary()['overcentering_s'] - 2.1265) < 0.02
