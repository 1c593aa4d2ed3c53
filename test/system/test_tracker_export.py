"""The tracker's exports (.xlsx and CSV) in every variant of shared/docs/tracking_export.md.

Each variant is built here from synthetic marker motion (openpyxl for .xlsx, CSV text with the
lab's quirks), read back with load_tracks and compared with what was written; seeded damaged
copies of a real export are read or refused. Every shared .xlsx export reads into the tracks
that openpyxl's reading of it gives (the reference: the reader under test is python-calamine).
That every real export loads as it states itself is checked with the analysis of the real
trials (test_analysis_real_trials.py), which reads each file once.
"""
import csv
import io
import re
import zipfile

from conftest import data_file
import numpy as np
from openpyxl import Workbook, load_workbook
import pytest

from mantis_rig.analysis import TrackFormatError, load_tracks
from mantis_rig.analysis.inputs import tracker_export as te

N = 240                      # frames of every generated export
RATE = 19000
FIVE = ('mb1', 'mb2', 'mb3', 'ma1', 'ma2')
MM_PER_PX = 0.1695
CALIBRATION = ('Name: Calibration1, Type: Normal, Scale: 5.89969 pixels/millimeter,        '
               '0.1695 millimeters/pixel, Origin: 195.7, 293.5 pixels, Tilt: 0 degrees, '
               'System: Left-Handed Coordinate, Calibration Units: Millimeters')
VIDEO = r'F:\Lab\Mantis Shrimp TORSION\031320\031320_19kfps_T_2X_A_1_1_2p3_-6_7_1\031320_19kfps' \
        r'_T_2X_A_1_1_2p3_-6_7_1.avi'
VIDEO_11K = r'F:\Lab\111319\111319_11kfps_T_2X_A_2_1_2p3_-10_5_2\111319_11kfps_T_2X_A_2_1_2p3' \
            r'_-10_5_2.avi'
VIDEO_NO_RATE = r'F:\Lab\111319\trial_T_2X_A_2_1_2p3_-10_5_2\trial_T_2X_A_2_1_2p3_-10_5_2.avi'


# ------------------------------------------------------------------------------ builders
def motion(names=FIVE, n=N) -> dict:
    """Marker positions (mm): body markers on slow arcs, arm markers on fast ones."""
    k = np.arange(n)
    out = {}
    for i, name in enumerate(names):
        rate = 0.002 if name.startswith('mb') else 0.01
        angle = 0.7 * i + rate * k + 0.3 * np.sin(k / 17.0)
        radius = 4.0 + 3.0 * i
        out[name] = np.column_stack([radius * np.cos(angle) + 10.0,
                                     radius * np.sin(angle) - 12.0])
    return out


def header_block(rate=RATE, units='Millimeters', calibration=CALIBRATION, video=VIDEO,
                 extra=False) -> list:
    """The rows above the column header, as the tracker writes them (``extra``: more blank
    rows, labels on other rows, an unknown label and a second calibration-like title)."""
    rows = [['Motion Analysis Data Sheet']] + [[]] * 7 + [['Test Data']]
    if extra:
        rows += [[], [], ['Operator:', 'someone'], []]
    rows += [['Date:', '2020-03-13', None, 'Time:', '17:23:07'], ['File Name:', video],
             ['Record Rate:', rate], []]
    if extra:
        rows += [[], ['Notes', None, 'free text: with a colon'], []]
    rows += [['Calibration(s)'], ['Calibration 1:', calibration], ['Export Units:', units]]
    rows += [[]] * (7 if extra else 4) + [['Tracking Data']]
    return rows


def tracking_rows(markers: dict, order=None, numbers=None, time=None, scale=1.0,
                  rate=RATE) -> list:
    """The column header, the x/y row and one row per frame (markers in ``order``, features
    numbered ``numbers``; ``time``: the Time column, default seconds at ``rate``)."""
    order = list(order or markers)
    numbers = numbers or range(1, len(order) + 1)
    n = len(next(iter(markers.values())))
    labels = ['Frame', 'Time']
    for number, name in zip(numbers, order):
        labels += [f'Feature {number} ({name})', None]
    rows = [labels, [None, None] + ['x', 'y'] * len(order)]
    time = np.round(np.arange(n) / rate, 7) if time is None else time
    for f in range(n):
        row = [f, float(time[f])]
        for name in order:
            x, y = markers[name][f]
            row += [float(x) * scale, float(y) * scale]
        rows.append(row)
    return rows


