"""The simulated camera (mantis_sim.camera): calibrations (YAML, the tracker's string, px <->
mm), the tracker's CSV read back through the analysis, and films rendered, written as .avi
and .cine and read back with their truth."""
import math

import numpy as np
import pytest

from mantis_rig.analysis.inputs import read_trial
from mantis_rig.analysis.inputs.base import TrackFormatError
from mantis_rig.video.recording import open_recording
from mantis_sim.camera.calibration import (
    Calibration,
    CalibrationError,
    load_calibration,
    save_calibration,
)
from mantis_sim.camera.render import CameraSetup, Pose, Renderer, film
from mantis_sim.camera.tracker_csv import TrackerCsvWriter, write_tracker_csv
from mantis_sim.errors import InputError

LAB = ('Name: Calibration1, Type: Normal, Scale: 5.89969 pixels/millimeter,        0.1695 '
       'millimeters/pixel, Origin: 195.7, 293.5 pixels, Tilt: 0 degrees, System: Left-Handed '
       'Coordinate, Calibration Units: Millimeters')
NAMES = ['mb1', 'mb2', 'mb3', 'ma1', 'ma2']


# ----------------------------------------------------------------------------- calibration
def test_the_lab_calibration_string_parses_and_formats_back():
    cal = Calibration.from_tracker_string(LAB)
    assert (cal.scale_px_per_mm, cal.origin_px, cal.tilt_deg, cal.handedness) == (
        5.89969, (195.7, 293.5), 0.0, 'left')
    assert 'Scale: 5.89969 pixels/millimeter' in cal.tracker_string()
    assert 'Tilt: 0 degrees, System: Left-Handed Coordinate' in cal.tracker_string()
    assert Calibration.from_tracker_string(cal.tracker_string()) == cal
    odd = Calibration(6.123456789, (10.25, -3.5), 33.3, 'right', 'Cal2')
    assert Calibration.from_tracker_string(odd.tracker_string()) == odd


@pytest.mark.parametrize('tilt_deg, handedness', [(0, 'left'), (180, 'left'), (33.0, 'right'),
                                                  (-90, 'right')])
def test_pixels_and_millimetres_convert_both_ways(tilt_deg, handedness):
    cal = Calibration(6.2, (100.0, 240.0), tilt_deg, handedness)
    px = np.random.default_rng(0).uniform(0, 500, (7, 2))
    np.testing.assert_allclose(cal.mm_to_px(cal.px_to_mm(px)), px, atol=1e-9)
    assert np.isnan(cal.px_to_mm([np.nan, 1.0])).any()


def test_the_frames_convention_is_the_analysis_one():
    """Left-handed at tilt t: R(t) p, p the image's offset (y down) over the scale; right-
    handed: the same with y negated (test_import_analyze.reexported)."""
    cal = Calibration(5.0, (100.0, 200.0), 90.0, 'left')
    np.testing.assert_allclose(cal.px_to_mm([110.0, 200.0]), [0.0, 2.0], atol=1e-12)
    right = Calibration(5.0, (100.0, 200.0), 0.0, 'right')
    np.testing.assert_allclose(right.px_to_mm([100.0, 210.0]), [0.0, -2.0])
    flipped = Calibration(5.0, (100.0, 200.0), 180.0, 'left')
    np.testing.assert_allclose(flipped.px_to_mm([110.0, 190.0]), [-2.0, 2.0])


def test_a_calibration_from_two_markers_a_known_distance_apart():
    cal = Calibration.from_marker_distance((10.0, 10.0), (40.0, 50.0), 8.0, origin_px=(5, 5))
    assert cal.scale_px_per_mm == pytest.approx(50.0 / 8.0)
    assert np.hypot(*(cal.px_to_mm([40, 50]) - cal.px_to_mm([10, 10]))) == pytest.approx(8.0)
    with pytest.raises(CalibrationError, match='marker distance'):
        Calibration.from_marker_distance((1, 1), (1, 1), 8.0)
    with pytest.raises(CalibrationError, match='positive length'):
        Calibration.from_marker_distance((1, 1), (2, 2), -1.0)


