"""Pivots, link length and joint angles from marker tracks; tip speed from joint rates.

θ1 is the angle of the link a–b (physics.md): the direction of the arm pivot b seen from the
fitted body pivot a; θ3 the arm axis's angle to that line. The body's rigid rotation, measured
about the pivot of its regime (below), is kept alongside (``JointAngles.body_angle_rad``): with
joint play the link turns less than the body while the body turns about another point than a.
The pivots also set the constant offsets of θ1 and θ3 and the length L1 (see
:func:`fit_linkage`).

**Where the pivots are fitted: on the strike.** The joint has play. On the reference trial the
body's centre of rotation during the strike (phase IV and the body's rebound) lies 0.5 mm from
its centre during the seconds of loading, when the tendon loads the pin: one fixed pivot for
both leaves a systematic residual, and 'rotation about' the loading pivot overstates the strike
rotation by 3 % (about the strike pivot, the loading rotation is understated by 2.7 %; the
pivot-free Kabsch angle agrees with the regime-wise rotation in both). The strike is what the
tip speed, L1 and the phase-IV dynamics are about, so the linkage geometry is fitted on the
strike frames: from the start of phase IV (the body turns round at maximum spring contraction)
until the body's rebound has died down below ``STRIKE_SPEED_SHARE`` of its peak angular speed.
The pivot of the loading frames is kept (``LinkageFit.loading_pivot_mm``) and used for the body
angle before the strike. When the strike is not resolved (too few frames, too little rotation,
no strike in the tracks), the frames before it turn too little to pin a pivot of their own, or
the strike does not turn about a significantly different point (:func:`pivot_moved`), one
pivot is fitted on all frames.

Conventions (those of physics.md, in a right-handed frame):
- The tracking frame is left-handed (image y down); y is negated once, before any fit. That
  right-handed frame is the model's frame when the camera's x axis runs from the body pivot
  towards the tendon guide (the simulated camera's convention, and the authors' θ1).
- θ1_cam: direction of the link a→b (body pivot to arm pivot), counter-clockwise from the
  camera's +x axis. It differs from the model's θ1 by the direction of the guide hole, the
  model's x axis (see ``energy.model_theta1``). Loading turns the body clockwise (θ1 falls),
  the strike counter-clockwise.
- θ3: counter-clockwise angle from the arm axis (b → tip) to the link (b → a). θ3 = 0 is the
  arm folded onto the link; the arm opens with θ3 rising. The tip is not tracked, so the arm
  axis is taken as b → the arm marker farthest from b, plus an optional fixed offset
  ``arm_axis_offset_rad`` = counter-clockwise angle (right-handed frame) from the b → tip line
  to the b → outermost-marker line, an arm constant the markers cannot reveal.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import math

import numpy as np
from scipy import stats

from . import phases as ph
from .geometry import (
    complete_rigid_markers,
    fit_fixed_pivot,
    fixed_point_of_motion,
    rigid_poses,
    rotate,
    rotation_about,
    rotation_model_rms,
    signed_angle,
    template_point,
)
from .inputs import MarkerTracks
from .smoothing import (
    angle_noise_rad,
    full_window,
    linear_rate_noise,
    local_poly_fit,
    smooth_angle,
)

# The strike window ends when the body's angular speed has fallen below this share of its peak
# for good (the rebound has died down). On the reference trial shares of 0.02 .. 0.5 move the
# body pivot by <= 0.13 mm and L1 by <= 0.12 mm.
STRIKE_SPEED_SHARE = 0.1
# Below this the strike is not resolved well enough to fit pivots on: use all frames.
MIN_STRIKE_FRAMES = 25
MIN_STRIKE_ROTATION_RAD = 0.1
# The link's direction a -> b at the start of a trial in the robot-facing frame (camera x axis
# towards the tendon guide): 2.0-2.5 rad on every real trial seen (physics.md's set-up, 2.48).
# Only its half-plane is used, to tell a camera mounted the other way round (tilt 180°).
NOMINAL_THETA1_RAD = 2.3
# Significance level at which the strike is taken to rotate about another point than the
# loading (:func:`pivot_moved`).
PIVOT_SHIFT_P = 1e-3


@dataclass
class LinkageFit:
    """Fixed geometry of the tracked linkage."""

    body_pivot_mm: np.ndarray        # a, in the camera frame as recorded (x, y)
    arm_pivot_body_mm: np.ndarray    # b − a in the right-handed frame at the first frame
    L1_mm: float
    body_fit_rms_mm: float           # RMS marker residual of 'body rotates about a' (fit window)
    arm_fit_rms_mm: float            # same for the arm about b, in the body frame
    angle_noise_floor_rad: float     # quantisation floor for the arm angle θ3
    fit_window_s: tuple[float, float] = (float('nan'), float('nan'))
    strike_fit: bool = False         # pivots fitted on the strike (else on all frames)
    # Body pivot fitted on the frames before the strike (camera frame as recorded), NaN if
    # there is no strike; its distance from body_pivot_mm shows the joint's play.
    loading_pivot_mm: np.ndarray | None = None
    body_noise_floor_rad: float = 0.0    # quantisation floor for the body angle θ1
    # Rotation (deg) from the tracker's axes to the robot-facing frame: the calibration's tilt,
    # or 180 where no tilt is stated and the markers show the camera the other way round.
    robot_turn_deg: float = 0.0


@dataclass
class JointAngles:
    time_s: np.ndarray
    theta1_cam_rad: np.ndarray      # direction a → b from the camera's x axis (right-handed)
    theta3_rad: np.ndarray          # arm axis to the line b → a
    # The body's rigid rotation, on θ1_cam's zero at the first frame: equal to θ1_cam
    # without joint play, and in the strike (the body turns about a) up to a constant.
    body_angle_rad: np.ndarray | None = None


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
    """(n, m, 2) positions of the named markers in the robot-facing right-handed frame: the
    calibration's tilt undone (:func:`robot_turn_rad`), then y flipped if the tracker's frame
    is left-handed."""
    pts = np.stack([tracks.markers_mm[n] for n in names], axis=1)
    if tracks.handedness == 'left':
        pts = pts * np.array([1.0, -1.0])
    turn = robot_turn_rad(tracks)
    return rotate(pts, np.full(len(pts), turn)) if turn else pts


def robot_turn_rad(tracks: MarkerTracks) -> float:
    """Rotation (rad, counter-clockwise in the right-handed frame) that undoes the camera's
    tilt: the calibration's, or the one :func:`fit_linkage` found from the markers
    (``tracks.tilt_inferred``); none where neither states one."""
    return math.radians(float(tracks.tilt_deg or 0.0))


def complete_tracks(tracks: MarkerTracks) -> MarkerTracks:
    """The tracks with every lost marker placed by its body's pose from the markers still
    tracked (:func:`geometry.complete_rigid_markers`); frames where the body or the arm keeps
    fewer than two tracked markers are gaps and are left out (the analysis's time base skips
    them). Raises TrackFormatError if too few frames remain."""
    lost = any(np.isnan(xy).any() for xy in tracks.markers_mm.values())
    if not lost:
        return tracks
    markers: dict[str, np.ndarray] = {}
    keep = np.ones(tracks.n_frames, bool)
    notes = []
    for names in (tracks.body_markers, tracks.arm_markers):
        pts = np.stack([tracks.markers_mm[n] for n in names], axis=1)
        filled, ok, kept = complete_rigid_markers(pts)
        keep &= ok
        dropped = sorted(set(names) - {names[i] for i in kept})
        if dropped:
            notes.append(f'{",".join(dropped)} left out (too few frames with every marker)')
        markers.update({names[i]: filled[:, j] for j, i in enumerate(kept)})
    gaps = int((~keep).sum())
    if gaps:
        notes.append(f'{gaps} frames with fewer than 2 tracked markers on the body or the arm '
                     'are gaps')
    source = dict(tracks.source)
    source['gaps'] = '; '.join(notes) if notes else 'lost markers placed from the tracked ones'
    out = replace(tracks, time_s=tracks.time_s[keep], frames=tracks.frames[keep],
                  markers_mm={n: xy[keep] for n, xy in markers.items()}, source=source)
    out.validate()
    return out


def _to_camera(tracks: MarkerTracks, point: np.ndarray) -> np.ndarray:
    """A point of the analysis frame (:func:`_right_handed`) in the tracker's frame."""
    turn = robot_turn_rad(tracks)
    point = rotate(np.asarray(point, float)[None, :], np.array([-turn]))[0] if turn else point
    return point * np.array([1.0, -1.0]) if tracks.handedness == 'left' else point