def write_xlsx(path, rows):
    wb = Workbook()
    ws = wb.active
    for row in rows:
        ws.append(list(row))
    wb.save(path)
    return path


def csv_text(rows, crlf=True, digits=10) -> str:
    """Rows as the lab's CSV: numbers at ``digits`` significant digits, blanks empty, text
    quoted where it holds a comma."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\r\n' if crlf else '\n')
    for row in rows:
        writer.writerow(['' if v is None else f'{v:.{digits}g}' if isinstance(v, float) else v
                         for v in row])
    return out.getvalue()


def assert_markers(tracks, markers, scale=1.0, atol=1e-12):
    assert sorted(tracks.markers_mm) == sorted(markers)
    for name, xy in markers.items():
        np.testing.assert_allclose(tracks.markers_mm[name], xy * scale, rtol=1e-9, atol=atol,
                                   err_msg=name)


# ------------------------------------------------------------------- the .xlsx variants
def test_the_standard_layout(tmp_path):
    markers = motion()
    path = write_xlsx(tmp_path / 'std.xlsx', header_block() + tracking_rows(markers))
    tracks = load_tracks(path)
    assert tracks.n_frames == N
    assert tracks.body_markers == ['mb1', 'mb2', 'mb3'] and tracks.arm_markers == ['ma1', 'ma2']
    np.testing.assert_array_equal(tracks.frames, np.arange(N))
    np.testing.assert_allclose(tracks.time_s, np.round(np.arange(N) / RATE, 7), atol=1e-15)
    assert_markers(tracks, markers)
    assert tracks.source['format'] == 'xlsx'
    assert tracks.frame_rate_hz == RATE
    assert tracks.handedness == 'left' and tracks.tilt_deg == 0.0


def test_labels_on_other_rows_with_extra_blank_rows(tmp_path):
    """The blocks are found by their labels, wherever the rows fall."""
    markers = motion()
    rows = [[]] * 3 + header_block(extra=True) + [[], []] + tracking_rows(markers)
    path = write_xlsx(tmp_path / 'moved.xlsx', rows)
    tracks = load_tracks(path)
    assert tracks.n_frames == N and tracks.frame_rate_hz == RATE
    assert tracks.source['operator'] == 'someone'
    assert tracks.source['export units'] == 'Millimeters'
    assert tracks.source['calibration_units_per_pixel'] == MM_PER_PX
    assert_markers(tracks, markers)


def test_calibration_string_is_parsed():
    cal = te.parse_calibration(CALIBRATION)
    assert cal == {'units_per_pixel': 0.1695, 'pixels_per_unit': 5.89969,
                   'origin_px': (195.7, 293.5), 'tilt_deg': 0.0, 'handedness': 'left',
                   'units': 'millimeters'}
    turned = CALIBRATION.replace('Tilt: 0 degrees', 'Tilt: 180 degrees') \
        .replace('Left-Handed', 'Right-Handed')
    cal = te.parse_calibration(turned)
    assert cal['tilt_deg'] == 180.0 and cal['handedness'] == 'right'
    # Only the pixels/unit scale stated: the units per pixel follow from it.
    cal = te.parse_calibration('Scale: 6.5 pixels/micrometer, Calibration Units: Micrometers')
    assert cal['units_per_pixel'] == pytest.approx(1 / 6.5) and cal['units'] == 'micrometers'


def test_calibration_reaches_the_tracks(tmp_path):
    markers = motion()
    turned = CALIBRATION.replace('Tilt: 0 degrees', 'Tilt: 180 degrees') \
        .replace('Left-Handed', 'Right-Handed').replace('195.7, 293.5', '226.5, 261.4')
    rows = header_block(calibration=turned) + tracking_rows(markers)
    tracks = load_tracks(write_xlsx(tmp_path / 'turned.xlsx', rows))
    assert tracks.tilt_deg == 180.0 and tracks.handedness == 'right'
    assert tracks.source['calibration_units_per_pixel'] == MM_PER_PX
    meta = te.parse_export_rows(rows, 'turned.xlsx').source
    assert meta['calibration_origin_px'] == (226.5, 261.4)
    assert meta['calibration_tilt_deg'] == 180.0


@pytest.mark.parametrize('units, written_scale, read_scale', [
    ('Millimeters', 1.0, 1.0),
    ('Pixels', 1.0 / MM_PER_PX, 1.0),            # pixels, converted back by the calibration
    ('Micrometers', 1.0, 1e-3),                  # believed as labelled (override: below)
])
def test_export_units(tmp_path, units, written_scale, read_scale):
    markers = motion()
    path = write_xlsx(tmp_path / f'{units}.xlsx',
                      header_block(units=units) + tracking_rows(markers, scale=written_scale))
    tracks = load_tracks(path)
    assert_markers(tracks, markers, scale=read_scale)


def test_length_unit_overrides_the_export_units(tmp_path):
    """The file whose Micrometers are in fact millimetres; a Pixels export read as given."""
    markers = motion()
    microns = write_xlsx(tmp_path / 'um.xlsx', header_block(units='Micrometers')
                         + tracking_rows(markers))
    assert_markers(load_tracks(microns, length_unit='mm'), markers)
    assert load_tracks(microns, length_unit='mm').source['length_unit_source'] == 'given'
    assert_markers(load_tracks(microns, length_unit='um'), markers, scale=1e-3)
    pixels = write_xlsx(tmp_path / 'mm_but_px.xlsx', header_block(units='Millimeters')
                        + tracking_rows(markers, scale=1 / MM_PER_PX))
    assert_markers(load_tracks(pixels, length_unit='px'), markers)
    with pytest.raises(TrackFormatError, match='length unit'):
        load_tracks(pixels, length_unit='inch')


def test_unknown_export_units_are_refused(tmp_path):
    path = write_xlsx(tmp_path / 'furlongs.xlsx', header_block(units='Furlongs')
                      + tracking_rows(motion()))
    with pytest.raises(TrackFormatError, match="unknown Export Units 'Furlongs'"):
        load_tracks(path)


# ---------------------------------------------------------------------- Record Rate N/A
def frame_number_export(tmp_path, video, name):
    """Record Rate N/A: the Time column holds the frame numbers."""
    markers = motion()
    rows = header_block(rate='N/A', video=video) + tracking_rows(
        markers, time=np.arange(N, dtype=float))
    return write_xlsx(tmp_path / name, rows), markers


def test_rate_not_stated_comes_from_the_trial_name(tmp_path):
    path, markers = frame_number_export(tmp_path, VIDEO_11K, 'na.xlsx')
    tracks = load_tracks(path)
    np.testing.assert_allclose(tracks.time_s, np.arange(N) / 11000.0, rtol=1e-12)
    assert tracks.frame_rate_hz == 11000.0
    assert tracks.source['frame_rate_source'] == 'trial name'
    assert_markers(tracks, markers)


def test_rate_stated_nowhere_is_refused_naming_the_option(tmp_path):
    path, _ = frame_number_export(tmp_path, VIDEO_NO_RATE, 'na.xlsx')
    with pytest.raises(TrackFormatError, match='--frame-rate'):
        load_tracks(path)


def test_rate_given_by_the_caller(tmp_path):
    path, markers = frame_number_export(tmp_path, VIDEO_NO_RATE, 'na.xlsx')
    tracks = load_tracks(path, frame_rate_hz=8000.0)
    np.testing.assert_allclose(tracks.time_s, np.arange(N) / 8000.0, rtol=1e-12)
    assert tracks.source['frame_rate_source'] == 'given'
    assert_markers(tracks, markers)
    # Given where the name carries one: the caller's wins.
    path, _ = frame_number_export(tmp_path, VIDEO_11K, 'na11k.xlsx')
    assert load_tracks(path, frame_rate_hz=8000.0).frame_rate_hz == 8000.0


def test_rate_given_against_the_record_rate_is_refused(tmp_path):
    path = write_xlsx(tmp_path / 'std.xlsx', header_block() + tracking_rows(motion()))
    with pytest.raises(TrackFormatError, match='contradicts'):
        load_tracks(path, frame_rate_hz=11000.0)
    assert load_tracks(path, frame_rate_hz=float(RATE)).n_frames == N


# -------------------------------------------------------------------------- marker sets
@pytest.mark.parametrize('order', [
    ('mb1', 'mb2', 'mb3', 'ma1', 'ma2'),
    ('ma2', 'mb3', 'ma1', 'mb1', 'mb2'),           # any order
    ('mb1', 'mb2', 'ma1', 'ma3', 'ma2'),           # ma3 naming
    ('mb1', 'mb2', 'ma1', 'ma2', 'ma3'),
    ('mb1', 'mb2', 'ma1', 'ma2'),                  # four markers
])
def test_marker_sets_and_orders(tmp_path, order):
    markers = motion(order)
    path = write_xlsx(tmp_path / 'set.xlsx', header_block() + tracking_rows(markers, order))
    tracks = load_tracks(path)
    assert tracks.body_markers == sorted(n for n in order if n.startswith('mb'))
    assert tracks.arm_markers == sorted(n for n in order if n.startswith('ma'))
    assert_markers(tracks, markers)


def test_lost_markers_are_gaps(tmp_path):
    markers = motion()
    lost = np.zeros(N, bool)
    lost[100:160] = True
    markers['ma2'][lost] = -1.0
    markers['ma1'][170:200] = -1.0
    markers['ma1'][50] = (-1.0, 3.0)               # one coordinate at -1: a position
    path = write_xlsx(tmp_path / 'lost.xlsx', header_block() + tracking_rows(markers))
    tracks = load_tracks(path)
    assert np.isnan(tracks.markers_mm['ma2'][lost]).all()
    assert np.isfinite(tracks.markers_mm['ma2'][~lost]).all()
    assert np.isnan(tracks.markers_mm['ma1'][170:200]).all()
    np.testing.assert_array_equal(tracks.markers_mm['ma1'][50], [-1.0, 3.0])
    for name in ('mb1', 'mb2', 'mb3'):
        assert np.isfinite(tracks.markers_mm[name]).all()
    keep = ~lost
    np.testing.assert_allclose(tracks.markers_mm['ma2'][keep], markers['ma2'][keep])


def test_a_cell_that_is_not_a_number_is_refused_naming_its_row(tmp_path):
    rows = header_block() + tracking_rows(motion())
    header_row = next(i for i, r in enumerate(rows) if r and r[0] == 'Frame')
    bad = header_row + 2 + 120                    # 0-based index of frame 120's row
    rows[bad] = list(rows[bad])
    rows[bad][5] = 'lost'
    path = write_xlsx(tmp_path / 'text.xlsx', rows)
    with pytest.raises(TrackFormatError, match=rf"row {bad + 1}: 'lost' is not a number"):
        load_tracks(path)
    path = tmp_path / 'text.csv'
    path.write_text(csv_text(rows))
    with pytest.raises(TrackFormatError, match=rf"row {bad + 1}: 'lost' is not a number"):
        load_tracks(path)


# --------------------------------------------------------------------- damaged .xlsx
def _damaged(tmp_path):
    good = write_xlsx(tmp_path / 'good.xlsx', header_block() + tracking_rows(motion()))
    data = good.read_bytes()
    other = tmp_path / 'other.zip'
    with zipfile.ZipFile(other, 'w') as z:
        z.writestr('readme.txt', 'not a workbook')
    return {'empty': b'', 'text': b'Frame,Time\n0,0\n', 'truncated': data[:len(data) // 2],
            'zip_without_workbook': other.read_bytes(),
            'corrupt_middle': data[:len(data) // 3] + bytes(200) + data[len(data) // 3 + 200:]}


@pytest.mark.parametrize('kind', ['empty', 'text', 'truncated', 'zip_without_workbook',
                                  'corrupt_middle'])
def test_damaged_xlsx_is_refused_not_a_crash(tmp_path, kind):
    path = tmp_path / f'{kind}.xlsx'
    path.write_bytes(_damaged(tmp_path)[kind])
    with pytest.raises(TrackFormatError, match=re.escape(path.name)):
        load_tracks(path)


# ------------------------------------------------- the shared exports against openpyxl
SHARED_XLSX = ['air_23mm_2p3mmps_trial1_tracker_export.xlsx', 'real_trials/air_19mm_11kfps.xlsx',
               'real_trials/air_19mm_6kfps.xlsx', 'real_trials/air_23mm_19kfps_4markers.xlsx',
               'real_trials/air_23mm_19kfps_ma3.xlsx', 'real_trials/air_23mm_19kfps_pair.xlsx',
               'real_trials/water_23mm_19kfps.xlsx']


def openpyxl_rows(path) -> list[list]:
    """The reference: the first worksheet's rows as openpyxl reads them (the reader before
    python-calamine: read-only, cached values of formulas)."""
    wb = load_workbook(path, read_only=True, data_only=True)
    try:
        return [list(r) for r in wb.worksheets[0].iter_rows(values_only=True)]
    finally:
        wb.close()


def test_every_shared_xlsx_export_is_in_the_test():
    found = {str(p.relative_to(data_file('.'))) for p in data_file('.').rglob('*.xlsx')}
    assert found == set(SHARED_XLSX)


@pytest.mark.parametrize('rel', SHARED_XLSX)
def test_a_shared_export_reads_as_openpyxl_reads_it(rel):
    """Identical tracks: every time, frame and coordinate (NaN where openpyxl's has NaN), the
    camera frame, rate, unit and the header block's text in ``source``."""
    path = data_file(rel)
    tracks = load_tracks(path)
    reference = te.read_export(openpyxl_rows(path), path, 'xlsx')
    for field in ('time_s', 'frames'):
        np.testing.assert_array_equal(getattr(tracks, field), getattr(reference, field))
    assert tracks.markers_mm.keys() == reference.markers_mm.keys()
    for name, xy in reference.markers_mm.items():
        np.testing.assert_array_equal(tracks.markers_mm[name], xy, err_msg=name)
    for field in ('handedness', 'tilt_deg', 'frame_rate_hz', 'length_unit', 'source'):
        assert getattr(tracks, field) == getattr(reference, field), field


# ------------------------------------------------------------------------ the CSV form
def test_headerless_csv_crlf_trailing_comma_columns_out_of_order(tmp_path):
    """The lab's usual CSV: the column header first, features numbered out of order, a marker
    left out (features 1, 2, 3, 5, 4 of six), CRLF, 10 significant digits; times in seconds."""
    order = ('mb1', 'mb2', 'ma1', 'ma2', 'ma3')
    markers = motion(order)
    markers['ma2'][30:90] = -1.0
    rows = tracking_rows(markers, order, numbers=(1, 2, 3, 5, 4))
    text = csv_text(rows)
    first, rest = text.split('\r\n', 1)
    text = first + ',\r\n' + rest                 # and one more trailing comma on the header
    assert first.endswith('Feature 4 (ma3),') and '\r\n' in rest
    path = tmp_path / 'trial_track.csv'
    path.write_bytes(text.encode())
    tracks = load_tracks(path)
    assert tracks.source['format'] == 'csv' and tracks.n_frames == N
    np.testing.assert_allclose(tracks.time_s, np.round(np.arange(N) / RATE, 7), atol=1e-15)
    assert tracks.frame_rate_hz == pytest.approx(RATE, rel=1e-3)
    assert tracks.tilt_deg is None                # the CSV does not state the camera's tilt
    assert np.isnan(tracks.markers_mm['ma2'][30:90]).all()
    markers['ma2'][30:90] = np.nan
    for name, xy in markers.items():
        np.testing.assert_allclose(tracks.markers_mm[name], xy, rtol=1e-9, atol=1e-8)


def test_csv_with_the_header_block(tmp_path):
    """The full header block as CSV rows: the calibration string quoted (it holds commas)."""
    markers = motion()
    text = csv_text(header_block(rate=10000, units='Pixels')
                    + tracking_rows(markers, rate=10000, scale=1 / MM_PER_PX))
    assert f'Calibration 1:,"{CALIBRATION}"' in text
    path = tmp_path / 'with_header_track.csv'
    path.write_text(text, newline='')
    tracks = load_tracks(path)
    assert tracks.frame_rate_hz == 10000.0
    assert tracks.source['calibration_units_per_pixel'] == MM_PER_PX
    np.testing.assert_allclose(tracks.time_s, np.round(np.arange(N) / 10000, 7), atol=1e-15)
    assert_markers(tracks, markers, atol=1e-8)


def test_gzipped_csv_export(tmp_path):
    import gzip
    markers = motion()
    path = tmp_path / 'trial_track.csv.gz'
    path.write_bytes(gzip.compress(csv_text(tracking_rows(markers)).encode()))
    assert_markers(load_tracks(path), markers, atol=1e-8)


def test_csv_refusals(tmp_path):
    markers = motion()
    path = tmp_path / 'units.csv'
    path.write_text(csv_text(header_block(units='Furlongs') + tracking_rows(markers)))
    with pytest.raises(TrackFormatError, match='unknown Export Units'):
        load_tracks(path)
    path = tmp_path / 'na.csv'
    path.write_text(csv_text(header_block(rate='N/A', video=VIDEO_NO_RATE)
                             + tracking_rows(markers, time=np.arange(N, dtype=float))))
    with pytest.raises(TrackFormatError, match='--frame-rate'):
        load_tracks(path)
    assert load_tracks(path, frame_rate_hz=2000.0).time_s[-1] == pytest.approx((N - 1) / 2000)


# ------------------------------------------------------------------ seeded damaged copies
def _mutations(data: bytes, rng) -> bytes:
    """One damaged copy: truncated, bytes flipped, a range zeroed, a cell replaced by NaN /
    Inf / a huge or non-numeric value, rows shuffled, or garbage appended."""
    b = bytearray(data)
    kind = rng.randrange(6)
    if kind == 0:
        return bytes(b[:rng.randrange(len(b))])
    if kind == 1:
        for _ in range(rng.randrange(1, 20)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    if kind == 2:
        i = rng.randrange(len(b))
        j = min(len(b), i + rng.randrange(1, 3000))
        b[i:j] = bytes(j - i)
        return bytes(b)
    if kind == 3:
        cells = data.split(b',')
        cells[rng.randrange(len(cells))] = rng.choice(
            [b'nan', b'inf', b'-1e308', b'1e400', b'abc', b'', b'-1'])
        return b','.join(cells)
    if kind == 4:
        rows = data.split(b'\r\n')
        body = rows[2:]
        rng.shuffle(body)
        return b'\r\n'.join(rows[:2] + body)
    return data + rng.randbytes(rng.randrange(1, 100))


@pytest.mark.parametrize('suffix, copies', [('.csv', 200), ('.xlsx', 20)])
@pytest.mark.slow
def test_damaged_copies_are_read_or_refused(tmp_path, suffix, copies):
    """Seeded damaged copies of a real export: each is read into tracks that pass their own
    checks (finite, strictly increasing times; no (-1, -1) left as a position) or refused
    with a TrackFormatError; never another exception."""
    import random
    if suffix == '.csv':
        rows = data_file('real_trials/air_23mm_19kfps_pair_track.csv').read_bytes()
        data = b'\r\n'.join(rows.split(b'\r\n')[:600])
    else:
        data = data_file('real_trials/air_23mm_19kfps_pair.xlsx').read_bytes()
    rng = random.Random(20261125)
    outcomes = {'read': 0, 'refused': 0}
    for k in range(copies):
        path = tmp_path / f'copy{k}{suffix}'
        path.write_bytes(_mutations(data, rng))
        try:
            tracks = load_tracks(path)
        except TrackFormatError:
            outcomes['refused'] += 1
            continue
        outcomes['read'] += 1
        tracks.validate()
        assert np.all(np.isfinite(tracks.time_s)) and np.all(np.diff(tracks.time_s) > 0)
        for xy in tracks.markers_mm.values():
            assert not np.any(np.all(xy == -1.0, axis=1))
            assert not np.any(np.isinf(xy))
    assert outcomes['read'] > 0 and outcomes['refused'] > 0, outcomes
