"""The equations of motion of mantis_sim.model, compiled: the same modes, terms and events.

Each function here mirrors one of the Python model (named in its docstring), reading the
scene's constants from the vector of mantis_sim.fast.layout. The Python model stays the
reference: test/test_fast_engine.py holds the two to agreement at random states, term by term.
"""
from __future__ import annotations

import math

from numba import njit
import numpy as np

from .. import mechanism
from .layout import (
    EV_ARM_STOPS,
    EV_LATCH_MARGIN,
    EV_MAX_CONTRACTION,
    EV_OVERCENTER,
    EV_RECONTACT,
    EV_SLIP,
    EV_STRETCH,
    EV_TAUT_TENSION,
    EV_TENSION,
    INDEX,
)

# The vector's indices, as compile-time constants (layout.FIELDS; a test checks the names).
(L1, L2, L3, L5, D_T, BETA, CONTACT, M1, M2, X1, Y1, X2, Y2, M11_CONST, ARM_ABOUT_B,
 BODY_ABOUT_A, ADDED_KIND, ADDED_BODY_ABOUT_A, STRIP_PER_MM, STRIP_K0, STRIP_K1, STRIP_K2,
 PUB_M_NORMAL, PUB_M_ALONG, PUB_ARM_INERTIA, SPRING_K, SPRING_REST, HINGE_ON, HINGE_K,
 HINGE_REST, DAMPING_ON, DAMPING_C1, DAMPING_C3, GRAVITY_ON, GRAVITY_X, GRAVITY_Y, DRAG_ON,
 DRAG_BLADE, DRAG_BODY, STRIP_R0, STRIP_R1, STRIP_R2, STRIP_A0, STRIP_A1, STRIP_A2,
 DRAG_EPS_SQ, DRAG_EDGE_ON, DRAG_RISE, LIFT_TWICE, AIRLOAD_ON, AIRLOAD_HALF_RHO_AREA,
 AIRLOAD_ALONG, AIRLOAD_ACROSS, AIRLOAD_BLADE_T, AIRLOAD_BLADE_N, RIGID, UNILATERAL,
 SATURATION, K_T, C_T, FRICTION_LEVER, KINETIC_LEVER, KAPPA, L_FREE0, DRIVE_KIND, DRIVE_V,
 DRIVE_A, DRIVE_TAU, DRIVE_T_RAMP, DRIVE_T0, DRIVE_X0) = range(len(INDEX))

AIRLOAD_THRESHOLD = 1e-4            # mm/ms, forces.PublishedArmAirLoad.THRESHOLD

# The dynamics vector (model.Dynamics) and the work vector's slots.
TH1, TH3, W1, W3, A1, A3, TENSION, CONTACT_TORQUE, STAGE_POWER, LOSS_POWER = range(10)
DYN_SIZE = 10
WS_THETA1_GUESS, WS_RHS_EVALS, WS_SIZE = 0, 1, 2


_tendon_terms = njit(cache=True)(mechanism.tendon_terms)


@njit(cache=True)
def tendon(th1, th3, p):
    """mechanism.Mechanism.tendon: (length, d1, d3, d11, d13, d33)."""
    return _tendon_terms(p[L1], p[L2], p[D_T], p[BETA], th1, th3)