def test_a_calibration_yaml_round_trip_and_the_trackers_string_in_it(tmp_path):
    cal = Calibration(6.02, (363.862, 299.68), 180.0, 'left', 'rig A')
    assert load_calibration(save_calibration(cal, tmp_path / 'cal.yaml')) == cal
    (tmp_path / 'lab.yaml').write_text(f'tracker: "{LAB}"\n')
    assert load_calibration(tmp_path / 'lab.yaml') == Calibration.from_tracker_string(LAB)


@pytest.mark.parametrize('text, field', [
    ('origin_px: [1, 2]\n', 'scale_px_per_mm'),
    ('scale_px_per_mm: 6\n', 'origin_px'),
    ('scale_px_per_mm: six\norigin_px: [1, 2]\n', 'scale_px_per_mm'),
    ('scale_px_per_mm: -6\norigin_px: [1, 2]\n', 'scale_px_per_mm'),
    ('scale_px_per_mm: .nan\norigin_px: [1, 2]\n', 'scale_px_per_mm'),
    ('scale_px_per_mm: 6\norigin_px: [1]\n', 'origin_px'),
    ('scale_px_per_mm: 6\norigin_px: [1, x]\n', 'origin_px'),
    ('scale_px_per_mm: 6\norigin_px: [1, 2]\ntilt_deg: up\n', 'tilt_deg'),
    ('scale_px_per_mm: 6\norigin_px: [1, 2]\nhandedness: sideways\n', 'handedness'),
    ('scale_px_per_mm: 6\norigin_px: [1, 2]\nzoom: 2\n', 'zoom'),
    ('tracker: "Name: C, Origin: 1, 2 pixels"\n', 'Scale'),
    ('tracker: "Scale: 6 pixels/millimeter"\n', 'Origin'),
    ('tracker: "Scale: 6 pixels/furlong, Origin: 1, 2"\n', 'Scale'),
])
def test_a_calibration_that_cannot_be_read_names_the_file_and_the_field(tmp_path, text, field):
    path = tmp_path / 'cal.yaml'
    path.write_text(text)
    with pytest.raises(CalibrationError, match=field) as err:
        load_calibration(path)
    assert 'cal.yaml' in str(err.value) and isinstance(err.value, InputError)


@pytest.mark.parametrize('content', [b'[1, 2, 3]\n', b'a: [\n', b'\xff\xfe\x00'])
def test_a_file_that_is_no_calibration_is_refused(tmp_path, content):
    path = tmp_path / 'cal.yaml'
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match='cal.yaml'):
        load_calibration(path)
    with pytest.raises(CalibrationError, match='missing.yaml'):
        load_calibration(tmp_path / 'missing.yaml')


# ------------------------------------------------------------------------------ tracker CSV
def tracks_px(n=60, seed=0):
    rng = np.random.default_rng(seed)
    return {name: rng.uniform(50, 450, (n, 2)) for name in NAMES}


def test_the_tracker_csv_reads_back_through_the_analysis_in_millimetres(tmp_path):
    positions = tracks_px()
    positions['ma2'][7] = np.nan                         # lost there: a gap
    cal = Calibration(5.9, (195.7, 293.5), 180.0, 'left')
    frames = np.arange(60) - 20
    path = write_tracker_csv(tmp_path / 'tracks.csv', frames, frames / 19000.0, positions,
                             19000.0, cal, r'C:\videos\air_19kfps_T_1.avi')
    assert path.read_bytes().count(b'\r\n') == path.read_bytes().count(b'\n')
    tracks = read_trial(path).tracks
    assert (tracks.frame_rate_hz, tracks.tilt_deg, tracks.handedness) == (19000.0, 180.0, 'left')
    np.testing.assert_array_equal(tracks.frames, frames)
    np.testing.assert_allclose(tracks.time_s, frames / 19000.0, atol=1e-12)
    for name in NAMES:
        np.testing.assert_allclose(tracks.markers_mm[name], cal.px_to_mm(positions[name]),
                                   rtol=1e-9, atol=1e-8)
    assert np.isnan(tracks.markers_mm['ma2'][7]).all()
    assert np.isfinite(tracks.markers_mm['ma2'][8]).all()


