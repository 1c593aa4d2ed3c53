"""Intervals of an analysis's numbers: what the tracking noise and the estimator's choices
leave uncertain in the peak tip speed, the most spring energy and the phase starts.

- **Tracking noise.** The markers tracked again, ``replicas`` times: each position moved by a
  jitter and rounded to the tracker's step once more, so that it moves by as much as tracking
  moved it (the step read off the tracks; the tracker's jitter TRACKING_NOISE_STEPS of it, as
  on the lab's seven exports: 0.03 px rms at 0.1 px steps), and the whole analysis run on each,
  the linkage fit included. The positions already hold one
  such draw: by local linearity the replicas' deviations from the trial's value scatter as the
  trial's value does about the truth, and reflected about it (the basic bootstrap: the trial's
  value minus the deviations' upper and lower quantiles) they also undo a bias the noise puts
  into a maximum.
- **The estimator's choices.** The trial analysed again with each other reasonable choice: the
  smoothing's velocity precision halved and doubled, the strike's polynomial window narrower
  and wider, the linkage's strike window narrower and wider. Which way the estimator errs is
  not known: the noise interval is widened to hold the trial's value moved by each choice's
  shift either way.
- **The resolution.** A phase start is found on the frames: its interval is widened by one
  frame either side; the spring energy by what the body angle's quantisation floor moves it.
- **The unlatching** is fitted by the form of the arm's departure (analysis.onset): its noise
  interval is that fit's profile likelihood, not the replicas', found on the starts tried.
- **The start of IV**, where it was extrapolated back along θ̇1's rise with a tangent, which a
  convex rise puts late: the interval reaches back to the earliest the convexity from
  overcentering on allows (phases.max_contraction_earliest).

The interval's level is LEVEL (80 %). A replica or a choice whose analysis fails (no strike
found in it, say) is counted and left out.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import functools
import math

import numpy as np

from mantis_sim.errors import InputError

from .inputs import MarkerTracks
from .kinematics import STRIKE_SPEED_SHARE, JointAngles, coordinate_resolution_mm
from .pipeline import AnalysisParams, TrialAnalysis, analyze_linkage, analyze_tracks

LEVEL = 0.8
#: The tracker's jitter in units of its step (mantis_sim.parameters.Camera: 0.03 px / 0.1 px).
TRACKING_NOISE_STEPS = 0.3
UNLATCHING = 'phase_start_s.II'
MAX_CONTRACTION = 'phase_start_s.IV'
#: The reported quantities: summary key (a dotted one is nested) -> unit.
QUANTITIES = {'peak_tip_speed_mps': 'm/s', 'max_spring_energy_mJ': 'mJ',
              UNLATCHING: 's', 'phase_start_s.III': 's', MAX_CONTRACTION: 's'}
# Each estimator choice and its alternatives (the defaults' half and double, or about so).
SMOOTHING_PRECISION = (0.5, 2.0)              # x AnalysisParams.rel_precision
STRIKE_WINDOW_SHARE = (1.0 / 10.0, 1.0 / 5.0)  # against the default 1/7
LINKAGE_SPEED_SHARE = (0.5, 2.0)              # x kinematics.STRIKE_SPEED_SHARE


@dataclass(frozen=True)
class Interval:
    value: float
    low: float
    high: float

    def holds(self, truth: float) -> bool:
        return self.low <= truth <= self.high


@dataclass(frozen=True)
class Intervals:
    quantities: dict            # summary key -> Interval
    replicas: int               # noise replicas analysed
    choices: int                # alternative choices analysed
    failed: int                 # replicas and choices whose analysis failed
    # Keys whose low end is only where the frames fitted begin: the frames do not bound them.
    open_below: tuple = ()

    def to_json(self) -> dict:
        return {'level': LEVEL, 'replicas': self.replicas, 'choices': self.choices,
                'failed': self.failed, 'open_below': list(self.open_below),
                **{key: {'low': i.low, 'high': i.high} for key, i in self.quantities.items()}}


def value_of(summary: dict, key: str) -> float:
    section, _, name = key.partition('.')
    value = summary[section][name] if name else summary[section]
    return math.nan if value is None else float(value)


def track_intervals(tracks: MarkerTracks, result: TrialAnalysis, replicas: int,
                    seed: int = 0, on_analysis=None) -> Intervals:
    """The intervals of ``result``, the analysis of ``tracks`` (with its own parameters).
    ``on_analysis(done, total)`` is called as each of the analyses they take finishes."""
    params = result.params
    rng = np.random.default_rng(seed)
    step_mm = coordinate_resolution_mm(tracks)
    # The unlatching's noise interval is its fit's own (below): the replicas need not fit it.
    retracked = replace(params, fit_unlatch_onset=False)
    choices = list(_choices(tracks, params, result.linkage, result.angles))  # the trial's fit
    summaries = []
    for done in range(1, replicas + len(choices) + 1):
        if done <= replicas:    # one copy of the markers at a time; tracks on no grid refused
            copy = _tracked_again(tracks, rng, step_mm)
            summaries.append(_summary_or_none(lambda c=copy: analyze_tracks(c, retracked)))
        else:
            summaries.append(_summary_or_none(choices[done - replicas - 1]))
        if on_analysis is not None:
            on_analysis(done, replicas + len(choices))
    failed = sum(s is None for s in summaries)
    noisy = [s for s in summaries[:replicas] if s is not None]
    chosen = [s for s in summaries[replicas:] if s is not None]
    trial = result.summary()
    resolution = _resolutions(tracks, params, trial, result.linkage, result.unlatch_onset)
    out, open_below = {}, []
    for key in QUANTITIES:
        value = value_of(trial, key)
        if key == UNLATCHING and result.unlatch_onset is not None:
            *noise, bounded = result.unlatch_onset.interval(LEVEL)
            if not bounded:
                open_below.append(key)
        else:
            noise = _basic_bootstrap(value, [value_of(s, key) for s in noisy])
        out[key] = _interval(value, noise, [value_of(s, key) for s in chosen
                                            if _same_method(s, trial, key)],
                             resolution.get(key, 0.0))
        earliest = result.max_contraction_earliest_s
        if key == MAX_CONTRACTION and earliest < out[key].low:
            out[key] = replace(out[key], low=earliest)
    return Intervals(out, replicas, len(chosen), failed, tuple(open_below))


def _resolutions(tracks: MarkerTracks, params: AnalysisParams, trial: dict, linkage,
                 onset) -> dict:
    """What the recording resolves at best: a phase start found on the frames to a frame (the
    unlatching fitted by its departure's form to the spacing of the starts tried); the
    spring energy, E = k (theta - rest)^2 / 2, to what the body angle's quantisation floor
    moves it, sqrt(2 k E) times that floor."""
    frame_s = float(np.median(np.diff(tracks.time_s)))
    energy = value_of(trial, 'max_spring_energy_mJ')
    out = {key: frame_s for key, unit in QUANTITIES.items() if unit == 's'}
    if onset is not None:
        out[UNLATCHING] = onset.step_s
    if math.isfinite(energy) and energy > 0:
        out['max_spring_energy_mJ'] = (math.sqrt(2.0 * params.k_s_Nmm_per_rad * energy)
                                       * linkage.body_noise_floor_rad)
    return out


def _tracked_again(tracks: MarkerTracks, rng: np.random.Generator,
                   step_mm: float) -> MarkerTracks:
    """The markers as the tracker might have reported them once more: each position moved by
    its jitter and rounded to the tracker's step again (a lost position stays lost)."""
    if not step_mm > 0:         # positions on no grid: no step to scale the jitter by
        raise InputError('--intervals: the tracks\' positions show no tracker step, which '
                         'sets the size of the re-tracking\'s jitter')
    moved = {}
    for name, xy in tracks.markers_mm.items():
        steps = np.round(xy / step_mm + rng.normal(0.0, retrack_sd_steps(), xy.shape))
        moved[name] = steps * step_mm
    return replace(tracks, markers_mm=moved)


@functools.cache
def retrack_sd_steps() -> float:
    """The jitter (in steps) that, rounded to the step from a position already on it, moves a
    position by as much as tracking did: the variance of the tracker's error, a rounding
    (1/12 step^2) on top of its jitter (TRACKING_NOISE_STEPS)."""
    from scipy.optimize import brentq
    from scipy.stats import norm
    target = 1.0 / 12.0 + TRACKING_NOISE_STEPS ** 2
    k = np.arange(1, 8)

    def variance(sd):           # of round(N(0, sd)): 2 sum k^2 P(round = k)
        p = norm.cdf((k + 0.5) / sd) - norm.cdf((k - 0.5) / sd)
        return 2.0 * float(np.sum(k * k * p))
    return float(brentq(lambda sd: variance(sd) - target, 0.05, 3.0))


def _choices(tracks: MarkerTracks, params: AnalysisParams, linkage, angles: JointAngles):
    """Analyses of the trial with each alternative choice (callables: run lazily)."""
    for factor in SMOOTHING_PRECISION:
        varied = replace(params, rel_precision=params.rel_precision * factor)
        yield lambda p=varied: analyze_linkage(tracks, linkage, angles, p)
    for share in STRIKE_WINDOW_SHARE:
        varied = replace(params, strike_window_share=share)
        yield lambda p=varied: analyze_linkage(tracks, linkage, angles, p)
    for factor in LINKAGE_SPEED_SHARE:
        yield lambda f=factor: analyze_tracks(tracks, params, STRIKE_SPEED_SHARE * f)


def _same_method(summary: dict, trial: dict, key: str) -> bool:
    """Whether a choice found ``key`` as the trial did: an unlatching that fell back to its
    level crossing, milliseconds late, is another estimate, not a choice's shift of it."""
    return key != UNLATCHING or summary['unlatch_method'] == trial['unlatch_method']


def _summary_or_none(run) -> dict | None:
    try:
        return run().summary()
    except (InputError, ValueError, IndexError, ArithmeticError):   # as analyse_trial refuses
        return None


def _basic_bootstrap(value: float, noisy: list[float]) -> tuple[float, float]:
    """The trial's value less the replicas' deviations' upper and lower quantiles."""
    noisy = np.array([v for v in noisy if math.isfinite(v)])
    if not math.isfinite(value) or noisy.size < 2:
        return math.nan, math.nan
    tail = (1.0 - LEVEL) / 2.0
    q_low, q_high = np.quantile(noisy, [tail, 1.0 - tail])
    return 2.0 * value - q_high, 2.0 * value - q_low


def _interval(value: float, noise: tuple[float, float], chosen: list[float],
              resolution: float = 0.0) -> Interval:
    """The noise's interval, widened by the choices' shifts either way and by ``resolution``
    either side (a time is found on the frames: within one of the truth at best)."""
    low, high = noise
    if not (math.isfinite(value) and math.isfinite(low) and math.isfinite(high)):
        return Interval(value, math.nan, math.nan)
    shifts = [abs(v - value) for v in chosen if math.isfinite(v)]
    if shifts:                          # which way the estimator errs is not known
        low, high = min(low, value - max(shifts)), max(high, value + max(shifts))
    return Interval(value, float(low - resolution), float(high + resolution))


__all__ = ['LEVEL', 'QUANTITIES', 'Interval', 'Intervals', 'track_intervals',
           'value_of']
