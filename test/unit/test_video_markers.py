"""Finding, naming and following markers on synthetic frames with known centres
(mantis_rig.video: markers, naming, follow, track)."""
import math

import cv2
import numpy as np
import pytest

from mantis_rig.video.follow import Follower
from mantis_rig.video.markers import FrameError, find_markers, grey_frame, measure_near
from mantis_rig.video.naming import (
    REAL_ROBOT,
    NamingError,
    linkage_names,
    name_markers,
    names_from_points,
    parse_name_args,
    simulated_robot,
)
from mantis_rig.video.track import Tracks, track, write_tracks
from mantis_sim.camera.calibration import Calibration
from mantis_sim.errors import InputError

SHIFT = 8
BG, LINK, WHITE = 128, 22, 235


def draw(centres: dict, shape=(200, 200), radius=4.5, hole=1.6, noise=1.5, seed=0,
         hidden=()) -> np.ndarray:
    """Black plates under white rings at ``centres`` (px) on a grey background, noisy."""
    img = np.full(shape, BG, np.uint8)
    for x, y in centres.values():
        cv2.circle(img, (int(x), int(y)), int(4 * radius), LINK, -1)
    for name, (x, y) in centres.items():
        if name in hidden:
            continue
        c = (round(x * 256), round(y * 256))
        cv2.circle(img, c, round(radius * 256), WHITE, -1, cv2.LINE_AA, SHIFT)
        cv2.circle(img, c, round(hole * 256), LINK, -1, cv2.LINE_AA, SHIFT)
    rng = np.random.default_rng(seed)
    return np.clip(img + rng.normal(0, noise, shape), 0, 255).astype(np.uint8)


def layout_px(layout, scale=5.0, angle_deg=20.0, origin=(60.0, 40.0), mirror=False):
    """The layout's markers placed in an image: turned, scaled, shifted (mirrored)."""
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    out = {}
    for name, p in {**layout.body_mm, **layout.arm_mm}.items():
        q = np.array(p, float) * ([1, -1] if mirror else [1, 1])
        out[name] = tuple(origin + scale * rot @ q)
    return out


def test_ring_centres_to_a_hundredth_of_a_pixel():
    rng = np.random.default_rng(1)
    centres = {f'm{k}': (40 + 40 * k + rng.random(), 60 + rng.random()) for k in range(4)}
    blobs = find_markers(draw(centres))
    assert len(blobs) == 4
    assert all(b.ring for b in blobs)
    for b in blobs:   # found in the whole frame, cut at a level: for naming
        err = min(math.dist((b.x_px, b.y_px), c) for c in centres.values())
        assert err < 0.15
    # The windowed measurement the follower uses agrees.
    img = draw(centres)
    for x, y in centres.values():
        got = measure_near(img, x + 1.7, y - 1.2, 9, LINK + 5, 10, BG)
        assert math.dist(got[:2], (x, y)) < 0.05


def test_background_tendon_and_mount_are_not_markers():
    img = np.full((160, 160), BG, np.uint8)
    img[:30] = 230                                      # the bright mount
    cv2.circle(img, (120, 15), 5, 255, -1)              # a screw on it
    cv2.line(img, (0, 150), (159, 60), 200, 1)          # the tendon, lit
    cv2.circle(img, (60, 90), 3, 200, -1)               # a speck on the background
    img[80:130, 10:40] = LINK                           # a link...
    cv2.circle(img, (25, 105), 4, WHITE, -1)            # ...with its marker
    blobs = find_markers(img)
    assert [(round(b.x_px), round(b.y_px)) for b in blobs] == [(25, 105)]


def test_bad_frame_is_refused_naming_it():
    with pytest.raises(FrameError, match='clip.avi, frame 7'):
        grey_frame(np.zeros((4, 4, 4, 4), np.uint8), 'clip.avi, frame 7')
    assert issubclass(FrameError, InputError)
    rgba = np.dstack([np.full((20, 20), 90, np.uint8)] * 3 + [np.full((20, 20), 255, np.uint8)])
    assert grey_frame(rgba).shape == (20, 20)


def test_the_lab_numbers_each_link_outwards_from_its_joint():
    body, arm = linkage_names([(22, 3), (10, 1), (18, -9)], [(5, 2), (15, 1)], l1_mm=20.0)
    assert body == {'mb1': (10, 1), 'mb2': (18, -9), 'mb3': (22, 3)}
    assert arm == {'ma1': (15, 1), 'ma2': (5, 2)}
    # Both robots' layouts obey it, and the simulated one names as mantis_sim.world does.
    for layout in (REAL_ROBOT, simulated_robot()):
        d_body = [math.hypot(*layout.body_mm[n]) for n in ('mb1', 'mb2', 'mb3')]
        hinge = np.array([layout.l1_mm, 0])
        d_arm = [math.dist(layout.arm_mm[n], hinge) for n in ('ma1', 'ma2')]
        assert d_body == sorted(d_body) and d_arm == sorted(d_arm)
    assert math.dist(simulated_robot().arm_mm['ma1'], (19, 0)) == pytest.approx(math.hypot(1, 7))


