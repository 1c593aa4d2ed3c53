"""A simulated study whose plan says `video: true` (issue 47, "The loop"): the simulated camera
films every trial into its bag's `video/`, the study tracks each film as the trial lands
(`DIR/tracks/<video name>.csv`) and takes the tip speed and spring energy from the pictures;
they agree with the same analysis of the bag's marker frames (the markers' truth, as the
simulated camera records them) within 2 %."""
from pathlib import Path

import pytest
from session_command import mantis

from mantis_rig.contract import FILM_FOLDER
from mantis_rig.recording import TRIAL_OUTCOME, BagReader
from mantis_rig.study_session.measure import marker_quantities
from mantis_rig.study_session.record import read_record
from mantis_rig.video.recording import open_recording

PLAN = """scene: air_23mm_rig
factors:
  d_t_mm: [19, 25]
repeats: 1
order: as-listed
seed: 3
robots: 20
video: true
"""
# A short camera window at the rig's rate: 0.12 s, 2,280 frames a film. Before the trigger
# enough for the release heard late at real-time factor 0 (the world runs at most 0.05 s ahead
# of the supervisor's force stream), after it the strike's end.
WINDOW = ('--set', 'pre_trigger_s=0.1', '--set', 'post_trigger_s=0.02')

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow, pytest.mark.ros]


def test_a_simulated_study_with_video_tracks_every_trial_s_film(tmp_path):
    plan = tmp_path / 'plan.yaml'
    plan.write_text(PLAN)
    out = tmp_path / 'study'
    with mantis('study', plan, '--out', out, '--real-time-factor', '0', *WINDOW) as command:
        assert command.finish(600) == 0, command.text()
        assert 'Traceback' not in command.text()
        command.assert_nothing_left()
    rows = read_record(out / 'study.csv').rows
    assert [r['status'] for r in rows] == ['done', 'done'], rows
    agreement = []
    for row in rows:
        bag = out / row['bag']
        film = bag / FILM_FOLDER
        assert row['markers_from'] == 'video', row
        assert (film / 'video.cine').is_file() and (film / 'calibration.yaml').is_file()
        assert not any(p.name.endswith('.tmp') for p in bag.iterdir())
        tracks = out / 'tracks' / f'{row["video"]}.csv'
        assert tracks.is_file(), row
        outcome = BagReader(bag, warn=False).metadata(TRIAL_OUTCOME)
        assert outcome['release_in_camera_window'] == 'true', outcome
        with open_recording(film / 'video.cine') as recording:     # the camera's own frames
            assert recording.frame_count == int(outcome['marker_frames'])
            assert recording.rate_hz == 19_000.0
        from_bag, why = marker_quantities(bag)
        assert not why, why
        speed = row['peak_tip_speed_mps'] / from_bag['peak_tip_speed_mps'] - 1.0
        energy = row['max_spring_energy_mJ'] / from_bag['max_spring_energy_mJ'] - 1.0
        agreement.append((row['run'], row['peak_tip_speed_mps'], from_bag['peak_tip_speed_mps'],
                          speed, energy))
        assert abs(speed) <= 0.02, agreement
        assert abs(energy) <= 0.05, agreement
    for run, video, bag, speed, energy in agreement:
        print(f'run {run}: tip speed {video:.3f} m/s from the film, {bag:.3f} from the bag '
              f'({speed:+.2%}); spring energy {energy:+.2%}')
    assert Path(out / 'report' / 'report.md').exists()