def test_the_tracker_csv_without_calibration_is_in_pixels(tmp_path):
    positions = tracks_px()
    path = tmp_path / 'px.csv'
    with TrackerCsvWriter(path, NAMES, rate_hz=None) as w:
        for k in range(60):
            w.write_frame(k, k, {n: xy[k] for n, xy in positions.items()})
    text = path.read_text()
    assert 'Export Units:,Pixels' in text and 'Record Rate:,N/A' in text
    assert 'Calibration 1' not in text
    lines = text.splitlines()
    row = lines[lines.index(',,x,y,x,y,x,y,x,y,x,y') + 3].split(',')
    assert float(row[2]) == pytest.approx(positions['mb1'][2, 0], abs=1e-6)
    with pytest.raises(TrackFormatError, match='calibration'):
        read_trial(path, frame_rate_hz=1000.0)


# ---------------------------------------------------------------------------------- render
def spinning_arm(turns_per_s: float):
    """A body at rest and an arm turning about b at a steady rate, in camera mm (y down)."""
    a, b = np.array([0.0, 0.0]), np.array([19.0, 0.0])
    body = {'mb1': (4.0, 8.0), 'mb2': (-3.0, 14.0), 'mb3': (6.0, 17.0)}
    arm = {'ma1': (1.0, 7.0), 'ma2': (-1.0, 14.0)}

    def pose(times_s):
        t = np.asarray(times_s, float)
        n = len(t)
        angle = 2.0 * math.pi * turns_per_s * t + 2.2
        axis = np.column_stack([np.cos(angle), np.sin(angle)])
        normal = np.column_stack([-axis[:, 1], axis[:, 0]])
        markers = {name: np.tile([along, -across], (n, 1)) * 0.7 + [1.0, 2.0]
                   for name, (across, along) in body.items()}
        for name, (across, along) in arm.items():
            markers[name] = b + along * axis + across * normal
        return Pose(np.tile(a, (n, 1)), np.tile(b, (n, 1)), b + 18.66 * axis, markers)
    return pose


def blob_centre(image, near_px, radius=6.5, link_grey=22.0):
    """The centroid of the brightness above the link's within ``radius`` px of a point (the
    markers sit on the black links, which reach 15 px beyond them)."""
    x0, y0 = np.round(near_px).astype(int)
    r = int(math.ceil(radius))
    window = image[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1].astype(float)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    weight = np.clip(window - link_grey, 0, None) * (np.hypot(xx, yy) <= radius)
    return np.array([x0 + (weight * xx).sum() / weight.sum(),
                     y0 + (weight * yy).sum() / weight.sum()])


SMALL = dict(width_px=256, height_px=256, noise_grey=1.5)


@pytest.mark.parametrize('video_format', ['cine', 'avi', 'avi-raw'])
def test_a_film_reads_back_with_its_rate_numbers_times_and_truth(tmp_path, video_format):
    setup = CameraSetup(rate_hz=8000.0, **SMALL)
    out = film(spinning_arm(5.0), tmp_path / 'film', trigger_s=0.01, start_s=0.0095,
               stop_s=0.017, setup=setup, video_format=video_format)
    assert (out.frame_count, out.first_number) == (61, -4)
    truth = read_trial(out.truth).tracks
    assert truth.frame_rate_hz == 8000.0 and sorted(truth.markers_mm) == sorted(NAMES)
    np.testing.assert_array_equal(truth.frames, np.arange(-4, 57))
    cal = load_calibration(out.calibration)
    rate = None if video_format == 'cine' else 8000.0
    with open_recording(out.video, rate_hz=rate) as rec:
        assert (rec.width, rec.height, rec.frame_count, rec.rate_hz) == (256, 256, 61, 8000.0)
        frames = list(rec.frames())
    if video_format == 'cine':
        assert rec.trigger_index == 4 and rec.rate_source == 'the .cine header'
        assert [f.index for f in frames] == list(range(-4, 57))
        np.testing.assert_allclose([f.time_s for f in frames], truth.time_s, atol=1e-9)
    for k in (0, 30, 60):
        for name in NAMES:
            drawn = cal.mm_to_px(truth.markers_mm[name][k])
            found = blob_centre(frames[k].image, drawn)
            assert np.hypot(*(found - drawn)) < 0.15, (k, name, found, drawn)


