"""Rigid-body linkage fit (Kabsch poses, fixed points, ML pivot) on synthetic marker tracks."""
import math

import numpy as np
import pytest

from mantis_rig.analysis import AnalysisParams, MarkerTracks, analyze_tracks, fit_linkage
from mantis_rig.analysis.geometry import (
    fit_fixed_pivot,
    fixed_point_of_motion,
    kabsch_angles,
    rigid_poses,
    rotate,
)

PIVOT_A = np.array([2.0, -1.0])                    # right-handed frame, mm
BODY_OFFSETS = np.array([[-5.0, -7.0], [-12.0, -14.0], [-3.0, -21.0]])   # markers − a


def _rotating_body(angle_rad, pivot=PIVOT_A, offsets=BODY_OFFSETS):
    return pivot + rotate(np.broadcast_to(offsets, (len(angle_rad),) + offsets.shape), angle_rad)


def _tracker(points, rng, sigma_mm=0.03, step_mm=0.017):
    """Tracker noise, then quantisation to the tracker's coordinate step."""
    return np.round((points + rng.normal(0.0, sigma_mm, points.shape)) / step_mm) * step_mm


def test_kabsch_recovers_pose_exactly():
    angle = np.linspace(-0.3, 2.5, 50)
    pts = _rotating_body(angle) + np.array([0.5, -0.25])
    template = pts[0] - pts[0].mean(axis=0)
    got, centroid = kabsch_angles(pts, template)
    np.testing.assert_allclose(got - got[0], angle - angle[0], atol=1e-12)
    np.testing.assert_allclose(centroid, pts.mean(axis=1), atol=1e-12)


def test_fixed_point_exact_without_noise_and_refuses_no_rotation():
    angle = np.linspace(0.0, -0.2, 200)
    template, ang, cen = rigid_poses(_rotating_body(angle))
    p, _, rms = fixed_point_of_motion(ang, cen)
    np.testing.assert_allclose(p, PIVOT_A, atol=1e-9)
    assert rms < 1e-9
    with pytest.raises(ValueError, match='does not rotate'):
        fixed_point_of_motion(np.zeros(100), np.ones((100, 2)))


def test_ml_pivot_on_short_noisy_quantised_arc():
    """12° of rotation, 0.03 mm noise: the ML pivot is within 0.03 mm, and beats its start."""
    angle = np.linspace(0.0, math.radians(-12.0), 4000)
    clean = _rotating_body(angle)
    err_ml, err_start = [], []
    for seed in range(4):
        pts = _tracker(clean, np.random.default_rng(seed))
        template, ang, cen = rigid_poses(pts)
        p0, q0, _ = fixed_point_of_motion(ang, cen)
        p, offsets, theta, rms = fit_fixed_pivot(pts, p0, template - q0)
        err_start.append(np.linalg.norm(p0 - PIVOT_A))
        err_ml.append(np.linalg.norm(p - PIVOT_A))
        np.testing.assert_allclose(np.linalg.norm(offsets, axis=1),
                                   np.linalg.norm(BODY_OFFSETS, axis=1), atol=0.03)
        dev = theta - angle                           # constant gauge + per-frame noise
        assert np.std(dev) < 2e-3
        assert rms == pytest.approx(0.03 * math.sqrt(2.0), rel=0.15)
    assert max(err_ml) < 0.03
    assert np.mean(err_ml) < np.mean(err_start)


