"""Whole-trial analysis: tracks or joint angles in, time series and a summary out."""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from . import phases as ph
from .energy import (
    InertiaParams,
    kinetic_energies_mJ,
    model_theta1,
    spring_energy_mJ,
    tendon_length_mm,
    tendon_work_mJ,
)
from .kinematics import LinkageFit, fit_linkage, tip_speed_mps
from .smoothing import angle_noise_rad, smooth_angle
from .tracking import MIN_FRAMES, MarkerTracks, TrackFormatError


@dataclass
class AnalysisParams:
    """Model parameters (physics.md reference values) and analysis settings."""

    L3_mm: float = 18.66
    L2_mm: float = 1.5
    beta_rad: float = math.radians(140.24)
    d_t_mm: float = 23.0
    k_s_Nmm_per_rad: float = 47.7
    theta1_rest_rad: float = math.pi + math.radians(50.63)
    # θ1 mapping for tracked data (see energy.py): the direction of the guide hole from the
    # body pivot in the right-handed camera frame (y up), or else the model θ1 at the first
    # frame. Default: the camera's x axis runs towards the guide, as on the simulated rig and
    # in the authors' published θ1 (it starts at 2.31 rad on the reference trial).
    guide_direction_cam_rad: float | None = 0.0
    theta1_start_rad: float | None = None
    # Counter-clockwise angle (right-handed frame) from the b→tip line to the
    # b→outermost-arm-marker line: an arm constant, not visible to the camera.
    arm_axis_offset_rad: float = 0.0
    # The latched contact angle measured on the rig (shim), if known: θ3 is then offset so its
    # latched level equals it (the authors' convention: relative θ3 plus a per-trial θ3
    # initial value), instead of relying on arm_axis_offset_rad.
    contact_angle_rad: float | None = None
    # Frame of summary()['body_pivot_mm']: 'x_mirrored' (the tracker's x negated: the frame of
    # the published reference pivot), 'tracker' (as recorded) or 'right_handed' (y negated
    # for a left-handed tracker: the analysis and model frame).
    pivot_frame: str = 'x_mirrored'
    inertia: InertiaParams = field(default_factory=InertiaParams)
    # Smoothing: relative velocity precision and the widest window.
    rel_precision: float = 0.02
    max_window_s: float = 0.02
    # Optional tendon force samples (N) with their own time base (s).
    tendon_force_N: np.ndarray | None = None
    tendon_force_time_s: np.ndarray | None = None


@dataclass
class TrialAnalysis:
    time_s: np.ndarray
    theta1_rad: np.ndarray          # model θ1, smoothed
    theta3_rad: np.ndarray          # smoothed
    omega1_radps: np.ndarray
    omega3_radps: np.ndarray
    tip_speed_mps: np.ndarray
    spring_energy_mJ: np.ndarray
    ke_body_mJ: np.ndarray
    ke_arm_mJ: np.ndarray
    overcentering_residual_mm: np.ndarray
    tendon_work_mJ: np.ndarray | None
    phases: ph.PhaseTimes
    L1_mm: float
    contact_angle_rad: float
    overcentering_trajectory_s: float
    linkage: LinkageFit | None = None
    body_pivot_mm: np.ndarray | None = None     # in AnalysisParams.pivot_frame

    @property
    def arm_ke_share_at_peak(self) -> float:
        i = self.phases.index_peak
        total = self.ke_body_mJ[i] + self.ke_arm_mJ[i]
        return float(self.ke_arm_mJ[i] / total) if total > 0 else float('nan')

    def summary(self) -> dict:
        p = self.phases
        strike = slice(p.index_max_contraction, None)
        pivot = (self.body_pivot_mm.tolist() if self.body_pivot_mm is not None
                 else [float('nan'), float('nan')])
        return {
            'peak_tip_speed_mps': float(self.tip_speed_mps[p.index_peak]),
            'max_spring_energy_mJ': float(np.max(self.spring_energy_mJ)),
            'phase_start_s': {'I': p.loading_start_s, 'II': p.unlatch_s,
                              'III': p.overcentering_s, 'IV': p.max_contraction_s},
            'overcentering_s': p.overcentering_s,
            'peak_body_speed_radps': float(np.max(self.omega1_radps[strike])),
            'peak_arm_speed_radps': float(np.max(self.omega3_radps[strike])),
            'contact_angle_deg': math.degrees(self.contact_angle_rad),
            'body_pivot_mm': pivot,
            'L1_mm': self.L1_mm,
        }


def analyze_tracks(tracks: MarkerTracks, params: AnalysisParams | None = None) -> TrialAnalysis:
    """Fit the linkage to marker tracks, then run :func:`analyze_angles` on its angles."""
    params = params or AnalysisParams()
    linkage, angles = fit_linkage(tracks, params.arm_axis_offset_rad)
    theta1 = model_theta1(angles.theta1_cam_rad, params.theta1_start_rad,
                          params.guide_direction_cam_rad)
    result = _analyze(angles.time_s, theta1, angles.theta3_rad, linkage.L1_mm, params,
                      linkage.angle_noise_floor_rad)
    result.linkage = linkage
    result.body_pivot_mm = pivot_in_frame(linkage.body_pivot_mm, tracks.handedness,
                                          params.pivot_frame)
    return result