@njit(cache=True)
def mass(th3, p):
    """mechanism.Mechanism.mass: (m11, m12, m22, dm11, dm12, dm22)."""
    c, s = math.cos(th3), math.sin(th3)
    a = p[L1] * (p[X2] * s - p[Y2] * c)
    da = p[L1] * (p[X2] * c + p[Y2] * s)
    m2 = p[M2]
    m11 = p[M11_CONST] + 2 * m2 * a
    m12 = -m2 * a - p[ARM_ABOUT_B]
    m22 = p[ARM_ABOUT_B]
    dm11, dm12 = 2 * m2 * da, -m2 * da
    kind = p[ADDED_KIND]
    if kind == 1.0:
        m, l1 = p[STRIP_PER_MM], p[L1]
        k0, k1, k2 = p[STRIP_K0], p[STRIP_K1], p[STRIP_K2]
        m11 += m * (k2 - 2 * l1 * c * k1 + l1 * l1 * c * c * k0) + p[ADDED_BODY_ABOUT_A]
        m12 += -m * (k2 - l1 * c * k1)
        m22 += m * k2
        dm11 += m * (2 * l1 * s * k1 - 2 * l1 * l1 * c * s * k0)
        dm12 += -m * l1 * s * k1
    elif kind == 2.0:
        l1, x2, y2 = p[L1], p[X2], p[Y2]
        jn1, jt1 = y2 - l1 * c, l1 * s + x2
        mn, mt, inertia = p[PUB_M_NORMAL], p[PUB_M_ALONG], p[PUB_ARM_INERTIA]
        m11 += mn * jn1 * jn1 + mt * jt1 * jt1 + inertia + p[ADDED_BODY_ABOUT_A]
        m12 += -mn * y2 * jn1 - mt * x2 * jt1 - inertia
        m22 += mn * y2 * y2 + mt * x2 * x2 + inertia
        dm11 += 2 * mn * jn1 * l1 * s + 2 * mt * jt1 * l1 * c
        dm12 += -mn * y2 * l1 * s - mt * x2 * l1 * c
    return m11, m12, m22, dm11, dm12, 0.0


@njit(cache=True)
def mass_solve(m11, m12, m22, r1, r3):
    det = m11 * m22 - m12 * m12
    return (m22 * r1 - m12 * r3) / det, (m11 * r3 - m12 * r1) / det


@njit(cache=True)
def velocity_terms(m11, m12, m22, dm11, dm12, dm22, w1, w3):
    quad = 0.5 * (dm11 * w1 * w1 + 2.0 * dm12 * w1 * w3 + dm22 * w3 * w3)
    return w3 * (dm11 * w1 + dm12 * w3), w3 * (dm12 * w1 + dm22 * w3) - quad


@njit(cache=True)
def kinetic_energy(th3, w1, w3, p):
    m11, m12, m22, _, _, _ = mass(th3, p)
    return 0.5 * (m11 * w1 * w1 + 2.0 * m12 * w1 * w3 + m22 * w3 * w3)


@njit(cache=True)
def tip_speed(th3, w1, w3, p):
    """mechanism.Mechanism.tip_speed, mm/ms = m/s."""
    w2 = w1 - w3
    sq = (p[L1] ** 2 * w1 * w1 + p[L3] ** 2 * w2 * w2
          - 2 * p[L1] * p[L3] * w1 * w2 * math.cos(th3))
    return math.sqrt(max(sq, 0.0))


@njit(cache=True)
def tip_power_rate(th3, w1, w3, a1, a3, p):
    """mechanism.Mechanism.tip_power_rate."""
    l1, l3 = p[L1], p[L3]
    w2, a2 = w1 - w3, a1 - a3
    c, s = math.cos(th3), math.sin(th3)
    return (l1 * l1 * w1 * a1 + l3 * l3 * w2 * a2
            - l1 * l3 * ((a1 * w2 + w1 * a2) * c - w1 * w2 * s * w3))


# --- applied forces (mantis_sim.forces) --------------------------------------------------------
@njit(cache=True)
def _gravity(th1, th3, p):
    c1, s1 = math.cos(th1), math.sin(th1)
    psi = th1 - th3
    cp, sp = math.cos(psi), math.sin(psi)
    gx, gy = p[GRAVITY_X], p[GRAVITY_Y]
    x1, y1, x2, y2, l1 = p[X1], p[Y1], p[X2], p[Y2], p[L1]
    dp1x, dp1y = x1 * c1 - y1 * s1, x1 * s1 + y1 * c1
    dpsix, dpsiy = -x2 * cp + y2 * sp, -x2 * sp - y2 * cp
    dbx, dby = -l1 * s1, l1 * c1
    q1 = (p[M1] * (gx * dp1x + gy * dp1y)
          + p[M2] * (gx * (dbx + dpsix) + gy * (dby + dpsiy)))
    q3 = -p[M2] * (gx * dpsix + gy * dpsiy)
    return q1, q3


