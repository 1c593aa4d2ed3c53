"""The simulated high-speed camera: a strike filmed as the rig's camera films it
(``docs/tracking_video.md``, "The simulated camera").

Each frame: a grey background, the body and the arm of the four-bar as black plates (the
convex hull of each link's pivots, tip and markers, padded; drawn anti-aliased by OpenCV), and
white markers where the world puts them (body markers: rings with a dark centre; arm markers:
squares with a dark dot), each stamped with its exact coverage of every pixel (supersampled,
box-filtered down), so that a marker's brightness centroid is its true centre; in water darker,
with less contrast, smaller-looking markers and a slight optical blur (:data:`MEDIUM_LOOKS`);
optionally a marker hidden under a dark patch in chosen frames (``CameraSetup.hidden``); the
exposure (1/rate - 20 µs by default) as motion blur, the mean of sub-frames spread evenly over
it, as many as keep each sub-frame's motion under a quarter pixel; sensor noise; 8-bit (or
16-bit in a .cine).

The truth (``truth.csv``) is each marker's centre at mid-exposure, the frame's time: the point
the renderer drew the marker's shapes around in the middle sub-frame (an odd number of them),
hidden or not. Under acceleration the blurred picture's centre differs from it by the motion's
curvature over the exposure (at most a few hundredths of a pixel in the strike at 19,000
frames/s; pixels at 2,000 frames/s, whose exposure is 0.48 ms).

:func:`film` writes a directory: ``video.avi`` (lossless FFV1; ``'avi-raw'``: uncompressed
8-bit) or ``video.cine``, ``calibration.yaml`` and ``truth.csv``; frames are rendered and
written one at a time.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
import math
from pathlib import Path

import numpy as np

from .calibration import Calibration, save_calibration
from .tracker_csv import TrackerCsvWriter

__all__ = ['MEDIUM_LOOKS', 'CameraSetup', 'FilmResult', 'Pose', 'Renderer', 'film',
           'film_strike']

FORMATS = ('avi', 'avi-raw', 'cine')
# OpenCV's sub-pixel drawing: coordinates in 1/2**SHIFT px.
SHIFT = 8
MAX_SUBFRAMES = 33
SUPERSAMPLE = 16          # points per pixel side where markers are stamped
SUBFRAME_MOTION_PX = 0.25
NOISE_BANK = 61


@dataclass(frozen=True)
class CameraSetup:
    """What the camera and the scene look like. Defaults: the real recordings' (camera.md)."""

    rate_hz: float = 19000.0
    scale_px_per_mm: float = 6.0
    width_px: int = 512
    height_px: int = 512
    exposure_s: float | None = None          # None: 1/rate - 20 µs
    background_grey: float = 128.0
    link_grey: float = 22.0
    marker_grey: float = 235.0
    noise_grey: float = 1.5                   # sensor noise, standard deviation (grey levels)
    marker_size_mm: float = 1.5               # ring diameter, square side
    marker_hole_mm: float = 0.55              # the dark centre's diameter
    link_margin_mm: float = 2.5
    blur_px: float = 0.0                      # optical blur, Gaussian sigma (px)
    bit_depth: int = 8                        # 8, or 9..16 (a .cine only)
    seed: int = 0
    # The medium's look (MEDIUM_LOOKS): None takes the scene's (film_strike), and replaces the
    # look's fields above by that medium's; 'air' or 'water' keeps the fields as given.
    medium: str | None = None
    # Markers hidden under a dark patch (the link's grey, a little larger than the marker):
    # (marker name, first frame, last frame), frames numbered from the trigger, both included.
    hidden: tuple = ()

    @property
    def exposure(self) -> float:
        e = (1.0 / self.rate_hz - 20e-6) if self.exposure_s is None else self.exposure_s
        return max(e, 0.0)

    def in_medium(self, medium: str) -> CameraSetup:
        """This set-up filming in ``medium``: its look's fields replaced by the medium's
        (:data:`MEDIUM_LOOKS`) unless the set-up names its medium already."""
        if self.medium is not None:
            return self
        if medium not in MEDIUM_LOOKS:
            raise ValueError(f'medium {medium!r}: expected one of {sorted(MEDIUM_LOOKS)}')
        return replace(self, medium=medium, **MEDIUM_LOOKS[medium])

    def hidden_in(self, number: int) -> set:
        """The markers hidden in frame ``number``."""
        return {name for name, first, last in self.hidden if first <= number <= last}