def strike_window(time_s: np.ndarray, body_angle_rad: np.ndarray, noise_floor_rad: float,
                  speed_share: float = STRIKE_SPEED_SHARE) -> slice | None:
    """Frames of the strike: start of phase IV to the end of the body's rebound.

    The body angle (counter-clockwise, right-handed) is smoothed as in the analysis; phase IV
    starts where θ̇1 turns positive just before the body's fastest forward motion
    (:func:`phases.max_contraction`). The window ends once |θ̇1| has stayed below
    ``speed_share`` of that peak for as long as the body took from the start of IV to its peak
    (the rebound's swings pass through θ̇1 = 0 too, but briefly). None if there is no such
    strike, or it is too short or turns too little to fit a pivot on.
    """
    sigma = angle_noise_rad(body_angle_rad, noise_floor_rad)
    _, omega, half = smooth_angle(time_s, body_angle_rad, sigma)
    dt_s = float(np.median(np.diff(time_s)))
    i_peak = ph.strike_index(omega, full_window(half))
    try:
        t_iv, _ = ph.max_contraction(time_s, omega, linear_rate_noise(sigma, half, dt_s), i_peak,
                                     ph.loading_rate(time_s, body_angle_rad, i_peak))
    except (ValueError, IndexError):
        return None
    i_start = int(np.searchsorted(time_s, t_iv))
    fast = i_peak + np.nonzero(np.abs(omega[i_peak:]) > speed_share * omega[i_peak])[0]
    quiet = np.nonzero(np.diff(fast) > max(i_peak - i_start, 1))[0]
    i_stop = int(fast[quiet[0]] if len(quiet) else fast[-1]) + 1
    if (i_stop - i_start < MIN_STRIKE_FRAMES
            or np.ptp(body_angle_rad[i_start:i_stop]) < MIN_STRIKE_ROTATION_RAD):
        return None
    return slice(i_start, i_stop)


