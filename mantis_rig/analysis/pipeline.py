"""The analysis pipeline: one trial's tracks (or joint angles) in, time series and a summary out
(the linkage fit, smoothing, phases, onset, energies, the checks on the result)."""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from mantis_sim.errors import InputError

from . import phases as ph
from .energy import (
    InertiaParams,
    kinetic_energies_mJ,
    model_theta1,
    spring_energy_mJ,
    tendon_length_mm,
    tendon_work_mJ,
)
from .inputs import MIN_FRAMES, MarkerTracks, TrackFormatError
from .kinematics import (
    MIN_STRIKE_ROTATION_RAD,
    STRIKE_SPEED_SHARE,
    JointAngles,
    LinkageFit,
    fit_linkage,
    tip_speed_mps,
)
from .onset import Onset, unlatch_onset
from .smoothing import (
    STRIKE_POLY,
    angle_noise_rad,
    linear_rate_noise,
    local_poly_fit,
    smooth_angle,
    smoothing_spline_fit,
)


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
    # θ3's zero. The camera sees the arm's rotation, not the direction of its axis (b → tip:
    # the tip is not tracked), so θ3 is known up to a constant. In order of precedence:
    # - contact_angle_rad: the latched contact angle measured on the rig (shim): θ3's
    #   latched level is set to it (physics.md: the arm rests at θ3 = φc);
    # - arm_axis_offset_rad: counter-clockwise angle (right-handed frame) from the b→tip line
    #   to the b→outermost-arm-marker line, an arm constant: θ3 is then absolute, and the
    #   contact angle is measured;
    # - neither: θ3 counts from the latch (zero while latched; contact angle reported NaN).
    #   This is the authors' θ3 (their series start at 0 with the contact angle kept aside).
    contact_angle_rad: float | None = None
    arm_axis_offset_rad: float | None = None
    # L1 of the tendon geometry (overcentering, tendon length): the camera sees neither the
    # attachment c nor the guide d, so L2, β and d_t are the design's, and so is the L1 they
    # are laid out with (physics.md: 19 mm). None: the fitted L1 instead. Tip speed and
    # kinetic energy use the fitted L1.
    tendon_L1_mm: float | None = 19.0
    # Frame of summary()['body_pivot_mm']: 'x_mirrored' (the left-handed tracker frame's x
    # negated: the frame of the published reference pivot), 'tracker' (as recorded) or
    # 'right_handed' (the left-handed tracker frame's y negated); both of these are the same
    # for a right-handed export of the same video (see pivot_in_frame).
    pivot_frame: str = 'x_mirrored'
    inertia: InertiaParams = field(default_factory=InertiaParams)
    # Smoothing: relative velocity precision and the widest window.
    rel_precision: float = 0.02
    max_window_s: float = 0.02
    # The strike's polynomial fits reach this share of the time from the start of IV to the
    # peak tip speed either side of a frame.
    strike_window_share: float = 1.0 / 7.0
    # Unlatching: refine the level crossing by fitting the arm's departure (analysis.onset).
    fit_unlatch_onset: bool = True
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
    peak_tip_speed: float = float('nan')         # m/s, at the sub-frame maximum
    strike_half_width: int = 0                  # frames, of the strike's polynomial fits
    linkage: LinkageFit | None = None
    angles: JointAngles | None = None           # the linkage's joint angles, as fitted
    body_pivot_mm: np.ndarray | None = None     # in AnalysisParams.pivot_frame
    overcentering_method: str = 'tendon geometry'   # or 'trajectory knee'
    lost_frames_in_strike: int = 0                  # gaps (lost markers) in phase IV
    # The unlatching's start from the departure's form (phases.unlatch_s is it when found);
    # None where the frames could not hold the fit and the level crossing stands.
    unlatch_onset: Onset | None = None
    params: AnalysisParams | None = None            # what it was analysed with
    # The earliest the start of IV can be where it was extrapolated back along θ̇1's rise
    # (phases.max_contraction_earliest); NaN where not.
    max_contraction_earliest_s: float = float('nan')

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
            'peak_tip_speed_mps': self.peak_tip_speed,
            'max_spring_energy_mJ': float(np.max(self.spring_energy_mJ)),
            'phase_start_s': {'I': p.loading_start_s, 'II': p.unlatch_s,
                              'III': p.overcentering_s, 'IV': p.max_contraction_s},
            'overcentering_s': p.overcentering_s,
            'overcentering_method': self.overcentering_method,
            'unlatch_method': ('departure form' if self.unlatch_onset is not None
                               else 'level crossing'),
            'peak_tip_speed_s': p.peak_tip_speed_s,
            'peak_body_speed_radps': float(np.max(self.omega1_radps[strike])),
            'peak_arm_speed_radps': float(np.max(self.omega3_radps[strike])),
            'contact_angle_deg': math.degrees(self.contact_angle_rad),
            'body_pivot_mm': pivot,
            'L1_mm': self.L1_mm,
            'lost_frames_in_strike': self.lost_frames_in_strike,
        }


