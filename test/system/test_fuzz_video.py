"""Fuzz suite for the strike's video (issue 47): damaged recordings (.cine, an uncompressed
.avi) are tracked up to the damage and then refused with the recording's own error naming the
file and the frame, never another exception; damaged calibrations load or are refused with the
calibration's own error naming the file.

Property-based with hypothesis, profiles of test/fuzzing.py (MANTIS_FUZZ_PROFILE=long for the
long run). The recordings are a simulated strike's first frames, rendered once per module."""
from collections import Counter
from pathlib import Path
import shutil
import tempfile

from fuzzing import both_outcomes, fuzz
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
import yaml

from mantis_rig.video.recording_error import RecordingError
from mantis_rig.video.to_csv import track_to_csv
from mantis_sim.camera.calibration import CalibrationError, load_calibration
from mantis_sim.camera.render import CameraSetup, film_strike
from mantis_sim.errors import InputError
from mantis_sim.scene import load_scene

pytestmark = [pytest.mark.timeout(600), pytest.mark.slow]
RATE_HZ = 2000.0


@pytest.fixture(scope='module')
def films(tmp_path_factory):
    """A strike filmed at 2,000 frames/s, 40 ms before the release to 5 ms after, as an
    uncompressed .avi and as a .cine."""
    scene = load_scene('air_23mm')
    setup = CameraSetup(rate_hz=RATE_HZ, width_px=256, height_px=256, scale_px_per_mm=5.0)
    out = {}
    for fmt in ('avi-raw', 'cine'):
        result = film_strike(scene, tmp_path_factory.mktemp(fmt), setup, before_s=0.04,
                             after_s=0.005, video_format=fmt)
        out[fmt] = result.video
    return out


def _tracked_or_refused(video: Path, outcomes: Counter) -> None:
    """Tracked (up to the damage, which then names the file and a frame) or refused with an
    InputError naming the file; any other exception fails the property."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            result = track_to_csv(video, Path(tmp) / 'tracks.csv', rate_hz=RATE_HZ)
        except InputError as exc:
            assert str(video) in str(exc) or video.name in str(exc), exc
            outcomes['refused'] += 1
            return
        if result.damage:
            assert video.name in result.damage and 'frame' in result.damage, result.damage
            assert (Path(tmp) / 'tracks.csv').is_file()       # the frames before it kept
            outcomes['refused'] += 1
        else:
            outcomes['tracked'] += 1


def _damaged_copy(source: Path, directory: Path, cut: float = None, edits=()) -> Path:
    data = bytearray(source.read_bytes())
    for where, value in edits:
        data[int(where * (len(data) - 1))] = value
    if cut is not None:
        data = data[:int(cut * len(data))]
    copy = directory / source.name
    copy.write_bytes(bytes(data))
    shutil.copy(source.parent / 'calibration.yaml', directory / 'calibration.yaml')
    return copy


@pytest.mark.parametrize('fmt', ['avi-raw', 'cine'])
def test_a_recording_cut_anywhere_is_tracked_up_to_the_cut_or_refused(films, fmt):
    outcomes = Counter()

    @fuzz
    @given(cut=st.floats(0.0, 1.0))
    def cut_anywhere(cut):
        with tempfile.TemporaryDirectory() as tmp:
            _tracked_or_refused(_damaged_copy(films[fmt], Path(tmp), cut=cut), outcomes)

    cut_anywhere()
    assert outcomes['refused'] > 0, dict(outcomes)


@pytest.mark.parametrize('fmt', ['avi-raw', 'cine'])
def test_a_recording_with_changed_bytes_is_tracked_or_refused(films, fmt):
    outcomes = Counter()
    header_bytes = st.lists(st.tuples(st.floats(0.0, 0.002), st.integers(0, 255)),
                            min_size=1, max_size=6)
    any_bytes = st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), min_size=1,
                         max_size=6)

    @fuzz
    @given(edits=st.one_of(header_bytes, any_bytes))
    def changed(edits):
        with tempfile.TemporaryDirectory() as tmp:
            _tracked_or_refused(_damaged_copy(films[fmt], Path(tmp), edits=edits), outcomes)

    changed()
    both_outcomes(outcomes, 'tracked')


CALIBRATION_FIELDS = ('scale_px_per_mm', 'origin_px', 'tilt_deg', 'handedness', 'name')
VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                   st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
                   st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=3))


def test_a_calibration_with_any_field_changed_loads_or_is_refused(films):
    source = yaml.safe_load((films['cine'].parent / 'calibration.yaml').read_text())
    outcomes = Counter()

    @fuzz
    @given(field=st.sampled_from(CALIBRATION_FIELDS), value=VALUES, drop=st.booleans())
    def changed(field, value, drop):
        data = dict(source)
        if drop:
            data.pop(field, None)
        else:
            data[field] = value
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / 'calibration.yaml'
            path.write_text(yaml.safe_dump(data))
            try:
                calibration = load_calibration(path)
            except CalibrationError as exc:
                assert str(path) in str(exc), exc
                outcomes['refused'] += 1
                return
            xy = calibration.px_to_mm(np.array([[10.0, 20.0]]))
            assert np.all(np.isfinite(xy)) and calibration.scale_px_per_mm > 0
            outcomes['loaded'] += 1

    changed()
    both_outcomes(outcomes, 'loaded')


@given(data=st.binary(max_size=300))
@settings(max_examples=60, derandomize=True, deadline=None)
def test_random_bytes_as_a_calibration_are_refused_or_loaded(data):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'calibration.yaml'
        path.write_bytes(data)
        try:
            calibration = load_calibration(path)
        except CalibrationError as exc:
            assert str(path) in str(exc)
            return
        assert calibration.scale_px_per_mm > 0


def test_a_damaged_recording_is_a_recording_error_not_another(films, tmp_path):
    """The error type the command line turns into exit 2 and one line."""
    copy = _damaged_copy(films['cine'], tmp_path, cut=0.5)
    result = track_to_csv(copy, tmp_path / 'tracks.csv', rate_hz=RATE_HZ)
    assert result.damage and len(result.tracks.index) > 0
    assert issubclass(RecordingError, InputError)
