"""Pivots, link length and joint angles from marker tracks; tip speed from joint rates.

Fits are rigid-body fits (see :func:`fit_linkage`): the body pivot a is the point fixed under
the body's motion, the arm pivot b the point fixed in both the body frame and the arm frame,
L1 = |a − b|. On the reference trial the rigid fit and a common-centre circle fit agree to
0.2 mm; both leave ~0.04 mm marker residuals, while the body markers' mutual distances drift
by ~0.1 mm with the body angle (non-rigidity of the image), which bounds how well any
estimator can place a along the radius (~0.5 mm).

Conventions (those of physics.md, in a right-handed frame):
- The tracking frame is left-handed (image y down); y is negated once, before any fit.
- θ1_cam: direction of the body link a→b (body pivot to arm pivot), counter-clockwise from
  the camera's +x axis. It differs from the model's θ1 by a constant (the direction of the
  guide hole, the model's x axis), which the caller supplies; see ``energy.model_theta1``.
  Loading turns the body clockwise (θ1 falls), the strike counter-clockwise.
- θ3: counter-clockwise angle from the arm axis (b → tip) to the body link (b → a). θ3 = 0 is
  the arm folded onto the body; the arm opens with θ3 rising. The tip is not tracked, so the
  arm axis is taken as b → the arm marker farthest from b, plus an optional fixed offset
  ``arm_axis_offset_rad`` = counter-clockwise angle (right-handed frame) from the b → tip line
  to the b → outermost-marker line, an arm constant the markers cannot reveal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import fit_fixed_pivot, fixed_point_of_motion, rigid_poses, rotate, signed_angle
from .tracking import MarkerTracks


@dataclass
class LinkageFit:
    """Fixed geometry of the tracked linkage."""

    body_pivot_mm: np.ndarray        # a, in the camera frame as recorded (x, y)
    arm_pivot_body_mm: np.ndarray    # b − a in the right-handed frame at the first frame
    L1_mm: float
    body_fit_rms_mm: float           # RMS marker residual of 'body rotates about a'
    arm_fit_rms_mm: float            # same for the arm about b, in the body frame
    angle_noise_floor_rad: float     # quantisation floor for the joint angles


@dataclass
class JointAngles:
    time_s: np.ndarray
    theta1_cam_rad: np.ndarray
    theta3_rad: np.ndarray


def coordinate_resolution_mm(tracks: MarkerTracks) -> float:
    """Smallest step between distinct coordinate values: the tracker's quantisation."""
    steps = []
    for xy in tracks.markers_mm.values():
        for col in xy.T:
            u = np.unique(col[np.isfinite(col)])
            d = np.diff(u)
            d = d[d > 1e-9]
            if len(d):
                steps.append(np.percentile(d, 5))
    return float(np.median(steps)) if steps else 0.0


def _right_handed(tracks: MarkerTracks, names: list[str]) -> np.ndarray:
    """(n, m, 2) positions of the named markers, y flipped if the frame is left-handed."""
    pts = np.stack([_fill_gaps(tracks.time_s, tracks.markers_mm[n]) for n in names], axis=1)
    if tracks.handedness == 'left':
        pts = pts * np.array([1.0, -1.0])
    return pts


def _fill_gaps(time_s: np.ndarray, xy: np.ndarray) -> np.ndarray:
    ok = np.all(np.isfinite(xy), axis=1)
    if ok.all():
        return xy
    if ok.sum() < 2:
        raise ValueError('a marker is lost in almost every frame')
    return np.column_stack([np.interp(time_s, time_s[ok], xy[ok, k]) for k in range(2)])