@njit(cache=True)
def _blade_drag(th3, w1, w3, p):
    """forces.FluidDrag's blade: three Gauss strips."""
    c, s = math.cos(th3), math.sin(th3)
    q1 = q3 = power = 0.0
    for k in range(3):
        r, half_rho_area = p[STRIP_R0 + k], p[STRIP_A0 + k]
        jt1 = p[L1] * s
        jn1, jn3 = r - p[L1] * c, -r
        v_t = jt1 * w1
        v_n = jn1 * w1 + jn3 * w3
        speed = math.sqrt(v_t * v_t + v_n * v_n + p[DRAG_EPS_SQ])
        drag = half_rho_area * (p[DRAG_EDGE_ON] + p[DRAG_RISE] * v_n * v_n / (speed * speed)) \
            * speed
        lift = half_rho_area * p[LIFT_TWICE] * v_t * v_n / speed
        f_t = -drag * v_t + lift * v_n
        f_n = -drag * v_n - lift * v_t
        q1 += f_t * jt1 + f_n * jn1
        q3 += f_n * jn3
        power += f_t * v_t + f_n * v_n
    return q1, q3, power


@njit(cache=True)
def _published_air_load(th3, w1, w3, p):
    """forces.PublishedArmAirLoad."""
    c, s = math.cos(th3), math.sin(th3)
    across, along = p[AIRLOAD_ACROSS], p[AIRLOAD_ALONG]
    jt1, jt3 = p[L1] * s + across, -across
    jn1, jn3 = along - p[L1] * c, -along
    v_t = jt1 * w1 + jt3 * w3
    v_n = jn1 * w1 + jn3 * w3
    speed = math.hypot(v_t, v_n)
    if speed <= AIRLOAD_THRESHOLD:
        return 0.0, 0.0, 0.0
    bt, bn = p[AIRLOAD_BLADE_T], p[AIRLOAD_BLADE_N]
    cos_a = max(-1.0, min(1.0, (v_t * bt + v_n * bn) / speed))
    a = math.acos(cos_a)
    c_d = 1.9 - 1.5 * math.cos(2.0 * a)
    c_l = abs(1.8 * math.sin(2.0 * a))
    l_t, l_n = -v_n, v_t
    if l_t * bt + l_n * bn < 0.0:
        l_t, l_n = -l_t, -l_n
    f_t = p[AIRLOAD_HALF_RHO_AREA] * speed * (-c_d * v_t + c_l * l_t)
    f_n = p[AIRLOAD_HALF_RHO_AREA] * speed * (-c_d * v_n + c_l * l_n)
    return f_t * jt1 + f_n * jn1, f_t * jt3 + f_n * jn3, -(f_t * v_t + f_n * v_n)


@njit(cache=True)
def applied(th1, th3, w1, w3, p):
    """model.Model.applied: (Q1, Q3, dissipated power)."""
    q1 = -p[SPRING_K] * (th1 - p[SPRING_REST])
    q3 = 0.0
    loss = 0.0
    if p[HINGE_ON] != 0.0:
        q3 -= p[HINGE_K] * (th3 - p[HINGE_REST])
    if p[DAMPING_ON] != 0.0:
        c1, c3 = p[DAMPING_C1], p[DAMPING_C3]
        q1 -= c1 * w1
        q3 -= c3 * w3
        loss += c1 * w1 * w1 + c3 * w3 * w3
    if p[GRAVITY_ON] != 0.0:
        g1, g3 = _gravity(th1, th3, p)
        q1 += g1
        q3 += g3
    if p[DRAG_ON] != 0.0:
        body = -p[DRAG_BODY] * abs(w1) * w1
        q1 += body
        power = body * w1
        if p[DRAG_BLADE] != 0.0:
            b1, b3, blade_power = _blade_drag(th3, w1, w3, p)
            q1 += b1
            q3 += b3
            power += blade_power
        loss -= power
    if p[AIRLOAD_ON] != 0.0:
        a1, a3, air_loss = _published_air_load(th3, w1, w3, p)
        q1 += a1
        q3 += a3
        loss += air_loss
    return q1, q3, loss


