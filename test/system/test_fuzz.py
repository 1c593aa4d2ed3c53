"""Fuzz suite (issue 16): damaged bags, bag metadata, tracking files and scenes are read or
refused with the reader's own error, never another exception, never a hang; a damaged tracking
file that is analysed gives only numbers the robot can produce.

Property-based with hypothesis. The CI profile (default) is small and deterministic; the long
profile runs by one command:

    MANTIS_FUZZ_PROFILE=long .venv/bin/python -m pytest -q test/system/test_fuzz.py

Each case writes the damaged copy to a fresh directory; the source files are never touched.
Damaged spreadsheets (.xlsx) are covered by test_tracker_export.py (seeded damaged copies of
real exports); the tracker's CSV export is fuzzed here, cell by cell and in its header.
"""
from collections import Counter
from pathlib import Path
import shutil
import struct
import tempfile
import warnings
import zlib

from fuzzing import both_outcomes, fuzz
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader
import numpy as np
import pytest
import yaml

from mantis_rig.analysis.inputs import TrackFormatError, read_trial
from mantis_rig.analysis.inputs.bag import read_trial_bag
from mantis_rig.analysis.one_trial import analyse_trial
from mantis_rig.recording import BagError, BagReader, BagWriter, TruncatedBagWarning
from mantis_rig.replay.synthetic import TOPICS, synthetic_messages
from mantis_sim.errors import InputError
from mantis_sim.parameters import ParameterError
from mantis_sim.scene import SceneError, load_scene_file

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.timeout(600), pytest.mark.slow]


# --------------------------------------------------------------------------- bags
@pytest.fixture(scope='module')
def source_bag(tmp_path_factory):
    """A small trial bag, uncompressed (so that records can be edited in place), in chunks
    of 4 kB."""
    path = tmp_path_factory.mktemp('fuzz') / 'trial'
    with BagWriter(path, sync_period_s=0, compression='none', chunk_size_bytes=4096) as bag:
        for topic, (type_name, qos) in TOPICS.items():
            bag.add_topic(topic, type_name, qos)
        bag.add_metadata('trial_conditions', {'medium': 'air', 'd_t_mm': '23.0'})
        for topic, msg, t_ns in synthetic_messages(duration_s=0.3, marker_blocks=2,
                                                   frames_per_block=50):
            bag.write(topic, msg, t_ns)
        bag.close(trial_outcome={'result': 'completed'})
    return path


def read_everything(bag: Path) -> str:
    """What analyze, replay and recover do with a bag before any analysis: open it, decode
    every message, read the trial's marker and force blocks. Only the readers' own errors may
    come out. Returns 'read' or 'refused'."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', TruncatedBagWarning)
        try:
            reader = BagReader(bag, warn=False)
            for _ in reader.messages():
                pass
            read_trial_bag(bag)
        except (BagError, TrackFormatError):
            return 'refused'
    return 'read'


def damaged_copy(source: Path, edit) -> Path:
    """A copy of the bag directory in a new temp dir, its .mcap bytes passed through edit."""
    destination = Path(tempfile.mkdtemp(prefix='fuzz_bag_')) / source.name
    shutil.copytree(source, destination)
    mcap = next(destination.glob('*.mcap'))
    mcap.write_bytes(edit(bytearray(mcap.read_bytes())))
    return destination


def chunk_records(data: bytes):
    """(offset, length) of each chunk's records in an uncompressed MCAP file, and the offset
    of the chunk's CRC field."""
    import io
    summary = make_reader(io.BytesIO(bytes(data))).get_summary()
    spans = []
    for index in summary.chunk_indexes:
        start = index.chunk_start_offset + 1 + 8          # opcode, record length
        crc_at = start + 8 + 8 + 8                        # start, end times, uncompressed size
        (compression_length,) = struct.unpack_from('<I', data, crc_at + 4)
        records_length_at = crc_at + 4 + 4 + compression_length
        (records_length,) = struct.unpack_from('<Q', data, records_length_at)
        spans.append((records_length_at + 8, records_length, crc_at))
    return spans


BYTE_EDITS = st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), min_size=1,
                      max_size=8)


