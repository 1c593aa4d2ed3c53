"""Radau IIA of order 5, compiled, with event location: one segment of a hybrid run.

The algorithm is scipy.integrate.Radau's (Hairer and Wanner, Solving ODEs II, sec. IV.8:
simplified Newton on the collocation system in its real/complex eigenbasis, the third-order
embedded error estimate, the predictive step-size controller, finite-difference Jacobians
refreshed as scipy refreshes them) and its event handling is solve_ivp's (sign changes at the
steps, Brent's method on the dense output to 4 eps). So at the same tolerances it takes the
same steps as scipy's Radau, and `mantis bench accuracy` holds it against that reference; it
runs without a Python call per step, which is where scipy's Radau spends its time on a
two-to-six-state system.
"""
from __future__ import annotations

import math

from numba import njit
import numpy as np

from . import equations as eq

S6 = 6 ** 0.5
C = np.array([(4 - S6) / 10, (4 + S6) / 10, 1.0])
E = np.array([-13 - 7 * S6, -13 + 7 * S6, -1.0]) / 3
MU_REAL = 3 + 3 ** (2 / 3) - 3 ** (1 / 3)
MU_COMPLEX = (3 + 0.5 * (3 ** (1 / 3) - 3 ** (2 / 3))) - 0.5j * (3 ** (5 / 6) + 3 ** (7 / 6))
T = np.array([
    [0.09443876248897524, -0.14125529502095421, 0.03002919410514742],
    [0.25021312296533332, 0.20412935229379994, -0.38294211275726192],
    [1.0, 1.0, 0.0]])
TI = np.array([
    [4.17871859155190428, 0.32768282076106237, 0.52337644549944951],
    [-4.17871859155190428, -0.32768282076106237, 0.47662355450055044],
    [0.50287263494578682, -2.57192694985560522, 0.59603920482822492]])
P = np.array([
    [13 / 3 + 7 * S6 / 3, -23 / 3 - 22 * S6 / 3, 10 / 3 + 5 * S6],
    [13 / 3 - 7 * S6 / 3, -23 / 3 + 22 * S6 / 3, 10 / 3 - 5 * S6],
    [1 / 3, -8 / 3, 10 / 3]])
NEWTON_MAXITER = 6
MIN_FACTOR, MAX_FACTOR = 0.2, 10.0
EPS = float(np.finfo(float).eps)
JAC_DIFF_REJECT, JAC_DIFF_SMALL, JAC_DIFF_BIG = EPS ** 0.875, EPS ** 0.75, EPS ** 0.25
JAC_MIN_FACTOR, JAC_MAX_FACTOR = 1e3 * EPS, 1.0

# integrate()'s status
FINISHED, EVENT, STEP_TOO_SMALL, OVER_BUDGET = 0, 1, -1, -2
# mode vector (hybrid.Mode): latched, taut, saturated, stuck_at (NaN: at the contact), slip
MODE_SIZE = 5


@njit(cache=True)
def _rhs(t, y, n, mode, p, knots, ws, d, f):
    eq.mode_dynamics(t, y, mode, p, knots, ws, d)
    eq.rhs_from(d, n, f)


@njit(cache=True)
def _events(t, y, n, mode, p, knots, ws, d, scratch, kinds, consts, g):
    """Every event function at (t, y) into g."""
    eq.mode_dynamics(t, y, mode, p, knots, ws, d)
    _event_values(t, y, mode, p, knots, d, scratch, kinds, consts, g)


@njit(cache=True)
def _event_values(t, y, mode, p, knots, d, scratch, kinds, consts, g):
    """Every event function at (t, y) into g, d the dynamics there."""
    for k in range(kinds.size):
        g[k] = eq.event_value(kinds[k], consts[k], t, y, d, mode[0] != 0.0, mode[3], p, knots,
                              scratch)


@njit(cache=True)
def _rms(x, scale):
    total = 0.0
    for i in range(x.size):
        v = x.flat[i] / scale[i % scale.size]
        total += v * v
    return math.sqrt(total / x.size)