@dataclass
class _Pivot:
    point: np.ndarray        # fixed point, in the points' frame
    offsets: np.ndarray      # markers − point at the reference pose
    rms: float               # RMS marker residual


def _fixed_pivot(points: np.ndarray) -> _Pivot:
    """ML fixed pivot of a rigid marker set that rotates about it (ValueError if it does not)."""
    template, angle, centroid = rigid_poses(points, iterations=1)
    p0, q0, _ = fixed_point_of_motion(angle, centroid)
    p, offsets, _, rms = fit_fixed_pivot(points, p0, template - q0)
    return _Pivot(p, offsets, rms)


def pivot_moved(points: np.ndarray, own: _Pivot, other: np.ndarray,
                p_value: float = PIVOT_SHIFT_P) -> bool:
    """Do these frames rotate about their own fitted pivot rather than ``other``?

    F-test of the nested models 'rigid rotation about ``other``' (offsets and angles free) and
    'about a free pivot' (2 more unknowns), against the free fit's residual variance.
    """
    n, m, _ = points.shape
    rss_own = own.rms ** 2 * n * m
    rss_other = rotation_model_rms(points, other) ** 2 * n * m
    dof = 2 * n * m - (n + 2 * m + 2)
    if dof <= 0 or rss_own <= 0.0:
        return False
    f_stat = 0.5 * (rss_other - rss_own) / (rss_own / dof)
    return bool(f_stat > stats.f.isf(p_value, 2, dof))


def _rotation(points: np.ndarray, pivot: _Pivot, reference: np.ndarray) -> np.ndarray:
    """Rotation about the pivot in every frame, on the 2π branch and zero of ``reference``."""
    angle = rotation_about(pivot.point, pivot.point + pivot.offsets, points)
    return angle + np.median(reference - angle)