def changed_bytes(edits):
    """An edit for damaged_copy: each (where, value) sets the byte at that share of the file."""
    def edit(data):
        for where, value in edits:
            data[min(int(len(data) * where), len(data) - 1)] = value
        return data
    return edit


def changed_behind_crc(chunk, where, value, span):
    """An edit for damaged_copy: `span` bytes inside a chunk's records set to `value`, the
    chunk's CRC recomputed, so the decoder meets wrong lengths, opcodes and payloads."""
    def edit(data):
        spans = chunk_records(data)
        start, length, crc_at = spans[chunk % len(spans)]
        first = start + int(where * (length - 1))
        data[first:min(first + span, start + length)] = bytes([value]) * min(
            span, start + length - first)
        struct.pack_into('<I', data, crc_at, zlib.crc32(bytes(data[start:start + length])))
        return data
    return edit


def test_a_bag_cut_anywhere_is_read_up_to_the_cut_or_refused(source_bag):
    outcomes = Counter()

    @fuzz
    @given(cut=st.floats(0.0, 1.0))
    def check(cut):
        bag = damaged_copy(source_bag, lambda data: data[:int(len(data) * cut)])
        (bag / 'metadata.yaml').unlink()
        outcomes[read_everything(bag)] += 1
        shutil.rmtree(bag.parent)

    check()
    both_outcomes(outcomes, 'read')


def test_a_bag_with_changed_bytes_is_read_or_refused(source_bag):
    outcomes = Counter()

    @fuzz
    @given(edits=BYTE_EDITS)
    def check(edits):
        bag = damaged_copy(source_bag, changed_bytes(edits))
        outcomes[read_everything(bag)] += 1
        shutil.rmtree(bag.parent)

    check()
    both_outcomes(outcomes, 'read')


def test_records_changed_behind_a_valid_crc_are_read_or_refused(source_bag):
    """The damage the CRCs do not catch: bytes inside a chunk changed, the chunk's CRC
    recomputed, so the decoder meets wrong lengths, opcodes and message payloads."""
    outcomes = Counter()

    @fuzz
    @given(chunk=st.integers(0, 10_000), where=st.floats(0.0, 1.0),
           value=st.integers(0, 255), span=st.integers(1, 64))
    def check(chunk, where, value, span):
        bag = damaged_copy(source_bag, changed_behind_crc(chunk, where, value, span))
        outcomes[read_everything(bag)] += 1
        shutil.rmtree(bag.parent)

    check()
    both_outcomes(outcomes, 'read')


YAML_VALUES = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                        st.text(max_size=20), st.lists(st.one_of(st.none(), st.text(max_size=8)),
                                                       max_size=3),
                        st.dictionaries(st.text(max_size=5), st.integers(), max_size=2))
METADATA_KEYS = ('version', 'storage_identifier', 'relative_file_paths', 'duration',
                 'starting_time', 'message_count', 'topics_with_message_count', 'files',
                 'compression_format', 'custom_data')


def test_a_bags_metadata_yaml_with_any_field_changed_is_read_or_refused(source_bag):
    outcomes = Counter()

    @fuzz
    @given(key=st.sampled_from(METADATA_KEYS), value=YAML_VALUES)
    def check(key, value):
        bag = damaged_copy(source_bag, lambda data: data)
        path = bag / 'metadata.yaml'
        document = yaml.safe_load(path.read_text())
        document['rosbag2_bagfile_information'][key] = value
        path.write_text(yaml.safe_dump(document))
        outcomes[read_everything(bag)] += 1
        shutil.rmtree(bag.parent)

    check()
    both_outcomes(outcomes, 'read')


# --------------------------------------------------------------------------- scenes
SCENE = yaml.safe_load((REPO / 'mantis_sim' / 'scenes' / 'air_23mm_rig.yaml').read_text())
SCENE_FIELDS = [(section, key) for section, values in SCENE.items() if isinstance(values, dict)
                for key in values] + [(key, None) for key in SCENE]
SCENE_VALUES = st.one_of(st.none(), st.booleans(), st.integers(),
                         st.integers(min_value=10 ** 300, max_value=10 ** 400),
                         st.floats(allow_nan=True, allow_infinity=True),
                         st.text(max_size=12), st.lists(st.integers(), max_size=3),
                         st.dictionaries(st.text(max_size=5), st.floats(), max_size=2))


