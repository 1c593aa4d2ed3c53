"""Planar rigid-body geometry: rigid poses (2-D Kabsch), fixed points of a motion, circle fits."""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares


def fit_common_centre(point_sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre shared by several arcs, one arc per marker, each with its own radius.

    Algebraic (Kasa) fit first: |p|² = 2 c·p + k_i is linear in (c, k_1..k_m). It is biased
    towards small radii on short arcs, so it only seeds a geometric least-squares fit of the
    orthogonal distances | |p − c| − r_i |.

    Returns (centre (2,), radii (m,), rms residual in the input unit).
    """
    sets = [np.asarray(p, float)[np.all(np.isfinite(p), axis=1)] for p in point_sets]
    m = len(sets)
    n_rows = sum(len(p) for p in sets)
    if n_rows < 3 * m:
        raise ValueError('too few points for a circle fit')
    # Centre the coordinates: keeps the algebraic system well conditioned.
    origin = np.mean(np.concatenate(sets), axis=0)
    a_mat = np.zeros((n_rows, 2 + m))
    rhs = np.empty(n_rows)
    row = 0
    for i, p in enumerate(sets):
        q = p - origin
        a_mat[row:row + len(q), :2] = 2.0 * q
        a_mat[row:row + len(q), 2 + i] = 1.0
        rhs[row:row + len(q)] = np.einsum('ij,ij->i', q, q)
        row += len(q)
    sol, *_ = np.linalg.lstsq(a_mat, rhs, rcond=None)
    centre0 = sol[:2]
    radii0 = [np.linalg.norm(p - origin - centre0, axis=1).mean() for p in sets]
    shifted = [p - origin for p in sets]

    def residuals(x):
        return np.concatenate([np.linalg.norm(q - x[:2], axis=1) - x[2 + i]
                               for i, q in enumerate(shifted)])

    def jacobian(x):
        blocks = []
        for i, q in enumerate(shifted):
            d = q - x[:2]
            r = np.linalg.norm(d, axis=1)[:, None]
            j = np.zeros((len(q), 2 + m))
            j[:, :2] = -d / np.maximum(r, 1e-12)
            j[:, 2 + i] = -1.0
            blocks.append(j)
        return np.concatenate(blocks)

    fit = least_squares(residuals, np.r_[centre0, radii0], jac=jacobian, method='lm')
    rms = float(np.sqrt(np.mean(fit.fun ** 2)))
    return fit.x[:2] + origin, fit.x[2:], rms


def rotation_about(centre: np.ndarray, ref_points: np.ndarray,
                   points: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, counter-clockwise) of a marker set about a fixed centre.

    ref_points: (m, 2) marker positions at the reference pose; points: (n, m, 2) over time.
    The least-squares rotation of m vectors about a known centre is atan2(Σ u×v, Σ u·v); the
    sum weights each marker by its radius, as it should. Result is unwrapped.
    """
    u = ref_points - centre
    v = points - centre
    cross = np.sum(u[None, :, 0] * v[..., 1] - u[None, :, 1] * v[..., 0], axis=1)
    dot = np.sum(u[None, :, 0] * v[..., 0] + u[None, :, 1] * v[..., 1], axis=1)
    return np.unwrap(np.arctan2(cross, dot))


def rotate(points: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rotate (n, ..., 2) points counter-clockwise by a per-frame angle (n,)."""
    c = np.cos(angle_rad).reshape((-1,) + (1,) * (points.ndim - 2))
    s = np.sin(angle_rad).reshape(c.shape)
    x, y = points[..., 0], points[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


def signed_angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Counter-clockwise angle from vector u to vector v (rad, in (−π, π])."""
    return np.arctan2(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0],
                      u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1])