@pytest.mark.parametrize('layout', [REAL_ROBOT, simulated_robot()], ids=['real', 'sim'])
@pytest.mark.parametrize('mirror', [False, True])
def test_naming_from_the_linkage_with_distractors(layout, mirror):
    truth = layout_px(layout, mirror=mirror)
    names = list(truth)
    rng = np.random.default_rng(3)
    order = rng.permutation(len(names))
    pts = [truth[names[k]] for k in order]
    pts += [(30.0, 170.0), (150.0, 20.0), (pts[0][0] + 9, pts[0][1] + 4)]   # glare, specks
    naming = name_markers(pts)
    assert naming.layout == layout.name and naming.mirrored == mirror
    for name, xy in truth.items():
        assert math.dist(naming.positions_px[name], xy) < 1e-6
    # The arm may have left its latch: turned about the hinge, still named.
    hinge = np.array(naming.hinge_px)
    turned = dict(truth)
    a = math.radians(25 if not mirror else -25)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    for n in ('ma1', 'ma2'):
        turned[n] = tuple(hinge + rot @ (np.array(truth[n]) - hinge))
    assert name_markers(list(turned.values())).positions_px.keys() == truth.keys()


def test_naming_refuses_what_is_no_linkage():
    with pytest.raises(NamingError, match='still.png'):
        name_markers([(0, 0), (10, 0), (20, 0), (30, 0), (40, 0)], where='still.png')
    with pytest.raises(NamingError, match='at least four'):
        name_markers([(0, 0), (10, 0)])


def test_naming_by_hand():
    given = parse_name_args(['mb1=10.5,20', 'ma1=40,41.25'])
    assert given == {'mb1': (10.5, 20.0), 'ma1': (40.0, 41.25)}
    naming = names_from_points(given, [(11.0, 20.5), (90, 90)])
    assert naming.positions_px == {'ma1': (40.0, 41.25), 'mb1': (11.0, 20.5)}
    for bad in (['mb1=10'], ['xx1=1,2'], ['mb1=a,b'], ['mb1=nan,2']):
        with pytest.raises(NamingError):
            parse_name_args(bad)


class _Frames:
    """A recording of synthetic frames: the body still, the arm turning about its hinge."""

    def __init__(self, n, turn_deg_per_frame=0.0, hide=None, start_turn=5):
        self.n, self.rate_hz, self.path, self.frame_count = n, 1000.0, 'synthetic', n
        self.layout = simulated_robot()
        self.base = layout_px(self.layout, scale=6.0, angle_deg=-30, origin=(40.0, 150.0))
        self.turn, self.hide, self.start_turn = turn_deg_per_frame, hide or {}, start_turn

    def centres(self, k):
        out = dict(self.base)
        a = math.radians(self.turn * max(0, k - self.start_turn))
        hinge = self._hinge()
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        for n in ('ma1', 'ma2'):
            out[n] = tuple(hinge + rot @ (np.array(self.base[n]) - hinge))
        return out

    def _hinge(self):
        a = math.radians(-30)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        return np.array((40.0, 150.0)) + 6.0 * rot @ np.array([self.layout.l1_mm, 0.0])

    def frames(self, start=0, stop=None):
        from mantis_rig.video.recording_base import Frame
        for k in range(self.n):
            c = self.centres(k)
            yield Frame(k, k / self.rate_hz, draw(c, shape=(220, 220), seed=k,
                                                  hidden=self.hide.get(k, ())))


def test_follow_a_turning_arm_with_sub_pixel_accuracy():
    rec = _Frames(40, turn_deg_per_frame=1.5)
    tracks = track(rec)
    assert isinstance(tracks, Tracks) and tracks.names == ['ma1', 'ma2', 'mb1', 'mb2', 'mb3']
    assert not tracks.lost
    for k in range(rec.n):
        centres = rec.centres(k)
        for name, xy in centres.items():
            err = math.dist(tracks.xy_px[name][k], xy)
            # Two rings touching in the picture (the simulated ma1 sweeps past mb2) share
            # their rim: split between them, each is off by up to about half a pixel.
            apart = min(math.dist(xy, c) for n, c in centres.items() if n != name)
            assert err < (0.05 if k < rec.start_turn else 0.1 if apart > 20 else 0.75), (k, name)


def test_a_hidden_marker_is_a_gap_then_found_again():
    rec = _Frames(30, hide={k: ('mb3',) for k in range(10, 14)})
    tracks = track(rec)
    mb3 = tracks.xy_px['mb3']
    assert np.all(np.isnan(mb3[10:14]))
    assert np.all(np.isfinite(mb3[:10])) and np.all(np.isfinite(mb3[14:]))
    assert not tracks.lost


def test_a_marker_lost_for_good_is_reported_with_its_last_frame():
    rec = _Frames(25, hide={k: ('ma2',) for k in range(12, 25)})
    tracks = track(rec)
    assert tracks.lost == {'ma2': 11}
    assert np.all(np.isnan(tracks.xy_px['ma2'][12:]))


def test_follower_state_is_fixed_in_size():
    rec = _Frames(3)
    frames = list(rec.frames())
    f = Follower(frames[0].image, name_markers(list(rec.base.values())))
    size = len(f.__dict__)
    for fr in frames[1:]:
        f.step(fr.image, fr.index)
    assert len(f.__dict__) == size


def test_tracks_written_in_the_trackers_csv_form(tmp_path):
    from mantis_rig.analysis.inputs.read import load_tracks
    rec = _Frames(60, hide={5: ('mb2',)})
    tracks = track(rec)
    px = write_tracks(tracks, tmp_path / 'px.csv')
    assert 'Export Units:,Pixels' in px.read_text()
    cal = Calibration(6.0, (110.0, 110.0))
    read = load_tracks(write_tracks(tracks, tmp_path / 'mm.csv', cal))
    assert read.frame_rate_hz == 1000.0
    back = cal.mm_to_px(read.markers_mm['mb1'])
    assert np.allclose(back, tracks.xy_px['mb1'], atol=1e-6)
    assert np.isnan(read.markers_mm['mb2'][5]).all()