@njit(cache=True)
def potential_energy(th1, th3, p):
    """The conservative terms' energy (mJ): spring, hinge, gravity (not the tendon)."""
    energy = 0.5 * p[SPRING_K] * (th1 - p[SPRING_REST]) ** 2
    if p[HINGE_ON] != 0.0:
        energy += 0.5 * p[HINGE_K] * (th3 - p[HINGE_REST]) ** 2
    if p[GRAVITY_ON] != 0.0:
        l1, x1, y1, x2, y2 = p[L1], p[X1], p[Y1], p[X2], p[Y2]
        bx, by = l1 * math.cos(th1), l1 * math.sin(th1)
        axis = th1 + math.pi - th3
        across = axis - 0.5 * math.pi
        com1x = x1 * math.sin(th1) + y1 * math.cos(th1)
        com1y = -x1 * math.cos(th1) + y1 * math.sin(th1)
        com2x = bx + x2 * math.cos(across) + y2 * math.cos(axis)
        com2y = by + x2 * math.sin(across) + y2 * math.sin(axis)
        gx, gy = p[GRAVITY_X], p[GRAVITY_Y]
        energy -= p[M1] * (gx * com1x + gy * com1y) + p[M2] * (gx * com2x + gy * com2y)
    return energy


# --- the drive (mantis_sim.drive) --------------------------------------------------------------
@njit(cache=True)
def _ramping(t, a, tau):
    if tau <= 0.0:
        return 0.5 * a * t * t, a * t, a
    decay = math.exp(-t / tau)
    return a * (0.5 * t * t - tau * t + tau * tau * (1.0 - decay)), a * (t - tau * (1.0 - decay)), \
        a * (1.0 - decay)


@njit(cache=True)
def pulled(t, p, knots):
    """(mm, mm/ms, mm/ms^2) the stage has pulled at t ms: drive.ConstantPull, RampedPull or
    CommandedPull."""
    kind = p[DRIVE_KIND]
    if kind == 0.0:
        return p[DRIVE_V] * t, p[DRIVE_V], 0.0
    if kind == 1.0:
        if t <= 0.0:
            return 0.0, 0.0, 0.0
        v, tau, tr = p[DRIVE_V], p[DRIVE_TAU], p[DRIVE_T_RAMP]
        if t < tr:
            return _ramping(t, p[DRIVE_A], tau)
        if tr > 0.0:
            pos_r, vel_r, _ = _ramping(tr, p[DRIVE_A], tau)
        else:
            pos_r, vel_r = 0.0, 0.0
        if tau <= 0.0:
            return pos_r + v * (t - tr), v, 0.0
        decay = math.exp(-(t - tr) / tau)
        gap = vel_r - v
        return pos_r + v * (t - tr) + gap * tau * (1.0 - decay), v + gap * decay, \
            -gap * decay / tau
    world_t = t + p[DRIVE_T0]
    if world_t <= 0.0:
        return -p[DRIVE_X0], 0.0, 0.0
    i = max(np.searchsorted(knots[:, 0], world_t, side='right') - 1, 0)
    dt = world_t - knots[i, 0]
    x, v, a = knots[i, 1], knots[i, 2], knots[i, 3]
    return x + v * dt + 0.5 * a * dt * dt - p[DRIVE_X0], v + a * dt, a


@njit(cache=True)
def free_length(t, p, knots):
    x, v, a = pulled(t, p, knots)
    return p[L_FREE0] - x, -v, -a


# --- the modes (model.Model) ------------------------------------------------------------------
@njit(cache=True)
def compliant_tension(length, d1, d3, w1, w3, t, taut, p, knots):
    """model.Model.compliant_tension: (F, tendon damping loss)."""
    if not taut:
        return 0.0, 0.0
    l_free, l_free_dot, _ = free_length(t, p, knots)
    stretch = length - l_free
    rate = d1 * w1 + d3 * w3 - l_free_dot
    tension = p[K_T] * stretch + p[C_T] * rate
    if p[UNILATERAL] != 0.0 and tension < 0.0:
        tension = 0.0
    return tension, (tension - p[K_T] * stretch) * rate


