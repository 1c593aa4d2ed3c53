"""`mantis study attach DIR FILES...`: the tip speed and spring energy of trials filmed on the
rig, from their videos (tracked here, into ``DIR/tracks/<name>.csv``) or their videos' tracker
exports, each matched to its row by the name the study gave it (``<study>_run<NNN>_trial<NNN>``,
with .cine, .avi, .xlsx, .csv or .csv.gz), then every row judged again against its forecast. A
file that matches no trial, or one that did not end done, is refused with the names the study
expects; nothing is written then."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mantis_rig.study_session.measure import marker_quantities
from mantis_rig.study_session.record import DONE, RECORD_NAME, read_record
from mantis_rig.study_session.runner import judge_rows, plan_as_run, study_forecaster
from mantis_sim.errors import InputError

SUFFIXES = ('.xlsx', '.csv.gz', '.csv')
VIDEO_SUFFIXES = ('.cine', '.avi')
TRACKS = 'tracks'           # DIR/tracks/: the videos' tracks, in the tracker's CSV form


def export_stem(path: Path) -> str:
    name = path.name
    for suffix in SUFFIXES + VIDEO_SUFFIXES:
        if name.lower().endswith(suffix):
            return name[:-len(suffix)]
    raise InputError(f'{path}: not a video or a tracker export (expected '
                     f'{", ".join(VIDEO_SUFFIXES + SUFFIXES)})')


def attach_exports(directory: Path, exports: list, say=print,
                   track_video: Callable[[Path, Path], Path] | None = None) -> int:
    """Fill the rows of the study in ``directory`` from ``exports`` (videos, tracked by
    ``track_video(video, csv)`` into DIR/tracks/, or tracker exports); the rows filled."""
    directory = Path(directory)
    record = read_record(directory / RECORD_NAME)
    plan = plan_as_run(directory)
    by_video = {r['video']: r for r in record.rows if r.get('video')}
    matched = []
    for export in map(Path, exports):
        stem = export_stem(export)
        row = by_video.get(stem)
        if row is None:
            owed = [r['video'] for r in record.rows if r['status'] == DONE and r.get('video')]
            raise InputError(f'{export}: no trial of the study in {directory} is named {stem!r}; '
                             f'its trials are saved as {", ".join(owed[:3])}'
                             f'{", ..." if len(owed) > 3 else ""}')
        if row['status'] != DONE:
            raise InputError(f'{export}: run {row["run"]} ended {row["status"]}: there is no '
                             f'strike to attach')
        matched.append((export, row))
    if any(_is_video(e) for e, _ in matched) and track_video is None:
        raise InputError('a video needs tracking: attach it through `mantis study attach`')
    for export, row in matched:
        source = 'export'
        if _is_video(export):
            (directory / TRACKS).mkdir(exist_ok=True)
            export = track_video(export, directory / TRACKS / f'{row["video"]}.csv')
            source = 'video'
        row['markers_from'] = source
        given = {'d_t_mm': row['d_t_mm'], 'contact_angle_deg': row['contact_angle_deg']}
        values, why = marker_quantities(export, given=given)
        if why:
            raise InputError(f'{export}: cannot be analysed: {why}')
        row.update(values)
        say(f'run {row["run"]}: {export.name}: peak tip speed '
            f'{values["peak_tip_speed_mps"]:.4g} m/s, spring energy '
            f'{values["max_spring_energy_mJ"]:.4g} mJ')
    judge_rows(record.rows, study_forecaster(directory, plan, record.rows, say=say))
    record.save()
    return len(matched)


def _is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


__all__ = ['attach_exports']
