"""Issue 16's damaged files through the command line, one case per kind (points 1, 2, 4, 5, 7,
8 and 9 of the issue): each is refused with exit 2 and one line on stderr that names the file
and the problem, no traceback, and the input file's bytes are unchanged. (Point 3, signals:
test_replay.py; point 6, a bag's conditions: test_import_analyze.py; nothing to replay or
recover, exit 1: test_replay.py, test_recording.py.)"""
import gzip
import hashlib
from pathlib import Path
import zipfile

from conftest import data_file, rewritten_copy
import pytest
import yaml

from mantis_rig.cli import main as cli_main

PAIR_CSV = 'real_trials/air_23mm_19kfps_pair_track.csv'
WINDOW = (9000, 11300)             # frames around the strike


def digest(path: Path) -> str:
    paths = sorted(p for p in path.rglob('*') if p.is_file()) if path.is_dir() else [path]
    return hashlib.sha256(b''.join(p.read_bytes() for p in paths)).hexdigest()


def refused(capsys, args, path: Path, why: str) -> None:
    before = digest(path)
    code = cli_main([str(a) for a in args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count('\n') == 1 and 'Traceback' not in err, err
    assert why in err, err
    assert str(path.name) in err, err
    assert digest(path) == before, 'the input was changed'


@pytest.fixture(scope='module')
def window_csv(tmp_path_factory) -> bytes:
    lines = data_file(PAIR_CSV).read_bytes().splitlines()
    return b'\n'.join(lines[:2] + lines[2 + WINDOW[0]:2 + WINDOW[1]]) + b'\n'


@pytest.fixture(scope='module')
def strike_bag(tmp_path_factory, window_csv):
    work = tmp_path_factory.mktemp('bad_input')
    csv = work / 'strike_track.csv'
    csv.write_bytes(window_csv)
    bag = work / 'strike_bag'
    assert cli_main(['import-tracking', str(csv), '--out', str(bag), '--d-t-mm', '23']) == 0
    return bag


@pytest.mark.parametrize('name, content, why', [
    ('zero.xlsx', b'', 'not a readable .xlsx workbook'),
    ('not_a_zip.xlsx', b'PK\x03\x04 this is not a zip', 'not'),
    ('no_sheet.xlsx', 'no_sheet', 'sheet'),
])
def test_a_damaged_spreadsheet(capsys, tmp_path, name, content, why):
    path = tmp_path / name
    if content == 'no_sheet':
        with zipfile.ZipFile(path, 'w') as z:
            z.writestr('[Content_Types].xml', '<Types/>')
    else:
        path.write_bytes(content)
    for command in ('analyze', 'import-tracking'):
        extra = ['--out', tmp_path / f'out_{command}'] if command == 'import-tracking' else []
        refused(capsys, [command, path, *extra], path, why)


def test_tracking_files_with_a_bad_header_a_cut_gzip_or_an_infinite_time(capsys, tmp_path,
                                                                         window_csv):
    header = tmp_path / 'latin1_track.csv'
    header.write_bytes(b'Frame,Time,Feature 1 (mb1)\xe9,,' + window_csv.split(b',', 5)[-1])
    refused(capsys, ['analyze', header], header, 'not')
    cut = tmp_path / 'cut_track.csv.gz'
    cut.write_bytes(gzip.compress(window_csv)[:5000])
    refused(capsys, ['analyze', cut], cut, 'cut_track.csv.gz')
    lines = window_csv.splitlines()
    cells = lines[-1].split(b',')
    cells[1] = b'inf'
    infinite = tmp_path / 'inf_track.csv'
    infinite.write_bytes(b'\n'.join(lines[:-1] + [b','.join(cells)]) + b'\n')
    for command in ('analyze', 'import-tracking'):
        extra = ['--out', tmp_path / f'inf_{command}'] if command == 'import-tracking' else []
        refused(capsys, [command, infinite, *extra], infinite, 'Time is not a number')


def test_marker_positions_a_thousand_times_too_large_are_refused(capsys, tmp_path, window_csv):
    lines = window_csv.splitlines()
    rows = []
    for line in lines[2:]:
        cells = line.split(b',')
        rows.append(b','.join(cells[:2] + [b'%r' % (float(c) * 1000) if c not in (b'-1', b'')
                                           else c for c in cells[2:]]))
    big = tmp_path / 'thousand_track.csv'
    big.write_bytes(b'\n'.join(lines[:2] + rows) + b'\n')
    refused(capsys, ['analyze', big, '--d-t-mm', '23'], big, 'L1 =')


def test_a_null_in_metadata_yaml(capsys, tmp_path, strike_bag):
    import shutil
    bag = tmp_path / 'null_bag'
    shutil.copytree(strike_bag, bag)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    meta['rosbag2_bagfile_information']['relative_file_paths'] = [None]
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(meta))
    refused(capsys, ['analyze', bag], bag, 'relative_file_paths')
    refused(capsys, ['recover', bag, '-o', tmp_path / 'recovered'], bag, 'relative_file_paths')
    refused(capsys, ['replay', bag], bag, 'relative_file_paths')


def test_a_scene_with_a_huge_integer_non_utf8_bytes_or_cut_short(capsys, tmp_path):
    scene = yaml.safe_load(Path(data_file('../../mantis_sim/scenes/air_23mm.yaml')).read_text())
    huge = tmp_path / 'huge.yaml'
    huge.write_text(yaml.safe_dump({**scene, 'geometry': {'d_t_mm': 10 ** 400}}))
    refused(capsys, ['sim', '--scene', huge], huge, 'd_t_mm')
    latin = tmp_path / 'latin.yaml'
    latin.write_bytes(yaml.safe_dump(scene).encode() + b'# caf\xe9\n')
    refused(capsys, ['sim', '--scene', latin], latin, 'not UTF-8')
    cut = tmp_path / 'cut.yaml'                 # cut after its first lines: still YAML
    cut.write_text(yaml.safe_dump({'name': 'cut', 'effects': []}))
    refused(capsys, ['sim', '--scene', cut], cut, 'missing required key')


def test_arm_markers_lost_inside_the_strike_are_refused_not_guessed(capsys, tmp_path,
                                                                     window_csv):
    """Point 1: the arm's markers lost (-1, -1) for 20 frames around the peak tip speed, then
    tracked again: no number is given for a strike the markers do not show."""
    lines = window_csv.splitlines()
    rows = [line.split(b',') for line in lines[2:]]
    peak_row = 10747 - WINDOW[0]                # the peak tip speed of this export
    for row in rows[peak_row - 10:peak_row + 10]:
        row[6:12] = [b'-1'] * 6                 # ma1, ma2, ma3
    lost = tmp_path / 'lost_track.csv'
    lost.write_bytes(b'\n'.join(lines[:2] + [b','.join(r) for r in rows]) + b'\n')
    refused(capsys, ['analyze', lost, '--d-t-mm', '23'], lost,
            'the markers were lost inside the strike')


def test_a_bag_whose_marker_block_has_the_wrong_length(capsys, tmp_path, strike_bag):
    """Point 4: contents that pass every CRC but are wrong."""
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64MultiArray

    def short_block(message):
        msg = deserialize_message(message.data, Float64MultiArray)
        msg.data = list(msg.data)[:len(msg.data) // 2]          # the layout still says all
        return serialize_message(msg)
    bag = rewritten_copy(strike_bag, tmp_path / 'short_block_bag', short_block)
    refused(capsys, ['analyze', bag], bag, 'a malformed block on /camera/markers')


# ------------------------------------------------- the two roots, caught once (issue 25)
def test_bad_input_and_rig_faults_have_roots_of_their_own():
    """InputError is not a ValueError (an `except ValueError` around a library call must not
    swallow a refusal); the device and stack faults stand under RigFault, not under it."""
    from mantis_rig import faults
    from mantis_rig.analysis.inputs import TrackFormatError
    from mantis_rig.faults import StackError
    from mantis_rig.hardware.device_interfaces import DeviceError
    from mantis_rig.recording import BagClosedError, BagError, BagWriteError
    from mantis_rig.simulated.world_port import WorldTimeout
    from mantis_sim.errors import InputError
    from mantis_sim.scene import SceneError

    assert not hasattr(faults, 'InputError')       # one way in: mantis_sim.errors
    assert not issubclass(InputError, ValueError)
    for refusal in (TrackFormatError, BagError, SceneError):
        assert issubclass(refusal, InputError) and not issubclass(refusal, faults.RigFault)
    for fault in (DeviceError, faults.SafetyLimitError, faults.ConfigurationError, WorldTimeout,
                  StackError, BagClosedError, BagWriteError):
        assert issubclass(fault, faults.RigFault) and not issubclass(fault, (InputError,
                                                                             ValueError))
    assert DeviceError is faults.DeviceError and StackError is faults.StackError


@pytest.mark.parametrize('raised, status', [
    ('InputError', 2), ('DeviceError', 3), ('StackError', 3), ('BagClosedError', 3)])
def test_mantis_says_each_error_in_one_line_with_its_exit_status(monkeypatch, capsys, raised,
                                                                 status):
    from mantis_rig import faults
    from mantis_rig.cli import sim
    from mantis_sim.errors import InputError

    def run_sim(args):
        raise (InputError if raised == 'InputError' else getattr(faults, raised))(
            'the reason, named')

    monkeypatch.setattr(sim, 'run_sim', run_sim)
    assert cli_main(['sim', '--scene', 'air_23mm']) == status == (
        faults.USAGE_ERROR if raised == 'InputError' else faults.RIG_FAULT)
    captured = capsys.readouterr()
    assert captured.out == '' and captured.err == 'mantis sim: the reason, named\n'


def test_the_usage_exit_status_is_defined_once():
    root = Path(__file__).resolve().parents[2] / 'mantis_rig'
    defined = [p for p in root.rglob('*.py') if 'USAGE_ERROR = ' in p.read_text()]
    assert defined == [root / 'faults.py'], defined