def _synthetic_trial(rng, contact_deg=3.0, L1=19.0, marker_axis_deg=6.0, fps=4000.0,
                     play_mm=(0.0, 0.0), return_b=False):
    """Body and arm of physics.md in a left-handed camera frame, with tracker noise.

    θ1_cam falls 25° in 0.9 s (loading), the arm sits at the contact angle until 0.5 s, then
    opens 6° by 0.9 s; the strike swings the body back 12° and opens the arm 150° in 10 ms.
    ``play_mm``: from the strike on, the body turns about PIVOT_A + play_mm instead (a joint
    with play, loaded differently by the tendon and by the strike); the motion stays continuous.
    """
    t = np.arange(0.0, 1.0, 1.0 / fps)
    load = np.clip(t / 0.9, 0.0, 1.0)
    strike = np.clip((t - 0.9) / 0.01, 0.0, 1.0)
    smooth = strike ** 2 * (3.0 - 2.0 * strike)
    theta1 = np.radians(140.0 - 25.0 * load + 12.0 * smooth)
    opening = np.clip((t - 0.5) / 0.4, 0.0, 1.0) ** 2
    theta3 = np.radians(contact_deg + 6.0 * opening + 150.0 * smooth)
    link = L1 * np.array([np.cos(theta1[0]), np.sin(theta1[0])])
    points = np.vstack([BODY_OFFSETS, link])                       # markers and b, minus a
    moved = PIVOT_A + rotate(np.broadcast_to(points, (len(t),) + points.shape),
                             theta1 - theta1[0])
    after = t >= 0.9
    if after.any():
        k = int(np.argmax(after))
        pivot2 = PIVOT_A + np.asarray(play_mm, float)
        rel = np.broadcast_to(moved[k] - pivot2, (int(after.sum()),) + points.shape)
        moved[after] = pivot2 + rotate(rel, theta1[after] - theta1[k])
    body, b = moved[:, :3], moved[:, 3]
    psi = theta1 + np.pi - theta3                     # arm axis b → tip
    arm_local = np.array([[7.5, 1.0], [16.0, 16.0 * math.tan(math.radians(marker_axis_deg))]])
    arm = b[:, None, :] + rotate(np.broadcast_to(arm_local, (len(t), 2, 2)), psi)
    markers = {}
    for name, xy in [('mb1', body[:, 0]), ('mb2', body[:, 1]), ('mb3', body[:, 2]),
                     ('ma1', arm[:, 0]), ('ma2', arm[:, 1])]:
        markers[name] = _tracker(xy, rng) * np.array([1.0, -1.0])   # image y points down
    tracks = MarkerTracks(time_s=t, frames=np.arange(len(t)), markers_mm=markers)
    if return_b:
        return tracks, theta1, theta3, b
    return tracks, theta1, theta3


def test_fit_linkage_recovers_pivots_and_angles():
    tracks, theta1, theta3 = _synthetic_trial(np.random.default_rng(7))
    fit, angles = fit_linkage(tracks, arm_axis_offset_rad=math.radians(6.0))
    np.testing.assert_allclose(fit.body_pivot_mm, PIVOT_A * [1.0, -1.0], atol=0.05)
    assert fit.L1_mm == pytest.approx(19.0, abs=0.05)
    assert fit.body_fit_rms_mm < 0.05 and fit.arm_fit_rms_mm < 0.05
    err1 = np.degrees(angles.theta1_cam_rad - theta1)
    err3 = np.degrees(angles.theta3_rad - theta3)
    assert np.max(np.abs(err1)) < 0.5 and abs(np.mean(err1)) < 0.05
    assert np.max(np.abs(err3)) < 1.0 and abs(np.mean(err3)) < 0.1


def test_fit_linkage_keeps_one_pivot_when_the_strike_does_not_move_it():
    tracks, _, _ = _synthetic_trial(np.random.default_rng(5))
    fit, _ = fit_linkage(tracks)
    assert not fit.strike_fit                          # all frames: the better-determined fit
    np.testing.assert_allclose(fit.loading_pivot_mm, PIVOT_A * [1.0, -1.0], atol=0.05)