def test_markers_at_rest_are_drawn_where_the_truth_puts_them_to_a_hundredth_of_a_pixel():
    setup = CameraSetup(rate_hz=2000.0, width_px=256, height_px=256, noise_grey=0.0)
    pose = spinning_arm(0.0)
    cal = Calibration(6.0, (103.37, 96.81))
    renderer = Renderer(pose, setup, cal, reference_s=0.0)
    errors = []
    for shift in np.linspace(0.0, 1.0, 7):
        moved = Calibration(6.0, (103.37 + shift, 96.81 + 0.6 * shift))
        renderer.calibration = moved
        (image, centres), = renderer.render(np.array([0.0]))
        errors += [blob_centre(image, c) - c for c in centres.values()]
    assert np.sqrt(np.mean(np.square(errors))) < 0.03


def test_motion_blur_spreads_a_fast_marker_and_keeps_its_centre():
    setup = CameraSetup(rate_hz=2000.0, width_px=256, height_px=256, noise_grey=0.0)
    renderer = Renderer(spinning_arm(40.0), setup, Calibration(6.0, (40.0, 128.0)), 0.0)
    assert len(renderer.frame_subtimes(0.0, 30000.0)) > 9
    assert len(renderer.frame_subtimes(0.0, 10.0)) == 1
    (image, centres), = renderer.render(np.array([0.001]))
    tip = centres['ma2']
    sharp_setup = CameraSetup(rate_hz=2000.0, width_px=256, height_px=256, noise_grey=0.0,
                              exposure_s=0.0)
    sharp = Renderer(spinning_arm(40.0), sharp_setup, Calibration(6.0, (40.0, 128.0)), 0.0)
    (instant, _), = sharp.render(np.array([0.001]))

    def white(picture, centre):
        x, y = np.round(centre).astype(int)
        return int((picture[y - 11:y + 12, x - 11:x + 12] > 200).sum())
    assert white(instant, tip) > 30 and white(image, tip) < 0.3 * white(instant, tip)
    assert np.hypot(*(blob_centre(image, tip, radius=11) - tip)) < 0.2


def test_a_16_bit_cine_film_and_formats_refused(tmp_path):
    setup = CameraSetup(rate_hz=2000.0, bit_depth=12, **SMALL)
    out = film(spinning_arm(1.0), tmp_path, 0.0, 0.0, 0.002, setup, 'cine')
    with open_recording(out.video) as rec:
        assert rec.bit_depth == 12
        image = next(rec.frames()).image
    assert image.dtype == np.uint16 and 1500 < np.median(image) < 2600
    with pytest.raises(ValueError, match='only a .cine'):
        film(spinning_arm(1.0), tmp_path, 0.0, 0.0, 0.002, setup, 'avi')
    with pytest.raises(ValueError, match='video format'):
        film(spinning_arm(1.0), tmp_path, 0.0, 0.0, 0.002, CameraSetup(), 'mp4')