def test_a_scene_with_any_field_changed_loads_or_is_refused(tmp_path_factory):
    import copy
    outcomes = Counter()

    @fuzz
    @given(field=st.sampled_from(SCENE_FIELDS), value=SCENE_VALUES)
    def check(field, value):
        data = copy.deepcopy(SCENE)
        section, key = field
        if key is None:
            data[section] = value
        else:
            data[section][key] = value
        path = tmp_path_factory.mktemp('scene') / 'fuzzed.yaml'
        path.write_text(yaml.safe_dump(data))
        try:
            load_scene_file(path)
        except (SceneError, ParameterError):
            outcomes['refused'] += 1
            return
        outcomes['loaded'] += 1

    check()
    both_outcomes(outcomes, 'loaded')


def test_the_scene_files_own_bytes_load_by_the_random_bytes_path(tmp_path):
    """The companion of the random-bytes property below, which can only refuse: the same
    path (bytes written, then loaded) accepts a real scene's bytes."""
    path = tmp_path / 'bytes.yaml'
    path.write_bytes((REPO / 'mantis_sim' / 'scenes' / 'air_23mm_rig.yaml').read_bytes())
    assert load_scene_file(path) is not None


@fuzz
@given(data=st.binary(max_size=400))
def test_random_bytes_as_a_scene_are_refused(tmp_path_factory, data):
    path = tmp_path_factory.mktemp('scene') / 'bytes.yaml'
    path.write_bytes(data)
    with pytest.raises((SceneError, ParameterError)):
        load_scene_file(path)


# ------------------------------------------------- random valid parameters, simulated
def _numeric_parameters():
    """(key, strategy) of every numeric scene parameter that simulate() uses: valid values
    (inside the parameter's range) around its default, from a quarter to four times it (a
    default of zero or a signed one: an eighth of the range either side). The extremes of
    the ranges are valid too, but an arm damped 2000 times its default is a stiff system that
    the explicit solvers cross in minutes, not a failure. Integration, load cell and camera
    stay the scene's: the solver's cost and the simulated rig's sensors are not this
    property's subject."""
    from dataclasses import fields

    from mantis_sim.parameters import SECTIONS
    keys = []
    for section, cls in SECTIONS.items():
        if section in ('integration', 'loadcell', 'camera'):
            continue
        for f in fields(cls):
            meta = f.metadata
            if meta['choices'] is not None or meta['lo'] is None:
                continue
            lo, hi, default = meta['lo'], meta['hi'], f.default
            if default is None:
                default = lo
            if default > 0 and lo >= 0:
                low, high = max(lo, default / 4), min(hi, default * 4)
            else:
                low, high = max(lo, default - (hi - lo) / 8), min(hi, default + (hi - lo) / 8)
            keys.append((f'{section}.{f.name}',
                         st.floats(low, high, exclude_min=meta['lo_open'] and low == lo)))
    return keys


SIM_PARAMETERS = _numeric_parameters()
SIM_SCENES = ('air_23mm_rig', 'air_23mm', 'water_23mm')
# Rig time simulated per example: the nominal strike comes at about 2.2 s. A drawn design
# with no damping at all on the stiff identified tendon rings for the whole pull (7.6 s at
# 2.33 mm/s) and Radau follows every cycle: 40-50 s of one core for one example.
FUZZ_RIG_TIME_S = 3.0


@st.composite
def parameter_changes(draw):
    """A scene and 2-6 of its parameters changed at once, each anywhere in its valid range,
    sometimes with its effects changed too."""
    from mantis_sim.scene import EFFECTS
    chosen = draw(st.lists(st.sampled_from(SIM_PARAMETERS), min_size=2, max_size=6,
                           unique_by=lambda item: item[0]))
    values = {key: draw(strategy) for key, strategy in chosen}
    if draw(st.booleans()):
        values['effects'] = sorted(draw(st.sets(st.sampled_from(sorted(EFFECTS)))))
    return draw(st.sampled_from(SIM_SCENES)), values


