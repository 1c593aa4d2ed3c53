"""A small study on disk for the tests of `mantis study attach` and `report`: its plan as run
and a record of two trials done at 23 mm, not yet measured from markers."""
from pathlib import Path

import yaml

from mantis_rig.study_session.record import StudyRecord, new_row

PLAN = {'scene': 'air_23mm_rig', 'factors': {'d_t_mm': [23.0]}, 'repeats': 2,
        'order': 'as-listed', 'seed': 0, 'robots': 20}


def two_trials_done(parent: Path) -> Path:
    """``parent/guide``: the study, its trials' videos named ``guide_run00K_trial00K``."""
    directory = parent / 'guide'
    directory.mkdir()
    (directory / 'plan.yaml').write_text(yaml.safe_dump(PLAN))
    rows = []
    for k in (1, 2):
        row = new_row(k, 1, 1, {'d_t_mm': 23.0, 'contact_angle_deg': 3.0, 'medium': 'air',
                                'pull_speed_mm_s': 2.3})
        row.update(run=k, status='done', video=f'guide_run{k:03d}_trial{k:03d}',
                   day='2026-11-28', loading_work_mJ=40.0 + k)
        rows.append(row)
    StudyRecord(directory / 'study.csv', rows).save()
    return directory