# ------------------------------------------------------------ markers, media, hidden markers
@pytest.mark.parametrize('medium', ['air', 'water'])
@pytest.mark.parametrize('shape', ['disc', 'square'])
def test_each_markers_brightness_centroid_is_its_true_centre(medium, shape):
    """Stamped with its exact coverage of each pixel (supersampled, box-filtered): at any
    sub-pixel place and turn the centroid of its brightness is its centre (OpenCV's anti-
    aliased shapes were up to 0.45 px off)."""
    from mantis_sim.camera.render import _stamp
    s = CameraSetup().in_medium(medium)
    radius_px = 0.5 * s.marker_size_mm * s.scale_px_per_mm
    hole_px = 0.5 * s.marker_hole_mm * s.scale_px_per_mm
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(60):
        centre = np.array([30.0, 30.0]) + rng.uniform(0.0, 1.0, 2)
        picture = np.full((60, 60), s.link_grey, np.float32)
        _stamp(picture, centre, shape, radius_px, hole_px, rng.uniform(0, np.pi), s.marker_grey)
        weight = picture - s.link_grey
        yy, xx = np.indices(picture.shape)
        errors.append([(weight * xx).sum() / weight.sum() - centre[0],
                       (weight * yy).sum() / weight.sum() - centre[1]])
        area = weight.sum() / (s.marker_grey - s.link_grey)
        full = (np.pi if shape == 'disc' else 4.0) * radius_px ** 2 - np.pi * hole_px ** 2
        assert area == pytest.approx(full, rel=0.01)
    errors = np.array(errors)
    assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.01
    assert np.max(np.hypot(*errors.T)) < 0.03


def test_water_looks_darker_with_less_contrast_and_smaller_markers():
    """As the real water frames (test/data/real_frames/0116*, 0117*) look; the medium comes
    from the scene (film_strike), or is named in the set-up."""
    air, water = CameraSetup(), CameraSetup().in_medium('water')
    assert water.medium == 'water' and CameraSetup(medium='air').in_medium('water').medium == 'air'
    assert CameraSetup().in_medium('air') == CameraSetup(medium='air')
    with pytest.raises(ValueError, match='medium'):
        CameraSetup().in_medium('oil')
    pictures = {}
    for name, setup in (('air', air), ('water', water)):
        setup = CameraSetup(**{**setup.__dict__, 'width_px': 400, 'height_px': 400,
                               'noise_grey': 0.0})
        renderer = Renderer(spinning_arm(0.0), setup, Calibration(6.0, (200.0, 256.0)), 0.0)
        (pictures[name], centres), = renderer.render(np.array([0.0]))
    a, w = pictures['air'].astype(float), pictures['water'].astype(float)
    assert np.median(w) < 0.75 * np.median(a)
    tip = np.round(centres['ma2']).astype(int)

    def bright_px(picture):
        box = picture[tip[1] - 8:tip[1] + 9, tip[0] - 8:tip[0] + 9]
        return int((box > 0.5 * (box.max() + np.median(picture))).sum())
    # Less contrast: the markers and the background above the links.
    assert w.max() - water.link_grey < 0.9 * (a.max() - air.link_grey)
    assert np.median(w) - water.link_grey < 0.75 * (np.median(a) - air.link_grey)
    assert bright_px(w) < 0.6 * bright_px(a)
    # The markers' centres stay true through the optical blur.
    for name, xy in centres.items():
        found = blob_centre(pictures['water'], xy, link_grey=water.link_grey)
        assert np.hypot(*(found - xy)) < 0.02, name


def test_a_hidden_marker_is_not_in_the_picture_in_its_frames_only(tmp_path):
    setup = CameraSetup(rate_hz=8000.0, hidden=(('ma2', 3, 5), ('mb1', 0, 0)), **SMALL)
    assert setup.hidden_in(4) == {'ma2'} and setup.hidden_in(0) == {'mb1'}
    assert setup.hidden_in(6) == set()
    out = film(spinning_arm(0.0), tmp_path / 'film', trigger_s=0.0, start_s=0.0,
               stop_s=0.007, setup=setup, video_format='avi-raw')
    truth = read_trial(out.truth).tracks
    cal = load_calibration(out.calibration)
    with open_recording(out.video, rate_hz=8000.0) as rec:
        frames = [f.image for f in rec.frames()]
    for k, image in enumerate(frames):
        for name in ('ma2', 'mb1'):
            x, y = np.round(cal.mm_to_px(truth.markers_mm[name][k])).astype(int)
            peak = image[y - 5:y + 6, x - 5:x + 6].max()
            hidden = name in setup.hidden_in(k)
            assert (peak < 60) if hidden else (peak > 200), (k, name, peak)
    assert np.isfinite(truth.markers_mm['ma2']).all()      # the truth keeps where it is
