"""import-tracking -> bag -> analyze: the bag path gives the same analysis as the tracking file;
damaged bags are analysed up to the damage; bad spreadsheets name what is missing."""
import json
import math
import re
import shutil

from conftest import data_file, rewritten_copy
from mcap.reader import make_reader
import numpy as np
from openpyxl import load_workbook
import pytest

from mantis_rig.analysis import TrackFormatError, analyze_tracks, load_tracks
from mantis_rig.analysis.inputs.bag import read_trial_bag
from mantis_rig.analysis.inputs.bag_writer import ANGLES_TOPIC
from mantis_rig.cli import main
from mantis_rig.contract import FORCE_BLOCK, MARKERS, resolve
from mantis_rig.recording import BagReader, BagWriter
from mantis_rig.recording.force_block import force_block_to_msg
from mantis_rig.recording.marker_block import (
    MarkerFrames,
    marker_block_from_msg,
    marker_blocks_to_msgs,
)

pytestmark = pytest.mark.slow

DATA = data_file('air_23mm_2p3mmps_trial1_markers.csv.gz')
N_FRAMES = 65255


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def analyze_json(capsys, path):
    code, out, err = run(capsys, 'analyze', path, '--json')
    return code, (json.loads(out) if code == 0 else None), err


@pytest.fixture(scope='module')
def csv_analysis():
    return analyze_tracks(load_tracks(DATA))


@pytest.fixture(scope='module')
def imported_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp('import') / 'trial1'
    assert main(['import-tracking', str(DATA), '--out', str(out)]) == 0
    return out


def cut_copy(bag, dest, keep_fraction):
    """A copy of ``bag`` whose .mcap keeps only its first ``keep_fraction`` of bytes, without
    metadata.yaml: what a crash mid-recording leaves."""
    shutil.copytree(bag, dest)
    (dest / 'metadata.yaml').unlink()
    mcap = next(dest.glob('*.mcap'))
    with open(mcap, 'r+b') as f:
        f.truncate(int(mcap.stat().st_size * keep_fraction))
    return dest


# ------------------------------------------------------------------------ the real trial
def test_imported_bag_holds_markers_angles_and_source(imported_bag, csv_analysis):
    tracks = load_tracks(DATA)
    reader = BagReader(imported_bag)
    assert reader.complete
    conditions = reader.metadata('trial_conditions')
    assert conditions['source_file'] == str(DATA) and conditions['source_format'] == 'csv'
    assert int(conditions['frames']) == N_FRAMES
    counts = {t: i.message_count for t, i in reader.topics.items()}
    assert counts == {resolve(MARKERS): 66, ANGLES_TOPIC: N_FRAMES}
    blocks = [marker_block_from_msg(m) for _, _, _, m in reader.messages([resolve(MARKERS)])]
    time_s = np.concatenate([b.time_s for b in blocks])
    np.testing.assert_array_equal(time_s, tracks.time_s)
    for name, xy_mm in tracks.markers_mm.items():  # metres in the bag
        xy_m = np.concatenate([b.markers_m[name] for b in blocks])
        np.testing.assert_allclose(xy_m * 1e3, xy_mm, rtol=0, atol=1e-12)
    angles = [m for _, _, _, m in reader.messages([ANGLES_TOPIC])]
    assert angles[0].name == ['theta1', 'theta3']
    for i in (0, 49_000, N_FRAMES - 1):
        assert list(angles[i].position) == [csv_analysis.theta1_rad[i],
                                            csv_analysis.theta3_rad[i]]
        assert list(angles[i].velocity) == [csv_analysis.omega1_radps[i],
                                            csv_analysis.omega3_radps[i]]
        stamp = angles[i].header.stamp
        assert stamp.sec + stamp.nanosec * 1e-9 == pytest.approx(tracks.time_s[i], abs=1e-9)


