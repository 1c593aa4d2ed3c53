"""`mantis analyze PATHS... --table`: many trials in parallel, one row each, refusals never stop
the batch; and --frame-rate / --length-unit for the tracker's exports that need them.

Kept light: the trials are the real pair trial's CSV (16,266 frames, ~0.3 s to analyse) in
several forms, plus files that must be refused.
"""
import contextlib
import csv
import gzip
import io
import json
import shutil

from conftest import data_file
import numpy as np
import pytest

from mantis_rig.analysis import batch, one_trial
from mantis_rig.analysis.inputs import tracker_export
from mantis_rig.cli import main
from mantis_rig.cli import options as cli_options

PAIR_CSV = data_file('real_trials/air_23mm_19kfps_pair_track.csv')
REFERENCE = data_file('air_23mm_2p3mmps_trial1_markers.csv.gz')
CALIBRATION = ('Name: Calibration1, Type: Normal, Scale: 6.46952 pixels/millimeter,        '
               '0.154571 millimeters/pixel, Origin: 224.5, 314.3 pixels, Tilt: 180 degrees, '
               'System: Left-Handed Coordinate, Calibration Units: Millimeters')


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def read_table(text):
    rows = list(csv.DictReader(io.StringIO(text)))
    assert rows and list(rows[0]) == list(batch.COLUMNS)
    return rows


def export_with_header(path, rate='19000', units='Millimeters', video='trial.avi',
                       frame_numbers=False):
    """The pair trial's CSV with the tracker's header block in front (as some of the lab's
    CSV files carry it); ``frame_numbers``: the Time column holds frame numbers (N/A rate)."""
    lines = PAIR_CSV.read_text().splitlines()
    if frame_numbers:
        lines = lines[:2] + [','.join([r.split(',', 1)[0]] * 2 + r.split(',')[2:])
                             for r in lines[2:]]
    header = ['Motion Analysis Data Sheet', '', 'Test Data', f'File Name:,{video}',
              f'Record Rate:,{rate}', '', 'Calibration(s)', f'Calibration 1:,"{CALIBRATION}"',
              f'Export Units:,{units}', '', 'Tracking Data']
    path.write_text('\r\n'.join(header + lines) + '\r\n')
    return path


