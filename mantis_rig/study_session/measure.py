"""What a study measures of one trial's bag (mantis_sim.studies.rig_study.quantities):

- from the load cell and the stage, at once: the peak tendon force (N), the work done loading
  the spring (mJ: the tendon force integrated over the stage's travel from the start of the
  pull to the release) and the time from the start of the pull to the release (s); the release
  is the force stream's first jump, as the supervisor's monitor finds it;
- where the bag holds marker frames: the peak tip speed and the stored spring energy, as
  `mantis analyze` finds them;
- of a trial the simulated camera filmed (a study's ``video: true``): those two from the film
  instead, tracked into the tracker's CSV form (:func:`measure_filmed_trial`), as a video of
  the real rig is.
"""
from __future__ import annotations

import math
from pathlib import Path
import time

import numpy as np

from mantis_rig import contract
from mantis_rig.recording import TRIAL_CONDITIONS, TRIAL_OUTCOME, BagReader
from mantis_rig.recording.force_block import force_block_from_msg
from mantis_rig.recording.trial_summary import summarize
from mantis_sim.errors import InputError


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
        if values:
            out['markers_from'] = FROM_BAG
    out['analysis_note'] = note
    return out


#: how long a filmed trial's measurement waits for its film (wall time, from when it starts
#: waiting: the trial has ended, and its film renders after its marker frames)
FILM_WAIT_S = 300.0
FILM_POLL_S = 0.1
FILM_NAMES = ('video.cine', 'video.avi')
#: the row's ``markers_from``: where its tip speed and spring energy came from
FROM_BAG, FROM_VIDEO = 'bag', 'video'


def film_of(bag: Path) -> Path:
    """Where the simulated camera films a trial: its bag directory's ``video/``."""
    return Path(bag) / contract.FILM_FOLDER


def wait_for_film(film: Path, timeout_s: float = FILM_WAIT_S) -> tuple[Path | None, str]:
    """(the film's recording, '') once the folder ``film`` is there (the camera renames it
    into place whole), or (None, why) when the camera said it could not film or
    ``timeout_s`` of wall time passed."""
    failed = film.with_name(film.name + contract.FILM_FAILED_SUFFIX)
    deadline = time.monotonic() + timeout_s
    while True:
        if film.is_dir():
            for name in FILM_NAMES:
                if (film / name).is_file():
                    return film / name, ''
            return None, f'{film} holds no {" or ".join(FILM_NAMES)}'
        if failed.is_file():
            why = failed.read_text(encoding='utf-8', errors='replace').strip()
            return None, f'the camera did not film it: {why}'
        if time.monotonic() >= deadline:
            return None, f'no film in {film} within {timeout_s:g} s'
        time.sleep(FILM_POLL_S)


def _bag_conditions(bag: Path) -> dict:
    return BagReader(bag, warn=False).metadata(TRIAL_CONDITIONS) or {}


def film_quantities(bag: Path, tracks_csv: Path,
                    film_wait_s: float = FILM_WAIT_S) -> tuple[dict, str]:
    """(peak_tip_speed_mps and max_spring_energy_mJ, '' or why not) of a trial's film: waited
    for, tracked into ``tracks_csv`` (mantis_rig.video.to_csv: the calibration.yaml beside the
    film; the rate from the .cine, or for an .avi the camera's rate the bag records) and
    analysed as a tracker export with the bag's guide distance and contact angle."""
    from mantis_rig.video.to_csv import track_to_csv
    video, why = wait_for_film(film_of(bag), film_wait_s)
    if video is None:
        return {}, why
    conditions = _bag_conditions(bag)
    try:
        given = {'d_t_mm': float(conditions['d_t_mm']),
                 'contact_angle_deg': float(conditions['contact_angle_deg'])}
        rate_hz = None if video.suffix == '.cine' else float(conditions['frame_rate_hz'])
    except (KeyError, ValueError) as exc:
        return {}, f'{bag}: its trial conditions lack {exc} to analyse the film'
    tracks_csv = Path(tracks_csv)
    tracks_csv.parent.mkdir(parents=True, exist_ok=True)
    try:
        tracked = track_to_csv(video, tracks_csv, rate_hz=rate_hz)
    except InputError as exc:           # a recording or calibration that cannot be read
        return {}, f'{video}: {exc}'
    if tracked.damage:
        return {}, f'{video}: damaged: {tracked.damage}'
    values, why = marker_quantities(tracks_csv, given=given)
    return values, (f'{tracks_csv.name}: {why}' if why else '')


def measure_filmed_trial(bag: Path, tracks_csv: Path,
                         film_wait_s: float = FILM_WAIT_S) -> dict:
    """:func:`measure_trial` of a trial the simulated camera filmed: the force's quantities
    from the bag, the markers' from its film (never from the bag's marker frames: a film that
    does not come leaves them empty, with why in 'analysis_note'); 'markers_from': 'video'
    when they came."""
    out = force_quantities(bag)
    values, note = film_quantities(bag, tracks_csv, film_wait_s)
    out.update(values)
    out['analysis_note'] = note
    out['markers_from'] = FROM_VIDEO if values else ''
    return out


__all__ = ['FILM_WAIT_S', 'FROM_BAG', 'FROM_VIDEO', 'bag_has_markers', 'film_of',
           'film_quantities', 'force_quantities', 'marker_quantities', 'measure_filmed_trial',
           'measure_trial', 'wait_for_film']