#: How each medium looks to the camera. Water (the real frames 0116*, 0117*: the background
#: near 80 where air's is near 120, the markers dimmer and smaller-looking, their dark centres
#: not seen, softer edges): darker, less contrast, smaller markers, a slight optical blur.
MEDIUM_LOOKS = {
    'air': {},
    'water': dict(background_grey=82.0, link_grey=12.0, marker_grey=185.0, marker_size_mm=1.0,
                  marker_hole_mm=0.0, blur_px=0.6),
}


@dataclass(frozen=True)
class Pose:
    """The mechanism at some instants, in the world's camera frame (mm, image axes: x right, y
    down): pivots a and b, the tip, and each marker; arrays of shape (n, 2)."""

    a_mm: np.ndarray
    b_mm: np.ndarray
    tip_mm: np.ndarray
    markers_mm: dict = field(default_factory=dict)


@dataclass
class FilmResult:
    video: Path
    calibration: Path
    truth: Path
    frame_count: int
    first_number: int
    rate_hz: float


def world_poses(world) -> Callable[[np.ndarray], Pose]:
    """The pose function of a :class:`~mantis_sim.world.World` (times in world seconds)."""
    from mantis_sim.world import CAMERA_ORIGIN_MM
    g = world.scene.geometry

    def pose(times_s: np.ndarray) -> Pose:
        th1, th3 = world.joint_angles_rad(times_s)
        b = np.column_stack([g.L1_mm * np.cos(th1), g.L1_mm * np.sin(th1)])
        axis = th1 + math.pi - th3
        tip = b + g.L3_mm * np.column_stack([np.cos(axis), np.sin(axis)])
        a = np.zeros_like(b)

        def camera(xy):
            return np.column_stack([xy[:, 0] + CAMERA_ORIGIN_MM[0],
                                    -xy[:, 1] + CAMERA_ORIGIN_MM[1]])
        markers = {n: xy * 1e3 for n, xy in world.marker_positions_m(times_s).items()}
        return Pose(camera(a), camera(b), camera(tip), markers)
    return pose


