"""Name the markers found in a frame from the robot's linkage, as the lab's exports name them.

The linkage (docs/physics.md): the body turns about the ground pivot a (by the mount), the arm
about the hinge b at the body's far end. The lab numbers the markers of each link outwards from
that link's own joint: ``mb1, mb2, mb3`` by distance from the pivot a, ``ma1, ma2`` by distance
from the hinge b. That rule holds on every export seen (the pivot fitted by the authors, the
hinge fitted to the arm's turn about the body: mb 9.9 / 20.0 / 22.2 mm from a, ma 7.7 / 17.7 mm
from b) and on the simulated robot (``mantis_sim.world``), so a layout only says where the
markers sit on each link; the names follow from the rule (:func:`linkage_names`).

Naming a frame = finding the linkage in it: every ordered choice of three blobs for the body
(mirror allowed: a screenshot may be flipped) is fitted by a similarity to the body's markers;
a fit that holds places a and b in the picture, and the arm's markers are then the blobs at
their distances from b, turned about b together by one angle (the arm need not rest on its
latch). The best fit that explains the most markers wins; blobs that fit nowhere (a glinting
screw, a speck) are left out. A person may name the markers instead (:func:`names_from_points`,
the ``--name mb1=x,y`` form).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import itertools
import math

import numpy as np

from mantis_sim.errors import InputError

__all__ = ['LinkageLayout', 'Naming', 'NamingError', 'REAL_ROBOT', 'layouts', 'linkage_names',
           'name_markers', 'names_from_points', 'parse_name_args', 'simulated_robot']

# A fit holds if the markers sit within this share of the layout's size (RMS distance of its
# markers from their centroid) of where the linkage puts them. The lab's own placements scatter
# by ~2.5 %; one marker taken for another misses by 20 % or more.
MAX_RESIDUAL = 0.085
# The body's three markers are rigid: on the lab's frames they fit the layout within 1.2 %
# (and the found centres add a pixel or so), so a body fit must hold this closely.
MAX_BODY_RESIDUAL = 0.04
# Body fits kept for the arm's search, best first.
KEPT_BODY_FITS = 40
# The arm may have turned this far from its latched pose about b (either way) in the frame
# that is named.
MAX_ARM_TURN_DEG = 60.0
# A marker candidate's size is plausible for the robot's markers (0.5 to 4 mm across): a fit
# that would need a smaller or larger robot is a coincidence of specks.
MARKER_DIAMETER_MM = (0.4, 4.5)


class NamingError(InputError):
    """The markers of a frame cannot be named (the linkage is not found, or a given name is
    malformed), naming the frame."""


@dataclass(frozen=True)
class LinkageLayout:
    """Where the markers sit on the robot's links, in the linkage frame (mm): the pivot a at
    (0, 0), the hinge b at (l1_mm, 0), image handedness (y down), the arm on its latch."""

    name: str
    body_mm: dict            # marker name -> (x, y) mm
    arm_mm: dict             # marker name -> (x, y) mm, arm latched
    l1_mm: float

    @property
    def pivot_mm(self) -> np.ndarray:
        return np.zeros(2)

    @property
    def hinge_mm(self) -> np.ndarray:
        return np.array([self.l1_mm, 0.0])

    @property
    def size_mm(self) -> float:
        pts = np.array([*self.body_mm.values(), *self.arm_mm.values()], float)
        return float(np.sqrt(np.mean(np.sum((pts - pts.mean(axis=0)) ** 2, axis=1))))


def linkage_names(body_mm, arm_mm, l1_mm: float) -> tuple[dict, dict]:
    """The lab's rule: body markers ``mb1..`` outwards from the pivot a (0, 0), arm markers
    ``ma1..`` outwards from the hinge b (l1_mm, 0)."""
    body = sorted((np.asarray(p, float) for p in body_mm), key=lambda p: float(np.hypot(*p)))
    hinge = np.array([l1_mm, 0.0])
    arm = sorted((np.asarray(p, float) for p in arm_mm),
                 key=lambda p: float(np.hypot(*(p - hinge))))
    return ({f'mb{i + 1}': tuple(p) for i, p in enumerate(body)},
            {f'ma{i + 1}': tuple(p) for i, p in enumerate(arm)})


def _layout(name: str, body, arm, l1_mm: float) -> LinkageLayout:
    b, a = linkage_names(body, arm, l1_mm)
    return LinkageLayout(name, b, a, l1_mm)


# The real robot, from the lab's exports: the body's three markers are rigid to 0.1 mm across
# the 20 first frames of real_frames (air and water, five recording days), averaged; the pivot
# is the authors' fitted body pivot of 031320_19kfps_..._1 and the hinge the centre the arm's
# markers turn about relative to the body in that trial's tracks. The arm's markers scatter
# more between days (ma2 by up to 1.5 mm): the fit's tolerance and the arm's free turn take it.
REAL_ROBOT = _layout('real robot',
                     body=[(9.851, 1.363), (19.957, 1.293), (17.675, 13.429)],
                     arm=[(14.975, -4.629), (3.636, -3.283)], l1_mm=21.07)


def simulated_robot(contact_angle_deg: float = 3.0, l1_mm: float = 19.0) -> LinkageLayout:
    """The simulated robot's layout, from where ``mantis_sim.world`` puts its markers (the body
    turned to lie along the image's x: the pivot at the world's camera origin)."""
    from mantis_sim.world import ARM_MARKERS_MM, BODY_MARKERS_MM, CAMERA_ORIGIN_MM, World
    pos = World._markers_mm(np.zeros(1), np.radians([contact_angle_deg]), np.array([l1_mm]))
    pivot = np.asarray(CAMERA_ORIGIN_MM, float)
    return _layout('simulated robot', [pos[n][0] - pivot for n in BODY_MARKERS_MM],
                   [pos[n][0] - pivot for n in ARM_MARKERS_MM], l1_mm)


def layouts() -> tuple[LinkageLayout, ...]:
    """The layouts a frame is named against unless told: the real robot, the simulated one."""
    return (REAL_ROBOT, simulated_robot())


@dataclass
class Naming:
    """The named markers of one frame (px) and the linkage found there."""

    positions_px: dict                       # name -> (x, y)
    layout: str = 'named by hand'
    residual: float = float('nan')           # RMS misfit / the layout's size
    scale_px_per_mm: float = float('nan')
    mirrored: bool = False
    arm_turn_deg: float = float('nan')
    pivot_px: tuple | None = None
    hinge_px: tuple | None = None
    candidate_index: dict = field(default_factory=dict)   # name -> index of the blob used

    @property
    def body(self) -> list[str]:
        return sorted(n for n in self.positions_px if n.startswith('mb'))

    @property
    def arm(self) -> list[str]:
        return sorted(n for n in self.positions_px if n.startswith('ma'))


def name_markers(points_px, diameters_px=None, candidates_layouts=None,
                 where: str = 'frame') -> Naming:
    """Name the blobs at ``points_px`` ((n, 2) px) by the linkage; raise NamingError if no
    layout fits three body markers and at least one arm marker."""
    pts = np.asarray(points_px, float).reshape(-1, 2)
    if len(pts) < 4:
        raise NamingError(f'{where}: {len(pts)} marker candidates found; the linkage needs at '
                          f'least four (three on the body, one on the arm)')
    diam = None if diameters_px is None else np.asarray(diameters_px, float)
    best = None
    for layout in candidates_layouts or layouts():
        fit = _best_fit(pts, diam, layout)
        if fit is not None and (best is None or _better(fit, best)):
            best = fit
    if best is None:
        raise NamingError(f'{where}: the robot\'s linkage is not found among {len(pts)} marker '
                          f'candidates (no three fit the body and one the arm within '
                          f'{MAX_RESIDUAL:.0%}); name the markers by hand (--name mb1=x,y ...)')
    return best


def _better(a: Naming, b: Naming) -> bool:
    return (len(a.positions_px), -a.residual) > (len(b.positions_px), -b.residual)


def _similarities(src: np.ndarray, dst: np.ndarray):
    """Least-squares similarity src (k, 2) -> dst (m, k, 2) as complex c, t with z = c w + t,
    and the RMS residual of each."""
    w = src[:, 0] + 1j * src[:, 1]
    z = dst[..., 0] + 1j * dst[..., 1]
    wc = w - w.mean()
    zc = z - z.mean(axis=-1, keepdims=True)
    c = (zc @ np.conj(wc)) / np.sum(np.abs(wc) ** 2)
    t = z.mean(axis=-1) - c * w.mean()
    res = np.sqrt(np.mean(np.abs(zc - c[:, None] * wc[None, :]) ** 2, axis=-1))
    return c, t, res


def _best_fit(pts: np.ndarray, diam, layout: LinkageLayout) -> Naming | None:
    body_names = list(layout.body_mm)
    body = np.array([layout.body_mm[n] for n in body_names])
    size = layout.size_mm
    triples = np.array(list(itertools.permutations(range(len(pts)), 3)))
    fits = []
    for mirror in (False, True):
        src = body * np.array([1.0, -1.0]) if mirror else body
        c, t, res = _similarities(src, pts[triples])
        rel = res / np.maximum(np.abs(c), 1e-12) / size
        ok = np.flatnonzero(rel < MAX_BODY_RESIDUAL)
        fits += [(rel[i], mirror, c[i], t[i], triples[i]) for i in ok]
    fits.sort(key=lambda f: f[0])
    best = None
    for rel_body, mirror, c, t, triple in fits[:KEPT_BODY_FITS]:
        scale = abs(c)
        if diam is not None and not _plausible_size(diam[list(triple)] / scale):
            continue
        # The candidates in the layout's frame (mm).
        z = (pts[:, 0] + 1j * pts[:, 1] - t) / c
        w = np.conj(z) if mirror else z
        found = _arm(w, set(triple.tolist()), layout, diam, scale)
        arm_idx, arm_sq, turn = found
        n_body = len(body_names)
        total_sq = rel_body ** 2 * size ** 2 * n_body + arm_sq
        rel = math.sqrt(total_sq / (n_body + len(arm_idx))) / size
        if not arm_idx or rel >= MAX_RESIDUAL:
            continue
        names = dict(zip(body_names, triple.tolist(), strict=True)) | arm_idx
        naming = Naming(
            positions_px={n: tuple(pts[i]) for n, i in sorted(names.items())},
            layout=layout.name, residual=rel, scale_px_per_mm=scale, mirrored=mirror,
            arm_turn_deg=math.degrees(turn),
            pivot_px=_to_px(layout.pivot_mm, c, t, mirror),
            hinge_px=_to_px(layout.hinge_mm, c, t, mirror),
            candidate_index=dict(sorted(names.items())))
        if best is None or _better(naming, best):
            best = naming
    return best


def _to_px(p_mm, c, t, mirror: bool) -> tuple:
    w = complex(p_mm[0], -p_mm[1] if mirror else p_mm[1])
    z = c * w + t
    return (z.real, z.imag)


def _plausible_size(diam_mm: np.ndarray) -> bool:
    lo, hi = MARKER_DIAMETER_MM
    return bool(np.all((diam_mm >= lo) & (diam_mm <= hi)))


def _arm(w: np.ndarray, used: set, layout: LinkageLayout, diam, scale: float):
    """The arm's markers among the candidates w (complex, layout frame, mm): the assignment
    with the most markers, then the least squared misfit, for one common turn about b.
    Returns ({name: index}, squared misfit sum (mm^2), turn (rad))."""
    hinge = complex(*layout.hinge_mm)
    names = list(layout.arm_mm)
    q = np.array([complex(*layout.arm_mm[n]) - hinge for n in names])
    free = [i for i in range(len(w)) if i not in used
            and (diam is None or _plausible_size(diam[i:i + 1] / scale))]
    u = w - hinge
    max_turn = math.radians(MAX_ARM_TURN_DEG)
    tol_sq = (MAX_RESIDUAL * layout.size_mm) ** 2
    best = ({}, 0.0, 0.0)
    for k in range(len(names), 0, -1):
        for chosen in itertools.combinations(range(len(names)), k):
            for idx in itertools.permutations(free, k):
                uu, qq = u[list(idx)], q[list(chosen)]
                # The common turn: the least-squares rotation of qq onto uu about b.
                turn = float(np.angle(np.sum(uu * np.conj(qq))))
                if abs(turn) > max_turn:
                    continue
                sq = float(np.sum(np.abs(uu - qq * np.exp(1j * turn)) ** 2))
                if sq / k > 2.0 * tol_sq:
                    continue
                if not best[0] or sq < best[1]:
                    best = ({names[c]: i for c, i in zip(chosen, idx, strict=True)}, sq, turn)
        if best[0]:
            return best
    return best


def names_from_points(given_px: dict, points_px=None, snap_px: float = 6.0,
                      where: str = 'frame') -> Naming:
    """A person's naming (name -> (x, y) px on the first frame). Each point snaps to the nearest
    found blob within ``snap_px`` if blobs are given; otherwise it is taken as given."""
    pts = None if points_px is None else np.asarray(points_px, float).reshape(-1, 2)
    out, index = {}, {}
    for name, xy in given_px.items():
        _check_name(name, where)
        p = np.asarray(xy, float)
        if pts is not None and len(pts):
            d = np.hypot(*(pts - p).T)
            i = int(np.argmin(d))
            if d[i] <= snap_px:
                p = pts[i]
                index[name] = i
        out[name] = (float(p[0]), float(p[1]))
    return Naming(positions_px=dict(sorted(out.items())), candidate_index=index)


def _check_name(name: str, where: str) -> None:
    if not (name[:2] in ('mb', 'ma') and name[2:].isdigit()):
        raise NamingError(f'{where}: marker name {name!r}: expected mb<n> (body) or ma<n> (arm)')


def parse_name_args(items, where: str = '--name') -> dict:
    """``['mb1=120.5,340', 'ma1=88,120']`` (or one string with spaces) -> {name: (x, y)}."""
    if isinstance(items, str):
        items = items.split()
    out = {}
    for item in items:
        name, sep, xy = item.partition('=')
        parts = xy.split(',')
        try:
            if not sep or len(parts) != 2:
                raise ValueError
            x, y = float(parts[0]), float(parts[1])
        except ValueError:
            raise NamingError(f'{where}: {item!r}: expected NAME=X,Y (pixels), e.g. '
                              f'mb1=120.5,340') from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise NamingError(f'{where}: {item!r}: the position is not finite')
        _check_name(name.strip(), where)
        out[name.strip()] = (x, y)
    return out