@njit(cache=True)
def solve_theta1(l_target, th3, p, ws):
    """model.Model.solve_theta1, from the work vector's last solution. Returns theta1 and
    its tendon geometry; NaN if Newton does not converge."""
    th1 = ws[WS_THETA1_GUESS]
    for _ in range(50):
        g = tendon(th1, th3, p)
        step = (g[0] - l_target) / g[1]
        if abs(step) < 1e-14:
            ws[WS_THETA1_GUESS] = th1
            return th1, g
        th1 -= step
    return math.nan, tendon(th1, th3, p)


@njit(cache=True)
def latched_constrained(t, th3, p, knots, ws, out):
    """model.Model.latched_constrained."""
    l_free, l_free_dot, l_free_ddot = free_length(t, p, knots)
    th1, g = solve_theta1(l_free, th3, p, ws)
    _, d1, d3, d11, _, _ = g
    w1 = l_free_dot / d1
    a1 = (l_free_ddot - d11 * w1 * w1) / d1
    m11, m12, m22, dm11, dm12, dm22 = mass(th3, p)
    q1, q3, loss = applied(th1, th3, w1, 0.0, p)
    c1, c3 = velocity_terms(m11, m12, m22, dm11, dm12, dm22, w1, 0.0)
    tension = (q1 - c1 - m11 * a1) / d1
    contact = m12 * a1 + c3 - q3 + d3 * tension
    _fill(out, th1, th3, w1, 0.0, a1, 0.0, tension, contact, -tension * l_free_dot, loss)


@njit(cache=True)
def latched_free(t, th1, w1, taut, th3, p, knots, out):
    """model.Model.latched_free."""
    m11, m12, m22, dm11, dm12, dm22 = mass(th3, p)
    q1, q3, loss = applied(th1, th3, w1, 0.0, p)
    tension = 0.0
    if p[RIGID] == 0.0:
        length, d1, d3, _, _, _ = tendon(th1, th3, p)
        tension, tendon_loss = compliant_tension(length, d1, d3, w1, 0.0, t, taut, p, knots)
        q1 -= tension * d1
        q3 -= tension * d3
        loss += tendon_loss
    c1, c3 = velocity_terms(m11, m12, m22, dm11, dm12, dm22, w1, 0.0)
    a1 = (q1 - c1) / m11
    contact = m12 * a1 + c3 - q3
    l_free_dot = free_length(t, p, knots)[1]
    _fill(out, th1, th3, w1, 0.0, a1, 0.0, tension, contact, -tension * l_free_dot, loss)


@njit(cache=True)
def unlatched(t, th1, th3, w1, w3, taut, saturated, slip, p, knots, out):
    """model.Model.unlatched."""
    m11, m12, m22, dm11, dm12, dm22 = mass(th3, p)
    q1, q3, loss = applied(th1, th3, w1, w3, p)
    c1, c3 = velocity_terms(m11, m12, m22, dm11, dm12, dm22, w1, w3)
    f1, f3 = q1 - c1, q3 - c3
    tension = 0.0
    per_newton = -slip * p[KINETIC_LEVER]
    l_free, l_free_dot, l_free_ddot = free_length(t, p, knots)
    rigid = p[RIGID] != 0.0
    if saturated:
        _, d1, d3, _, _, _ = tendon(th1, th3, p)
        tension = p[SATURATION]
        f1 -= tension * d1
        f3 -= tension * (d3 - per_newton)
        loss += tension * (d1 * w1 + d3 * w3 - l_free_dot)
        a1, a3 = mass_solve(m11, m12, m22, f1, f3)
    elif rigid and taut:
        length, d1, d3, d11, d13, d33 = tendon(th1, th3, p)
        rate_error = d1 * w1 + d3 * w3 - l_free_dot
        curvature = d11 * w1 * w1 + 2 * d13 * w1 * w3 + d33 * w3 * w3
        k = p[KAPPA]
        gamma = l_free_ddot - curvature - 2 * k * rate_error - k * k * (length - l_free)
        u1, u3 = mass_solve(m11, m12, m22, d1, d3 - per_newton)
        a1_free, a3_free = mass_solve(m11, m12, m22, f1, f3)
        tension = (d1 * a1_free + d3 * a3_free - gamma) / (d1 * u1 + d3 * u3)
        a1, a3 = a1_free - u1 * tension, a3_free - u3 * tension
    else:
        if not rigid:
            length, d1, d3, _, _, _ = tendon(th1, th3, p)
            tension, tendon_loss = compliant_tension(length, d1, d3, w1, w3, t, taut, p, knots)
            f1 -= tension * d1
            f3 -= tension * (d3 - per_newton)
            loss += tendon_loss
        a1, a3 = mass_solve(m11, m12, m22, f1, f3)
    loss += p[KINETIC_LEVER] * abs(tension * w3)
    _fill(out, th1, th3, w1, w3, a1, a3, tension, 0.0, -tension * l_free_dot, loss)