class Renderer:
    """Draws frames of a mechanism whose pose at any instant ``pose(times_s)`` gives, with the
    calibration ``calibration`` (camera mm -> image px). Link outlines come from the pose at
    ``reference_s``."""

    def __init__(self, pose: Callable[[np.ndarray], Pose], setup: CameraSetup,
                 calibration: Calibration, reference_s: float):
        import cv2  # noqa: F401 - fail here, not mid-film, without OpenCV
        self.pose, self.setup, self.calibration = pose, setup, calibration
        self.marker_names = sorted(pose(np.array([reference_s])).markers_mm)
        self._outlines = self._link_outlines(pose(np.array([reference_s])))
        rng = np.random.default_rng(setup.seed)
        shape = (NOISE_BANK, setup.height_px, setup.width_px)
        # A bank of noise pictures drawn from at random: drawing 512 x 512 normal numbers for
        # each frame would cost more than rendering it.
        self._noise = rng.normal(0.0, setup.noise_grey, shape).astype(np.float32)
        self._rng = rng
        self._top = float((1 << setup.bit_depth) - 1)
        self._grey_scale = self._top / 255.0

    # ------------------------------------------------------------------------ geometry
    def _link_outlines(self, pose: Pose) -> dict:
        """Each link's outline in its own frame (origin at its pivot, x along the link): the
        convex hull of its points padded by the margin."""
        import cv2
        m = self.setup.link_margin_mm
        ring = m * np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 16, endpoint=False)),
                                    np.sin(np.linspace(0, 2 * np.pi, 16, endpoint=False))])
        out = {}
        for link, (origin, end) in {'body': (pose.a_mm, pose.b_mm),
                                    'arm': (pose.b_mm, pose.tip_mm)}.items():
            names = [n for n in self.marker_names if n.startswith('mb' if link == 'body'
                                                                   else 'ma')]
            points = [origin[0], end[0]] + [pose.markers_mm[n][0] for n in names]
            local = _to_link(np.array(points), origin[0], end[0])
            padded = (local[:, None, :] + ring[None]).reshape(-1, 2).astype(np.float32)
            out[link] = cv2.convexHull(padded)[:, 0, :].astype(float)
        return out

    def frame_subtimes(self, time_s: float, speed_px_per_s: float) -> np.ndarray:
        """The sub-frame instants of a frame at ``time_s`` (mid-exposure), an odd number."""
        exposure = self.setup.exposure
        motion_px = speed_px_per_s * exposure
        n = min(MAX_SUBFRAMES, max(1, math.ceil(motion_px / SUBFRAME_MOTION_PX)))
        n += 1 - n % 2
        if n == 1 or exposure == 0:
            return np.array([time_s])
        return time_s + exposure * ((np.arange(n) + 0.5) / n - 0.5)

    # ------------------------------------------------------------------------- drawing
    def render(self, times_s: np.ndarray, numbers=None) -> Iterator[tuple[np.ndarray, dict]]:
        """(picture, {marker: centre px at mid-exposure}) for each frame time; ``numbers``:
        the frames' numbers from the trigger (for ``setup.hidden``)."""
        times_s = np.asarray(times_s, float)
        mid = self.pose(times_s)
        speed = self._speeds_px_per_s(mid, times_s)
        for k, t in enumerate(times_s):
            hidden = (self.setup.hidden_in(int(numbers[k]))
                      if numbers is not None and self.setup.hidden else set())
            subtimes = self.frame_subtimes(t, speed[k])
            pose = self.pose(subtimes) if len(subtimes) > 1 else _pose_at(mid, k)
            picture = self._draw(_pose_at(pose, 0), hidden)
            if len(subtimes) > 1:
                for j in range(1, len(subtimes)):
                    picture += self._draw(_pose_at(pose, j), hidden)
                picture *= np.float32(1.0 / len(subtimes))
            if self.setup.blur_px > 0:
                import cv2
                picture = cv2.GaussianBlur(picture, (0, 0), self.setup.blur_px)
            truth = {n: self.calibration.mm_to_px(mid.markers_mm[n][k])
                     for n in self.marker_names}
            yield self._finish(picture), truth

    def _speeds_px_per_s(self, pose: Pose, times_s: np.ndarray) -> np.ndarray:
        """The fastest point's speed at each frame (px/s), from the pose an exposure apart."""
        e = max(self.setup.exposure, 1e-7)
        after = self.pose(times_s + 0.5 * e)
        before = self.pose(times_s - 0.5 * e)
        moved = [np.hypot(*(after.tip_mm - before.tip_mm).T)]
        moved += [np.hypot(*(after.markers_mm[n] - before.markers_mm[n]).T)
                  for n in self.marker_names]
        return np.max(moved, axis=0) * self.setup.scale_px_per_mm / e

    def _draw(self, pose: Pose, hidden=frozenset()) -> np.ndarray:
        """One instant's picture (float32 grey levels, 0-255)."""
        import cv2
        s = self.setup
        # 8-bit: OpenCV draws anti-aliased edges only there (a float canvas gets hard ones).
        canvas = np.full((s.height_px, s.width_px), round(s.background_grey), np.uint8)
        for link, (origin, end) in (('body', (pose.a_mm, pose.b_mm)),
                                    ('arm', (pose.b_mm, pose.tip_mm))):
            outline = self.calibration.mm_to_px(_from_link(self._outlines[link], origin[0],
                                                           end[0]))
            cv2.fillPoly(canvas, [self._fixed(outline)], round(s.link_grey), cv2.LINE_AA, SHIFT)
        # The markers in float, each pixel blended by the share of it the marker covers: no
        # rounding to whole grey levels moves a marker's centroid.
        picture = canvas.astype(np.float32)
        radius = 0.5 * s.marker_size_mm * s.scale_px_per_mm
        hole = 0.5 * s.marker_hole_mm * s.scale_px_per_mm
        along = pose.tip_mm[0] - pose.b_mm[0]
        arm_angle = math.atan2(along[1], along[0])
        for name in self.marker_names:
            centre = self.calibration.mm_to_px(pose.markers_mm[name][0])
            shape = 'disc' if name.startswith('mb') else 'square'
            _stamp(picture, centre, shape, radius, hole, arm_angle, s.marker_grey)
        for name in hidden:
            # A dark patch over the marker (a tendon, a shadow): the link's grey, 1.5 times
            # the marker's reach.
            centre = self.calibration.mm_to_px(pose.markers_mm[name][0])
            _stamp(picture, centre, 'disc', 1.5 * math.sqrt(2.0) * radius, 0.0, 0.0,
                   s.link_grey)
        return picture

    def _fixed(self, xy_px: np.ndarray) -> np.ndarray:
        """Pixel coordinates (pixel centres at integers) in OpenCV's fixed point."""
        return np.round(np.asarray(xy_px) * (1 << SHIFT)).astype(np.int32)

    def _finish(self, picture: np.ndarray) -> np.ndarray:
        """The picture with the sensor's noise, at the camera's bit depth."""
        noise = self._noise[self._rng.integers(NOISE_BANK)]
        out = picture * np.float32(self._grey_scale) + noise * np.float32(self._grey_scale)
        np.clip(out, 0.0, self._top, out=out)
        dtype = np.uint8 if self.setup.bit_depth == 8 else np.uint16
        return np.rint(out).astype(dtype)