def kabsch_angles(points: np.ndarray, template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid pose of a marker set in each frame (2-D Kabsch/Procrustes).

    points: (n, m, 2); template: (m, 2), centred on its centroid. Returns the rotation angle
    θ_k (rad, counter-clockwise, unwrapped) and the centroid c_k (n, 2) such that
    points[k] ≈ c_k + R(θ_k) template. The angle does not depend on any pivot estimate.
    """
    centroid = points.mean(axis=1)
    d = points - centroid[:, None, :]
    cross = np.sum(template[None, :, 0] * d[..., 1] - template[None, :, 1] * d[..., 0], axis=1)
    dot = np.sum(template[None, :, 0] * d[..., 0] + template[None, :, 1] * d[..., 1], axis=1)
    return np.unwrap(np.arctan2(cross, dot)), centroid


def rigid_poses(points: np.ndarray, iterations: int = 2,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean shape of a rigid marker set and its pose in every frame.

    The template starts as the first frame and is refined by generalised Procrustes
    analysis (align every frame to the template, average), so no single frame's noise sets
    the body frame. Returns (template (m, 2) centred, angles (n,), centroids (n, 2)).
    """
    points = np.asarray(points, float)
    template = points[0] - points[0].mean(axis=0)
    for _ in range(iterations):
        angle, centroid = kabsch_angles(points, template)
        aligned = rotate(points - centroid[:, None, :], -angle)
        template = aligned.mean(axis=0)
        template = template - template.mean(axis=0)
    angle, centroid = kabsch_angles(points, template)
    return template, angle, centroid


def fixed_point_of_motion(angle_rad: np.ndarray, centroid: np.ndarray,
                          ) -> tuple[np.ndarray, np.ndarray, float]:
    """The point that stays fixed while a rigid body moves with poses (θ_k, c_k).

    A point q of the body (template coordinates) is at c_k + R_k q in frame k. Minimising
    Σ_k |c_k + R_k q − p|² over the fixed position p and q is linear; eliminating q gives
    (1 − |mean e^{iθ}|²) p = mean c − R̄ mean(R_kᵀ c_k), R̄ = mean R_k.

    The Kabsch angles are noisy regressors, so this is slightly biased and less precise than
    the maximum-likelihood :func:`fit_fixed_pivot`, which it starts.

    Returns (p (2,) in the points' frame, q (2,) in template coordinates, rms distance of the
    per-frame point c_k + R_k q from p, i.e. how far the 'fixed' point wanders).
    """
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    c_mean, s_mean = float(c.mean()), float(s.mean())
    spread = 1.0 - c_mean ** 2 - s_mean ** 2
    # spread ≈ var θ for small rotations; zero means one pose only: no fixed point exists.
    if spread < 1e-10:
        raise ValueError('the body does not rotate: its pivot is not observable')
    origin = centroid.mean(axis=0)
    cc = centroid - origin
    rtc = np.array([np.mean(c * cc[:, 0] + s * cc[:, 1]), np.mean(-s * cc[:, 0] + c * cc[:, 1])])
    r_mean = np.array([[c_mean, -s_mean], [s_mean, c_mean]])
    p = -(r_mean @ rtc) / spread
    q = r_mean.T @ p - rtc
    wander = np.column_stack([c * q[0] - s * q[1], s * q[0] + c * q[1]]) + cc - p
    rms = float(np.sqrt(np.mean(np.sum(wander ** 2, axis=1))))
    return p + origin, q, rms


def template_point(point: np.ndarray, angle_rad: np.ndarray, centroid: np.ndarray,
                   ) -> np.ndarray:
    """Body-fixed point (template coordinates) that best stays at ``point`` under the poses.

    With poses (θ_k, c_k) from :func:`kabsch_angles`, the body point q is at c_k + R_k q; the
    least-squares q for a fixed position p is mean_k R_kᵀ (p − c_k).
    """
    return rotate(np.asarray(point, float) - centroid, -angle_rad).mean(axis=0)


def fit_fixed_pivot(points: np.ndarray, pivot0: np.ndarray, offsets0: np.ndarray,
                    max_iterations: int = 20, tol_mm: float = 1e-6,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Maximum-likelihood pivot of a rigid marker set that only rotates about a fixed point.

    Model: points[k, i] = p + R(θ_k) s_i + noise (iid). Unknowns: the pivot p, the markers'
    offsets s_i from it (body frame) and one angle per frame. For given (p, s) each θ_k has a
    closed form (:func:`rotation_about`), so the per-frame angles are eliminated (variable
    projection) and Gauss–Newton runs on the 2 + 2m global unknowns, with the reduced normal
    matrix Σ_k J_xᵀ(I − P_θ)J_x. Start from :func:`fixed_point_of_motion` (close already).

    Using all markers' phases together (rigidity) is what a per-marker or common-centre circle
    fit leaves out. Returns (p, s (m, 2), θ (n,), rms marker residual).
    """
    points = np.asarray(points, float)
    n, m, _ = points.shape
    origin = points.reshape(-1, 2).mean(axis=0)
    pts = points - origin
    p = np.asarray(pivot0, float) - origin
    s_off = np.asarray(offsets0, float).copy()
    angle = rotation_about(p, p + s_off, pts)
    jmat = np.array([[0.0, -1.0], [1.0, 0.0]])
    for _ in range(max_iterations):
        # Per frame k and marker i: ∂r/∂p = I, ∂r_i/∂s_i = R_k, ∂r_i/∂θ_k = J R_k s_i. Sums:
        # J_xᵀJ_x = [[n m I, R_Σ …], [R_Σᵀ, n I]] with R_Σ = Σ_k R_k; J_xᵀj_θ = [J R_k σ; J s_i]
        # (σ = Σ_i s_i, since R_kᵀ J R_k = J); j_θᵀj_θ = Σ_i |s_i|².
        c, sn = np.cos(angle), np.sin(angle)
        rs = rotate(np.broadcast_to(s_off, pts.shape), angle)
        resid = p + rs - pts
        r_sum = np.array([[c.sum(), -sn.sum()], [sn.sum(), c.sum()]])
        h = np.zeros((2 + 2 * m, 2 + 2 * m))
        h[:2, :2] = n * m * np.eye(2)
        for k in range(m):
            blk = slice(2 + 2 * k, 4 + 2 * k)
            h[:2, blk] = r_sum
            h[blk, :2] = r_sum.T
            h[blk, blk] = n * np.eye(2)
        sigma = s_off.sum(axis=0)
        u = rotate(np.broadcast_to(sigma, (n, 2)), angle) @ jmat.T          # J R_k σ
        js = s_off @ jmat.T                                                  # J s_i
        cross_ps = (r_sum @ sigma) @ jmat.T                                  # Σ_k J R_k σ
        v_sum = np.concatenate([u.T @ u, np.outer(cross_ps, js.ravel())], axis=1)
        corr = np.zeros_like(h)
        corr[:2, :] = v_sum
        corr[2:, :2] = v_sum[:, 2:].T
        corr[2:, 2:] = n * np.outer(js.ravel(), js.ravel())
        h -= corr / np.sum(s_off ** 2)
        g = np.concatenate([resid.sum(axis=(0, 1)),
                            rotate(resid, -angle).sum(axis=0).ravel()])
        # The common rotation of all s_i (absorbed by the θ_k) is a null direction: lstsq.
        step, *_ = np.linalg.lstsq(h, -g, rcond=1e-12)
        p = p + step[:2]
        s_off = s_off + step[2:].reshape(m, 2)
        angle = rotation_about(p, p + s_off, pts)
        if np.max(np.abs(step[:2])) < tol_mm:
            break
    rs = rotate(np.broadcast_to(s_off, pts.shape), angle)
    rms = float(np.sqrt(np.mean(np.sum((p + rs - pts) ** 2, axis=-1))))
    return p + origin, s_off, angle, rms


def rotation_model_rms(points: np.ndarray, pivot: np.ndarray, iterations: int = 10) -> float:
    """RMS marker residual (input unit) of 'rigid rotation about this given pivot'.

    For comparing a candidate pivot (e.g. one measured on the rig, or published) with the
    fitted one: the markers' offsets and the per-frame angles are optimised, the pivot is not.
    """
    points = np.asarray(points, float)
    pivot = np.asarray(pivot, float)
    _, angle, _ = rigid_poses(points, iterations=1)
    offsets = rotate(points - pivot, -angle).mean(axis=0)
    for _ in range(iterations):
        angle = rotation_about(pivot, pivot + offsets, points)
        offsets = rotate(points - pivot, -angle).mean(axis=0)
    angle = rotation_about(pivot, pivot + offsets, points)
    predicted = pivot + rotate(np.broadcast_to(offsets, points.shape), angle)
    return float(np.sqrt(np.mean(np.sum((points - predicted) ** 2, axis=-1))))


# A marker set's shape is taken from frames where all its markers are tracked; fewer than this
# and the marker seen least is left out instead.
MIN_SHAPE_FRAMES = 20


def complete_rigid_markers(points: np.ndarray, min_markers: int = 2,
                           ) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Fill a rigid marker set's lost markers (NaN) from the markers still tracked.

    The set's shape is the mean shape (:func:`rigid_poses`) over the frames where every marker
    is tracked. In a frame where at least ``min_markers`` are tracked, the set's pose is the
    least-squares fit of that shape to them (2-D Kabsch on the tracked subset), and a lost
    marker is where that pose puts it: the body's own motion, not an interpolation in time.
    A frame with fewer tracked markers is a gap: it stays NaN.

    If too few frames show every marker (:data:`MIN_SHAPE_FRAMES`), the marker lost most often
    is dropped and the rest are tried again.

    Returns (points (n, m', 2), ok (n,) bool: frame has a pose, indices of the markers kept).
    """
    points = np.asarray(points, float)
    kept = list(range(points.shape[1]))
    while True:
        sub = points[:, kept]
        seen = np.all(np.isfinite(sub), axis=2)
        full = np.all(seen, axis=1)
        if full.sum() >= MIN_SHAPE_FRAMES or len(kept) <= min_markers:
            break
        kept.pop(int(np.argmin(seen.sum(axis=0))))
    if full.sum() < 3 or len(kept) < min_markers:     # no shape to place the markers with
        return sub, np.zeros(len(sub), bool), kept
    out = sub.copy()
    if full.all():
        return out, full, kept
    template, _, _ = rigid_poses(sub[full], iterations=2)
    ok = seen.sum(axis=1) >= min_markers
    # Frames that lack a marker, grouped by which markers they still have.
    patterns = {}
    for k in np.nonzero(ok & ~full)[0]:
        patterns.setdefault(tuple(seen[k]), []).append(k)
    for pattern, frames in patterns.items():
        have = np.array(pattern)
        frames = np.array(frames)
        tpl = template[have]
        centre = tpl.mean(axis=0)
        angle, centroid = kabsch_angles(sub[frames][:, have], tpl - centre)
        placed = centroid[:, None, :] + rotate(np.broadcast_to(template - centre,
                                                              (len(frames),) + template.shape),
                                               angle)
        for j in np.nonzero(~have)[0]:
            out[frames, j] = placed[:, j]
    out[~ok] = np.nan
    return out, ok, kept
