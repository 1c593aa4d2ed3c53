"""Generalised-force terms on q = (theta1, theta3), one per effect (N mm, ms).

Each term returns (Q1, Q3, dissipated power in mJ/ms) and, if conservative, its potential
energy (mJ). The model assembles only the terms its scene enables.
"""
from __future__ import annotations

import math

from .mechanism import Mechanism
from .scene import Scene

GRAVITY_MM_PER_MS2 = 9.807e-3


class TorsionSpring:
    """The energy store: V = 1/2 k (theta1 - theta1_0)^2, theta1_0 = pi + alpha. Always on."""

    name = 'spring'

    def __init__(self, scene: Scene):
        self.k = scene.spring.k_Nmm_per_rad
        self.rest = math.pi + math.radians(scene.geometry.alpha_deg)

    def __call__(self, th1, th3, w1, w3):
        return -self.k * (th1 - self.rest), 0.0, 0.0

    def potential(self, th1, th3):
        return 0.5 * self.k * (th1 - self.rest) ** 2


class HingeStiffness:
    name = 'hinge_stiffness'

    def __init__(self, scene: Scene):
        self.k = scene.hinge.k_Nmm_per_rad
        self.rest = math.radians(scene.hinge.rest_angle_deg)

    def __call__(self, th1, th3, w1, w3):
        return 0.0, -self.k * (th3 - self.rest), 0.0

    def potential(self, th1, th3):
        return 0.5 * self.k * (th3 - self.rest) ** 2


class JointDamping:
    name = 'joint_damping'

    def __init__(self, scene: Scene):
        self.c1 = scene.damping.body_Nmm_ms_per_rad
        self.c3 = scene.damping.arm_Nmm_ms_per_rad

    def __call__(self, th1, th3, w1, w3):
        return -self.c1 * w1, -self.c3 * w3, self.c1 * w1 * w1 + self.c3 * w3 * w3


class Gravity:
    """Gravity along `direction_deg` in the ground frame (x: pivot a towards guide hole d).
    The rig's stage is vertical and the tendon leaves the base downwards, so -y by default."""

    name = 'gravity'

    def __init__(self, mech: Mechanism, direction_deg: float = -90.0):
        self.mech = mech
        g = GRAVITY_MM_PER_MS2
        self.gx = g * math.cos(math.radians(direction_deg))
        self.gy = g * math.sin(math.radians(direction_deg))

    def __call__(self, th1, th3, w1, w3):
        m = self.mech
        c1, s1 = math.cos(th1), math.sin(th1)
        psi = th1 - th3
        cp, sp = math.cos(psi), math.sin(psi)
        dp1 = (m.x1 * c1 - m.y1 * s1, m.x1 * s1 + m.y1 * c1)
        dpsi = (-m.x2 * cp + m.y2 * sp, -m.x2 * sp - m.y2 * cp)
        db = (-m.L1 * s1, m.L1 * c1)
        q1 = (m.m1 * (self.gx * dp1[0] + self.gy * dp1[1])
              + m.m2 * (self.gx * (db[0] + dpsi[0]) + self.gy * (db[1] + dpsi[1])))
        q3 = -m.m2 * (self.gx * dpsi[0] + self.gy * dpsi[1])
        return q1, q3, 0.0

    def potential(self, th1, th3):
        pts = self.mech.points(th1, th3)
        m = self.mech
        return -sum(mass * (self.gx * p[0] + self.gy * p[1])
                    for mass, p in ((m.m1, pts['com_body']), (m.m2, pts['com_arm'])))


# Gauss-Legendre nodes and weights on [-1, 1]: the blade's strip integral with three strips,
# exact for pure rotation (force ~ r^2, moment ~ r^3); against a 64-strip sum over random
# states, within 0.04 % where the flow does not reverse along the blade, 6 % where it does.
_GAUSS_NODES = (-math.sqrt(0.6), 0.0, math.sqrt(0.6))
_GAUSS_WEIGHTS = (5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0)