def _body_fit(body: np.ndarray, time_s: np.ndarray, sigma_xy: float, speed_share: float,
              ) -> tuple[_Pivot, _Pivot | None, np.ndarray, slice]:
    """(pivot for the linkage, loading pivot or None, body angle per frame, frames fitted on).

    One fixed pivot on all frames first; its rotation (less noisy than the Kabsch angle)
    locates the strike. With a resolved strike: the strike pivot, unless the strike frames
    are explained as well by the pivot of the frames before it (then the all-frames pivot,
    the better-determined one). The body angle is the rotation about each regime's pivot,
    joined where the body rests at the end of loading.
    """
    _, kabsch, _ = rigid_poses(body, iterations=2)
    pooled = _fixed_pivot(body)
    pooled_angle = _rotation(body, pooled, kabsch)
    floor = sigma_xy / np.sqrt(np.sum(pooled.offsets ** 2))
    window = strike_window(time_s, pooled_angle, floor, speed_share)
    if window is None:
        return pooled, None, pooled_angle, slice(None)
    strike = _fixed_pivot(body[window])
    loading = None
    if window.start >= MIN_STRIKE_FRAMES:
        if np.ptp(pooled_angle[:window.start]) < MIN_STRIKE_ROTATION_RAD:
            # The frames before the strike turn too little to pin a pivot of their own (a
            # camera window that starts late in the loading): play cannot be told from
            # a poorly fixed loading pivot, and one pivot for all frames is the better fit
            # (the strike's arc alone pins the pivot along the body poorly: its sagitta is
            # about a pixel).
            return pooled, None, pooled_angle, slice(None)
        try:
            loading = _fixed_pivot(body[:window.start])
        except ValueError:                  # the body did not turn before the strike
            loading = None
    if loading is not None and not pivot_moved(body[window], strike, loading.point):
        return pooled, loading, pooled_angle, slice(None)
    angle = _rotation(body, strike, kabsch)
    if loading is not None:
        pre = slice(0, window.start)
        before = _rotation(body[pre], loading, kabsch[pre])
        n = min(MIN_STRIKE_FRAMES, window.start)
        angle[pre] = before + np.mean(angle[window.start - n:window.start] - before[-n:])
    return strike, loading, angle, window


# The body pose that carries the arm's centre: a local quintic through this many frames either
# side (the body turns at most ~5 mrad a frame in a strike: the fit follows it).
BODY_POSE_HALF_WIDTH = 6


def _smoothed_body_point(centroid: np.ndarray, angle_rad: np.ndarray, point: np.ndarray,
                         ) -> np.ndarray:
    """Camera position per frame of a body-template point, from a smoothed body pose."""
    if len(angle_rad) > 2 * BODY_POSE_HALF_WIDTH + 1:
        angle_rad = local_poly_fit(angle_rad, 1.0, BODY_POSE_HALF_WIDTH)[0]
        centroid = np.column_stack([local_poly_fit(centroid[:, k], 1.0,
                                                   BODY_POSE_HALF_WIDTH)[0] for k in range(2)])
    return centroid + rotate(np.broadcast_to(point, centroid.shape), angle_rad)


def _rotation_about_moving(centre: np.ndarray, offsets: np.ndarray, points: np.ndarray,
                           ) -> np.ndarray:
    """Least-squares rotation (unwrapped) of markers ≈ centre_k + R(φ_k) offsets."""
    v = points - centre[:, None, :]
    cross = np.sum(offsets[None, :, 0] * v[..., 1] - offsets[None, :, 1] * v[..., 0], axis=1)
    dot = np.sum(offsets[None, :, 0] * v[..., 0] + offsets[None, :, 1] * v[..., 1], axis=1)
    return np.unwrap(np.arctan2(cross, dot))


def fit_linkage(tracks: MarkerTracks, arm_axis_offset_rad: float = 0.0,
                speed_share: float = STRIKE_SPEED_SHARE) -> tuple[LinkageFit, JointAngles]:
    """Fit the body pivot, the arm pivot and L1; return them with θ1_cam(t) and θ3(t).

    1. body pose per frame (2-D Kabsch on all body markers against their mean shape) and one
       maximum-likelihood fixed pivot for all frames (:func:`geometry.fit_fixed_pivot`,
       started from :func:`geometry.fixed_point_of_motion`);
    2. the strike window (:func:`strike_window`) from the rotation about that pivot;
    3. body pivot a = the same fit on the strike, and the loading pivot on the frames before
       it; if the strike frames do not rotate about a significantly different point
       (:func:`pivot_moved`), the all-frames pivot instead;
    4. body angle = rotation about the pivot of each regime, joined at the end of loading
       (rotation about the right centre is unbiased and less noisy than the Kabsch angle);
    5. arm markers in the body frame (body angle, marker centroid); the arm pivot b = the
       fixed point of the arm's motion relative to the body, on the same frames as a; arm
       angle = rotation about b, placed in the camera by the (lightly smoothed) body pose;
    6. L1 = |a − b| in the body frame; θ1_cam = direction of b (carried by the body's pose)
       seen from a; θ3 = angle from the arm axis to b→a.
    """
    tracks.validate()
    tracks = complete_tracks(tracks)
    fit, angles = _fit_linkage(tracks, arm_axis_offset_rad, speed_share)
    if tracks.tilt_deg is None and math.cos(angles.theta1_cam_rad[0] - NOMINAL_THETA1_RAD) < 0:
        # No calibration states the camera's tilt, and the link points away from where the
        # robot's frame has it: the camera looks the other way round (a tilt of 180°).
        tracks = replace(tracks, tilt_deg=180.0, tilt_inferred=True)
        fit, angles = _fit_linkage(tracks, arm_axis_offset_rad, speed_share)
    fit.robot_turn_deg = math.degrees(robot_turn_rad(tracks))
    return fit, angles