@njit(cache=True)
def _fill(out, th1, th3, w1, w3, a1, a3, tension, contact, stage_power, loss):
    out[TH1], out[TH3], out[W1], out[W3], out[A1], out[A3] = th1, th3, w1, w3, a1, a3
    out[TENSION], out[CONTACT_TORQUE] = tension, contact
    out[STAGE_POWER], out[LOSS_POWER] = stage_power, loss


# --- one mode's system -------------------------------------------------------------------------
@njit(cache=True)
def constrained(latched, taut, saturated, p):
    """hybrid.HybridSimulator._constrained: a latched arm on a taut rigid tendon."""
    return latched and taut and p[RIGID] != 0.0 and not saturated


@njit(cache=True)
def dynamics(t, y, latched, taut, saturated, stuck_at, slip, p, knots, ws, out):
    """hybrid.HybridSimulator._dynamics on the mode's integrated state y."""
    ws[WS_RHS_EVALS] += 1.0
    held = p[CONTACT] if math.isnan(stuck_at) else stuck_at
    if constrained(latched, taut, saturated, p):
        latched_constrained(t, held, p, knots, ws, out)
    elif latched:
        latched_free(t, y[0], y[1], taut, held, p, knots, out)
    else:
        unlatched(t, y[0], y[1], y[2], y[3], taut, saturated, slip, p, knots, out)


@njit(cache=True)
def rhs_from(d, n, dydt):
    """The mode's derivative from its dynamics: n = 2 (constrained), 4 (latched), 6 (free)."""
    if n == 2:
        dydt[0], dydt[1] = d[STAGE_POWER], d[LOSS_POWER]
    elif n == 4:
        dydt[0], dydt[1], dydt[2], dydt[3] = d[W1], d[A1], d[STAGE_POWER], d[LOSS_POWER]
    else:
        dydt[0], dydt[1], dydt[2], dydt[3] = d[W1], d[W3], d[A1], d[A3]
        dydt[4], dydt[5] = d[STAGE_POWER], d[LOSS_POWER]


@njit(cache=True)
def full_state(y, n, d, full):
    """hybrid.HybridSimulator._unpack: (th1, th3, w1, w3, W_drive, E_dissipated)."""
    if n == 2:
        full[0], full[1], full[2], full[3], full[4], full[5] = \
            d[TH1], d[TH3], d[W1], 0.0, y[0], y[1]
    elif n == 4:
        full[0], full[1], full[2], full[3], full[4], full[5] = \
            y[0], d[TH3], y[1], 0.0, y[2], y[3]
    else:
        for i in range(6):
            full[i] = y[i]


@njit(cache=True)
def event_value(kind, const, t, y, d, latched, stuck_at, p, knots, scratch):
    """One event function of hybrid.HybridSimulator._events at (t, y), d the mode's dynamics
    there. ``scratch``: room for the taut mode's dynamics (EV_TAUT_TENSION)."""
    if kind == EV_LATCH_MARGIN:
        return d[CONTACT_TORQUE] + p[FRICTION_LEVER] * abs(d[TENSION])
    if kind == EV_SLIP:
        return p[FRICTION_LEVER] * abs(d[TENSION]) - abs(d[CONTACT_TORQUE])
    if kind == EV_RECONTACT:
        return y[1] + const
    if kind == EV_ARM_STOPS:
        return y[3] + const
    if kind == EV_STRETCH:
        held = p[CONTACT] if math.isnan(stuck_at) else stuck_at
        th3 = held if latched else y[1]
        return tendon(y[0], th3, p)[0] - free_length(t, p, knots)[0] + const
    if kind == EV_TENSION:
        return d[TENSION] + const
    if kind == EV_TAUT_TENSION:
        unlatched(t, y[0], y[1], y[2], y[3], True, False, 1.0, p, knots, scratch)
        return scratch[TENSION]
    if kind == EV_OVERCENTER:
        return tendon(y[0], y[1], p)[2]
    if kind == EV_MAX_CONTRACTION:
        return y[2]
    return tip_power_rate(d[TH3], d[W1], d[W3], d[A1], d[A3], p)


