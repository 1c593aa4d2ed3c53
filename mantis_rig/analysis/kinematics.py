"""Pivots, link length and joint angles from marker tracks; tip speed from joint rates.

Conventions (those of physics.md, in a right-handed frame):
- The tracking frame is left-handed (image y down); y is negated once, before any fit.
- θ1_cam: direction of the body link a→b (body pivot to arm pivot), counter-clockwise from
  the camera's +x axis. It differs from the model's θ1 by a constant (the direction of the
  guide hole, the model's x axis), which the caller supplies; see ``energy.model_theta1``.
  Loading turns the body clockwise (θ1 falls), the strike counter-clockwise.
- θ3: counter-clockwise angle from the arm axis (b → tip) to the body link (b → a). θ3 = 0 is
  the arm folded onto the body; the arm opens with θ3 rising. The tip is not tracked, so the
  arm axis is taken as b → the arm marker farthest from b, plus an optional fixed offset
  (``arm_axis_offset_rad``) for when the marker-to-tip angle of the arm is known.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import fit_common_centre, rotate, rotation_about, signed_angle
from .tracking import MarkerTracks


@dataclass
class LinkageFit:
    """Fixed geometry of the tracked linkage."""

    body_pivot_mm: np.ndarray        # a, in the camera frame as recorded (x, y)
    arm_pivot_body_mm: np.ndarray    # b − a in the right-handed frame at the first frame
    L1_mm: float
    body_fit_rms_mm: float
    arm_fit_rms_mm: float
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
    """Fit the body pivot, the arm pivot and L1; return them with θ1_cam(t) and θ3(t)."""
    tracks.validate()
    body = _right_handed(tracks, tracks.body_markers)
    arm = _right_handed(tracks, tracks.arm_markers)

    a, _, body_rms = fit_common_centre([body[:, k] for k in range(body.shape[1])])
    body_rot = rotation_about(a, body[0], body)
    # Arm markers in the body frame (body pose of the first frame, origin at a).
    arm_in_body = rotate(arm - a, -body_rot)
    b, _, arm_rms = fit_common_centre([arm_in_body[:, k] for k in range(arm.shape[1])])
    arm_rot = rotation_about(b, arm_in_body[0], arm_in_body)

    rel0 = arm_in_body[0] - b
    outer = int(np.argmax(np.linalg.norm(rel0, axis=1)))
    theta3_0 = signed_angle(rel0[outer], -b) + arm_axis_offset_rad
    theta3 = theta3_0 - arm_rot
    theta1_cam = np.arctan2(b[1], b[0]) + body_rot

    resolution = coordinate_resolution_mm(tracks)
    sigma_xy = resolution / np.sqrt(12.0)
    radii_body = np.linalg.norm(body[0] - a, axis=1)
    radii_arm = np.linalg.norm(rel0, axis=1)
    floor = sigma_xy / np.sqrt(np.sum(radii_body ** 2)) + sigma_xy / np.sqrt(np.sum(radii_arm ** 2))

    pivot_cam = a * np.array([1.0, -1.0]) if tracks.handedness == 'left' else a
    fit = LinkageFit(pivot_cam, b, float(np.linalg.norm(b)), body_rms, arm_rms, float(floor))
    return fit, JointAngles(tracks.time_s, theta1_cam, theta3)


def tip_speed_mps(L1_mm: float, L3_mm: float, theta3_rad: np.ndarray,
                  omega1_radps: np.ndarray, omega3_radps: np.ndarray) -> np.ndarray:
    """|v_tip| from physics.md; mm·rad/s is mm/s, hence the 1e-3."""
    w_arm = omega1_radps - omega3_radps
    v2 = ((L1_mm * omega1_radps) ** 2 + (L3_mm * w_arm) ** 2
          - 2.0 * L1_mm * L3_mm * omega1_radps * w_arm * np.cos(theta3_rad))
    return 1e-3 * np.sqrt(np.maximum(v2, 0.0))