@njit(cache=True)
def _lu_factor(a):
    """In-place LU with partial pivoting (real or complex); returns the pivots."""
    n = a.shape[0]
    piv = np.empty(n, np.int64)
    for k in range(n):
        pk, big = k, abs(a[k, k])
        for i in range(k + 1, n):
            if abs(a[i, k]) > big:
                pk, big = i, abs(a[i, k])
        piv[k] = pk
        if pk != k:
            for j in range(n):
                a[k, j], a[pk, j] = a[pk, j], a[k, j]
        if a[k, k] == 0:
            continue
        for i in range(k + 1, n):
            a[i, k] /= a[k, k]
            for j in range(k + 1, n):
                a[i, j] -= a[i, k] * a[k, j]
    return piv


@njit(cache=True)
def _lu_solve(lu, piv, b):
    n = lu.shape[0]
    x = b.copy()
    for k in range(n):
        if piv[k] != k:
            x[k], x[piv[k]] = x[piv[k]], x[k]
    for i in range(n):
        for j in range(i):
            x[i] -= lu[i, j] * x[j]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            x[i] -= lu[i, j] * x[j]
        x[i] /= lu[i, i]
    return x


@njit(cache=True)
def _num_jac(t, y, f, threshold, factor, n, mode, p, knots, ws, d, jac):
    """scipy's dense num_jac (common._dense_num_jac): forward differences with a per-column
    factor that adapts to the rounding it sees; ``factor`` is updated in place."""
    h = np.empty(n)
    y_scale = np.empty(n)
    for i in range(n):
        y_scale[i] = (1.0 if f[i] >= 0 else -1.0) * max(threshold[i], abs(y[i]))
        h[i] = (y[i] + factor[i] * y_scale[i]) - y[i]
        while h[i] == 0.0:
            factor[i] *= 10.0
            h[i] = (y[i] + factor[i] * y_scale[i]) - y[i]
    yp = np.empty(n)
    f_new = np.empty(n)
    for j in range(n):
        yp[:] = y
        yp[j] += h[j]
        _rhs(t, yp, n, mode, p, knots, ws, d, f_new)
        diff = f_new - f
        imax = np.argmax(np.abs(diff))
        max_diff = abs(diff[imax])
        scale = max(abs(f[imax]), abs(f_new[imax]))
        if max_diff < JAC_DIFF_REJECT * scale:
            new_factor = 10.0 * factor[j]
            h_new = (y[j] + new_factor * y_scale[j]) - y[j]
            yp[:] = y
            yp[j] += h_new
            _rhs(t, yp, n, mode, p, knots, ws, d, f_new)
            diff_new = f_new - f
            imax_new = np.argmax(np.abs(diff_new))
            max_diff_new = abs(diff_new[imax_new])
            scale_new = max(abs(f[imax_new]), abs(f_new[imax_new]))
            if max_diff * scale_new < max_diff_new * scale:
                factor[j], h[j], diff, scale, max_diff = (new_factor, h_new, diff_new,
                                                          scale_new, max_diff_new)
        for i in range(n):
            jac[i, j] = diff[i] / h[j]
        if max_diff < JAC_DIFF_SMALL * scale:
            factor[j] *= 10.0
        elif max_diff > JAC_DIFF_BIG * scale:
            factor[j] *= 0.1
        # Unlike scipy's, capped: a column nothing depends on (the energy accumulators) grew
        # its factor tenfold at every Jacobian until it overflowed.
        factor[j] = min(max(factor[j], JAC_MIN_FACTOR), JAC_MAX_FACTOR)


@njit(cache=True)
def _dense(y_old, q, x, out):
    """The step's collocation polynomial at x = (t - t_old) / h."""
    for i in range(out.size):
        out[i] = y_old[i] + x * (q[i, 0] + x * (q[i, 1] + x * q[i, 2]))