# --- what a trajectory reports (results._trajectory) -------------------------------------------
OBS_TENSION, OBS_CONTACT, OBS_TIP_SPEED, OBS_SPRING, OBS_KINETIC, OBS_ENERGY, OBS_LENGTH, \
    OBS_FREE_LENGTH = range(8)
OBS_SIZE = 8


@njit(cache=True)
def observe(t, s, mode, p, knots, ws, d, out):
    """One trajectory row's derived values at the full state s (results._trajectory): the
    dynamics at s, tip speed, spring, kinetic and mechanical energy, tendon and free length."""
    state_dynamics(t, s, mode, p, knots, ws, d)
    kinetic = kinetic_energy(s[1], s[2], s[3], p)
    length = tendon(s[0], s[1], p)[0]
    free = free_length(t, p, knots)[0]
    energy = kinetic + potential_energy(s[0], s[1], p)
    if p[RIGID] == 0.0:
        stretch = length - free
        if stretch > 0.0 or p[UNILATERAL] == 0.0:
            energy += 0.5 * p[K_T] * stretch * stretch
    out[OBS_TENSION], out[OBS_CONTACT] = d[TENSION], d[CONTACT_TORQUE]
    out[OBS_TIP_SPEED] = tip_speed(s[1], s[2], s[3], p)
    out[OBS_SPRING] = 0.5 * p[SPRING_K] * (s[0] - p[SPRING_REST]) ** 2
    out[OBS_KINETIC], out[OBS_ENERGY] = kinetic, energy
    out[OBS_LENGTH], out[OBS_FREE_LENGTH] = length, free


@njit(cache=True)
def mode_dynamics(t, y, mode, p, knots, ws, out):
    """dynamics() in the mode of a mode vector (radau.MODE_SIZE: latched, taut, saturated,
    stuck_at (NaN: at the contact), slip)."""
    dynamics(t, y, mode[0] != 0.0, mode[1] != 0.0, mode[2] != 0.0, mode[3], mode[4], p, knots,
             ws, out)


@njit(cache=True)
def state_dynamics(t, s, mode, p, knots, ws, out):
    """hybrid.HybridSimulator._state_dynamics: the dynamics at a full state s, from the mode's
    integrated state (hybrid._pack); a latched arm on a taut rigid tendon starts its Newton
    solve for theta1 from s's."""
    y = np.empty(6)
    if constrained(mode[0] != 0.0, mode[1] != 0.0, mode[2] != 0.0, p):
        ws[WS_THETA1_GUESS] = s[0]
        y[0], y[1] = s[4], s[5]
    elif mode[0] != 0.0:
        y[0], y[1], y[2], y[3] = s[0], s[2], s[4], s[5]
    else:
        for i in range(6):
            y[i] = s[i]
    mode_dynamics(t, y, mode, p, knots, ws, out)


@njit(cache=True)
def full_states(ts, ys, mode, p, knots, ws):
    """hybrid._unpack of every row of a segment: (rows, 6) full states."""
    rows, n = ys.shape
    out = np.empty((rows, 6))
    d = np.empty(DYN_SIZE)
    for r in range(rows):
        if n == 6:
            out[r] = ys[r]
            continue
        mode_dynamics(ts[r], ys[r], mode, p, knots, ws, d)
        full_state(ys[r], n, d, out[r])
    return out


@njit(cache=True)
def observe_rows(ts, states, mode, p, knots, ws):
    """observe() of every row: (rows, OBS_SIZE)."""
    rows = ts.size
    out = np.empty((rows, OBS_SIZE))
    d = np.empty(DYN_SIZE)
    for r in range(rows):
        observe(ts[r], states[r], mode, p, knots, ws, d, out[r])
    return out