@pytest.fixture(scope='module')
def pair_report():
    """`mantis analyze` of the pair CSV, the single-trial way (JSON)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(['analyze', str(PAIR_CSV), '--json']) == 0
    return json.loads(out.getvalue())


# --------------------------------------------------------------------------- the batch
@pytest.mark.slow
def test_batch_writes_one_row_per_trial_and_reports_refusals(tmp_path, capsys, pair_report):
    trials = tmp_path / 'trials'
    (trials / 'nested' / 'deeper').mkdir(parents=True)
    shutil.copy(PAIR_CSV, trials / 'pair_track.csv')
    (trials / 'nested' / 'pair_track.csv.gz').write_bytes(gzip.compress(PAIR_CSV.read_bytes()))
    (trials / 'nested' / 'deeper' / 'broken.xlsx').write_bytes(b'PK\x03\x04 not really')
    (trials / 'notes.txt').write_text('not a trial')
    (trials / '.hidden.csv').write_text('never a trial')
    bag = trials / 'nested' / 'pair_bag'
    code, _, err = run(capsys, 'import-tracking', PAIR_CSV, '--out', bag, '--no-angles')
    assert code == 0, err
    table = tmp_path / 'out.csv'
    code, out, err = run(capsys, 'analyze', trials, '--table', table, '--jobs', 2)
    assert code == 1, err
    assert out == ''
    assert err.strip().splitlines()[-1] == (
        f'3 of 4 trials analysed; 1 refused: see the reason column in {table}')
    rows = read_table(table.read_text())
    assert [r['path'] for r in rows] == [str(trials / p) for p in (
        'nested/deeper/broken.xlsx', 'nested/pair_bag', 'nested/pair_track.csv.gz',
        'pair_track.csv')]
    broken, from_bag, gz, plain = rows
    assert broken['status'] == 'refused' and 'broken.xlsx' in broken['reason']
    assert broken['trial'] == 'broken' and broken['peak_tip_speed_mps'] == ''
    for row in (from_bag, gz, plain):
        assert row['status'] == 'ok' and row['reason'] == '', row
        assert int(row['n_frames']) == 16266
        assert float(row['frame_rate_hz']) == pytest.approx(19000, rel=1e-3)
        assert float(row['peak_tip_speed_mps']) == pytest.approx(
            pair_report['peak_tip_speed_mps'], rel=1e-8)
        for phase in batch.PHASES:
            assert float(row[f'phase_{phase}_start_s']) == pytest.approx(
                pair_report['phase_start_s'][phase], rel=1e-8, abs=1e-9)
        for key in ('overcentering_s', 'peak_body_speed_radps', 'peak_arm_speed_radps',
                    'max_spring_energy_mJ', 'L1_mm'):
            assert float(row[key]) == pytest.approx(pair_report[key], rel=1e-8), key
        assert row['contact_angle_deg'] == ''     # unknown: not given, not in the files
    assert plain['trial'] == 'pair_track' and from_bag['trial'] == 'pair_bag'
    # Progress went to stderr, one line per trial (stderr is not a terminal here).
    assert sum(line.startswith('[') for line in err.splitlines()) == 4


def test_batch_refuses_what_analysis_refuses_and_what_crashes(tmp_path, monkeypatch):
    """Synthetic tracks the analysis finds implausible, a missing path, an unexpected
    exception type: each a refused row with its reason; the others still analysed."""
    from test_tracker_export import header_block, motion, tracking_rows, write_xlsx
    synthetic = write_xlsx(tmp_path / 'synthetic.xlsx', header_block()
                           + tracking_rows(motion(n=300)))
    rows = batch.run_batch([synthetic, tmp_path / 'absent.csv'], jobs=1)
    assert [r['status'] for r in rows] == ['refused', 'refused']
    assert rows[0]['reason'].startswith('analysis failed: ') and rows[0]['n_frames'] == 300
    assert 'No such file' in rows[1]['reason']

    def explode(*_):
        raise KeyError('boom')
    monkeypatch.setattr(one_trial, 'analyze_tracks', explode)
    row = batch.analyse_one(PAIR_CSV)
    assert row['status'] == 'refused'
    assert row['reason'] == "unexpected KeyError in analysis: 'boom'"
    assert row['n_frames'] == 16266 and row['trial'] == 'air_23mm_19kfps_pair_track'


@pytest.mark.slow
def test_table_on_stdout_and_conditions_for_every_trial(capsys, tmp_path, pair_report):
    code, out, err = run(capsys, 'analyze', PAIR_CSV, '--table', '-')
    assert code == 0, err
    assert err.strip().splitlines()[-1] == '1 of 1 trials analysed: the table on stdout'
    (row,) = read_table(out)
    assert float(row['peak_tip_speed_mps']) == pytest.approx(pair_report['peak_tip_speed_mps'],
                                                             rel=1e-8)
    # Several paths without --table: the table goes to stdout. The conditions apply to every
    # trial, as they apply to the one trial of `mantis analyze PATH`.
    conditions = ('--d-t-mm', 19, '--contact-angle-deg', 3.2)
    code, out, err = run(capsys, 'analyze', REFERENCE, PAIR_CSV, *conditions, '--jobs', 2)
    assert code == 0, err
    reference, pair = read_table(out)
    code, out, err = run(capsys, 'analyze', REFERENCE, '--json', *conditions)
    assert code == 0, err
    single = json.loads(out)
    assert single['input']['parameters'] == ['d_t = 19 mm (given)',
                                             'contact angle 3.2 deg (given)']
    for key in ('peak_tip_speed_mps', 'overcentering_s', 'contact_angle_deg', 'L1_mm'):
        assert float(reference[key]) == pytest.approx(single[key], rel=1e-9), key
    assert float(pair['contact_angle_deg']) == pytest.approx(3.2)
    assert float(pair['peak_tip_speed_mps']) != pytest.approx(   # cos θ3 in the tip speed
        pair_report['peak_tip_speed_mps'], rel=1e-4)


def test_batch_usage_errors(capsys, tmp_path):
    code, _, err = run(capsys, 'analyze', PAIR_CSV, '--table', tmp_path / 'no' / 'out.csv')
    assert code == 2 and 'no such directory' in err
    code, _, err = run(capsys, 'analyze', PAIR_CSV, '--table', tmp_path)
    assert code == 2 and 'is a directory' in err
    code, _, err = run(capsys, 'analyze', PAIR_CSV, PAIR_CSV, '--json')
    assert code == 2 and '--json and --plot apply to one trial' in err
    (tmp_path / 'empty').mkdir()
    code, _, err = run(capsys, 'analyze', tmp_path / 'empty', '--table', '-')
    assert code == 2 and 'no tracking files' in err and 'no trials' in err
    with pytest.raises(SystemExit) as exc:
        main(['analyze', str(PAIR_CSV), '--table', '-', '--jobs', '0'])
    assert exc.value.code == 2 and '--jobs' in capsys.readouterr().err
    code, _, err = run(capsys, 'analyze', tmp_path / 'empty', '--d-t-mm', 0.5, '--table', '-')
    assert code == 2 and '--d-t-mm' in err


def test_the_table_being_written_is_not_a_trial(tmp_path, capsys):
    trials = tmp_path / 'trials'
    trials.mkdir()
    shutil.copy(PAIR_CSV, trials / 'pair_track.csv')
    table = trials / 'results.csv'
    table.write_text('an earlier table\n')
    code, _, err = run(capsys, 'analyze', trials, '--table', table)
    assert code == 0, err
    assert [r['path'] for r in read_table(table.read_text())] == [str(trials / 'pair_track.csv')]


# ------------------------------------------------------------------- the parts, directly
def test_expand_paths(tmp_path):
    root = tmp_path / 'root'
    for d in ('a/b', 'bag_ok', 'bag_crashed', '.git', 'c'):
        (root / d).mkdir(parents=True)
    (root / 'bag_ok' / 'metadata.yaml').write_text('')
    (root / 'bag_ok' / 'bag_ok_0.mcap').write_bytes(b'')
    (root / 'bag_crashed' / 'bag_crashed_0.mcap').write_bytes(b'')
    for f in ('a/t1.xlsx', 'a/b/t2.CSV', 'a/b/t3.csv.gz', 'c/t4.csv', 'a/readme.md',
              'a/~$t1.xlsx', 'a/.t5.csv', '.git/t6.csv', 'c/t7.txt', 'c/out.csv'):
        (root / f).write_bytes(b'')
    (tmp_path / 'empty').mkdir()
    trials, notes = batch.expand_paths([root, root / 'a' / 't1.xlsx', root / 'c' / 't7.txt',
                                        tmp_path / 'absent.xlsx', tmp_path, tmp_path / 'empty'],
                                       exclude=[root / 'c' / 'out.csv'])
    rel = [p.relative_to(tmp_path).as_posix() for p in trials]
    assert rel == ['root/a/b/t2.CSV', 'root/a/b/t3.csv.gz', 'root/a/t1.xlsx', 'root/bag_crashed',
                   'root/bag_ok', 'root/c/t4.csv', 'root/c/t7.txt', 'absent.xlsx']
    assert notes == [f'{tmp_path / "empty"}: no tracking files (.xlsx, .csv, .csv.gz) or bags '
                     'in it']
    assert batch.expand_paths([root / 'bag_ok'])[0] == [root / 'bag_ok']


def test_progress_on_a_terminal_and_in_a_log():
    class Terminal(io.StringIO):
        def isatty(self):
            return True
    rows = [{'path': 'x/a.csv', 'trial': 'a', 'status': 'ok', 'reason': ''},
            {'path': 'x/b.xlsx', 'trial': 'b', 'status': 'refused', 'reason': 'damaged'}]
    term = Terminal()
    progress = batch.Progress(2, term, width=10)
    for row in rows:
        progress(row)
    progress.close()
    text = term.getvalue()
    assert text.startswith('\r[#####     ] 1/2 a')
    assert 'refused x/b.xlsx: damaged\n' in text and '\r[##########] 2/2 b' in text
    assert text.endswith('\n') and text.count('\n') == 2
    log = io.StringIO()
    progress = batch.Progress(2, log)
    for row in rows:
        progress(row)
    progress.close()
    assert log.getvalue() == '[1/2] ok x/a.csv\n[2/2] refused x/b.xlsx: damaged\n'


def test_table_cells():
    out = io.StringIO()
    row = dict.fromkeys(batch.COLUMNS)
    row.update(path='p', trial='t', status='ok', reason='', peak_tip_speed_mps=27.123456789012,
               overcentering_s=float('nan'), n_frames=100, warnings='a, "b"')
    batch.write_table([row], out)
    (back,) = read_table(out.getvalue())
    assert back['peak_tip_speed_mps'] == '27.12345679' and back['overcentering_s'] == ''
    assert back['n_frames'] == '100' and back['warnings'] == 'a, "b"'


# ------------------------------------------------- --frame-rate and --length-unit
def test_frame_rate_option(tmp_path, capsys, pair_report):
    path = export_with_header(tmp_path / 'na_track.csv', rate='N/A', frame_numbers=True)
    code, _, err = run(capsys, 'analyze', path, '--json')
    assert code == 2 and '--frame-rate' in err
    code, out, err = run(capsys, 'analyze', path, '--json', '--frame-rate', 19000)
    assert code == 0, err
    report = json.loads(out)
    # The times are frame / 19000 here, the CSV's are rounded to 0.1 µs: close, not equal.
    assert report['peak_tip_speed_mps'] == pytest.approx(pair_report['peak_tip_speed_mps'],
                                                         rel=1e-3)
    assert report['phase_start_s']['IV'] == pytest.approx(pair_report['phase_start_s']['IV'],
                                                          abs=1e-6)
    code, _, err = run(capsys, 'import-tracking', path, '--out', tmp_path / 'bag',
                       '--frame-rate', 19000, '--no-angles')
    assert code == 0, err
    code, _, err = run(capsys, 'import-tracking', path, '--out', tmp_path / 'bag2',
                       '--no-angles')
    assert code == 2 and '--frame-rate' in err and not (tmp_path / 'bag2').exists()
    for bad in ('0', '-5', 'nan', 'fast'):
        with pytest.raises(SystemExit) as exc:
            main(['analyze', str(path), '--frame-rate', bad])
        assert exc.value.code == 2


def test_length_unit_option(tmp_path, capsys, pair_report):
    """The lab's file whose Export Units say Micrometers while its numbers are millimetres:
    --length-unit mm reads it as the millimetres it holds."""
    path = export_with_header(tmp_path / 'um_track.csv', units='Micrometers')
    code, out, err = run(capsys, 'analyze', path, '--json', '--length-unit', 'mm')
    assert code == 0, err
    assert json.loads(out)['peak_tip_speed_mps'] == pytest.approx(
        pair_report['peak_tip_speed_mps'], rel=1e-8)
    code, out, err = run(capsys, 'analyze', path, '--table', '-')   # believed: micrometres
    assert code == 1 and read_table(out)[0]['status'] == 'refused'
    with pytest.raises(SystemExit):
        main(['analyze', str(path), '--length-unit', 'inch'])
    assert cli_options.LENGTH_UNITS == tracker_export.LENGTH_UNITS


def test_export_options_are_refused_with_a_bag(tmp_path, capsys):
    bag = tmp_path / 'bag'
    code, _, err = run(capsys, 'import-tracking', PAIR_CSV, '--out', bag, '--no-angles')
    assert code == 0, err
    code, _, err = run(capsys, 'analyze', bag, '--frame-rate', 19000)
    assert code == 2 and 'is a bag' in err and '--frame-rate' in err
    code, _, err = run(capsys, 'analyze', bag, PAIR_CSV, '--length-unit', 'mm', '--table', '-')
    assert code == 2 and str(bag) in err
    code, out, err = run(capsys, 'analyze', bag, '--table', '-')
    assert code == 0 and read_table(out)[0]['status'] == 'ok'
    assert np.isfinite(float(read_table(out)[0]['peak_tip_speed_mps']))