@njit(cache=True)
def _event_root(k, t_old, h, y_old, q, g_lo, g_hi, n, mode, p, knots, ws, d, scratch,
                kinds, consts):
    """Brent's method (scipy's brentq) on event k along the step's dense output, to 4 eps."""
    y = np.empty(n)
    xtol = rtol = 4 * EPS
    xpre, xcur, fpre, fcur = t_old, t_old + h, g_lo, g_hi
    xblk = fblk = spre = scur = 0.0
    if fpre == 0.0:
        return xpre
    if fcur == 0.0:
        return xcur
    for _ in range(100):
        if fpre != 0.0 and fcur != 0.0 and (fpre < 0.0) != (fcur < 0.0):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0.0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):
                spre, scur = scur, stry
            else:
                spre = scur = sbis
        else:
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        _dense(y_old, q, (xcur - t_old) / h, y)
        eq.mode_dynamics(xcur, y, mode, p, knots, ws, d)
        fcur = eq.event_value(kinds[k], consts[k], xcur, y, d, mode[0] != 0.0, mode[3], p,
                              knots, scratch)
    return xcur


@njit(cache=True)
def _left3(a, b, out):
    """out = a b for a 3x3 and b 3xn (numba's @ calls BLAS, dear on these sizes)."""
    for i in range(3):
        for j in range(b.shape[1]):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True)
def _collocation(t, y, h, z0, scale, tol, lu_r, piv_r, lu_c, piv_c, n, mode, p, knots, ws,
                 d):
    """scipy's solve_collocation_system: (converged, iterations, Z, rate (-1: none))."""
    m_real = MU_REAL / h
    m_complex = MU_COMPLEX / h
    w = np.empty((3, n))
    _left3(TI, z0, w)
    z = z0.copy()
    f = np.empty((3, n))
    fi = np.empty(n)
    yi = np.empty(n)
    dw = np.empty((3, n))
    f_real = np.empty(n)
    f_complex = np.empty(n, np.complex128)
    dw_norm_old = -1.0
    rate = -1.0
    converged = False
    k = 0
    for k in range(NEWTON_MAXITER):
        for i in range(3):
            for j in range(n):
                yi[j] = y[j] + z[i, j]
            _rhs(t + h * C[i], yi, n, mode, p, knots, ws, d, fi)
            f[i] = fi
        if not np.all(np.isfinite(f)):
            break
        for j in range(n):
            f_real[j] = (f[0, j] * TI[0, 0] + f[1, j] * TI[0, 1] + f[2, j] * TI[0, 2]
                         - m_real * w[0, j])
            f_complex[j] = (f[0, j] * (TI[1, 0] + 1j * TI[2, 0])
                            + f[1, j] * (TI[1, 1] + 1j * TI[2, 1])
                            + f[2, j] * (TI[1, 2] + 1j * TI[2, 2])
                            - m_complex * (w[1, j] + 1j * w[2, j]))
        dw_real = _lu_solve(lu_r, piv_r, f_real)
        dw_complex = _lu_solve(lu_c, piv_c, f_complex)
        dw[0] = dw_real
        dw[1] = dw_complex.real
        dw[2] = dw_complex.imag
        dw_norm = _rms(dw, scale)
        if dw_norm_old >= 0.0:
            rate = dw_norm / dw_norm_old
        if rate >= 0.0 and (rate >= 1.0
                            or rate ** (NEWTON_MAXITER - k) / (1 - rate) * dw_norm > tol):
            break
        w += dw
        _left3(T, w, z)
        if dw_norm == 0.0 or (rate >= 0.0 and rate / (1 - rate) * dw_norm < tol):
            converged = True
            break
        dw_norm_old = dw_norm
    return converged, k + 1, z, rate


@njit(cache=True)
def _predict_factor(h_abs, h_abs_old, error_norm, error_norm_old):
    if error_norm_old < 0.0 or h_abs_old < 0.0 or error_norm == 0.0:
        multiplier = 1.0
    else:
        multiplier = h_abs / h_abs_old * (error_norm_old / error_norm) ** 0.25
    if error_norm == 0.0:
        return math.inf
    return min(1.0, multiplier) * error_norm ** -0.25