def _stamp(picture: np.ndarray, centre: np.ndarray, shape: str, half_px: float,
           hole_radius_px: float, angle_rad: float, grey: float) -> None:
    """A marker of ``grey`` around ``centre`` (px): a disc of radius ``half_px`` or a square of
    half-side ``half_px`` turned by ``angle_rad``, less a central hole of ``hole_radius_px``
    (which shows what lies beneath), each pixel blended by the share of it the marker covers
    (SUPERSAMPLE^2 points a pixel, box-filtered). The coverage is symmetric about the centre
    to the sampling's precision, so the marker's brightness centroid is its centre (OpenCV's
    anti-aliased polygons and circles put a small marker's centre up to 0.45 px off)."""
    reach = half_px * (math.sqrt(2.0) if shape == 'square' else 1.0) + 1.0
    x0, y0 = (int(math.floor(v - reach)) for v in centre)
    x1, y1 = (int(math.ceil(v + reach)) + 1 for v in centre)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, picture.shape[1]), min(y1, picture.shape[0])
    if x0 >= x1 or y0 >= y1:
        return
    xs = np.arange(x0, x1, dtype=np.float32)[None, :] - np.float32(centre[0])
    ys = np.arange(y0, y1, dtype=np.float32)[:, None] - np.float32(centre[1])
    c, s = np.float32(math.cos(angle_rad)), np.float32(math.sin(angle_rad))
    # Whole pixels inside or outside, from their centres; only the edge's pixels are sampled.
    r = np.hypot(xs, ys)
    half_diagonal = np.float32(math.sqrt(0.5))
    hole = float(hole_radius_px)
    if shape == 'square':
        u, v = np.abs(xs * c + ys * s), np.abs(-xs * s + ys * c)
        reach = np.float32(0.5 * (abs(math.cos(angle_rad)) + abs(math.sin(angle_rad))))
        full = (np.maximum(u, v) + reach <= half_px)
        empty = (np.maximum(u, v) - reach >= half_px)
    else:
        full = r + half_diagonal <= half_px
        empty = r - half_diagonal >= half_px
    if hole > 0:
        full &= r - half_diagonal >= hole
        empty |= r + half_diagonal <= hole
    cover = full.astype(np.float32)
    edge = np.nonzero(~full & ~empty)
    if len(edge[0]):
        sub = ((np.arange(SUPERSAMPLE, dtype=np.float32) + 0.5) / SUPERSAMPLE - 0.5)
        px = (xs[0, edge[1]][:, None, None] + sub[None, None, :])
        py = (ys[edge[0], 0][:, None, None] + sub[None, :, None])
        if shape == 'square':
            inside = ((np.abs(px * c + py * s) <= half_px)
                      & (np.abs(-px * s + py * c) <= half_px))
        else:
            inside = px * px + py * py <= half_px * half_px
        if hole > 0:
            inside &= px * px + py * py > hole * hole
        cover[edge] = inside.reshape(len(edge[0]), -1).mean(axis=1)
    patch = picture[y0:y1, x0:x1]
    patch += cover * (np.float32(grey) - patch)