def test_random_valid_parameter_combinations_simulate_or_are_refused():
    """Issue 25: several parameters changed at once (a stage profile with a following error)
    ended `mantis sim` in a RecursionError. Any combination of valid values is simulated (to
    finite numbers) or refused with the simulator's own errors; and some are simulated."""
    from hypothesis import example

    from mantis_sim.model import SimulationError
    from mantis_sim.results import simulate
    from mantis_sim.scene import load_scene
    outcomes = []

    @fuzz
    @given(case=parameter_changes())
    @example(case=('air_23mm_rig', {'drive.following_time_constant_ms': 5.0,
                                    'drive.acceleration_mm_per_s2': 4.0}))
    def check(case):
        name, values = case
        try:
            result = simulate(load_scene(name).with_values(
                {**values, 'integration.t_end_s': FUZZ_RIG_TIME_S}))
        except (InputError, SimulationError):
            outcomes.append('refused')
            return
        for column, series in vars(result.trajectory).items():
            if column != 'phase':
                assert np.all(np.isfinite(series)), column
        outcomes.append('simulated')

    check()
    assert outcomes.count('simulated') >= len(outcomes) // 4, outcomes


# ------------------------------------------------------------------ tracking files (CSV)
PAIR_CSV = REPO / 'test' / 'data' / 'real_trials' / 'air_23mm_19kfps_pair_track.csv'
WINDOW = (9000, 11300)        # frames around the strike: a whole analysis in about 0.1 s
# Numbers reach the analysis (NaN, infinities, the tracker's -1 for a lost marker, blanks,
# huge values, plausible but wrong positions); any text or bytes tests the reader itself.
NUMERIC_CELLS = st.one_of(
    st.sampled_from(['', 'nan', 'NaN', 'inf', '-inf', '-1', '0', '-0', '1e308', '-1e308',
                     '1e400']),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-60.0, 60.0).map(lambda x: f'{x:.4f}'))
CELL_VALUES = st.one_of(
    NUMERIC_CELLS,
    st.sampled_from(['12.5.3', 'x', '"', ',', '\n', '\r', ';']),
    st.text(max_size=12),
    st.binary(max_size=6))


@pytest.fixture(scope='module')
def tracking_lines():
    """The real tracker CSV export's two header lines and the frames around its strike."""
    lines = PAIR_CSV.read_bytes().splitlines()
    return lines[:2] + lines[2 + WINDOW[0]:2 + WINDOW[1]]


def as_bytes(value) -> bytes:
    return value if isinstance(value, bytes) else value.encode('utf-8', 'surrogatepass')


def analysed_plausibly_or_refused(path: Path) -> str:
    """What `mantis analyze FILE` does: read, analyse. Only bad input may be refused (an
    InputError naming it); what is accepted must be physically possible, checked here on its
    own rather than trusting the analysis' own check. Returns 'analysed' or 'refused'."""
    try:
        trial = read_trial(path)
        analysis, _, _ = analyse_trial(trial, {'d_t_mm': 23.0})
    except InputError:
        return 'refused'
    s = analysis.summary()
    assert 0.0 <= s['peak_tip_speed_mps'] <= 60.0, s
    assert 15.0 <= s['L1_mm'] <= 25.0, s
    assert 0.0 <= s['max_spring_energy_mJ'] <= 300.0, s
    times = [t for t in s['phase_start_s'].values() if t == t] + [s['peak_tip_speed_s']]
    assert times == sorted(times), s
    return 'analysed'


def write_tracking(tmp_path_factory, lines) -> Path:
    path = tmp_path_factory.mktemp('fuzz_tracking') / 'trial_track.csv'
    path.write_bytes(b'\n'.join(lines) + b'\n')
    return path


def test_a_tracking_file_with_any_cells_changed_is_analysed_plausibly_or_refused(
        tmp_path_factory, tracking_lines):
    outcomes = Counter()

    @fuzz
    @given(cells=st.lists(st.tuples(st.integers(0, WINDOW[1] - WINDOW[0] - 1),
                                    st.integers(0, 12), NUMERIC_CELLS), min_size=1, max_size=30),
           garbage=st.none() | st.tuples(st.integers(0, WINDOW[1] - WINDOW[0] - 1),
                                         st.integers(0, 12), CELL_VALUES))
    def check(cells, garbage):
        rows = [line.split(b',') for line in tracking_lines[2:]]
        for row, column, value in cells + ([garbage] if garbage else []):
            if column < len(rows[row]):
                rows[row][column] = as_bytes(value)
        path = write_tracking(tmp_path_factory,
                              tracking_lines[:2] + [b','.join(r) for r in rows])
        outcomes[analysed_plausibly_or_refused(path)] += 1

    check()
    both_outcomes(outcomes, 'analysed')