def analyze_tracks(tracks: MarkerTracks, params: AnalysisParams | None = None,
                   speed_share: float = STRIKE_SPEED_SHARE) -> TrialAnalysis:
    """Fit the linkage to marker tracks (``speed_share``: its strike window,
    kinematics.strike_window), then analyse its joint angles (:func:`analyze_linkage`)."""
    params = params or AnalysisParams()
    offset = params.arm_axis_offset_rad
    linkage, angles = fit_linkage(tracks, 0.0 if offset is None else offset, speed_share)
    return analyze_linkage(tracks, linkage, angles, params)


def analyze_linkage(tracks: MarkerTracks, linkage: LinkageFit, angles: JointAngles,
                    params: AnalysisParams) -> TrialAnalysis:
    """The analysis of the joint angles of a fitted linkage (phases, speeds, energies), checked
    against the tracks it came from."""
    theta1 = model_theta1(angles.theta1_cam_rad, params.theta1_start_rad,
                          params.guide_direction_cam_rad)
    body = theta1 + (angles.body_angle_rad - angles.theta1_cam_rad)
    result = _analyze(angles.time_s, theta1, angles.theta3_rad, linkage.L1_mm, params,
                      linkage.angle_noise_floor_rad, body_raw=body,
                      body_floor_rad=linkage.body_noise_floor_rad)
    result.linkage, result.angles = linkage, angles
    result.body_pivot_mm = pivot_in_frame(linkage.body_pivot_mm, tracks.handedness,
                                          params.pivot_frame)
    result.lost_frames_in_strike = check_strike_tracked(result, tracks.time_s)
    check_plausible(result, tracks)
    return result


class StrikeLost(InputError):
    """The markers were lost where the peak tip speed is measured: no number is given."""


#: Frames either side of the peak that its fit needs (the local quintic's minimum half-width).
PEAK_FRAMES_NEEDED = 6


def check_strike_tracked(result: TrialAnalysis, frame_times_s: np.ndarray) -> int:
    """The number of frames lost (gaps: too few markers tracked on the body or the arm) from
    overcentering (phase III) to PEAK_FRAMES_NEEDED frames after the peak. A gap there after which
    tracking resumes is a hole in the strike: a fit across it would be a guess (the true peak
    may lie inside it), so :class:`StrikeLost` names the frames. Tracking that ends there for
    good is reported by the count (the strike's end is extrapolated)."""
    lost_s = np.setdiff1d(np.asarray(frame_times_s, float), result.time_s)
    if lost_s.size == 0:
        return 0
    frame_s = float(np.median(np.diff(frame_times_s)))
    p = result.phases
    # from overcentering on: a hole that hides the strike moves the phases it defines
    start = min(p.overcentering_s, p.max_contraction_s) - PEAK_FRAMES_NEEDED * frame_s
    end = p.peak_tip_speed_s + (PEAK_FRAMES_NEEDED + 0.5) * frame_s
    in_strike = lost_s[(lost_s >= start) & (lost_s <= end)]
    if in_strike.size and result.time_s[-1] > in_strike[-1]:
        resumed = float(result.time_s[np.searchsorted(result.time_s, in_strike[-1])])
        raise StrikeLost(
            f'the markers were lost inside the strike: {in_strike.size} frame(s) between '
            f't = {in_strike[0]:.5f} and {in_strike[-1]:.5f} s are gaps (too few markers '
            f'tracked on the body or the arm; tracking resumes at {resumed:.5f} s), so the '
            f'peak tip speed cannot be measured')
    return int(in_strike.size)


class ImplausibleResult(InputError):
    """The analysis gave a number the robot cannot produce: it is refused, with the reason."""


# What the robot can physically do (the rig's size and its spring): numbers outside are refused.
L1_RANGE_MM = (15.0, 25.0)
SPRING_ENERGY_RANGE_MJ = (0.0, 300.0)
TIP_SPEED_RANGE_MPS = (0.0, 60.0)
TENDON_WORK_LIMIT_MJ = 300.0          # |work| of the tendon over the trial: the spring's scale


