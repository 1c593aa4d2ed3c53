"""`mantis study attach DIR EXPORTS...`: the tip speed and spring energy of trials filmed on the
rig, from their videos' tracker exports, each matched to its row by the name the study gave it
(``<study>_run<NNN>_trial<NNN>``, with .xlsx, .csv or .csv.gz), then every row judged again
against its forecast. An export that matches no trial, or one that did not end done, is
refused with the names the study expects; nothing is written then."""
from __future__ import annotations

from pathlib import Path

from mantis_sim.errors import InputError

from .measure import marker_quantities
from .record import DONE, RECORD_NAME, read_record
from .runner import judge_rows, plan_as_run, study_forecaster

SUFFIXES = ('.xlsx', '.csv.gz', '.csv')


def export_stem(path: Path) -> str:
    name = path.name
    for suffix in SUFFIXES:
        if name.lower().endswith(suffix):
            return name[:-len(suffix)]
    raise InputError(f'{path}: not a tracker export (expected {", ".join(SUFFIXES)})')


def attach_exports(directory: Path, exports: list, say=print) -> int:
    """Fill the rows of the study in ``directory`` from ``exports``; the rows filled."""
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
    for export, row in matched:
        given = {'d_t_mm': row['d_t_mm'], 'contact_angle_deg': row['contact_angle_deg']}
        values, why = marker_quantities(export, given=given)
        if why:
            raise InputError(f'{export}: cannot be analysed: {why}')
        row.update(values)
        say(f'run {row["run"]}: {export.name}: peak tip speed '
            f'{values["peak_tip_speed_mps"]:.4g} m/s, spring energy '
            f'{values["max_spring_energy_mJ"]:.4g} mJ')
    judge_rows(record.rows, study_forecaster(directory, plan, say=say))
    record.save()
    return len(matched)


__all__ = ['attach_exports']