def _to_link(points: np.ndarray, origin: np.ndarray, end: np.ndarray) -> np.ndarray:
    ux = (end - origin) / np.hypot(*(end - origin))
    uy = np.array([-ux[1], ux[0]])
    rel = points - origin
    return np.column_stack([rel @ ux, rel @ uy])


def _from_link(local: np.ndarray, origin: np.ndarray, end: np.ndarray) -> np.ndarray:
    ux = (end - origin) / np.hypot(*(end - origin))
    uy = np.array([-ux[1], ux[0]])
    return origin + local[:, :1] * ux + local[:, 1:] * uy


def _pose_at(pose: Pose, k: int) -> Pose:
    return Pose(pose.a_mm[k:k + 1], pose.b_mm[k:k + 1], pose.tip_mm[k:k + 1],
                {n: xy[k:k + 1] for n, xy in pose.markers_mm.items()})


# ---------------------------------------------------------------------------------- film
def centred_calibration(pose: Pose, setup: CameraSetup) -> Calibration:
    """A left-handed, untilted calibration that puts the poses' extent at the image's centre
    (the world's camera frame in mm, scaled); ValueError if it does not fit."""
    points = np.concatenate([pose.a_mm, pose.b_mm, pose.tip_mm, *pose.markers_mm.values()])
    low, high = points.min(axis=0), points.max(axis=0)
    extent_px = (high - low) * setup.scale_px_per_mm + 2 * 4 * setup.scale_px_per_mm
    if extent_px[0] > setup.width_px or extent_px[1] > setup.height_px:
        raise ValueError(f'the mechanism spans {extent_px[0]:.0f}x{extent_px[1]:.0f} px at '
                         f'{setup.scale_px_per_mm} px/mm: more than the {setup.width_px}x'
                         f'{setup.height_px} picture')
    centre_px = np.array([setup.width_px - 1, setup.height_px - 1]) / 2.0
    origin = centre_px - 0.5 * (low + high) * setup.scale_px_per_mm
    return Calibration(setup.scale_px_per_mm, (round(float(origin[0]), 3),
                                               round(float(origin[1]), 3)))