def check_plausible(result: TrialAnalysis, tracks: MarkerTracks | None = None) -> None:
    """Raise :class:`ImplausibleResult` naming the first impossible number, and what likely
    caused it (a length unit that contradicts the numbers, lost markers read as positions)."""
    lo, hi = L1_RANGE_MM
    if not lo <= result.L1_mm <= hi:
        raise ImplausibleResult(_length_problem(result.L1_mm, tracks))
    s = result.summary()
    energy = s['max_spring_energy_mJ']
    if not SPRING_ENERGY_RANGE_MJ[0] <= energy <= SPRING_ENERGY_RANGE_MJ[1]:
        raise ImplausibleResult(
            f'max spring energy {energy:.0f} mJ is outside the robot\'s '
            f'{SPRING_ENERGY_RANGE_MJ[0]:g}-{SPRING_ENERGY_RANGE_MJ[1]:g} mJ: the body angle '
            'does not match the robot\'s frame (camera orientation, a calibration\'s left- or '
            'right-handed system that does not fit the numbers, or a lost marker)')
    v = s['peak_tip_speed_mps']
    if not (math.isfinite(v) and TIP_SPEED_RANGE_MPS[0] <= v <= TIP_SPEED_RANGE_MPS[1]):
        raise ImplausibleResult(
            f'peak tip speed {v:.1f} m/s is outside the robot\'s '
            f'{TIP_SPEED_RANGE_MPS[0]:g}-{TIP_SPEED_RANGE_MPS[1]:g} m/s')
    if result.tendon_work_mJ is not None:
        work = float(np.nanmax(np.abs(result.tendon_work_mJ)))
        if not (math.isfinite(work) and work <= TENDON_WORK_LIMIT_MJ):
            raise ImplausibleResult(
                f'tendon work {work:.4g} mJ is beyond the robot\'s {TENDON_WORK_LIMIT_MJ:g} mJ: '
                f'the recorded force is not the tendon\'s (load-cell scale or units)')
    starts = [(k, x) for k, x in s['phase_start_s'].items() if math.isfinite(x)]
    starts.append(('peak tip speed', s['peak_tip_speed_s']))
    for (k0, t0), (k1, t1) in zip(starts, starts[1:]):
        if not t0 <= t1:
            raise ImplausibleResult(f'phases out of order: {k0} at {t0:.5f} s comes after '
                                    f'{k1} at {t1:.5f} s')


def _length_problem(L1_mm: float, tracks: MarkerTracks | None) -> str:
    lo, hi = L1_RANGE_MM
    text = f'L1 = {L1_mm:.4g} mm is outside the robot\'s {lo:g}-{hi:g} mm'
    unit = tracks.length_unit if tracks is not None else None
    stated = f'the file says {unit}' if unit else 'the file states no unit'
    if lo <= L1_mm * 1e3 <= hi:
        return (f'{text}: the lengths look a thousand times too small ({stated}); if the '
                'numbers are millimetres, give --length-unit mm')
    if lo <= L1_mm * 1e-3 <= hi:
        return (f'{text}: the lengths look a thousand times too large ({stated}); if the '
                'numbers are micrometres, give --length-unit um')
    return f'{text}: the markers do not describe the robot\'s linkage'


PIVOT_FRAMES = ('x_mirrored', 'tracker', 'right_handed')


def pivot_in_frame(pivot_tracker_mm: np.ndarray, handedness: str, frame: str) -> np.ndarray:
    """A point given in the tracker's frame, expressed in one of :data:`PIVOT_FRAMES`.

    'x_mirrored' and 'right_handed' are the lab's left-handed export's frame (at the
    calibration's tilt) with x, or y, negated: a right-handed export of the same video, whose
    y is the left-handed one's negated, gives the same point."""
    point = np.array(pivot_tracker_mm, float)
    if frame == 'tracker':
        return point
    left = point * np.array([1.0, -1.0]) if handedness == 'right' else point
    if frame == 'x_mirrored':
        return left * np.array([-1.0, 1.0])
    if frame == 'right_handed':
        return left * np.array([1.0, -1.0])
    raise ValueError(f'pivot_frame {frame!r}: expected one of {PIVOT_FRAMES}')


def analyze_angles(time_s: np.ndarray, theta1_rad: np.ndarray, theta3_rad: np.ndarray,
                   params: AnalysisParams | None = None, L1_mm: float = 19.0,
                   noise_floor_rad: float = 1e-7) -> TrialAnalysis:
    """Analyse joint angles given directly in the model's convention (e.g. a simulation)."""
    time_s = np.asarray(time_s, float)
    if len(time_s) < MIN_FRAMES:
        raise TrackFormatError(f'too few frames: {len(time_s)} (need at least {MIN_FRAMES})')
    return _analyze(time_s, np.asarray(theta1_rad, float), np.asarray(theta3_rad, float),
                    L1_mm, params or AnalysisParams(), noise_floor_rad, absolute_theta3=True)


