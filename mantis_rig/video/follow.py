"""Follow named markers from frame to frame, each in a small window around where it should be.

Where it should be: its last two positions carried on at constant velocity; for a marker missed
in a frame, its link carried rigidly by the link's markers found there (the body turns about
the pivot a, the arm about the hinge b, which rides on the body). The window grows with the
marker's speed (a strike at 19,000 frames/s moves the tip some 9 px a frame, blurred over the
exposure). A marker not found in its window is a gap, never a guessed position; a found blob
that breaks its link's rigidity (another marker, glare) is a gap too. A marker missed for a
while is looked for again every so often (less often the longer it stays lost) among the
blobs that fit its link, found in the part of the frame its link can reach; one still lost at
the end is reported with the frame it was last seen in.

Speed: the markers followed in a frame are measured together (``markers.measure_many``: their
windows side by side in one small tile, a dozen numpy and OpenCV calls a frame rather than a
dozen a marker); about 5,000 frames/s for five markers on this 2-core machine.

State is a few numbers per marker: memory does not grow with the recording.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from .markers import (
    FrameLevels,
    Window,
    arc_angle,
    find_markers,
    frame_levels,
    grey_frame,
    measure_many,
    measure_streak,
)
from .naming import Naming

__all__ = ['Follower']

# The window's half-width beyond the marker's radius: this many pixels plus this share of
# its speed in px/frame (prediction error and blur both grow with it).
WINDOW_MARGIN_PX = 3.0
WINDOW_SPEED_SHARE = 1.2
# A marker missed this many frames in a row is searched for (its link's reach); then again after
# twice as many frames, up to this many.
REACQUIRE_AFTER = 3
REACQUIRE_MAX_INTERVAL = 256
# A link's markers keep their distances within this (px) plus this share of the distance.
RIGID_TOLERANCE_PX = 1.5
RIGID_TOLERANCE_SHARE = 0.03
# A marker moving more than this many of its radii a frame is smeared into a streak by the
# exposure: measured as one (markers.measure_streak).
STREAK_SPEED_RADII = 1.0
# An arm marker moving more than this many of its radii a frame is measured on its arc about
# the hinge (Follower._arm_arcs), as is one seen in the last frame and missed in this; a fast
# one missed is looked for on its arc this much further (rad) for each frame it has been
# missed, up to so many frames (further on, its arc may hold other things: the
# re-acquisition's search takes over).
ARC_SPEED_RADII = 0.5
ARC_LOST_REACH_RAD = 0.1
ARC_LOST_FRAMES = 2
# A blob larger than this many times the marker's own (plus its blur's sweep) is the marker
# merged with another: a gap.
MAX_AREA_GROWTH = 1.6


@dataclass
class _Marker:
    name: str
    ref: np.ndarray              # position in the first frame (px)
    last: tuple                  # last position found (x, y px)
    velocity: tuple              # (x, y) px per frame
    radius_px: float
    level: float                 # grey level of the dark link around it, plus the noise
    area_px: float               # its area cut halfway up, in the first frame
    min_contrast: float
    last_seen: int               # frame index
    missed: int = 0              # frames missed in a row
    next_search: int = 0         # the frame of the next search for it while missed
    speeding: tuple = (0.0, 0.0)  # (x, y) px per frame per frame, in the strike (else 0)
    contrast: float = 0.0        # its peak above the link's level at rest (first frame)


_NOWHERE = np.full(2, np.nan)


class Follower:
    """Follows the markers of ``naming`` from the frame it was made in (``first``) on.
    ``step(image, index)`` -> (n, 2) px, NaN where a marker is not found, in ``names`` order."""

    def __init__(self, first, naming: Naming, index: int = 0, where: str = 'recording'):
        grey = grey_frame(first, f'{where}, frame {index}')
        self.where = where
        self.shape = grey.shape
        self.levels: FrameLevels = frame_levels(grey)
        self.names = sorted(naming.positions_px)
        self.pivot = None if naming.pivot_px is None else np.array(naming.pivot_px, float)
        self.hinge_ref = None if naming.hinge_px is None else np.array(naming.hinge_px, float)
        lv = self.levels
        self._last_area = self._last_contrast = 0.0
        self._expected_xy = [tuple(float(v) for v in naming.positions_px[n]) for n in self.names]
        self.markers: list[_Marker] = []
        for name in self.names:
            xy = np.array(naming.positions_px[name], float)
            radius = self._radius(grey, xy)
            level = self._dark_near(grey, xy, radius)
            m = _Marker(name, xy.copy(), tuple(xy.tolist()), (0.0, 0.0), radius, level,
                        area_px=12 * radius ** 2,
                        min_contrast=max(6 * lv.noise, 0.2 * (lv.background - lv.dark)),
                        last_seen=index)
            self.markers.append(m)
        self.body = [i for i, n in enumerate(self.names) if n.startswith('mb')]
        self.arm = [i for i, n in enumerate(self.names) if n.startswith('ma')]
        # The first frame's centres as this module measures them (NaN: not found there).
        first = []
        for m in self.markers:
            first.append(self._measure(grey, m, m.last, fast=False))
            if first[-1][0] == first[-1][0]:
                # its own blob's (measured just now), but no less than half its disc: the
                # brightest speck of a textured marker can be all its cut keeps
                m.area_px = max(self._last_area, 0.5 * math.pi * m.radius_px ** 2)
                m.contrast = self._last_contrast
        self.first_xy = np.array(first).reshape(-1, 2)
        for m, xy in zip(self.markers, self.first_xy, strict=True):
            if xy[0] == xy[0]:
                m.ref, m.last = xy.copy(), tuple(xy.tolist())
            else:
                m.missed = 1
        self._limits = self._rigid_limits()

    # ------------------------------------------------------------------ the first frame
    def _radius(self, grey, xy) -> float:
        found = measure_blob_radius(grey, xy)
        return found if found else 4.0

    def _dark_near(self, grey, xy, radius) -> float:
        r = int(math.ceil(2.5 * radius + 3))
        x, y = int(math.floor(xy[0] + 0.5)), int(math.floor(xy[1] + 0.5))
        win = grey[max(y - r, 0):y + r + 1, max(x - r, 0):x + r + 1]
        return float(np.percentile(win, 10)) + 3 * self.levels.noise

    # -------------------------------------------------------------------------- a frame
    def step(self, image, index: int) -> np.ndarray:
        grey = image if image.ndim == 2 else grey_frame(image, f'{self.where}, frame {index}')
        n = len(self.markers)
        out = np.full((n, 2), np.nan)
        self._expected_xy = [(m.last[0] + m.velocity[0] * (1 + m.missed) + m.speeding[0],
                              m.last[1] + m.velocity[1] * (1 + m.missed) + m.speeding[1])
                             for m in self.markers]
        # Every marker followed, measured together (one tile of windows: measure_many).
        todo = [i for i, m in enumerate(self.markers) if m.missed <= REACQUIRE_AFTER]
        windows = [self._window(self.markers[i], self._expected_xy[i], i) for i in todo]
        inside = [(i, w) for i, w in zip(todo, windows, strict=True) if w is not None]
        if inside:
            found = measure_many(grey, [w for _, w in inside], self.levels.background)
            for (i, w), got in zip(inside, found, strict=True):
                m = self.markers[i]
                if math.hypot(*m.velocity) > STREAK_SPEED_RADII * m.radius_px:
                    got = measure_streak(grey, w, m.radius_px, self.levels.noise)
                if got is not None:
                    out[i] = got[:2]
        self._arm_arcs(grey, out)
        if not self._check_rigid(out):
            self._arm_arcs(grey, out)       # the arm's markers missed or broken: on their arcs
            self._check_rigid(out)
            # Markers missed here: where their link, as found, carries them.
            for i in np.flatnonzero(~np.isfinite(out[:, 0])):
                guess = self._by_link(i, out)
                if guess is not None:
                    out[i] = self._measure(grey, self.markers[i], guess, fast=False, own=i)
            self._check_rigid(out, with_hinge=True)
            lost = [i for i in range(n) if not np.isfinite(out[i, 0])
                    and self.markers[i].missed >= REACQUIRE_AFTER
                    and index >= self.markers[i].next_search]
            if lost:
                self._reacquire(grey, lost, out, index)
        self._update(out, index)
        return out

    def _arm_arcs(self, grey, out: np.ndarray) -> None:
        """The arm's fast markers, and those missed here, measured on their arcs: an arm marker
        stays at its distance from the hinge, so over the exposure it sweeps an arc of its
        circle about the hinge (carried by the body, found as usual), and where it was is the
        mean angle of the light on that arc (markers.arc_angle), within the sweep its speed
        allows. Where the exposure smears it over tens of pixels the window about one
        predicted point (constant velocity or acceleration) loses it; its circle does not."""
        fast = [i for i in self.arm
                if self.markers[i].missed <= ARC_LOST_FRAMES
                and (math.hypot(*self.markers[i].velocity) > ARC_SPEED_RADII
                     * self.markers[i].radius_px
                     or (self.markers[i].missed == 0 and not np.isfinite(out[i, 0])))]
        if not fast or self.hinge_ref is None:
            return
        hinge = self._hinge_now(out)
        if hinge is None:
            return
        body = [tuple(out[i]) for i in self.body if np.isfinite(out[i, 0])]
        for i in fast:
            m = self.markers[i]
            r = float(np.hypot(*(m.ref - self.hinge_ref)))
            if r < 2 * m.radius_px:
                continue
            last = math.atan2(m.last[1] - hinge[1], m.last[0] - hinge[0])
            ex, ey = self._expected_xy[i]
            ahead = math.atan2(ey - hinge[1], ex - hinge[0])
            turn = math.remainder(ahead - last, math.tau)
            # The streak starts about halfway from its last place (the exposure is nearly the
            # frame interval) and, in the strike's acceleration, may reach twice as far on as
            # the prediction: the window runs from a fifth of the turn to two and a half.
            reach = (1.15 * abs(turn) + 2 * m.radius_px / r
                     + ARC_LOST_REACH_RAD * min(m.missed, ARC_LOST_FRAMES))
            # A streak spreads the marker's light over its length: its peak, at rest its
            # contrast, falls as the marker's width over the streak's; under a quarter of that is
            # not the marker (a link's edge, a speck).
            width = 2 * m.radius_px
            least = 0.25 * m.contrast * width / (width + abs(turn) * r)
            got = arc_angle(grey, hinge, r, last + 1.35 * turn, reach, m.radius_px,
                            self.levels.noise, body, least)
            out[i] = _NOWHERE if got is None else (hinge[0] + r * math.cos(got),
                                                    hinge[1] + r * math.sin(got))

    def _measure(self, grey, m: _Marker, at: np.ndarray, fast: bool = True,
                 own: int | None = None) -> np.ndarray:
        """Marker m's centre in a window about ``at`` (px), or NaN; ``fast``: the window as
        large as its speed asks; ``own``: m's index, so that its own expected place (stale
        when it was missed) is not taken for another marker's."""
        got = self._measure_at(grey, m, (float(at[0]), float(at[1])), own, fast)
        return _NOWHERE if got is None else np.array(got)

    def _measure_at(self, grey, m: _Marker, at: tuple, own: int | None,
                    fast: bool = True) -> tuple[float, float] | None:
        """As :meth:`_measure`, ``at`` a pair of floats."""
        window = self._window(m, at, own, fast)
        if window is None:
            return None
        got = measure_many(grey, [window], self.levels.background)[0]
        if got is None:
            return None
        self._last_area, self._last_contrast = got[3], got[2]
        return got[0], got[1]

    def _window(self, m: _Marker, at: tuple, own: int | None, fast: bool = True):
        """The window marker m is looked for in about ``at`` (a :class:`Window`), None if it
        lies off the picture. The other markers' expected places nearby are theirs (``own``:
        the index of m's own, when ``at`` is it)."""
        vx, vy = m.velocity
        speed = math.hypot(vx, vy) if fast else 0.0
        half = int(m.radius_px + WINDOW_MARGIN_PX + WINDOW_SPEED_SHARE * speed + 1.0)
        x, y = at
        if not (-half <= x < self.shape[1] + half and -half <= y < self.shape[0] + half):
            return None
        reach = 2 * half + 1
        others = [(px, py) for k, (px, py) in enumerate(self._expected_xy)
                  if k != own and abs(px - x) < reach and abs(py - y) < reach
                  and (px != x or py != y)]
        return Window(x, y, half, m.level, m.min_contrast,
                      MAX_AREA_GROWTH * m.area_px + 2.4 * (speed + 1) * m.radius_px, others)

    def _update(self, out: np.ndarray, index: int) -> None:
        for m, (x, y) in zip(self.markers, out.tolist(), strict=True):
            if x == x:
                frames = index - m.last_seen
                velocity = ((x - m.last[0]) / frames, (y - m.last[1]) / frames)
                # In the strike the markers speed up by tens of px a frame from frame to frame:
                # carried on at constant velocity they would be looked for far behind.
                fast = math.hypot(*velocity) > STREAK_SPEED_RADII * m.radius_px
                m.speeding = ((velocity[0] - m.velocity[0], velocity[1] - m.velocity[1])
                              if fast and frames == 1 else (0.0, 0.0))
                m.velocity = velocity
                m.last, m.last_seen, m.missed = (x, y), index, 0
            else:
                if m.missed == 0:
                    m.next_search = index + REACQUIRE_AFTER
                m.missed += 1

    # ------------------------------------------------------------------------ the links
    def _hinge_now(self, out: np.ndarray):
        """Where the arm's hinge is in this frame (carried by the body), or None."""
        if self.hinge_ref is None:
            return None
        return _carry(self._refs(self.body), out[self.body], self.hinge_ref,
                      self.pivot, self.pivot)

    def _refs(self, idx) -> np.ndarray:
        return np.array([self.markers[i].ref for i in idx]).reshape(-1, 2)

    def _by_link(self, i: int, out: np.ndarray):
        if i in self.body:
            return _carry(self._refs(self.body), out[self.body], self.markers[i].ref,
                          self.pivot, self.pivot)
        return _carry(self._refs(self.arm), out[self.arm], self.markers[i].ref,
                      self.hinge_ref, self._hinge_now(out))

    def _check_rigid(self, out: np.ndarray, with_hinge: bool = False) -> bool:
        """Turn into gaps the found positions that break their link's distances (to the
        link's other markers and its joint: the arm's hinge only ``with_hinge``, as it costs
        the body's pose); True if every marker is found and fits."""
        all_fine = True
        hinge = self._hinge_now(out) if with_hinge and self.hinge_ref is not None else None
        rows = out.tolist()
        for group, joint, limits in ((self.body, self.pivot, self._limits[0]),
                                     (self.arm, hinge, self._limits[1])):
            pts = [rows[i] for i in group]
            if limits[1] and joint is not None:
                pts.append(joint.tolist())
            table = limits[0]
            ok = [p[0] == p[0] for p in pts]
            all_fine &= all(ok)
            bad = [0] * len(pts)
            for a in range(len(pts)):
                if not ok[a]:
                    continue
                for b in range(a + 1, len(pts)):
                    if not ok[b]:
                        continue
                    d_ref, tolerance = table[a][b]
                    if abs(math.dist(pts[a], pts[b]) - d_ref) > tolerance:
                        bad[a] += 1
                        bad[b] += 1
            partners = sum(ok) - 1
            for k, i in enumerate(group):
                if not ok[k] or not bad[k]:
                    continue
                # Wrong if it disagrees with most of its link; of a pair, the one further
                # from where it was expected.
                if bad[k] * 2 > partners or (bad[k] * 2 == partners
                                             and self._least_expected(group, out) == i):
                    out[i] = np.nan
                    all_fine = False
        return all_fine

    def _rigid_limits(self) -> tuple:
        """Per link: the table of (reference distance, tolerance) between its markers and,
        last, its joint (the pivot; the arm's hinge), and whether the joint is known."""
        limits = []
        for group, joint_ref in ((self.body, self.pivot), (self.arm, self.hinge_ref)):
            refs = [self.markers[i].ref.tolist() for i in group]
            if joint_ref is not None:
                refs.append(joint_ref.tolist())
            table = [[(d, RIGID_TOLERANCE_PX + RIGID_TOLERANCE_SHARE * d)
                      for d in (math.dist(a, b) for b in refs)] for a in refs]
            limits.append((table, joint_ref is not None))
        return tuple(limits)

    def _least_expected(self, group, out) -> int:
        errs = {}
        for i in group:
            m, p = self.markers[i], out[i]
            if p[0] == p[0]:
                errs[i] = math.dist(p, (m.last[0] + m.velocity[0], m.last[1] + m.velocity[1]))
        return max(errs, key=errs.get)

    # ------------------------------------------------------------------- re-acquisition
    def _reacquire(self, grey, lost: list[int], out: np.ndarray, index: int) -> None:
        max_diameter = max(8.0, 6 * max(m.radius_px for m in self.markers))
        # Searched only where a lost marker could be picked (its link's reach): the same
        # blobs as in the whole frame there, at a fraction of its cost.
        box = self._search_box(lost, out, max_diameter)
        pts = np.zeros((0, 2))
        if box is not None:
            x0, y0, x1, y1 = box
            blobs = find_markers(grey[y0:y1, x0:x1], levels=self.levels,
                                 max_diameter_px=max_diameter)
            pts = np.array([(b.x_px + x0, b.y_px + y0) for b in blobs]).reshape(-1, 2)
        found = out[np.isfinite(out[:, 0])]
        if len(found) and len(pts):
            near = np.min(np.hypot(*(pts[:, None] - found[None]).transpose(2, 0, 1)), axis=1)
            pts = pts[near > 2 * max(m.radius_px for m in self.markers)]
        for i in lost:
            m = self.markers[i]
            m.next_search = index + min(REACQUIRE_MAX_INTERVAL,
                                        REACQUIRE_AFTER * 2 ** max(0, int(math.log2(
                                            max(1, m.missed // REACQUIRE_AFTER))) + 1))
            if not len(pts):
                continue
            best = self._pick(i, pts, out)
            if best is not None:
                out[i] = self._measure(grey, m, best, fast=False, own=i)
        self._check_rigid(out, with_hinge=True)

    def _search_box(self, lost: list[int], out: np.ndarray, margin: float):
        """(x0, y0, x1, y1) px of the part of the frame holding every place :meth:`_pick`
        could take a lost marker from (around where its link carries it, or the ring about
        its joint), widened by ``margin``; None where there is none (its link not found)."""
        spans = []
        for i in lost:
            m = self.markers[i]
            tol = RIGID_TOLERANCE_PX + m.radius_px
            guess = self._by_link(i, out)
            if guess is not None:
                centre = guess
                reach = tol + 0.05 * float(np.hypot(*(m.ref - guess)))
            else:
                joint_ref = self.pivot if i in self.body else self.hinge_ref
                centre = self.pivot if i in self.body else self._hinge_now(out)
                if joint_ref is None or centre is None:
                    continue
                r_ref = float(np.hypot(*(m.ref - joint_ref)))
                reach = r_ref + tol + RIGID_TOLERANCE_SHARE * r_ref
            reach += margin
            spans.append((centre[0] - reach, centre[1] - reach, centre[0] + reach,
                          centre[1] + reach))
        if not spans:
            return None
        rows, cols = self.shape
        x0 = max(int(math.floor(min(s[0] for s in spans))), 0)
        y0 = max(int(math.floor(min(s[1] for s in spans))), 0)
        x1 = min(int(math.ceil(max(s[2] for s in spans))) + 1, cols)
        y1 = min(int(math.ceil(max(s[3] for s in spans))) + 1, rows)
        return (x0, y0, x1, y1) if x1 - x0 >= 8 and y1 - y0 >= 8 else None

    def _pick(self, i: int, pts: np.ndarray, out: np.ndarray):
        """The blob that fits marker i's link: where the link carries it, or on its circle
        about the link's joint."""
        m = self.markers[i]
        tol = RIGID_TOLERANCE_PX + m.radius_px
        guess = self._by_link(i, out)
        if guess is not None:
            d = np.hypot(*(pts - guess).T)
            k = int(np.argmin(d))
            return pts[k] if d[k] <= tol + 0.05 * np.hypot(*(m.ref - guess)) else None
        joint_ref = self.pivot if i in self.body else self.hinge_ref
        joint = self.pivot if i in self.body else self._hinge_now(out)
        if joint_ref is None or joint is None:
            return None
        r_ref = float(np.hypot(*(m.ref - joint_ref)))
        d = np.abs(np.hypot(*(pts - joint).T) - r_ref)
        k = int(np.argmin(d))
        return pts[k] if d[k] <= tol + RIGID_TOLERANCE_SHARE * r_ref else None

    @property
    def last_seen(self) -> dict:
        """name -> the last frame index each marker was found in."""
        return {m.name: m.last_seen for m in self.markers}

    @property
    def missing_now(self) -> list[str]:
        return [m.name for m in self.markers if m.missed > 0]


def _carry(refs: np.ndarray, now: np.ndarray, point_ref, anchor_ref, anchor):
    """Where a rigid link puts ``point_ref`` now, from its markers found now (and its joint, if
    known): the least-squares rotation and shift of the reference onto them; None if fewer
    than two points fix it."""
    src = [tuple(r) for r, p in zip(refs, now, strict=True) if p[0] == p[0]]
    dst = [tuple(p) for p in now if p[0] == p[0]]
    if anchor_ref is not None and anchor is not None:
        src.append(tuple(anchor_ref))
        dst.append(tuple(anchor))
    k = len(src)
    if k < 2:
        return None
    sx, sy = sum(p[0] for p in src) / k, sum(p[1] for p in src) / k
    dx, dy = sum(p[0] for p in dst) / k, sum(p[1] for p in dst) / k
    cross = dot = 0.0
    for (ax, ay), (bx, by) in zip(src, dst, strict=True):
        ax, ay, bx, by = ax - sx, ay - sy, bx - dx, by - dy
        cross += ax * by - ay * bx
        dot += ax * bx + ay * by
    angle = math.atan2(cross, dot)
    c, s = math.cos(angle), math.sin(angle)
    px, py = float(point_ref[0]) - sx, float(point_ref[1]) - sy
    return np.array([dx + c * px - s * py, dy + s * px + c * py])


def measure_blob_radius(grey: np.ndarray, xy: np.ndarray) -> float | None:
    """The radius (px) of the bright blob at xy: half-peak extent, holes filled."""
    import cv2
    x, y = int(math.floor(xy[0] + 0.5)), int(math.floor(xy[1] + 0.5))
    r = 24
    win = grey[max(y - r, 0):y + r + 1, max(x - r, 0):x + r + 1].astype(np.float32)
    if win.size == 0:
        return None
    cy, cx = y - max(y - r, 0), x - max(x - r, 0)
    inner = win[max(cy - 3, 0):cy + 4, max(cx - 3, 0):cx + 4]
    peak, low = float(inner.max()), float(np.percentile(win, 10))
    mask = (win > low + 0.5 * (peak - low)).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    d = np.hypot(cents[1:, 0] - cx, cents[1:, 1] - cy)
    k = int(np.argmin(d)) + 1
    w, h = stats[k, cv2.CC_STAT_WIDTH], stats[k, cv2.CC_STAT_HEIGHT]
    return float(max(1.5, 0.5 * max(w, h)))