def film(pose: Callable[[np.ndarray], Pose], out_dir, trigger_s: float, start_s: float,
         stop_s: float, setup: CameraSetup = CameraSetup(), video_format: str = 'avi',
         video_name: str = '', progress: Callable[[int, int], None] | None = None,
         ) -> FilmResult:
    """Film from ``start_s`` to ``stop_s`` (the pose function's clock) into ``out_dir``.

    Frames lie on the trigger's grid: frame n at ``trigger_s + n / rate`` (mid-exposure),
    numbered from the trigger as the camera numbers them. ``video_format``: 'avi' (lossless
    FFV1), 'avi-raw' (uncompressed 8-bit) or 'cine'. ``progress(done, total)`` after each frame.
    """
    if video_format not in FORMATS:
        raise ValueError(f'video format {video_format!r}: expected one of {FORMATS}')
    if setup.bit_depth != 8 and video_format != 'cine':
        raise ValueError(f'{setup.bit_depth}-bit pictures: only a .cine holds more than 8 bits')
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rate = setup.rate_hz
    first = math.ceil((start_s - trigger_s) * rate - 1e-9)
    last = math.floor((stop_s - trigger_s) * rate + 1e-9)
    numbers = np.arange(first, last + 1)
    if len(numbers) == 0:
        raise ValueError(f'no frame between {start_s} and {stop_s} s at {rate:g} frames/s')
    times = trigger_s + numbers / rate
    calibration = centred_calibration(pose(times[:: max(1, len(times) // 400)]), setup)
    renderer = Renderer(pose, setup, calibration, reference_s=float(times[0]))
    calibration_path = save_calibration(calibration, out_dir / 'calibration.yaml')
    video_path = out_dir / ('video.cine' if video_format == 'cine' else 'video.avi')
    truth_path = out_dir / 'truth.csv'
    video_name = video_name or video_path.name
    with _video_writer(video_path, video_format, setup, numbers) as video, \
            TrackerCsvWriter(truth_path, renderer.marker_names, rate, calibration,
                             video_name) as truth:
        chunk = 256
        for lo in range(0, len(numbers), chunk):
            block = slice(lo, lo + chunk)
            frames = renderer.render(times[block], numbers[block])
            for k, (picture, centres) in enumerate(frames, start=lo):
                video.write(picture)
                truth.write_frame(int(numbers[k]), _time_from_trigger(numbers[k], rate,
                                                                      video_format), centres)
                if progress is not None:
                    progress(k + 1, len(numbers))
    return FilmResult(video_path, calibration_path, truth_path, len(numbers), int(first), rate)


def film_strike(scene, out_dir, setup: CameraSetup = CameraSetup(), before_s: float = 0.05,
                after_s: float = 0.02, video_format: str = 'avi',
                progress: Callable[[int, int], None] | None = None) -> FilmResult:
    """Pull ``scene``'s robot through one strike in a World and film it from ``before_s``
    before the release (the camera's trigger, the start of phase IV) to ``after_s`` after.
    The picture looks as the scene's medium does (``CameraSetup.in_medium``) unless ``setup``
    names its medium."""
    from mantis_sim.world import World
    setup = setup.in_medium(scene.medium.name)
    world = World(scene, history_s=max(5.0, before_s + after_s + 1.0))
    pull_start_s = 0.5
    world.advance_to(pull_start_s)
    world.set_stage_velocity(scene.drive.pull_speed_mm_per_s * 1e-3)
    t_s = pull_start_s
    while not math.isfinite(world.peak_time_s):
        if t_s - pull_start_s > 60.0:
            raise RuntimeError(f'scene {scene.name!r}: no strike within 60 s of pulling')
        t_s += 0.01
        world.advance_to(t_s)
    trigger_s = world.phase_start_s['IV']
    world.advance_to(max(world.time_s, trigger_s + after_s + 1e-3))
    start_s = max(trigger_s - before_s, pull_start_s)
    return film(world_poses(world), out_dir, trigger_s, start_s, trigger_s + after_s, setup,
                video_format, video_name=f'{scene.name}_{setup.rate_hz / 1000:g}kfps.avi',
                progress=progress)


def _time_from_trigger(number: int, rate_hz: float, video_format: str) -> float:
    if video_format == 'cine':
        from .cine_writer import frame_time_s
        return frame_time_s(int(number), rate_hz)   # as the .cine's time stamps read back
    return number / rate_hz


class _AviWriter:
    """OpenCV's .avi writer, fed from a thread of its own: FFV1's encoder takes as long as the
    rendering, and releases the GIL, so the two overlap. A short queue keeps memory flat."""

    def __init__(self, path: Path, raw: bool, setup: CameraSetup):
        import queue
        import threading

        import cv2
        fourcc = 0 if raw else cv2.VideoWriter_fourcc(*'FFV1')
        # The playback rate an .avi carries; the recording's rate is in truth.csv and the name.
        self._writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, fourcc, 30.0,
                                       (setup.width_px, setup.height_px), False)
        if not self._writer.isOpened():
            raise RuntimeError(f'{path}: OpenCV cannot write this .avi')
        self._queue: queue.Queue = queue.Queue(maxsize=8)
        self._thread = threading.Thread(target=self._run, name='avi-writer', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (picture := self._queue.get()) is not None:
            self._writer.write(picture)

    def write(self, picture: np.ndarray) -> None:
        self._queue.put(picture)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self._queue.put(None)
        self._thread.join()
        self._writer.release()


def _video_writer(path: Path, video_format: str, setup: CameraSetup, numbers: np.ndarray):
    if video_format == 'cine':
        from .cine_writer import CineWriter
        return CineWriter(path, setup.width_px, setup.height_px, len(numbers), setup.rate_hz,
                          first_number=int(numbers[0]), bit_depth=setup.bit_depth,
                          exposure_s=setup.exposure)
    return _AviWriter(path, video_format == 'avi-raw', setup)