def test_joint_play_the_linkage_is_fitted_on_the_strike():
    """The body turns about one point while loading and about another, 0.5 mm away, in the
    strike: the pivot and L1 are those of the strike, the loading pivot is kept, the body
    angle follows the rotation in both regimes (as a single fixed pivot would not), and θ1
    is the direction of b seen from the strike pivot a, θ3 the arm from that line (the link
    physics.md's angles are about; with play it turns less than the body while loading)."""
    play = np.array([0.3, 0.4])
    fps = 19000.0
    tracks, theta1, theta3, b = _synthetic_trial(np.random.default_rng(11), fps=fps,
                                                 play_mm=play, return_b=True)
    fit, angles = fit_linkage(tracks, arm_axis_offset_rad=math.radians(6.0))
    assert fit.strike_fit
    assert 0.895 < fit.fit_window_s[0] < 0.901 and fit.fit_window_s[1] < 0.92
    pivot2 = PIVOT_A + play
    np.testing.assert_allclose(fit.body_pivot_mm, pivot2 * [1.0, -1.0], atol=0.05)
    np.testing.assert_allclose(fit.loading_pivot_mm, PIVOT_A * [1.0, -1.0], atol=0.05)
    k = int(round(0.9 * fps))
    b_strike = PIVOT_A + 19.0 * np.array([np.cos(theta1[k]), np.sin(theta1[k])])
    assert fit.L1_mm == pytest.approx(np.linalg.norm(b_strike - pivot2), abs=0.05)
    a_to_b = b - pivot2
    link = np.unwrap(np.arctan2(a_to_b[:, 1], a_to_b[:, 0]))
    assert np.ptp((link - theta1)[:k]) > np.radians(0.15)      # the play shows while loading
    for got, true in ((angles.body_angle_rad, theta1), (angles.theta1_cam_rad, link),
                      (angles.theta3_rad, theta3 + link - theta1)):
        err = np.degrees(got - true)
        err -= np.mean(err)                      # the angles' zero is not under test here
        assert np.sqrt(np.mean(err ** 2)) < 0.25                # per-frame noise ~0.15 deg
        assert abs(np.mean(err[:k]) - np.mean(err[k:])) < 0.05  # the same in both regimes
    # the link's direction itself, not only its changes: within the pivot's uncertainty
    assert np.degrees(np.mean(angles.theta1_cam_rad - link)) == pytest.approx(0.0, abs=0.2)


def test_contact_angle_needs_the_arm_axis():
    """θ3 is measured from the arm axis (b → tip); the tip is not tracked. With the
    marker-to-axis angle supplied the contact angle is recovered; taking the outermost marker
    for the axis, it is off by exactly that angle, which no marker-only fit can see; with
    neither, θ3 counts from the latch and the contact angle is reported unknown."""
    tracks, _, _ = _synthetic_trial(np.random.default_rng(3), contact_deg=3.0,
                                    marker_axis_deg=6.0)
    known = analyze_tracks(tracks, AnalysisParams(arm_axis_offset_rad=math.radians(6.0)))
    assert known.summary()['contact_angle_deg'] == pytest.approx(3.0, abs=0.15)
    marker_axis = analyze_tracks(tracks, AnalysisParams(arm_axis_offset_rad=0.0))
    assert marker_axis.summary()['contact_angle_deg'] == pytest.approx(3.0 - 6.0, abs=0.15)
    assert marker_axis.L1_mm == pytest.approx(known.L1_mm, abs=1e-9)
    unknown = analyze_tracks(tracks)
    assert math.isnan(unknown.summary()['contact_angle_deg'])
    latched = unknown.time_s < 0.45
    assert np.median(unknown.theta3_rad[latched]) == pytest.approx(0.0, abs=math.radians(0.05))
    np.testing.assert_allclose(unknown.theta3_rad, known.theta3_rad - math.radians(3.0),
                               atol=math.radians(0.15))
    # A contact angle measured on the rig sets θ3's zero instead (the authors' convention).
    measured = analyze_tracks(tracks, AnalysisParams(contact_angle_rad=math.radians(3.0)))
    assert measured.summary()['contact_angle_deg'] == pytest.approx(3.0, abs=1e-12)
    np.testing.assert_allclose(measured.theta3_rad, known.theta3_rad, atol=math.radians(0.15))