def fit_linkage(tracks: MarkerTracks, arm_axis_offset_rad: float = 0.0,
                ) -> tuple[LinkageFit, JointAngles]:
    """Fit the body pivot, the arm pivot and L1; return them with θ1_cam(t) and θ3(t).

    Rigid-body fits, not per-marker circle fits:
    1. body pose per frame (2-D Kabsch on all body markers against their mean shape);
    2. body pivot a = the point fixed under that motion (:func:`fixed_point_of_motion`),
       refined to the maximum-likelihood fit of 'markers rotate rigidly about a fixed a'
       (:func:`fit_fixed_pivot`), which also gives θ1 as the rotation about a;
    3. arm markers moved into the body frame; arm pose relative to the body, likewise;
    4. arm pivot b = the point fixed in both the body frame and the arm frame; L1 = |a − b|.
    All frames count equally (the fits are maximum likelihood for iid marker noise).
    """
    tracks.validate()
    body = _right_handed(tracks, tracks.body_markers)
    arm = _right_handed(tracks, tracks.arm_markers)

    body_tpl, body_kabsch, body_c = rigid_poses(body, iterations=1)
    a0, a_tpl, _ = fixed_point_of_motion(body_kabsch, body_c)
    # Refine to the maximum-likelihood pivot; each frame then has one unknown, its rotation
    # about a, which is less noisy than the 3-DOF Kabsch pose.
    a, body_vecs, body_rot, body_rms = fit_fixed_pivot(body, a0, body_tpl - a_tpl)
    body_rot = _refine(body_rot, body_kabsch)
    # Arm markers in body-template coordinates, origin at a: R_kᵀ (p − a).
    arm_in_body = rotate(arm - a, -body_rot)
    arm_tpl, arm_kabsch, arm_c = rigid_poses(arm_in_body, iterations=1)
    b0, b_arm, _ = fixed_point_of_motion(arm_kabsch, arm_c)
    b_tpl, arm_vecs, arm_rot, arm_rms = fit_fixed_pivot(arm_in_body, b0, arm_tpl - b_arm)
    arm_rot = _refine(arm_rot, arm_kabsch)

    to_a = -b_tpl                              # b → a in body-template coordinates
    outer = int(np.argmax(np.linalg.norm(arm_vecs, axis=1)))
    axis0 = rotate(arm_vecs[outer][None, :], arm_rot[:1])[0]
    theta3 = signed_angle(axis0, to_a) - (arm_rot - arm_rot[0]) + arm_axis_offset_rad
    theta1_cam = np.arctan2(-to_a[1], -to_a[0]) + body_rot

    resolution = coordinate_resolution_mm(tracks)
    sigma_xy = resolution / np.sqrt(12.0)
    floor = (sigma_xy / np.sqrt(np.sum(body_vecs ** 2))
             + sigma_xy / np.sqrt(np.sum(arm_vecs ** 2)))

    pivot_cam = a * np.array([1.0, -1.0]) if tracks.handedness == 'left' else a
    b_minus_a0 = rotate(-to_a[None, :], body_rot[:1])[0]
    fit = LinkageFit(pivot_cam, b_minus_a0, float(np.linalg.norm(to_a)), body_rms, arm_rms,
                     float(floor))
    return fit, JointAngles(tracks.time_s, theta1_cam, theta3)


def _refine(angle_rad: np.ndarray, reference_rad: np.ndarray) -> np.ndarray:
    """Unwrap ``angle_rad`` onto the branch of ``reference_rad`` (same rotation, other 2π)."""
    return angle_rad + 2.0 * np.pi * np.round((reference_rad - angle_rad) / (2.0 * np.pi))


def tip_speed_mps(L1_mm: float, L3_mm: float, theta3_rad: np.ndarray,
                  omega1_radps: np.ndarray, omega3_radps: np.ndarray) -> np.ndarray:
    """|v_tip| from physics.md; mm·rad/s is mm/s, hence the 1e-3."""
    w_arm = omega1_radps - omega3_radps
    v2 = ((L1_mm * omega1_radps) ** 2 + (L3_mm * w_arm) ** 2
          - 2.0 * L1_mm * L3_mm * omega1_radps * w_arm * np.cos(theta3_rad))
    return 1e-3 * np.sqrt(np.maximum(v2, 0.0))