def _fit_linkage(tracks: MarkerTracks, arm_axis_offset_rad: float, speed_share: float,
                 ) -> tuple[LinkageFit, JointAngles]:
    body = _right_handed(tracks, tracks.body_markers)
    arm = _right_handed(tracks, tracks.arm_markers)
    t = tracks.time_s

    sigma_xy = coordinate_resolution_mm(tracks) / np.sqrt(12.0)
    a, loading, body_rot, fit_on = _body_fit(body, t, sigma_xy, speed_share)
    body_c = body.mean(axis=1)

    arm_in_body = rotate(arm - body_c[:, None, :], -body_rot)   # body-template coordinates
    b = _fixed_pivot(arm_in_body[fit_on])
    # In the gauge of b.offsets: arm markers ≈ b + R(arm_rot) offsets (body frame), i.e.
    # b_cam + R(body_rot + arm_rot) offsets in the camera. The arm's rotation is measured
    # about b where a lightly smoothed body pose puts it: the body's pose noise would
    # otherwise move the centre and add half as much again to the arm's angle noise.
    b_cam = _smoothed_body_point(body_c, body_rot, b.point)
    arm_rot = _rotation_about_moving(b_cam, b.offsets, arm) - body_rot

    a_tpl = template_point(a.point, body_rot[fit_on], body_c[fit_on])
    link = b.point - a_tpl                             # a → b, body-template coordinates
    outer = int(np.argmax(np.linalg.norm(b.offsets, axis=1)))
    axis0 = rotate(b.offsets[outer][None, :], arm_rot[:1])[0]    # b → outer marker, frame 0
    body_angle = np.arctan2(link[1], link[0]) + body_rot      # the link turned with the body
    # b in the camera in every frame; θ1_cam is the direction a → b seen from the fixed a. With
    # joint play this is not the body's rotation (b turns about the loading pivot, a is the
    # strike's): it is the link angle physics.md's θ1 is, and it places b where the tendon
    # geometry needs it. θ3 is measured from the arm axis to that same line (b → a).
    a_to_b = body_c + rotate(np.broadcast_to(b.point, body_c.shape), body_rot) - a.point
    theta1_cam = body_angle[0] + np.unwrap(
        signed_angle(np.array([np.cos(body_angle[0]), np.sin(body_angle[0])]), a_to_b))
    theta3 = (signed_angle(axis0, -link) - (arm_rot - arm_rot[0]) + arm_axis_offset_rad
              + theta1_cam - body_angle)

    body_floor = sigma_xy / np.sqrt(np.sum(a.offsets ** 2))
    floor = body_floor + sigma_xy / np.sqrt(np.sum(b.offsets ** 2))
    fit = LinkageFit(
        body_pivot_mm=_to_camera(tracks, a.point),
        arm_pivot_body_mm=rotate(link[None, :], body_rot[:1])[0],
        L1_mm=float(np.linalg.norm(link)), body_fit_rms_mm=a.rms, arm_fit_rms_mm=b.rms,
        angle_noise_floor_rad=float(floor),
        fit_window_s=(float(t[fit_on][0]), float(t[fit_on][-1])),
        strike_fit=fit_on != slice(None),
        loading_pivot_mm=(_to_camera(tracks, loading.point) if loading is not None
                          else np.full(2, np.nan)),
        body_noise_floor_rad=float(body_floor))
    return fit, JointAngles(t, theta1_cam, theta3, body_angle)


def tip_speed_mps(L1_mm: float, L3_mm: float, theta3_rad: np.ndarray,
                  omega1_radps: np.ndarray, omega3_radps: np.ndarray) -> np.ndarray:
    """|v_tip| from physics.md; mm·rad/s is mm/s, hence the 1e-3."""
    w_arm = omega1_radps - omega3_radps
    v2 = ((L1_mm * omega1_radps) ** 2 + (L3_mm * w_arm) ** 2
          - 2.0 * L1_mm * L3_mm * omega1_radps * w_arm * np.cos(theta3_rad))
    return 1e-3 * np.sqrt(np.maximum(v2, 0.0))