def test_analysis_of_bag_equals_analysis_of_tracking_file(imported_bag, csv_analysis, capsys,
                                                          tmp_path):
    code, from_bag, err = analyze_json(capsys, imported_bag)
    assert code == 0 and err == ''
    code, from_csv, _ = run(capsys, 'analyze', DATA, '--json', '--plot', tmp_path / 'trial.png')
    from_csv = json.loads(from_csv)
    assert (tmp_path / 'trial.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    direct = csv_analysis.summary()
    for key in direct:
        assert key in from_bag and key in from_csv
    for report in (from_bag, from_csv):
        assert report['input']['frames'] == N_FRAMES
        for key, value in direct.items():
            if isinstance(value, dict):
                assert report[key] == pytest.approx(value, rel=1e-9, nan_ok=True), key
            elif isinstance(value, list):
                assert report[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
            elif isinstance(value, str):
                assert report[key] == value, key
            elif value != value:                     # NaN is written as null
                assert report[key] is None, key
            else:
                assert report[key] == pytest.approx(value, rel=1e-9), key
    # the .mcap file alone is a bag too
    code, from_mcap, _ = analyze_json(capsys, next(imported_bag.glob('*.mcap')))
    assert code == 0 and from_mcap['phase_start_s'] == from_bag['phase_start_s']


def test_truncated_bag_is_analysed_up_to_the_damage(imported_bag, csv_analysis, capsys,
                                                    tmp_path):
    cut = cut_copy(imported_bag, tmp_path / 'cut', 0.92)
    code, report, err = analyze_json(capsys, cut)
    assert code == 0
    assert 'warning' in err and 'damaged at byte' in err and 'file cut mid-record' in err
    assert 'metadata.yaml is missing' in err
    frames = report['input']['frames']
    assert 50_000 < frames < N_FRAMES and report['input']['truncated']
    # the strike (t ~ 2.62 s) lies before the damage: same result as the whole trial
    full = csv_analysis.summary()
    assert abs(report['phase_start_s']['IV'] - full['phase_start_s']['IV']) < 1e-3
    assert report['peak_tip_speed_mps'] == pytest.approx(full['peak_tip_speed_mps'], rel=0.01)
    # `mantis recover` of the same bag analyses the same
    assert run(capsys, 'recover', cut, '-o', tmp_path / 'recovered')[0] == 0
    code, recovered, err = analyze_json(capsys, tmp_path / 'recovered')
    assert code == 0 and err == '' and recovered['input']['frames'] == frames
    assert recovered['phase_start_s'] == report['phase_start_s']


def test_bag_cut_before_the_strike_fails_with_reason(imported_bag, capsys, tmp_path):
    cut = cut_copy(imported_bag, tmp_path / 'early', 0.5)
    code, _, err = analyze_json(capsys, cut)
    assert code == 2
    assert 'damaged at byte' in err and 'not enough data before the damage' in err
    nothing = cut_copy(imported_bag, tmp_path / 'nothing', 0.001)
    code, _, err = analyze_json(capsys, nothing)
    assert code == 2 and 'no marker frames on /camera/markers' in err


def test_corrupted_chunk_is_reported_and_the_data_before_it_analysed(imported_bag, capsys,
                                                                     tmp_path):
    bad = tmp_path / 'corrupt'
    shutil.copytree(imported_bag, bad)
    mcap = next(bad.glob('*.mcap'))
    with open(mcap, 'rb') as f:
        summary = make_reader(f).get_summary()
    markers = next(i for i, c in summary.channels.items() if c.topic == resolve(MARKERS))
    chunks = sorted((c for c in summary.chunk_indexes if markers in c.message_index_offsets),
                    key=lambda c: c.message_start_time)
    chunk = chunks[int(len(chunks) * 0.9)]  # a chunk with marker frames, after the strike
    data = bytearray(mcap.read_bytes())
    at = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[at:at + 256] = bytes(range(256))  # garbage inside the chunk; summary still intact
    mcap.write_bytes(bytes(data))
    code, report, err = analyze_json(capsys, bad)
    assert code == 0 and 'is damaged' in err and 'unreadable data' in err, err
    assert 40_000 < report['input']['frames'] < N_FRAMES


def bag_with_force(path, tracks, newtons_scale=1.0):
    """A bag of the tracks' marker frames and a force stream of about 9 N x newtons_scale."""
    t_ns = np.round(tracks.time_s * 1e9).astype(np.int64)
    period_ns, block = 50_000, 1000
    force_t = np.arange(0, tracks.time_s[-1] + 0.05, period_ns / 1e9)
    force = (9.0 + 0.5 * np.sin(force_t)) * newtons_scale
    with BagWriter(path, sync_period_s=0) as bag:
        frames = MarkerFrames(tracks.time_s, {n: xy / 1e3 for n, xy in tracks.markers_mm.items()})
        for i, msg in enumerate(marker_blocks_to_msgs(frames)):
            bag.write(resolve(MARKERS), msg, int(t_ns[min((i + 1) * 1000, len(t_ns)) - 1]))
        for start in range(0, len(force), block):
            bag.write(resolve(FORCE_BLOCK), force_block_to_msg(
                start * period_ns / 1e9, period_ns / 1e9, force[start:start + block]),
                (start + block) * period_ns)
    return force


def test_an_impossible_tendon_work_is_refused(capsys, tmp_path):
    bag_with_force(tmp_path / 'huge_force', load_tracks(DATA), newtons_scale=1e11)
    code, _, err = analyze_json(capsys, tmp_path / 'huge_force')
    assert code == 2
    assert 'tendon work' in err and "beyond the robot's 300 mJ" in err


def test_tendon_force_in_bag_gives_tendon_work(capsys, tmp_path, csv_analysis):
    path = tmp_path / 'with_force'
    force = bag_with_force(path, load_tracks(DATA))
    trial = read_trial_bag(path)
    assert trial.force_N is not None and len(trial.force_N) == len(force)
    code, report, _ = analyze_json(capsys, path)
    assert code == 0
    assert np.isfinite(report['tendon_work_to_IV_mJ'])
    assert report['phase_start_s'] == pytest.approx(csv_analysis.summary()['phase_start_s'],
                                                    rel=1e-9)


# ------------------------------------------------------------------------- bad input files
def write_xlsx(path, labels, axes, rows, header=(('Record rate', 19000), ('Calibration', 0.1695))):
    from openpyxl import Workbook
    wb = Workbook()
    ws = wb.active
    for key, value in header:
        ws.append([key, value])
    ws.append([])
    ws.append(labels)
    ws.append(axes)
    for row in rows:
        ws.append(row)
    wb.save(path)
    return path


def marker_rows(n, markers):
    rng = np.random.default_rng(1)
    return [[i, i / 19000] + list(rng.normal(0, 5, 2 * markers)) for i in range(n)]


def test_xlsx_without_expected_columns_names_what_is_missing(tmp_path, capsys):
    no_y = write_xlsx(tmp_path / 'no_y.xlsx',
                      ['Frame', 'Time', 'mb1', '', 'mb2', '', 'ma1', '', 'ma2'],
                      ['', '', 'x', 'y', 'x', 'y', 'x', 'y', 'x'], marker_rows(60, 4)[:])
    code, out, err = run(capsys, 'import-tracking', no_y, '--out', tmp_path / 'b1')
    assert code == 2 and 'ma2 y' in err and 'no column' in err
    assert not (tmp_path / 'b1').exists()
    no_time = write_xlsx(tmp_path / 'no_time.xlsx',
                         ['Frame', 'mb1', '', 'mb2', '', 'ma1', '', 'ma2', ''],
                         ['', 'x', 'y', 'x', 'y', 'x', 'y', 'x', 'y'],
                         [r[:1] + r[2:] for r in marker_rows(60, 4)])
    code, _, err = run(capsys, 'import-tracking', no_time, '--out', tmp_path / 'b2')
    assert code == 2 and 'Frame, Time' in err
    no_rate = write_xlsx(tmp_path / 'no_rate.xlsx',
                         ['Frame', 'Time', 'mb1', '', 'mb2', '', 'ma1', '', 'ma2', ''],
                         ['', '', 'x', 'y', 'x', 'y', 'x', 'y', 'x', 'y'], marker_rows(60, 4),
                         header=(('Record Rate:', 'N/A'), ('Calibration', 0.1695)))
    code, _, err = run(capsys, 'import-tracking', no_rate, '--out', tmp_path / 'b3')
    assert code == 2 and 'Record Rate: N/A' in err and '--frame-rate' in err
    code, _, err = run(capsys, 'analyze', no_y)
    assert code == 2 and 'ma2 y' in err


def test_xlsx_markers_go_into_the_bag_in_metres(tmp_path, capsys):
    rows = marker_rows(120, 4)
    good = write_xlsx(tmp_path / 'good.xlsx',
                      ['Frame', 'Time', 'Feature 1 (mb1)', '', 'mb2', '', 'ma1', '', 'ma2', ''],
                      ['', '', 'x', 'y', 'x', 'y', 'x', 'y', 'x', 'y'], rows)
    code, out, err = run(capsys, 'import-tracking', good, '--out', tmp_path / 'bag',
                         '--no-angles')
    assert code == 0, err
    trial = read_trial_bag(tmp_path / 'bag')
    table = np.array(rows)
    np.testing.assert_allclose(trial.tracks.time_s, table[:, 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(trial.tracks.markers_mm['ma1'], table[:, 6:8], rtol=1e-12)
    conditions = BagReader(tmp_path / 'bag').metadata('trial_conditions')
    assert conditions['source_format'] == 'xlsx'
    assert float(conditions['source_record_rate']) == 19000.0
    assert float(conditions['source_calibration']) == 0.1695


def test_analyze_bad_paths(tmp_path, capsys):
    code, _, err = run(capsys, 'analyze', tmp_path / 'absent.csv')
    assert code == 2 and 'absent.csv' in err
    (tmp_path / 'empty_dir').mkdir()
    code, _, err = run(capsys, 'analyze', tmp_path / 'empty_dir')
    assert code == 2 and 'not a bag' in err


def test_frames_without_the_strike_are_refused_with_the_reason():
    """A camera window that missed the strike (only loading in the frames): a clear error,
    not an index error."""
    from mantis_rig.analysis.inputs import MarkerTracks
    tracks = load_tracks(DATA)
    keep = (tracks.time_s > 1.5) & (tracks.time_s < 2.55)          # phase IV starts at 2.6177
    loading = MarkerTracks(time_s=tracks.time_s[keep], frames=tracks.frames[keep],
                           markers_mm={n: xy[keep] for n, xy in tracks.markers_mm.items()})
    with pytest.raises(ValueError, match='no strike|do not hold the strike'):
        analyze_tracks(loading)


# --------------------------------------------------- trial conditions a tracking file lacks
def test_given_contact_angle_and_d_t_enter_the_analysis(capsys):
    """A tracking file carries no trial conditions: --contact-angle-deg sets θ3's zero (the
    contact angle is reported as given; unknown without it), --d-t-mm the tendon geometry.
    Both move the overcentering, which depends on the absolute θ3 and on d_t
    (docs/replay_analysis.md: 1.77 s with 3.2 deg)."""
    code, default, err = analyze_json(capsys, DATA)
    assert code == 0, err
    assert default['contact_angle_deg'] is None and default['input']['parameters'] == []
    code, out, err = run(capsys, 'analyze', DATA, '--json', '--contact-angle-deg', 3.2)
    assert code == 0, err
    given = json.loads(out)
    assert given['contact_angle_deg'] == pytest.approx(3.2, abs=1e-12)
    assert given['input']['parameters'] == ['contact angle 3.2 deg (given)']
    assert given['overcentering_s'] == pytest.approx(1.77, abs=0.02)
    assert given['peak_tip_speed_mps'] != default['peak_tip_speed_mps']   # cos θ3 in v_tip
    code, out, err = run(capsys, 'analyze', DATA, '--json', '--d-t-mm', 19)
    assert code == 0, err
    short = json.loads(out)
    assert short['input']['parameters'] == ['d_t = 19 mm (given)']
    assert abs(short['overcentering_s'] - default['overcentering_s']) > 0.05
    assert short['peak_tip_speed_mps'] == pytest.approx(default['peak_tip_speed_mps'])


def test_import_keeps_the_given_conditions_for_the_bag(capsys, tmp_path):
    bag = tmp_path / 'trial1_19mm'
    code, _, err = run(capsys, 'import-tracking', DATA, '--out', bag, '--d-t-mm', 19,
                       '--contact-angle-deg', 3.2)
    assert code == 0, err
    conditions = BagReader(bag).metadata('trial_conditions')
    assert float(conditions['d_t_mm']) == 19.0
    assert float(conditions['contact_angle_deg']) == 3.2
    code, from_bag, err = analyze_json(capsys, bag)
    assert code == 0, err
    assert from_bag['input']['parameters'] == ['d_t = 19 mm (trial conditions)',
                                               'contact angle 3.2 deg (trial conditions)']
    code, out, err = run(capsys, 'analyze', DATA, '--json', '--d-t-mm', 19,
                         '--contact-angle-deg', 3.2)
    from_file = json.loads(out)
    for key in ('overcentering_s', 'peak_tip_speed_mps', 'contact_angle_deg'):
        assert from_bag[key] == pytest.approx(from_file[key], rel=1e-9)
    # The angles the import wrote are the ones of the given geometry: θ3 starts at 3.2 deg.
    theta3 = [m.position[1] for _, _, _, m in BagReader(bag).messages([ANGLES_TOPIC])][:100]
    assert np.median(theta3) == pytest.approx(np.radians(3.2), abs=np.radians(0.2))


@pytest.mark.parametrize('option, value, why', [
    ('--contact-angle-deg', 60, 'contact_angle_deg = 60.0 deg is outside [-45.0, 45.0] deg'),
    ('--d-t-mm', 0.5, 'd_t_mm = 0.5 mm is outside [1.0, 100.0] mm'),
    ('--d-t-mm', 'nan', 'd_t_mm = nan mm is outside'),
])
def test_given_condition_out_of_range_is_refused(capsys, tmp_path, option, value, why):
    """Checked before anything is read or written: exit 2, naming the option, value and range."""
    code, _, err = run(capsys, 'analyze', tmp_path / 'absent.csv', option, value)
    assert code == 2 and f'{option}: {why}' in err
    out = tmp_path / 'bag'
    code, _, err = run(capsys, 'import-tracking', tmp_path / 'absent.csv', '--out', out,
                       option, value)
    assert code == 2 and f'{option}: {why}' in err and not out.exists()


def test_bag_contents_that_pass_the_crc_but_are_wrong_are_refused_with_the_reason(
        imported_bag, capsys, tmp_path):
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64MultiArray

    garbage = rewritten_copy(imported_bag, tmp_path / 'garbage', lambda m: b'\x00\x01\x00')
    code, _, err = analyze_json(capsys, garbage)
    assert code == 2, err
    assert 'on /camera/markers at log time' in err and 'cannot be decoded as' in err

    def short_block(message):
        msg = deserialize_message(message.data, Float64MultiArray)
        msg.data = list(msg.data)[:len(msg.data) // 2]          # the layout still says all
        return serialize_message(msg)
    short = rewritten_copy(imported_bag, tmp_path / 'short', short_block)
    code, _, err = analyze_json(capsys, short)
    assert code == 2, err
    assert 'a malformed block on /camera/markers at log time' in err
    assert 'its layout declares' in err


def test_a_force_block_with_an_impossible_start_time_is_refused():
    from mantis_rig.recording.force_block import force_block_from_msg, force_block_to_msg
    msg = force_block_to_msg(1e-3, 50e-6, np.ones(10))
    msg.data = [float('nan'), *list(msg.data)[1:]]
    with pytest.raises(ValueError, match='start time nan s'):
        force_block_from_msg(msg)


@pytest.mark.parametrize('conditions, why', [
    ({'contact_angle_deg': '-90'}, 'contact_angle_deg = -90.0 deg is outside [-45.0, 45.0] deg'),
    ({'d_t_mm': '-5'}, 'd_t_mm = -5.0 mm is outside [1.0, 100.0] mm'),
    ({'d_t_mm': 'wide'}, "d_t_mm = 'wide' is not a finite number"),
])
def test_a_bags_trial_conditions_are_checked_like_the_command_lines(imported_bag, capsys,
                                                                     tmp_path, conditions, why):
    bag = rewritten_copy(imported_bag, tmp_path / 'conditions', conditions=conditions)
    code, _, err = analyze_json(capsys, bag)
    assert code == 2, err
    assert f'trial conditions: {why}' in err


# ------------------------------------------- one motion, exported in another camera frame
PAIR = data_file('real_trials/air_23mm_19kfps_pair.xlsx')


def reexported(source, dest, handedness: str, tilt_deg: float):
    """``source`` (a left-handed export) as the tracker would have exported the same video with
    its calibration set to ``handedness`` and ``tilt_deg``, written with openpyxl.

    The conventions are those of tracking_export.md and kinematics._right_handed: a
    left-handed export at tilt t holds R(t) p (p: the image's axes, y down; R counter-
    clockwise in that frame), a right-handed one at the same tilt the same with y negated
    (y up). So the left-handed tilt-180 original becomes, right-handed at tilt 0, its x
    mirrored; at a tilt t, that turned by t. Lost markers stay (-1, -1)."""
    wb = load_workbook(source)
    ws = wb.worksheets[0]
    header = calibration = None
    for row in ws.iter_rows():
        label = str(row[0].value or '').strip()
        if label.startswith('Calibration 1'):
            calibration = row[1]
        if label == 'Frame':
            header = row[0].row
    text = calibration.value
    assert 'Left-Handed' in text
    old_tilt = float(re.search(r'Tilt: ([-\d.]+) degrees', text).group(1))
    calibration.value = re.sub(r'Tilt: [-\d.]+ degrees', f'Tilt: {tilt_deg:g} degrees',
                               text).replace('Left-Handed', handedness.title() + '-Handed')
    turn = math.radians(tilt_deg - old_tilt)
    c, s = round(math.cos(turn), 15), round(math.sin(turn), 15)
    flip = -1.0 if handedness == 'right' else 1.0
    for row in ws.iter_rows(min_row=header + 2):
        for x_cell, y_cell in zip(row[2::2], row[3::2]):
            x, y = x_cell.value, y_cell.value
            if x is None or (x, y) == (-1, -1):
                continue
            x_cell.value, y_cell.value = c * x - s * y, flip * (s * x + c * y)
    wb.save(dest)
    return dest


def test_a_right_handed_tilted_export_gives_the_same_analysis_directly_and_via_a_bag(
        tmp_path, capsys):
    """The same strike exported Right-Handed at a tilt of 180° (the original: Left-Handed at
    180°): `mantis analyze` on the file and on the bag that `mantis import-tracking` makes of
    it give the original's numbers, the body pivot included (the bag carries the frame's
    handedness and tilt)."""
    variant = reexported(PAIR, tmp_path / 'right_180.xlsx', 'right', 180.0)
    tracks = load_tracks(variant)
    assert (tracks.handedness, tracks.tilt_deg) == ('right', 180.0)
    assert main(['import-tracking', str(variant), '--out', str(tmp_path / 'bag')]) == 0
    capsys.readouterr()
    bag = read_trial_bag(tmp_path / 'bag')
    assert (bag.tracks.handedness, bag.tracks.tilt_deg) == ('right', 180.0)
    original = analyze_json(capsys, PAIR)[1]
    for path in (variant, tmp_path / 'bag'):
        code, report, err = analyze_json(capsys, path)
        assert code == 0, err
        for key, value in original.items():
            if key == 'input' or value is None or isinstance(value, str):
                assert key == 'input' or report[key] == value, (path, key)
                continue
            assert report[key] == pytest.approx(value, rel=1e-9, abs=1e-12, nan_ok=True), \
                (path, key)
    assert original['peak_tip_speed_mps'] == pytest.approx(24.17, abs=0.01)


def test_a_mirror_image_is_refused_on_both_routes(tmp_path, capsys):
    """Only the calibration's system changed, not the numbers: the file shows the robot
    mirrored, and both routes refuse it alike (the bag route used to take it for the
    left-handed original)."""
    wb = load_workbook(PAIR)
    for row in wb.worksheets[0].iter_rows(max_row=40):
        if str(row[0].value or '').startswith('Calibration 1'):
            row[1].value = row[1].value.replace('Left-Handed', 'Right-Handed')
    wb.save(tmp_path / 'mirrored.xlsx')
    code, _, direct = run(capsys, 'analyze', tmp_path / 'mirrored.xlsx')
    assert code != 0 and 'mJ is outside' in direct
    run(capsys, 'import-tracking', tmp_path / 'mirrored.xlsx', '--out', tmp_path / 'bag')
    code, _, via_bag = run(capsys, 'analyze', tmp_path / 'bag')
    assert code != 0 and via_bag.split(': ', 2)[2] == direct.split(': ', 2)[2]


def test_a_bag_states_its_camera_frame(imported_bag, tmp_path):
    """A bag's trial conditions give the tracks their handedness and tilt; a bag that states
    none is the tracker's left-handed frame with the tilt unknown."""
    assert (read_trial_bag(imported_bag).tracks.handedness,
            read_trial_bag(imported_bag).tracks.tilt_deg) == ('left', None)
    turned = rewritten_copy(imported_bag, tmp_path / 'turned',
                            conditions={'handedness': 'right', 'tilt_deg': '90.0'})
    tracks = read_trial_bag(turned).tracks
    assert (tracks.handedness, tracks.tilt_deg) == ('right', 90.0)
    for key, value in (('handedness', 'up'), ('tilt_deg', 'north')):
        bad = rewritten_copy(imported_bag, tmp_path / key, conditions={key: value})
        with pytest.raises(TrackFormatError, match=key):
            read_trial_bag(bad)


def test_a_tracking_file_with_gaps_is_imported_and_analysed_as_directly(capsys, tmp_path):
    """Issue 25: a CSV with empty cells (frames where every marker was lost) was analysed by
    `mantis analyze` but ended `mantis import-tracking` in an IndexError: the angles were
    written by the file's frame index, the analysis having none for the gaps. Both routes now
    analyse the frames that were tracked, and give the same numbers."""
    import gzip
    lines = gzip.open(DATA, 'rt').read().splitlines()
    gaps = list(range(1000, 1010)) + list(range(30000, 30003))
    for k in gaps:
        cells = lines[k + 1].split(',')
        lines[k + 1] = ','.join(cells[:2] + [''] * (len(cells) - 2))
    with_gaps = tmp_path / 'gaps.csv'
    with_gaps.write_text('\n'.join(lines) + '\n')
    bag = tmp_path / 'bag'
    code, out, err = run(capsys, 'import-tracking', with_gaps, '--out', bag)
    assert code == 0 and err == '', err
    analysis = analyze_tracks(load_tracks(with_gaps))
    assert len(analysis.time_s) == N_FRAMES - len(gaps)
    reader = BagReader(bag)
    assert reader.topics[ANGLES_TOPIC].message_count == N_FRAMES - len(gaps)
    angles = [m for _, _, _, m in reader.messages([ANGLES_TOPIC])]
    for i in (999, 1000, 40_000):          # the last before the first gap, then after it
        stamp = angles[i].header.stamp
        assert stamp.sec + stamp.nanosec * 1e-9 == pytest.approx(analysis.time_s[i], abs=1e-9)
        assert list(angles[i].position) == [analysis.theta1_rad[i], analysis.theta3_rad[i]]
    code, direct, _ = analyze_json(capsys, with_gaps)
    assert code == 0
    code, from_bag, _ = analyze_json(capsys, bag)
    assert code == 0
    for key in ('peak_tip_speed_mps', 'max_spring_energy_mJ', 'L1_mm', 'peak_tip_speed_s'):
        assert from_bag[key] == pytest.approx(direct[key], rel=1e-9), key


def test_a_bag_whose_scene_cannot_be_loaded_is_refused_unless_the_geometry_is_given(
        imported_bag, capsys, tmp_path):
    """Issue 25: a bag naming a scene that could not be loaded was analysed with the default
    geometry, spring and inertia, silently. It is refused, naming the bag, the scene and why;
    given d_t and the contact angle, it is analysed, and the output says what was assumed."""
    bag = rewritten_copy(imported_bag, tmp_path / 'unknown_scene',
                         conditions={'scene': 'no_such_scene'})
    code, out, err = run(capsys, 'analyze', bag)
    assert code == 2 and out == ''
    assert err.count('\n') == 1 and err.startswith(f'mantis analyze: {bag}: ')
    assert "scene 'no_such_scene', which cannot be loaded" in err
    assert '--d-t-mm and --contact-angle-deg' in err
    code, out, err = run(capsys, 'analyze', bag, '--json', '--d-t-mm', 23,
                         '--contact-angle-deg', 3)
    assert code == 0, err
    assumed = json.loads(out)['input']['parameters']
    assert any("scene 'no_such_scene' could not be loaded" in note and 'assumed' in note
               for note in assumed), assumed