@njit(cache=True)
def _grow(a, rows):
    out = np.empty((rows,) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


@njit(cache=True)
def integrate(y0, t0, t_bound, rtol, atol, mode, p, knots, kinds, directions, consts,
              max_rhs_evals, ws, keep_dense):
    """Integrate the mode's system from (t0, y0) to t_bound or its first event.

    Returns (status, event index or -1, step times, states (one row per time), and with
    ``keep_dense`` each step's (h, Q) of its collocation polynomial: the state at t in step
    i is ys[i] + Q_i [x, x^2, x^3], x = (t - ts[i]) / h_i)."""
    n = y0.size
    n_ev = kinds.size
    d = np.empty(eq.DYN_SIZE)
    scratch = np.empty(eq.DYN_SIZE)
    cap = 64
    ts = np.empty(cap)
    ys = np.empty((cap, n))
    hs = np.empty(cap if keep_dense else 1)
    qs = np.empty((cap if keep_dense else 1, n, 3))
    ts[0] = t0
    ys[0] = y0
    rows = 1
    t = t0
    y = y0.copy()
    f = np.empty(n)
    _rhs(t, y, n, mode, p, knots, ws, d, f)
    g = np.empty(n_ev)
    g_new = np.empty(n_ev)
    _events(t, y, n, mode, p, knots, ws, d, scratch, kinds, consts, g)

    # select_initial_step, for the error's order 3
    interval = t_bound - t0
    scale = atol + np.abs(y) * rtol
    d0, d1 = _rms(y, scale), _rms(f, scale)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, interval)
    f1 = np.empty(n)
    _rhs(t + h0, y + h0 * f, n, mode, p, knots, ws, d, f1)
    d2 = _rms(f1 - f, scale) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** 0.25
    h_abs = min(100 * h0, h1, interval)
    h_abs_old = -1.0
    error_norm_old = -1.0
    newton_tol = max(10 * EPS / rtol, min(0.03, rtol ** 0.5))

    jac = np.empty((n, n))
    jac_factor = np.full(n, EPS ** 0.5)
    _num_jac(t, y, f, atol, jac_factor, n, mode, p, knots, ws, d, jac)
    current_jac = True
    have_lu = False
    lu_r = np.empty((n, n))
    lu_c = np.empty((n, n), np.complex128)
    piv_r = np.empty(n, np.int64)
    piv_c = np.empty(n, np.int64)
    have_sol = False
    q = np.zeros((n, 3))
    y_old = y.copy()
    t_old = t
    h_sol = 1.0
    z0 = np.zeros((3, n))
    y_new = np.empty(n)
    f_new = np.empty(n)
    status = FINISHED
    event = -1

    while True:
        min_step = 10 * abs(np.nextafter(t, math.inf) - t)
        if h_abs < min_step:
            h_abs = min_step
            h_abs_old = -1.0
            error_norm_old = -1.0
        rejected = False
        accepted = False
        while not accepted:
            if h_abs < min_step:
                return STEP_TOO_SMALL, -1, ts[:rows], ys[:rows], hs[:rows - 1], qs[:rows - 1]
            t_new = t + h_abs
            if t_new - t_bound > 0:
                t_new = t_bound
            h = t_new - t
            h_abs = abs(h)
            if have_sol:
                for i in range(3):
                    x = (t + h * C[i] - t_old) / h_sol
                    for j in range(n):
                        z0[i, j] = (y_old[j] + x * (q[j, 0] + x * (q[j, 1] + x * q[j, 2]))
                                    - y[j])
            else:
                z0[:] = 0.0
            scale = atol + np.abs(y) * rtol
            converged = False
            n_iter = 0
            rate = -1.0
            z = z0
            while not converged:
                if not have_lu:
                    lu_r[:] = -jac
                    lu_c[:] = -jac
                    for i in range(n):
                        lu_r[i, i] += MU_REAL / h
                        lu_c[i, i] += MU_COMPLEX / h
                    piv_r = _lu_factor(lu_r)
                    piv_c = _lu_factor(lu_c)
                    have_lu = True
                converged, n_iter, z, rate = _collocation(
                    t, y, h, z0, scale, newton_tol, lu_r, piv_r, lu_c, piv_c, n, mode, p,
                    knots, ws, d)
                if not converged:
                    if current_jac:
                        break
                    _num_jac(t, y, f, atol, jac_factor, n, mode, p, knots, ws, d, jac)
                    current_jac = True
                    have_lu = False
            if not converged:
                h_abs *= 0.5
                have_lu = False
                continue
            y_new = y + z[2]
            ze = (z[0] * E[0] + z[1] * E[1] + z[2] * E[2]) / h
            error = _lu_solve(lu_r, piv_r, f + ze)
            scale = atol + np.maximum(np.abs(y), np.abs(y_new)) * rtol
            error_norm = _rms(error, scale)
            safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + n_iter)
            if rejected and error_norm > 1:
                _rhs(t, y + error, n, mode, p, knots, ws, d, f1)
                error = _lu_solve(lu_r, piv_r, f1 + ze)
                error_norm = _rms(error, scale)
            if error_norm > 1:
                factor = _predict_factor(h_abs, h_abs_old, error_norm, error_norm_old)
                h_abs *= max(MIN_FACTOR, safety * factor)
                have_lu = False
                rejected = True
            else:
                accepted = True
            if ws[eq.WS_RHS_EVALS] > max_rhs_evals:
                return OVER_BUDGET, -1, ts[:rows], ys[:rows], hs[:rows - 1], qs[:rows - 1]

        recompute_jac = n_iter > 2 and rate > 1e-3
        factor = _predict_factor(h_abs, h_abs_old, error_norm, error_norm_old)
        factor = min(MAX_FACTOR, safety * factor)
        if not recompute_jac and factor < 1.2:
            factor = 1.0
        else:
            have_lu = False
        _rhs(t_new, y_new, n, mode, p, knots, ws, d, f_new)
        # the events at the step's end, from the same evaluation of the dynamics
        _event_values(t_new, y_new, mode, p, knots, d, scratch, kinds, consts, g_new)
        if recompute_jac:
            _num_jac(t_new, y_new, f_new, atol, jac_factor, n, mode, p, knots, ws, d, jac)
            current_jac = True
        else:
            current_jac = False
        h_abs_old = h_abs
        error_norm_old = error_norm
        h_abs = h_abs * factor
        y_old[:] = y
        t_old = t
        h_sol = h
        for j in range(n):
            for c in range(3):
                q[j, c] = z[0, j] * P[0, c] + z[1, j] * P[1, c] + z[2, j] * P[2, c]
        have_sol = True
        t = t_new
        y = y_new.copy()
        f[:] = f_new

        # events: a sign change in the wanted direction, located on the dense output
        t_event = math.inf
        for k in range(n_ev):
            up = g[k] <= 0.0 and g_new[k] >= 0.0
            down = g[k] >= 0.0 and g_new[k] <= 0.0
            if ((up and directions[k] > 0) or (down and directions[k] < 0)
                    or ((up or down) and directions[k] == 0)):
                root = _event_root(k, t_old, h_sol, y_old, q, g[k], g_new[k], n, mode, p,
                                   knots, ws, d, scratch, kinds, consts)
                if root < t_event:
                    t_event, event = root, k
        g[:] = g_new
        if rows == ts.size:
            ts = _grow(ts, 2 * rows)
            ys = _grow(ys, 2 * rows)
            if keep_dense:
                hs = _grow(hs, 2 * rows)
                qs = _grow(qs, 2 * rows)
        if keep_dense:
            hs[rows - 1] = h_sol
            qs[rows - 1] = q
        if event >= 0:
            ts[rows] = t_event
            _dense(y_old, q, (t_event - t_old) / h_sol, ys[rows])
            status = EVENT
            rows += 1
            break
        ts[rows] = t
        ys[rows] = y
        rows += 1
        if t_new >= t_bound:
            break
        if ws[eq.WS_RHS_EVALS] > max_rhs_evals:
            return OVER_BUDGET, -1, ts[:rows], ys[:rows], hs[:rows - 1], qs[:rows - 1]
    n_dense = rows - 1 if keep_dense else 0
    return status, event, ts[:rows], ys[:rows], hs[:n_dense], qs[:n_dense]