PIVOT_FRAMES = ('x_mirrored', 'tracker', 'right_handed')


def pivot_in_frame(pivot_tracker_mm: np.ndarray, handedness: str, frame: str) -> np.ndarray:
    """A point given in the tracker's frame, expressed in one of :data:`PIVOT_FRAMES`."""
    if frame == 'tracker':
        return np.array(pivot_tracker_mm, float)
    if frame == 'x_mirrored':
        return np.array(pivot_tracker_mm, float) * np.array([-1.0, 1.0])
    if frame == 'right_handed':
        flip = [1.0, -1.0] if handedness == 'left' else [1.0, 1.0]
        return np.array(pivot_tracker_mm, float) * np.array(flip)
    raise ValueError(f'pivot_frame {frame!r}: expected one of {PIVOT_FRAMES}')


def analyze_angles(time_s: np.ndarray, theta1_rad: np.ndarray, theta3_rad: np.ndarray,
                   params: AnalysisParams | None = None, L1_mm: float = 19.0,
                   noise_floor_rad: float = 1e-7) -> TrialAnalysis:
    """Analyse joint angles given directly in the model's convention (e.g. a simulation)."""
    time_s = np.asarray(time_s, float)
    if len(time_s) < MIN_FRAMES:
        raise TrackFormatError(f'too few frames: {len(time_s)} (need at least {MIN_FRAMES})')
    return _analyze(time_s, np.asarray(theta1_rad, float), np.asarray(theta3_rad, float),
                    L1_mm, params or AnalysisParams(), noise_floor_rad)


def _analyze(t: np.ndarray, theta1_raw: np.ndarray, theta3_raw: np.ndarray, L1_mm: float,
             params: AnalysisParams, noise_floor_rad: float) -> TrialAnalysis:
    sig1 = angle_noise_rad(theta1_raw, noise_floor_rad)
    sig3 = angle_noise_rad(theta3_raw, noise_floor_rad)
    th1, w1, h1 = smooth_angle(t, theta1_raw, sig1, params.rel_precision, params.max_window_s)
    th3, w3, h3 = smooth_angle(t, theta3_raw, sig3, params.rel_precision, params.max_window_s)

    i_strike = ph.strike_index(w1)
    dt_s = float(np.median(np.diff(t)))
    t_iv, i_iv = ph.max_contraction(t, w1, sig1 / ((2 * h1 + 1) * dt_s), i_strike)
    # Level thresholds use the per-frame noise: a marker settling across a quantisation
    # boundary is a real sub-pixel step that averaging does not remove.
    thr1 = ph.LEVEL_SIGMAS * sig1
    thr3 = ph.LEVEL_SIGMAS * sig3
    t_load = ph.loading_start(t, th1, thr1, i_iv, int(np.max(h1)))
    i_load = int(np.searchsorted(t, t_load))
    t_unlatch = ph.unlatch_time(t, th3, thr3, i_load, i_iv)
    i_unlatch = int(np.searchsorted(t, t_unlatch))
    contact = float(np.median(th3[i_load:i_unlatch + 1]))
    if params.contact_angle_rad is not None:
        th3 = th3 + (params.contact_angle_rad - contact)
        contact = float(params.contact_angle_rad)
    tip = tip_speed_mps(L1_mm, params.L3_mm, th3, w1, w3)
    i_peak = ph.peak_after(tip, i_iv)
    residual = ph.overcentering_residual(th1, th3, L1_mm, params.beta_rad, params.d_t_mm)
    t_oc = ph.geometric_overcentering(t, residual, i_unlatch, i_iv + 1)
    t_knee = (ph.trajectory_knee_time(t, th1, th3, i_unlatch, i_iv)
              if i_iv - i_unlatch > 20 else float('nan'))

    ke_body, ke_arm = kinetic_energies_mJ(L1_mm, th3, w1, w3, params.inertia)
    work = None
    if params.tendon_force_N is not None:
        force = np.interp(t, params.tendon_force_time_s, params.tendon_force_N)
        lt = tendon_length_mm(th1, th3, L1_mm, params.L2_mm, params.beta_rad, params.d_t_mm)
        work = tendon_work_mJ(force, lt)

    times = ph.PhaseTimes(t_load, t_unlatch, t_oc, t_iv, float(t[i_peak]), i_iv, i_peak)
    return TrialAnalysis(
        time_s=t, theta1_rad=th1, theta3_rad=th3, omega1_radps=w1, omega3_radps=w3,
        tip_speed_mps=tip,
        spring_energy_mJ=spring_energy_mJ(th1, params.k_s_Nmm_per_rad, params.theta1_rest_rad),
        ke_body_mJ=ke_body, ke_arm_mJ=ke_arm, overcentering_residual_mm=residual,
        tendon_work_mJ=work, phases=times, L1_mm=float(L1_mm), contact_angle_rad=contact,
        overcentering_trajectory_s=t_knee,
    )
