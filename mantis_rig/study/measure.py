"""What a study measures of one trial's bag (mantis_sim.studies.rig_study.quantities):

- from the load cell and the stage, at once: the peak tendon force (N), the work done loading
  the spring (mJ: the tendon force integrated over the stage's travel from the start of the
  pull to the release) and the time from the start of the pull to the release (s); the release
  is the force stream's first jump, as the supervisor's monitor finds it;
- where the bag holds marker frames: the peak tip speed and the stored spring energy, as
  `mantis analyze` finds them.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mantis_rig import contract
from mantis_rig.recording import TRIAL_OUTCOME, BagReader
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_rig.recording.trial_summary import summarize


def force_quantities(bag: Path) -> dict:
    """peak_tendon_force_N, loading_work_mJ, release_time_s of a closed bag (NaN where the
    bag does not show them: no pull, no release): from the trial's outcome, which the
    supervisor's force monitor wrote as the trial ran; from the bag's streams where the outcome
    does not hold them (a bag of an older version, or recovered)."""
    outcome = BagReader(bag, warn=False).metadata(TRIAL_OUTCOME) or {}
    from_outcome = outcome_quantities(outcome)
    if from_outcome is not None:
        return from_outcome
    return stream_quantities(bag)


def outcome_quantities(outcome: dict) -> dict | None:
    """The force quantities a trial outcome states, or None if it lacks any of them."""
    try:
        states = dict(item.split('@') for item in outcome['states'].split(';') if '@' in item)
        peak, work = float(outcome['peak_force_n']), float(outcome['loading_work_mj'])
        release, pull = float(outcome['release_time_s']), float(states['pulling'])
    except (KeyError, ValueError):
        return None
    return {'peak_tendon_force_N': peak, 'loading_work_mJ': work,
            'release_time_s': release - pull}


def stream_quantities(bag: Path) -> dict:
    """The force quantities from the bag's force and stage streams."""
    summary = summarize(bag)
    out = {'peak_tendon_force_N': math.nan, 'loading_work_mJ': math.nan,
           'release_time_s': math.nan}
    if summary.force_samples:
        out['peak_tendon_force_N'] = float(summary.peak_force_n)
    pull_s, release_s = summary.state_time('pulling'), summary.release_s
    if pull_s is None or release_s is None or release_s <= pull_s:
        return out
    out['release_time_s'] = float(release_s - pull_s)
    out['loading_work_mJ'] = _loading_work_mJ(bag, summary.namespace, pull_s, release_s)
    return out


def _loading_work_mJ(bag: Path, namespace: str, start_s: float, end_s: float) -> float:
    """The integral of the tendon force over the stage's travel between two rig times."""
    force_topic = contract.resolve(contract.FORCE_BLOCK, namespace)
    stage_topic = contract.resolve(contract.JOINT_STATE, namespace)
    times, forces, stage_t, stage_x = [], [], [], []
    for message in BagReader(bag, warn=False).messages([force_topic, stage_topic]):
        if message.topic == force_topic:
            block = force_block_from_msg(message.message)
            t = block.t0_s + block.period_s * np.arange(block.force_n.size)
            keep = (t >= start_s) & (t <= end_s)
            times.append(t[keep])
            forces.append(block.force_n[keep])
        elif message.message.position:
            stamp = message.message.header.stamp
            stage_t.append(stamp.sec + stamp.nanosec * 1e-9)
            stage_x.append(message.message.position[0])
    if not times or len(stage_t) < 2:
        return math.nan
    t, f = np.concatenate(times), np.concatenate(forces)
    order = np.argsort(t)
    t, f = t[order], f[order]
    s_order = np.argsort(stage_t)
    x_m = np.interp(t, np.asarray(stage_t)[s_order], np.asarray(stage_x)[s_order])
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(x_m)) * 1e3)


def marker_quantities(path: Path, given: dict | None = None) -> tuple[dict, str]:
    """(peak_tip_speed_mps and max_spring_energy_mJ, '' or why not) of a bag with marker frames
    or of a tracker export, analysed as `mantis analyze` analyses it; ``given``: d_t_mm and
    contact_angle_deg for an export, which carries no conditions."""
    from mantis_rig.analysis.batch import OK, analyse_one
    row = analyse_one(path, given=given)
    if row['status'] != OK:
        return {}, row['reason']
    return {'peak_tip_speed_mps': float(row['peak_tip_speed_mps']),
            'max_spring_energy_mJ': float(row['max_spring_energy_mJ'])}, ''


def bag_has_markers(bag: Path) -> bool:
    reader = BagReader(bag, warn=False)
    return any(name.endswith(contract.MARKERS.name) and info.message_count
               for name, info in reader.topics.items())


def measure_trial(bag: Path) -> dict:
    """Every quantity the bag gives, and 'analysis_note': why its markers gave none ('' if
    they did or it has none)."""
    out = force_quantities(bag)
    note = ''
    if bag_has_markers(bag):
        values, note = marker_quantities(bag)
        out.update(values)
    out['analysis_note'] = note
    return out


__all__ = ['bag_has_markers', 'force_quantities', 'marker_quantities', 'measure_trial']