def _analyze(t: np.ndarray, theta1_raw: np.ndarray, theta3_raw: np.ndarray, L1_mm: float,
             params: AnalysisParams, noise_floor_rad: float, absolute_theta3: bool = False,
             body_raw: np.ndarray | None = None, body_floor_rad: float | None = None,
             ) -> TrialAnalysis:
    """``theta1_raw``: the link angle (direction a → b), ``theta3_raw`` the arm from that
    line; ``body_raw``: the body's rigid rotation (the spring's twist), equal to θ1 where the
    body turns about a (None: equal everywhere, no joint play). Phases that are about the body
    itself (loading, maximum spring contraction) and about the arm resting on it (the latch)
    use the body's rotation; the tendon geometry and the tip use the link angle.
    ``noise_floor_rad``: quantisation floor of θ3 (``body_floor_rad`` of θ1, default the same).
    """
    dt_s = float(np.median(np.diff(t)))
    floor1 = noise_floor_rad if body_floor_rad is None else body_floor_rad
    sig1 = angle_noise_rad(theta1_raw, floor1)
    sig3 = angle_noise_rad(theta3_raw, noise_floor_rad)
    th1, w1, h1 = smooth_angle(t, theta1_raw, sig1, params.rel_precision, params.max_window_s)
    th3, w3, h3 = smooth_angle(t, theta3_raw, sig3, params.rel_precision, params.max_window_s)
    if body_raw is None:
        body_raw = theta1_raw
        body, w_body, h_body, sig_body = th1, w1, h1, sig1
    else:
        sig_body = angle_noise_rad(body_raw, floor1)
        body, w_body, h_body = smooth_angle(t, body_raw, sig_body, params.rel_precision,
                                            params.max_window_s)
    play = th1 - body               # slow: the link turns less than the body while loading
    arm_on_body = th3 - play        # the arm relative to the body: constant while latched

    i_strike = ph.strike_index(w_body)
    rate_noise = linear_rate_noise(sig_body, h_body, dt_s)
    v_load = ph.loading_rate(t, body_raw, i_strike)
    exits = ph.band_exits(t, w_body, rate_noise, i_strike, v_load)
    t_iv, i_iv = ph.turn_time(t, w_body, exits)
    turned = float(np.max(body[i_iv:]) - body[i_iv])
    if turned < MIN_STRIKE_ROTATION_RAD:
        raise ValueError(f'no strike: after its slowest point (t = {t_iv:.4f} s) the body '
                         f'turns back by {turned:.3g} rad only')
    strike_k = _strike_rates(t, theta1_raw, theta3_raw, th1, th3, w1, w3, i_iv, L1_mm,
                             params)
    # Level thresholds use the per-frame noise: a marker settling across a quantisation
    # boundary is a real sub-pixel step that averaging does not remove.
    thr_body = ph.LEVEL_SIGMAS * sig_body
    thr3 = ph.LEVEL_SIGMAS * sig3
    if ph.loading_under_way(t, body_raw, sig_body):
        t_load, i_load = float('nan'), 0          # began before the first frame
    else:
        t_load = ph.loading_start(t, body, thr_body, i_iv, int(np.max(h_body)))
        i_load = int(np.searchsorted(t, t_load))
    t_unlatch = ph.unlatch_time(t, arm_on_body, thr3, i_load, i_iv)
    i_unlatch = int(np.searchsorted(t, t_unlatch))
    onset = (unlatch_onset(t, theta3_raw - play, arm_on_body, sig3, t_unlatch, i_iv, i_load)
             if params.fit_unlatch_onset else None)
    # θ3's latched level: the arm rests on the body, a constant angle to it; to the link it
    # is that angle in the rest pose, where loading starts (while loading, the link turns
    # less than the body if the joint has play, and the arm with the body).
    contact = float(np.median(arm_on_body[i_load:i_unlatch + 1]) + play[i_load])
    if params.contact_angle_rad is not None:
        th3 = th3 + (params.contact_angle_rad - contact)
        contact = float(params.contact_angle_rad)
    elif params.arm_axis_offset_rad is None and not absolute_theta3:
        th3 = th3 - contact
        contact = float('nan')
    tip = tip_speed_mps(L1_mm, params.L3_mm, th3, w1, w3)
    i_peak = ph.peak_after(tip, i_iv)
    t_peak, v_peak = ph.peak_time_and_value(t, tip, i_peak)
    tendon_L1 = L1_mm if params.tendon_L1_mm is None else params.tendon_L1_mm
    residual = ph.overcentering_residual(th1, th3, tendon_L1, params.beta_rad, params.d_t_mm)
    t_oc = ph.geometric_overcentering(t, residual, i_unlatch, i_iv + 1)
    t_knee = (ph.trajectory_knee_time(t, th1, th3, i_unlatch, i_iv)
              if i_iv - i_unlatch > 20 else float('nan'))

    ke_body, ke_arm = kinetic_energies_mJ(L1_mm, th3, w1, w3, params.inertia)
    work = None
    if params.tendon_force_N is not None:
        force = np.interp(t, params.tendon_force_time_s, params.tendon_force_N)
        lt = tendon_length_mm(th1, th3, tendon_L1, params.L2_mm, params.beta_rad,
                              params.d_t_mm)
        work = tendon_work_mJ(force, lt)

    oc_method = 'tendon geometry'
    if not math.isfinite(t_oc) and math.isfinite(t_knee):
        # The tendon line never crosses the pivot in the assumed geometry (the guide's
        # direction is not seen, and the set-up's θ1 varies by ±0.25 rad between trials): the
        # knee of the (θ1, θ3) path, where the tendon stops holding the arm, stands in.
        t_oc, oc_method = t_knee, 'trajectory knee'
    times = ph.PhaseTimes(t_load, t_unlatch if onset is None else onset.start_s, t_oc, t_iv,
                          t_peak, i_iv, i_peak)
    iv_earliest = ph.max_contraction_earliest(t, exits, v_load, t_oc)
    return TrialAnalysis(
        time_s=t, theta1_rad=th1, theta3_rad=th3, omega1_radps=w1, omega3_radps=w3,
        tip_speed_mps=tip,
        spring_energy_mJ=spring_energy_mJ(body, params.k_s_Nmm_per_rad,
                                          params.theta1_rest_rad),
        ke_body_mJ=ke_body, ke_arm_mJ=ke_arm, overcentering_residual_mm=residual,
        tendon_work_mJ=work, phases=times, L1_mm=float(L1_mm), contact_angle_rad=contact,
        overcentering_trajectory_s=t_knee, peak_tip_speed=v_peak, strike_half_width=strike_k,
        overcentering_method=oc_method, unlatch_onset=onset,
        max_contraction_earliest_s=iv_earliest, params=params,
    )


