"""`mantis analyze --intervals N`: the trial's peak tip speed, spring energy and phase starts
each with an 80 % interval around it, the same for a seed, in the JSON and the text."""
import gzip
import json

from conftest import data_file
import pytest

from mantis_rig.analysis import load_tracks
from mantis_rig.analysis.pipeline import analyze_tracks
from mantis_rig.cli import main as mantis

DATA = 'air_23mm_2p3mmps_trial1_markers.csv.gz'
QUANTITIES = ('peak_tip_speed_mps', 'max_spring_energy_mJ', 'phase_start_s.II',
              'phase_start_s.III', 'phase_start_s.IV')


def value(report, key):
    section, _, name = key.partition('.')
    return report[section][name] if name else report[section]


@pytest.fixture(scope='module')
def strike_file(tmp_path_factory):
    """The reference trial's markers from 0.3 s before phase IV to 0.03 s after it (each
    analysis of the whole 3.4 s takes about ten times as long)."""
    t_iv = analyze_tracks(load_tracks(data_file(DATA))).phases.max_contraction_s
    path = tmp_path_factory.mktemp('strike') / 'strike_markers.csv'
    with gzip.open(data_file(DATA), 'rt') as source:
        lines = source.read().splitlines()
    kept = [line for line in lines[1:] if -0.3 <= float(line.split(',')[1]) - t_iv <= 0.03]
    path.write_text('\n'.join([lines[0], *kept]) + '\n')
    return path


def test_analyze_gives_each_number_its_interval(strike_file, capsys):
    args = ['analyze', str(strike_file), '--intervals', '3', '--json']
    assert mantis(args) == 0
    report = json.loads(capsys.readouterr().out)
    intervals = report['intervals']
    assert intervals['level'] == 0.8 and intervals['replicas'] == 3
    assert intervals['choices'] + intervals['failed'] == 6
    for key in QUANTITIES:
        if value(report, key) is None:
            continue
        assert intervals[key]['low'] <= value(report, key) <= intervals[key]['high'], key
    assert intervals['peak_tip_speed_mps']['high'] > intervals['peak_tip_speed_mps']['low']
    assert mantis(args) == 0
    assert json.loads(capsys.readouterr().out)['intervals'] == intervals
    assert mantis(['analyze', str(strike_file), '--intervals', '2']) == 0
    text = capsys.readouterr().out
    assert '80 % intervals (tracking noise: 2 replicas' in text
    assert sum(key in text for key in QUANTITIES) == len(QUANTITIES)
    # the robot's arm creeps off its latch: its unlatching is the level crossing, and says so
    assert report['unlatch_method'] == 'level crossing' and intervals['open_below'] == []
    assert '(II: its level crossing)' in text
    assert 'the interval of its level crossing; the arm leaves the latch earlier' in text


def test_the_intervals_count_their_analyses_as_they_go(strike_file):
    from mantis_rig.analysis.intervals import track_intervals
    tracks = load_tracks(strike_file)
    counted = []
    track_intervals(tracks, analyze_tracks(tracks), 2, on_analysis=lambda *n: counted.append(n))
    assert counted == [(done, 8) for done in range(1, 9)]       # 2 re-trackings, 6 choices
