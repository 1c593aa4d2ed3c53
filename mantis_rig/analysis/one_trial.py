"""One trial's analysis, as ``mantis analyze PATH`` runs it: a trial as read
(:class:`~.inputs.TrialInput`, from :func:`~.inputs.read_trial`), its parameters from its
conditions and the user's, through the pipeline (:func:`~.pipeline.analyze_tracks`), judged:
refused (:class:`TrialRefused`, saying why) or analysed with its warnings.
"""
from __future__ import annotations

from mantis_rig.analysis.bag_conditions import params_for_trial
from mantis_rig.analysis.inputs import TrialInput
from mantis_rig.analysis.pipeline import analyze_tracks
from mantis_sim.errors import InputError

#: The strike counts as recorded once the tip speed has fallen below this share of its peak.
STRIKE_END_SHARE = 0.5


def strike_recorded(analysis) -> bool:
    """True if the tip speed falls below STRIKE_END_SHARE of its peak after the peak."""
    i = analysis.phases.index_peak
    tip = analysis.tip_speed_mps
    return bool(i < len(tip) - 1 and tip[i + 1:].min() < STRIKE_END_SHARE * tip[i])


class TrialRefused(InputError):
    """A trial that was read but cannot be analysed; the message says why."""


def trial_params(trial: TrialInput, given: dict | None = None) -> tuple:
    """(AnalysisParams, where they came from) of a trial that was read: its conditions, and
    ``given``, stated by the user; its recorded force, if any."""
    try:
        params, sources = params_for_trial(trial.conditions, given=given or {})
    except InputError as exc:          # ConditionError (a condition out of range), SceneError
        raise TrialRefused(str(exc)) from exc
    if trial.force_N is not None:
        params.tendon_force_N, params.tendon_force_time_s = trial.force_N, trial.force_time_s
    return params, sources


def analyse_trial(trial: TrialInput, given: dict | None = None) -> tuple:
    """(analysis, warnings, where the parameters came from) of a trial that was read
    (:class:`~.inputs.TrialInput`), as ``mantis analyze`` analyses it: its conditions (and
    ``given``, stated by the user) set the parameters, recorded force gives the tendon's work.
    Raises :class:`TrialRefused` if it cannot be analysed, or if a damaged trial's data end
    before the strike is over; an undamaged trial that ends too early is analysed with a
    warning."""
    tracks = trial.tracks
    last = float(tracks.time_s[-1])
    params, sources = trial_params(trial, given)
    try:
        analysis = analyze_tracks(tracks, params)
    except (InputError, ValueError, IndexError) as exc:    # refused, or no fit on these data
        raise TrialRefused(
            f'not enough data before the damage: the data end at t = {last:.4f} s: {exc}'
            if trial.truncated else f'analysis failed: {exc}') from exc
    notes = []
    if analysis.lost_frames_in_strike:
        notes.append(f'tracking ends {analysis.lost_frames_in_strike} frame(s) into the strike '
                     f'(markers lost from then on): its end is extrapolated')
    if strike_recorded(analysis):
        return analysis, notes, sources
    why = (f'the data end at t = {last:.4f} s, before the strike is over (the tip speed '
           f'never falls below {STRIKE_END_SHARE:.0%} of its peak after it)')
    if trial.truncated:
        raise TrialRefused(f'not enough data before the damage: {why}')
    return analysis, notes + [f'{why}; phase times and peaks are not reliable'], sources
