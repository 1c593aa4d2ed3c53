"""Find the markers in one grey frame: white rings, squares and blocks on the robot's black links.

A marker is a small blob brighter than the grey background, standing out of a white top-hat
(bright detail smaller than the largest marker), whose surround is mostly dark (it sits on a
link). That rejects the bright mount (large, its surround bright), the grey background and the
gaps between links (not brighter than the background), the tendon (thin and long) and most
glare; what it keeps that is no marker (a glinting screw on a dark hub) the naming leaves out,
since it fits no place of the linkage.

Each marker's centre is an intensity-weighted centroid of the pixels above a level (the
brighter of the local dark link and the background, plus the noise): a symmetric blob's
truncated centroid is unbiased at any level, and a ring's dark centre weighs nothing, so a
ring's centre is the ring's. The same measurement, in a small window, follows a marker from
frame to frame (:func:`measure_near`).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import NamedTuple

import cv2
import numpy as np

from mantis_sim.errors import InputError

__all__ = ['Blob', 'FrameError', 'FrameLevels', 'Window', 'find_markers', 'frame_levels',
           'arc_angle', 'grey_frame', 'measure_many', 'measure_near', 'measure_streak']

# The largest marker looked for (px across), unless told: a screenshot at 15 px/mm shows the
# rings some 25 px across; the camera's own pixels (6 px/mm) about 10.
DEFAULT_MAX_DIAMETER_PX = 40.0
DEFAULT_MIN_DIAMETER_PX = 2.5
# A blob longer than this many times its width is a line (the tendon, a link's lit edge).
MAX_ELONGATION = 3.5
# Of the ring around a blob, at least this share must be darker than halfway from the
# background down to the links: the marker sits on a link (which may be narrower than it).
MIN_DARK_SURROUND = 0.2


class FrameError(InputError):
    """A frame that cannot be searched for markers (not a 2-D grey image), naming the frame."""


@dataclass(frozen=True)
class Blob:
    """One marker candidate: centre (px, x right, y down, (0, 0) the top-left pixel's centre),
    its size and how it stands out."""

    x_px: float
    y_px: float
    area_px: float          # holes filled: a ring counts as its disc
    diameter_px: float      # of the disc of that area
    peak: float             # brightest grey level in it
    contrast: float         # peak above the level its centroid was weighed from
    level: float            # that level (the dark link or the background, plus the noise)
    ring: bool              # a dark centre inside a bright blob


@dataclass(frozen=True)
class FrameLevels:
    """The grey levels of a frame the markers are told from: the links (dark), the background
    and the noise."""

    dark: float
    background: float
    noise: float


def grey_frame(image, where: str = 'frame') -> np.ndarray:
    """The frame as a 2-D array of grey levels (uint8 or uint16 kept; colour with 3 or 4
    channels converted to grey, as a PNG screenshot stores it)."""
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] in (3, 4) and a.dtype in (np.uint8, np.uint16):
        code = cv2.COLOR_BGRA2GRAY if a.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        a = cv2.cvtColor(a, code)
    if a.ndim != 2 or a.dtype not in (np.uint8, np.uint16) or min(a.shape) < 8:
        raise FrameError(f'{where}: expected a 2-D grey image of uint8 or uint16 at least 8 px '
                         f'each way, got shape {a.shape} of {a.dtype}')
    return a


def frame_levels(grey: np.ndarray) -> FrameLevels:
    """Dark, background and noise levels of a frame (from a subsample: cheap on big frames)."""
    sub = grey[::4, ::4] if grey.size > 65536 else grey
    dark, background = np.percentile(sub, [2.0, 50.0])
    # Noise from pixel-to-pixel differences in the flat background, robust to edges.
    row = grey[grey.shape[0] // 2].astype(np.float32)
    diffs = np.abs(np.diff(row))
    noise = float(np.median(diffs) / 0.954) if diffs.size else 0.0
    return FrameLevels(float(dark), float(background), max(noise, 0.5))


def find_markers(image, *, max_diameter_px: float = DEFAULT_MAX_DIAMETER_PX,
                 min_diameter_px: float = DEFAULT_MIN_DIAMETER_PX,
                 levels: FrameLevels | None = None, where: str = 'frame') -> list[Blob]:
    """Every marker candidate in a whole frame, most contrasted first.

    The frame is cut at a ladder of grey levels from halfway between the links and the
    background up to near white: a marker that touches something bright (the mount) at a low
    cut stands alone at a higher one. Each blob is taken at the lowest cut where it passes as a
    marker (size, shape, a dark link around it)."""
    grey = grey_frame(image, where)
    lv = levels or frame_levels(grey)
    g = grey.astype(np.float32)
    span = max(lv.background - lv.dark, 8 * lv.noise)
    mid = lv.dark + 0.5 * span
    top = float(np.percentile(grey[::2, ::2], 99.9))
    min_area = np.pi / 4 * min_diameter_px ** 2
    max_area = np.pi / 4 * max_diameter_px ** 2 * 1.5
    found: list[Blob] = []
    # The pixels of the blobs taken: a blob cut at a higher level is part of one cut lower,
    # so a blob overlapping them is a piece of a marker already found.
    taken = np.zeros(grey.shape, bool)
    for cut in np.linspace(mid + 0.25 * span, max(top - 4 * lv.noise, mid + 0.3 * span),
                           LADDER_STEPS):
        bright = g > cut
        filled = _fill_holes(bright)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(filled.view(np.uint8),
                                                               connectivity=4)
        areas = stats[:, cv2.CC_STAT_AREA]
        for k in np.flatnonzero((areas >= min_area) & (areas <= max_area)):
            if k == 0:
                continue
            x, y, w, h = stats[k, :4]
            box = (slice(y, y + h), slice(x, x + w))
            if taken[box][labels[box] == k].any():
                continue
            blob = _candidate(g, labels, k, box, lv, float(cut), min_area, max_area, bright)
            if blob is not None:
                found.append(blob)
                taken[box] |= labels[box] == k
    found.sort(key=lambda b: -b.contrast)
    return found


LADDER_STEPS = 12


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask with its holes filled (the dark regions not reaching the border)."""
    outside = np.ones((mask.shape[0] + 2, mask.shape[1] + 2), np.uint8)
    outside[1:-1, 1:-1] = ~mask
    cv2.floodFill(outside, None, (0, 0), 0)
    return mask | outside[1:-1, 1:-1].view(bool)


def _candidate(g, labels, k, box, lv: FrameLevels, cut, min_area, max_area, bright):
    """The blob of label k as a marker candidate, or None if it is not one."""
    h, w = box[0].stop - box[0].start, box[1].stop - box[1].start
    if h * w < min_area or h * w > 4 * max_area:
        return None
    pad = max(max(h, w) // 2, 3)
    y0, x0 = max(box[0].start - pad, 0), max(box[1].start - pad, 0)
    y1, x1 = min(box[0].stop + pad, g.shape[0]), min(box[1].stop + pad, g.shape[1])
    own = labels[y0:y1, x0:x1] == k
    area = float(own.sum())
    if not min_area <= area <= max_area:
        return None
    if _elongation(own) > MAX_ELONGATION:
        return None
    win = g[y0:y1, x0:x1]
    grown = cv2.dilate(own.view(np.uint8), np.ones((2 * pad + 1, 2 * pad + 1), np.uint8))
    surround = win[grown.astype(bool) & ~own]
    if surround.size < 4:
        return None
    halfway = 0.5 * (lv.dark + lv.background)
    if np.mean(surround < halfway) < MIN_DARK_SURROUND:
        return None
    peak = float(win[own].max())
    centre = _weighted_centre(win, own, cut)
    if centre is None:
        return None
    hole = own & ~bright[y0:y1, x0:x1]
    return Blob(x_px=centre[0] + x0, y_px=centre[1] + y0, area_px=area,
                diameter_px=float(2 * np.sqrt(area / np.pi)), peak=peak,
                contrast=peak - float(np.percentile(surround, 10)), level=cut,
                ring=bool(hole.sum() >= 1))


def _elongation(mask: np.ndarray) -> float:
    """Long axis over short axis of a mask's second moments."""
    ys, xs = np.nonzero(mask)
    if xs.size < 3:
        return 1.0
    cov = np.cov(np.vstack([xs, ys]).astype(float))
    ev = np.linalg.eigvalsh(cov)
    return float(np.sqrt(max(ev[1], 1e-9) / max(ev[0], 1e-3 / 12 + 1 / 12)))


def _weighted_centre(win: np.ndarray, own: np.ndarray, level: float):
    """Centroid of (grey - level)+ over the blob (cut at that level: its truncated centroid is
    unbiased for a symmetric blob), in the window's pixel coordinates, or None."""
    w = np.where(own, win - level, 0.0)
    np.maximum(w, 0.0, out=w)
    total = w.sum()
    if total <= 0:
        return None
    ys, xs = np.indices(w.shape)
    return float((w * xs).sum() / total), float((w * ys).sum() / total)


def measure_near(grey: np.ndarray, x_px: float, y_px: float, half_px: int, level: float,
                 min_contrast: float, background: float | None = None, min_area_px: float = 2.0,
                 max_area_px: float = 2000.0,
                 others=()) -> tuple[float, float, float, float] | None:
    """The marker nearest (x_px, y_px) within a square window of half-width half_px: its
    centre (x, y px), its peak above ``level`` (the dark link's grey) and its area (px, cut
    halfway up), or None (a gap) if no
    blob stands ``min_contrast`` above the level there. The blob is cut halfway up from the
    link, or from the ``background`` where the marker outshines it clearly (so that a marker
    over the background, the arm swung out, stays a blob of its own). ``others``: where other
    markers are expected nearby; the pixels nearer one of them than (x_px, y_px) are theirs.
    (:func:`measure_many` for many markers at once, as the follower measures a frame.)"""
    return measure_many(grey, [Window(x_px, y_px, half_px, level, min_contrast, max_area_px,
                                      others)], background, min_area_px)[0]


class Window(NamedTuple):
    """One marker to measure by :func:`measure_many` (the arguments of :func:`measure_near`)."""

    x_px: float
    y_px: float
    half_px: int
    level: float
    min_contrast: float
    max_area_px: float = 2000.0
    others: tuple | list = ()


# Zero pixels around each window in measure_many's tile: the rim's dilation (2 px) of one
# window's blob never reaches the next window's.
_PAD = 2


def measure_many(grey: np.ndarray, windows: list[Window], background: float | None = None,
                 min_area_px: float = 2.0) -> list[tuple[float, float, float, float] | None]:
    """:func:`measure_near` for each window, in one pass: the windows are laid side by side in
    one tile (each on zeros, below any cut) and cut, labelled, dilated and weighed together,
    a dozen numpy and OpenCV calls for all the markers of a frame rather than for each."""
    rows, cols = grey.shape
    n_win = len(windows)
    results: list = [None] * n_win
    places = []
    for i, wd in enumerate(windows):
        cx, cy = math.floor(wd.x_px + 0.5), math.floor(wd.y_px + 0.5)
        x0, y0 = max(cx - wd.half_px, 0), max(cy - wd.half_px, 0)
        x1, y1 = min(cx + wd.half_px + 1, cols), min(cy + wd.half_px + 1, rows)
        if x1 - x0 >= 3 and y1 - y0 >= 3:
            places.append((i, x0, y0, x1, y1))
    if not places:
        return results
    side = max(max(x1 - x0, y1 - y0) for _, x0, y0, x1, y1 in places) + 2 * _PAD
    m = len(places)
    tile = np.zeros((m, side, side), grey.dtype)
    inside = np.zeros((m, side, side), np.uint8)
    # The pixels nearer another marker's expected place (ox, oy) than this window's (x, y)
    # are theirs: at picture pixel (X, Y), 2 X (ox - x) + 2 Y (oy - y) + x^2 + y^2 - ox^2 -
    # oy^2 > 0, a half-plane: (a, b, c) of it in the tile's (column, row) for each such pair.
    planes, starts, shared = [], [], []
    edge = side - 1
    for j, (i, x0, y0, x1, y1) in enumerate(places):
        wd = windows[i]
        tile[j, _PAD:_PAD + y1 - y0, _PAD:_PAD + x1 - x0] = grey[y0:y1, x0:x1]
        inside[j, _PAD:_PAD + y1 - y0, _PAD:_PAD + x1 - x0] = 1
        first = len(planes)
        x, y = wd.x_px, wd.y_px
        for ox, oy in wd.others:
            a, b = 2.0 * (ox - x), 2.0 * (oy - y)
            c = a * (x0 - _PAD) + b * (y0 - _PAD) + x * x + y * y - ox * ox - oy * oy
            if c + max(a * edge, 0.0) + max(b * edge, 0.0) > 0.0:   # it reaches the window
                planes.append((a, b, c))
        if len(planes) > first:
            starts.append(first)
            shared.append(j)
    if planes:
        _theirs_dark(tile, planes, starts, shared)
    peaks = tile.reshape(m, -1).max(axis=1).tolist()
    cuts = np.full(m, np.inf)
    kept = []                      # (j, peak, level, base, cut)
    for j, (i, *_rest) in enumerate(places):
        wd, peak = windows[i], float(peaks[j])
        if peak - wd.level < wd.min_contrast:
            continue
        base = wd.level
        if background is not None and peak - background > 2 * wd.min_contrast:
            base = max(wd.level, background)
        cut = base + 0.5 * (peak - base)
        cuts[j] = cut
        kept.append((j, peak, wd.level, base, cut))
    if not kept:
        return results
    mask = (tile > cuts[:, None, None]).view(np.uint8)
    mask &= inside                 # (a cut below zero would take the zeros around a window)
    # One image of the windows stacked; 16-bit labels (fewer than 65,536 blobs): faster.
    n, labels, stats, cents = cv2.connectedComponentsWithStats(
        mask.reshape(m * side, side), connectivity=8, ltype=cv2.CV_16U)
    # Each window's blob: the nearest to where the marker is expected, of a marker's size.
    best: dict = {}
    tops, areas = stats[:, cv2.CC_STAT_TOP].tolist(), stats[:, cv2.CC_STAT_AREA].tolist()
    centres = cents.tolist()
    for k in range(1, n):
        j = tops[k] // side
        i, x0, y0 = places[j][:3]
        wd = windows[i]
        if not min_area_px <= areas[k] <= wd.max_area_px:
            continue
        d2 = ((centres[k][0] - _PAD + x0 - wd.x_px) ** 2
              + (centres[k][1] - j * side - _PAD + y0 - wd.y_px) ** 2)
        if j not in best or d2 < best[j][0]:
            best[j] = (d2, k)
    if not best:
        return results
    pick = np.zeros(n, np.uint8)
    for _, k in best.values():
        pick[k] = 1
    own = pick.take(labels)
    zone = cv2.dilate(own, _RIM)
    zone &= inside.reshape(m * side, side)
    floors = np.zeros(m)
    rim = None
    for j, peak, level, base, cut in kept:
        if j not in best:
            continue
        floors[j] = level
        if base != level:
            if rim is None:
                rim = (zone - own).reshape(m, side, side)
                rim_count = rim.reshape(m, -1).sum(axis=1, dtype=np.int64)
                rim_sum = (tile * rim).reshape(m, -1).sum(axis=1, dtype=np.int64)
            rim_mean = rim_sum[j] / rim_count[j] if rim_count[j] else 0.0
            if rim_mean >= 0.5 * (level + base) + 0.25 * (peak - base):
                floors[j] = cut
    w = tile - floors[:, None, None]
    np.maximum(w, 0.0, out=w)
    w *= zone.reshape(m, side, side)
    by_column, by_row = w.sum(axis=1), w.sum(axis=2)
    along = np.arange(side, dtype=np.float64)
    m00, m10, m01 = by_column.sum(axis=1), by_column @ along, by_row @ along
    for j, (_, k) in best.items():
        if m00[j] <= 0:
            continue
        i, x0, y0 = places[j][:3]
        results[i] = (float(m10[j] / m00[j]) - _PAD + x0, float(m01[j] / m00[j]) - _PAD + y0,
                      float(peaks[j]) - windows[i].level, float(areas[k]))
    return results


def _theirs_dark(tile: np.ndarray, planes: list, starts: list, shared: list) -> None:
    """Blacken the tile's pixels on the far side of the half-planes ``planes`` (a, b, c: a
    column + b row + c > 0), those from ``starts[k]`` on in window ``shared[k]``."""
    abc = np.array(planes, np.float64)
    along = np.arange(tile.shape[1], dtype=np.float64)
    cols = abc[:, 0:1] * along
    rows = abc[:, 1:2] * along + abc[:, 2:3]
    far = (cols[:, None, :] + rows[:, :, None]) > 0.0
    if len(starts) < len(planes):
        far = np.logical_or.reduceat(far, starts, axis=0)
    tile[shared] *= ~far


_RIM = np.ones((5, 5), np.uint8)


def _white_top_hat(patch: np.ndarray, marker_radius_px: float) -> np.ndarray:
    """What an opening with a disc wider than a marker takes away: the narrow bright things (a
    marker, its streak), without the smooth or wide ones (the links, their smear, the
    background)."""
    patch = patch.astype(np.float32)
    size = 2 * int(math.ceil(1.6 * marker_radius_px)) + 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return patch - cv2.morphologyEx(patch, cv2.MORPH_OPEN, disc)


def measure_streak(grey: np.ndarray, window: Window, radius_px: float, noise: float
                   ) -> tuple[float, float, float, float] | None:
    """A fast marker smeared by the exposure into a streak along its path, over the smeared
    dark link: its centre is the mean of where it was during the exposure. The link's smear is
    smooth across the streak while the streak is as narrow as the marker, so an opening with a
    disc wider than the marker takes the streak away and leaves the smear (a white top-hat):
    the streak's centre is the centroid of what the opening took, in the connected part
    nearest where the marker is expected (the others' places blacked out as in
    :func:`measure_many`). (x, y, contrast, area) as measure_near's, or None."""
    rows, cols = grey.shape
    cx, cy = math.floor(window.x_px + 0.5), math.floor(window.y_px + 0.5)
    x0, y0 = max(cx - window.half_px, 0), max(cy - window.half_px, 0)
    x1, y1 = min(cx + window.half_px + 1, cols), min(cy + window.half_px + 1, rows)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    hat = _white_top_hat(grey[y0:y1, x0:x1], radius_px)
    x, y = window.x_px - x0, window.y_px - y0
    if window.others:
        along_x = np.arange(x1 - x0, dtype=np.float32)[None, :]
        along_y = np.arange(y1 - y0, dtype=np.float32)[:, None]
        for ox, oy in window.others:
            ox, oy = ox - x0, oy - y0
            theirs = (2 * (ox - x) * along_x + 2 * (oy - y) * along_y
                      + x * x + y * y - ox * ox - oy * oy) > 0
            hat[theirs] = 0.0
    peak = float(hat.max())
    if peak < max(6.0 * noise, window.min_contrast * 0.25):
        return None
    mask = (hat > max(3.0 * noise, 0.2 * peak)).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    d2 = (cents[1:, 0] - x) ** 2 + (cents[1:, 1] - y) ** 2
    big = stats[1:, cv2.CC_STAT_AREA] >= 4
    if not big.any():
        return None
    k = 1 + int(np.argmin(np.where(big, d2, np.inf)))
    w = np.where(labels == k, hat, 0.0)
    total = float(w.sum())
    if total <= 0:
        return None
    gx = float((w.sum(axis=0) @ np.arange(x1 - x0)) / total)
    gy = float((w.sum(axis=1) @ np.arange(y1 - y0)) / total)
    return gx + x0, gy + y0, peak, float(stats[k, cv2.CC_STAT_AREA])


def arc_angle(grey: np.ndarray, centre, radius_px: float, angle: float, reach: float,
              marker_radius_px: float, noise: float, exclude=(), least_peak: float = 0.0
              ) -> float | None:
    """The mean angle (rad, about ``centre``, image axes) of a marker's light on its circle of
    ``radius_px`` within ``angle`` +/- ``reach``: the white top-hat of the picture (as
    :func:`measure_streak`) in a band one marker wide along the arc, the discs about the
    points ``exclude`` (other markers found) left out. None where the arc holds too little
    light to be the marker, or none brighter than ``least_peak``."""
    rows, cols = grey.shape
    band = marker_radius_px + 1.5
    cx, cy = float(centre[0]), float(centre[1])
    ts = np.linspace(angle - reach, angle + reach, 9)
    xs, ys = cx + radius_px * np.cos(ts), cy + radius_px * np.sin(ts)
    x0 = max(int(math.floor(xs.min() - band - 1)), 0)
    x1 = min(int(math.ceil(xs.max() + band + 2)), cols)
    y0 = max(int(math.floor(ys.min() - band - 1)), 0)
    y1 = min(int(math.ceil(ys.max() + band + 2)), rows)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    hat = _white_top_hat(grey[y0:y1, x0:x1], marker_radius_px)
    gx = np.arange(x0, x1, dtype=np.float32)[None, :] - cx
    gy = np.arange(y0, y1, dtype=np.float32)[:, None] - cy
    off = np.remainder(np.arctan2(gy, gx) - angle + math.pi, 2 * math.pi) - math.pi
    keep = (np.abs(np.hypot(gx, gy) - radius_px) <= band) & (np.abs(off) <= reach)
    for ox, oy in exclude:
        keep &= np.hypot(gx + cx - ox, gy + cy - oy) > marker_radius_px + 3
    hat = np.where(keep, hat, 0.0)
    peak = float(hat.max()) if hat.size else 0.0
    if peak < max(6.0 * noise, least_peak):
        return None
    w = np.where(hat > max(3.0 * noise, 0.2 * peak), hat, 0.0)
    total = float(w.sum())
    # The marker's light: at rest its disc holds about pi r^2 pixels at the peak's level; a
    # streak spreads the same light thinner. A tenth of it is a marker; less is noise.
    if total < 0.1 * math.pi * marker_radius_px ** 2 * peak:
        return None
    return angle + float(np.sum(w * off) / total)
