"""The strike's video from the command line: `mantis sim --video` films a strike with its truth,
`mantis track` turns the film into the tracker's CSV, `mantis analyze` takes the film itself,
and a damaged recording ends with exit 2 naming the file and the frame, the frames tracked
before it kept."""
import json

import pytest

from mantis_rig.analysis.inputs import read_trial
from mantis_rig.cli import main as mantis

RATE = '19000'
pytestmark = pytest.mark.slow


@pytest.fixture(scope='module')
def film(tmp_path_factory):
    """A strike of air_23mm filmed at the camera's 19,000 frames/s, an uncompressed .avi."""
    out = tmp_path_factory.mktemp('film')
    assert mantis(['sim', '--scene', 'air_23mm', '--set', f'camera.frame_rate_hz={RATE}',
                   '--video', str(out), '--video-format', 'avi-raw', '--json']) == 0
    return out


def test_sim_video_writes_the_film_its_calibration_and_its_truth_and_nothing_else(film):
    assert sorted(p.name for p in film.iterdir()) == ['calibration.yaml', 'truth.csv',
                                                      'video.avi']
    truth = read_trial(film / 'truth.csv').tracks
    assert truth.frame_rate_hz == pytest.approx(float(RATE))
    assert sorted(truth.markers_mm) == ['ma1', 'ma2', 'mb1', 'mb2', 'mb3']


def test_track_writes_the_trackers_csv_which_reads_back_beside_the_truth(film, tmp_path,
                                                                        capsys):
    out = tmp_path / 'tracks.csv'
    assert mantis(['track', str(film / 'video.avi'), '--rate', RATE, '--out', str(out),
                   '--plot', str(tmp_path / 'tracks.png')]) == 0
    said = capsys.readouterr()
    assert f'rate {float(RATE):g} frames/s from --rate' in said.err
    assert 'calibration.yaml (beside the recording)' in said.err
    assert (tmp_path / 'tracks.png').stat().st_size > 10_000
    tracked, truth = read_trial(out).tracks, read_trial(film / 'truth.csv').tracks
    assert tracked.n_frames == truth.n_frames
    for name in truth.markers_mm:
        error_mm = abs(tracked.markers_mm[name] - truth.markers_mm[name])
        assert float(error_mm[:50].max()) < 0.05, name          # at rest: well under a pixel


def test_analyze_takes_the_recording_and_finds_the_truths_tip_speed(film, capsys):
    assert mantis(['analyze', str(film / 'truth.csv'), '--json']) == 0
    truth = json.loads(capsys.readouterr().out)['peak_tip_speed_mps']
    assert mantis(['analyze', str(film / 'video.avi'), '--rate', RATE, '--json']) == 0
    tracked = json.loads(capsys.readouterr().out)['peak_tip_speed_mps']
    assert tracked == pytest.approx(truth, rel=0.02)


def test_a_recording_cut_short_is_refused_naming_its_frame_its_frames_kept(film, tmp_path,
                                                                         capsys):
    data = (film / 'video.avi').read_bytes()
    cut = tmp_path / 'cut.avi'
    cut.write_bytes(data[:len(data) // 2])
    (tmp_path / 'calibration.yaml').write_bytes((film / 'calibration.yaml').read_bytes())
    out = tmp_path / 'tracks.csv'
    assert mantis(['track', str(cut), '--rate', RATE, '--out', str(out)]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith('mantis track: ') and 'cut.avi' in line and 'frame' in line
    assert 'kept in' in line
    kept = read_trial(out).tracks
    assert 0 < kept.n_frames < read_trial(film / 'truth.csv').tracks.n_frames


def test_a_calibration_that_cannot_be_read_is_refused_in_one_line(film, tmp_path, capsys):
    bad = tmp_path / 'cal.yaml'
    bad.write_text((film / 'calibration.yaml').read_text().replace('scale_px_per_mm: ',
                                                                   'scale_px_per_mm: -'))
    assert mantis(['track', str(film / 'video.avi'), '--rate', RATE, '--calibration',
                   str(bad), '--out', str(tmp_path / 't.csv')]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert 'cal.yaml' in line and 'scale' in line


def test_an_avi_without_a_rate_asks_for_one(film, tmp_path, capsys):
    assert mantis(['track', str(film / 'video.avi'), '--out', str(tmp_path / 't.csv')]) == 2
    assert '--rate' in capsys.readouterr().err


def test_study_attach_tracks_a_video_and_fills_its_trial(film, tmp_path, capsys):
    """A study's trial filmed as `<study>_run002_trial002.avi`: tracked into the study's
    tracks/, its tip speed the film's (the truth's within 2 %), judged, `markers_from` video."""
    import shutil

    from study_records import two_trials_done

    from mantis_rig.study_session.record import read_record
    directory = two_trials_done(tmp_path)
    video = tmp_path / 'videos' / 'guide_run002_trial002.avi'
    video.parent.mkdir()
    shutil.copy(film / 'video.avi', video)
    assert mantis(['study', 'attach', str(directory), str(video), '--rate', RATE,
                   '--calibration', str(film / 'calibration.yaml')]) == 0
    assert (directory / 'tracks' / 'guide_run002_trial002.csv').is_file()
    first, second = read_record(directory / 'study.csv').rows
    assert first['peak_tip_speed_mps'] is None
    capsys.readouterr()
    assert mantis(['analyze', str(film / 'truth.csv'), '--json',
                   '--d-t-mm', '23', '--contact-angle-deg', '3']) == 0
    truth = json.loads(capsys.readouterr().out)['peak_tip_speed_mps']
    assert second['peak_tip_speed_mps'] == pytest.approx(truth, rel=0.02)
    assert second['markers_from'] == 'video'
    assert 0.0 <= second['peak_tip_speed_mps_pit'] <= 1.0