def test_a_tracking_file_with_any_header_is_analysed_plausibly_or_refused(
        tmp_path_factory, tracking_lines):
    outcomes = Counter()

    @fuzz
    @given(line=st.integers(0, 1), edit=st.sampled_from(['replace', 'drop', 'insert', 'cell']),
           text=CELL_VALUES, column=st.integers(0, 12))
    def check(line, edit, text, column):
        header = list(tracking_lines[:2])
        if edit == 'replace':
            header[line] = as_bytes(text)
        elif edit == 'drop':
            del header[line]
        elif edit == 'insert':
            header.insert(line, as_bytes(text))
        else:
            cells = header[line].split(b',')
            cells[min(column, len(cells) - 1)] = as_bytes(text)
            header[line] = b','.join(cells)
        path = write_tracking(tmp_path_factory, header + tracking_lines[2:])
        outcomes[analysed_plausibly_or_refused(path)] += 1

    check()
    both_outcomes(outcomes, 'analysed')


# ----------------------------------------------------- a bag of a real strike, analysed
@pytest.fixture(scope='module')
def strike_bag(tmp_path_factory, tracking_lines):
    """The real export's frames around the strike, imported as `mantis import-tracking` does
    and rewritten uncompressed in 4 kB chunks, so that records can be changed in place."""
    from mantis_rig.analysis import load_tracks
    from mantis_rig.analysis.inputs.bag_writer import write_tracking_bag
    work = tmp_path_factory.mktemp('fuzz_strike')
    csv = write_tracking(tmp_path_factory, tracking_lines)
    write_tracking_bag(load_tracks(csv), work / 'imported', conditions={'d_t_mm': 23.0})
    source = BagReader(work / 'imported')
    path = work / 'strike'
    with BagWriter(path, sync_period_s=0, compression='none', chunk_size_bytes=4096) as bag:
        for topic, info in source.topics.items():
            bag.add_topic(topic, info.type_name)
        for name, record in source.metadata_records:
            bag.add_metadata(name, record)
        for topic, _, t_ns, msg in source.messages():
            bag.write(topic, msg, t_ns)
    return path


def bag_analysed_plausibly_or_refused(bag: Path) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', TruncatedBagWarning)
        return analysed_plausibly_or_refused(bag)


def test_the_strike_bag_itself_is_analysed(strike_bag):
    trial = read_trial(strike_bag)
    analysis, _, _ = analyse_trial(trial, {})
    assert 20.0 < analysis.summary()['peak_tip_speed_mps'] < 30.0


def test_a_strike_bag_with_changed_bytes_is_analysed_plausibly_or_refused(strike_bag):
    outcomes = Counter()

    @fuzz
    @given(edits=BYTE_EDITS)
    def check(edits):
        bag = damaged_copy(strike_bag, changed_bytes(edits))
        outcomes[bag_analysed_plausibly_or_refused(bag)] += 1
        shutil.rmtree(bag.parent)

    check()
    both_outcomes(outcomes, 'analysed')


def test_a_strike_bag_changed_behind_a_valid_crc_is_analysed_plausibly_or_refused(strike_bag):
    """Marker and force payloads changed where no CRC sees it: every number the analysis
    then reports must still be one the robot can produce."""
    outcomes = Counter()

    @fuzz
    @given(chunk=st.integers(0, 10_000), where=st.floats(0.0, 1.0),
           value=st.integers(0, 255), span=st.integers(1, 64))
    def check(chunk, where, value, span):
        bag = damaged_copy(strike_bag, changed_behind_crc(chunk, where, value, span))
        outcomes[bag_analysed_plausibly_or_refused(bag)] += 1
        shutil.rmtree(bag.parent)

    check()
    both_outcomes(outcomes, 'analysed')