class FluidDrag:
    """Quadratic drag on the body plate, quasi-steady lift and drag on the arm blade.

    Body: a plate of area S_b rotating about a feels -rho C_D S_b L1^3 |w1| w1 / 8 (strip
    integral). Blade: strip theory over [L5, L3] from b, each strip of width S_a / (L3 - L5)
    loaded by its own velocity with the section coefficients of the scene's arm (C_D from
    edge-on to broadside as sin^2 a, C_L peaking at 45 deg as sin 2a, a the angle between the
    local velocity and the blade); the integral is taken with three Gauss-Legendre strips.
    Below the regularisation speed the angle of attack is undefined; |v| is replaced by
    sqrt(|v|^2 + eps^2) so that every term stays smooth and vanishes at rest.
    """

    name = 'fluid_drag'

    def __init__(self, mech: Mechanism, scene: Scene, blade: bool = True):
        """blade: False where another term (PublishedArmAirLoad) loads the blade."""
        rho = scene.medium.density_g_per_mm3
        g = scene.geometry
        self.mech = mech
        self.blade = blade
        self.body_coeff = rho * scene.body.drag_coefficient * scene.body.area_mm2 * g.L1_mm ** 3 / 8
        lo, hi = g.L5_mm, g.L3_mm
        half_span = 0.5 * (hi - lo)
        chord = scene.arm.blade_area_mm2 / (hi - lo)
        self.strips = [(0.5 * (hi + lo) + half_span * x, 0.5 * rho * chord * half_span * w)
                       for x, w in zip(_GAUSS_NODES, _GAUSS_WEIGHTS)]
        self.eps_sq = scene.medium.regularisation_speed_m_per_s ** 2
        arm = scene.arm
        self.drag_edge_on = arm.blade_drag_edge_on
        self.drag_rise = arm.blade_drag_broadside - arm.blade_drag_edge_on
        self.lift_twice = 2.0 * arm.blade_lift_peak     # sin 2a = 2 sin a cos a

    def strip_force(self, r, half_rho_area, th3, w1, w3):
        """(F_along, F_normal) in N on the strip at r from b (``half_rho_area``: rho/2 times
        its share of the blade's area), the Jacobian rows of its velocity, and that velocity."""
        v_t, v_n, j_t, j_n = self.mech.arm_point_velocity(r, th3, w1, w3)
        speed = math.sqrt(v_t * v_t + v_n * v_n + self.eps_sq)
        drag = half_rho_area * (self.drag_edge_on + self.drag_rise * v_n * v_n / (speed * speed)) \
            * speed
        lift = half_rho_area * self.lift_twice * v_t * v_n / speed
        f_t = -drag * v_t + lift * v_n
        f_n = -drag * v_n - lift * v_t
        return f_t, f_n, j_t, j_n, v_t, v_n

    def __call__(self, th1, th3, w1, w3):
        body = -self.body_coeff * abs(w1) * w1
        q1, q3, power = body, 0.0, body * w1
        if self.blade:
            for r, half_rho_area in self.strips:
                f_t, f_n, j_t, j_n, v_t, v_n = self.strip_force(r, half_rho_area, th3, w1, w3)
                q1 += f_t * j_t[0] + f_n * j_n[0]
                q3 += f_t * j_t[1] + f_n * j_n[1]
                power += f_t * v_t + f_n * v_n
        return q1, q3, -power


class PublishedArmAirLoad:
    """The arm blade's fluid load in the form of the authors' published simulation (their Fig.
    S12 run), for reproducing it; fluid_drag's own blade term is the physically consistent one.

    The centre of pressure is the midpoint of the tip (L3 along the arm) and of the point L5
    from b at the tendon attachment's angle beta, so off the arm's axis (7.6 mm from b for the
    reference robot). Their velocity of that point is the true one turned by -90 degrees (their
    Jacobian takes the points' positions where their derivatives belong, the same quarter turn
    for both joints), and its generalised force is unchanged by the turn; their angle of attack
    is measured from that turned velocity to the blade. In the true velocity's terms, with a the
    angle between the velocity v and the blade (that point to the tip): C_D = 1.9 - 1.5 cos 2a
    (0.4 along the blade, 3.4 across it), |C_L| = 1.8 |sin 2a|; drag -1/2 rho S_a C_D |v| v,
    lift 1/2 rho S_a |C_L| |v|^2 normal to v, always on the tip's side (lift . blade >= 0).
    Below their speed threshold (1e-4 m/s) the load is zero, as in theirs.
    """

    name = 'published_arm_air_load'
    THRESHOLD = 1e-4          # mm/ms

    def __init__(self, mech: Mechanism, scene: Scene):
        g = scene.geometry
        beta = math.radians(g.beta_deg)
        self.mech = mech
        self.half_rho_area = 0.5 * scene.medium.density_g_per_mm3 * scene.arm.blade_area_mm2
        # the point in the arm's (along, across) axes; across = along turned by -90 degrees
        self.r_along = 0.5 * (g.L3_mm + g.L5_mm * math.cos(beta))
        self.r_across = 0.5 * g.L5_mm * math.sin(beta)
        # the blade direction in (along, normal) components (normal = along turned by +90)
        b_t, b_n = g.L3_mm - g.L5_mm * math.cos(beta), g.L5_mm * math.sin(beta)
        norm = math.hypot(b_t, b_n)
        self.blade = (b_t / norm, b_n / norm)

    def __call__(self, th1, th3, w1, w3):
        m, c, s = self.mech, math.cos(th3), math.sin(th3)
        j_t = (m.L1 * s + self.r_across, -self.r_across)
        j_n = (self.r_along - m.L1 * c, -self.r_along)
        v_t = j_t[0] * w1 + j_t[1] * w3
        v_n = j_n[0] * w1 + j_n[1] * w3
        speed = math.hypot(v_t, v_n)
        if speed <= self.THRESHOLD:
            return 0.0, 0.0, 0.0
        cos_a = max(-1.0, min(1.0, (v_t * self.blade[0] + v_n * self.blade[1]) / speed))
        a = math.acos(cos_a)
        c_d = 1.9 - 1.5 * math.cos(2.0 * a)
        c_l = abs(1.8 * math.sin(2.0 * a))
        l_t, l_n = -v_n, v_t                      # v turned by +90 degrees
        if l_t * self.blade[0] + l_n * self.blade[1] < 0.0:
            l_t, l_n = -l_t, -l_n
        f_t = self.half_rho_area * speed * (-c_d * v_t + c_l * l_t)
        f_n = self.half_rho_area * speed * (-c_d * v_n + c_l * l_n)
        q1 = f_t * j_t[0] + f_n * j_n[0]
        q3 = f_t * j_t[1] + f_n * j_n[1]
        return q1, q3, -(f_t * v_t + f_n * v_n)


def conservative_terms(terms) -> list:
    return [t for t in terms if hasattr(t, 'potential')]