# Below this half-width (frames) a local quintic's rate is dominated by the frames' noise (at
# 6,000 frames/s the strike spans ~20 frames): the strike is fitted by one smoothing spline
# whose smoothness the data choose (generalised cross-validation) instead.
MIN_POLY_HALF_WIDTH = 6


def _strike_rates(t, theta1_raw, theta3_raw, th1, th3, w1, w3, i_iv, L1_mm, params) -> int:
    """Replace the smoothed angles and rates of the strike (in place) by local polynomial fits
    (:func:`smoothing.strike_half_width`): from the start of IV to as far past the peak tip
    speed as the peak lies after the start. Where the strike spans too few frames for them
    (:data:`MIN_POLY_HALF_WIDTH`), by a smoothing spline through the strike and as many frames
    either side. Returns the half-width used (0: none)."""
    dt_s = float(np.median(np.diff(t)))
    i_peak = ph.peak_after(tip_speed_mps(L1_mm, params.L3_mm, th3, w1, w3), i_iv)
    stop = min(len(t), i_peak + max(i_peak - i_iv, 1) + 1)
    region = slice(i_iv, stop)
    if stop - i_iv < 2 * STRIKE_POLY or len(t) < 8 * STRIKE_POLY:
        return 0
    k = max(STRIKE_POLY // 2 + 2, int(round(params.strike_window_share * (i_peak - i_iv))))
    k = min(k, (len(t) - 1) // 2 - 1)
    if k < MIN_POLY_HALF_WIDTH:
        span = slice(max(0, i_iv - (stop - i_iv)), min(len(t), stop + (stop - i_iv)))
        for raw, smooth, rate in ((theta1_raw, th1, w1), (theta3_raw, th3, w3)):
            fitted, fitted_rate = smoothing_spline_fit(t[span], raw[span])
            smooth[region] = fitted[i_iv - span.start:stop - span.start]
            rate[region] = fitted_rate[i_iv - span.start:stop - span.start]
        return k
    for raw, smooth, rate in ((theta1_raw, th1, w1), (theta3_raw, th3, w3)):
        fitted, fitted_rate = local_poly_fit(raw, dt_s, k)
        smooth[region] = fitted[region]
        rate[region] = fitted_rate[region]
    return k
