"""Planar rigid-body geometry: common-centre circle fits and rotation angles about a centre."""
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
