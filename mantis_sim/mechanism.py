"""Kinematics and inertia of the four-bar (physics.md), in g, mm, ms, rad.

Coordinates q = (theta1, theta3): body angle about the ground pivot a, arm angle relative to
the body. Frames (derived from the tendon-length and mass-matrix formulas of physics.md):
- body frame: y along a->b (angle theta1), x at theta1 - pi/2;
- arm frame: y along the arm, pivot b -> tip (angle theta1 + pi - theta3), x at y - pi/2.
So at theta3 = 0 the arm lies folded back along the body. Scalar `math` throughout: this runs
in the integrator's inner loop, where numpy's per-call overhead on 2-vectors would dominate.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from .scene import Scene


# Value types of the inner loop are NamedTuples: built several times per right-hand-side
# evaluation, and a frozen dataclass costs a multiple of a tuple to construct.
class TendonGeometry(NamedTuple):
    """Tendon length l between c and d, its gradient and Hessian in (theta1, theta3)."""

    length: float
    d1: float
    d3: float
    d11: float
    d13: float
    d33: float


class MassMatrix(NamedTuple):
    """Symmetric M(theta3) and dM/dtheta3 (M depends on theta3 only)."""

    m11: float
    m12: float
    m22: float
    dm11: float
    dm12: float
    dm22: float

    def solve(self, r1: float, r3: float) -> tuple[float, float]:
        det = self.m11 * self.m22 - self.m12 * self.m12
        return ((self.m22 * r1 - self.m12 * r3) / det, (self.m11 * r3 - self.m12 * r1) / det)

    def velocity_terms(self, w1: float, w3: float) -> tuple[float, float]:
        """Christoffel terms c(q, qdot) of M qddot + c = Q, for M = M(theta3)."""
        quad = 0.5 * (self.dm11 * w1 * w1 + 2.0 * self.dm12 * w1 * w3 + self.dm22 * w3 * w3)
        return (w3 * (self.dm11 * w1 + self.dm12 * w3),
                w3 * (self.dm12 * w1 + self.dm22 * w3) - quad)

    def kinetic_energy(self, w1: float, w3: float) -> float:
        return 0.5 * (self.m11 * w1 * w1 + 2.0 * self.m12 * w1 * w3 + self.m22 * w3 * w3)


def tendon_terms(L1: float, L2: float, d: float, beta: float, th1: float, th3: float) -> tuple:
    """TendonGeometry's fields for links L1, L2, guide distance d and attachment angle beta: one
    formula for the Python model and the compiled one (mantis_sim.fast.equations)."""
    u = th1 - th3 - beta
    w = th3 + beta
    cos_u, sin_u, cos_w, sin_w = math.cos(u), math.sin(u), math.cos(w), math.sin(w)
    cos1, sin1 = math.cos(th1), math.sin(th1)
    sq = L1 * L1 + L2 * L2 + d * d - 2 * L1 * L2 * cos_w - 2 * d * (L1 * cos1 - L2 * cos_u)
    s1 = 2 * d * (L1 * sin1 - L2 * sin_u)
    s3 = 2 * L2 * (L1 * sin_w + d * sin_u)
    s11 = 2 * d * (L1 * cos1 - L2 * cos_u)
    s13 = 2 * d * L2 * cos_u
    s33 = 2 * L2 * (L1 * cos_w - d * cos_u)
    length = math.sqrt(sq)
    inv2l = 0.5 / length
    inv4l3 = inv2l / (2.0 * sq)
    return (length, s1 * inv2l, s3 * inv2l, s11 * inv2l - s1 * s1 * inv4l3,
            s13 * inv2l - s1 * s3 * inv4l3, s33 * inv2l - s3 * s3 * inv4l3)


class Mechanism:
    """Geometry and inertia of one scene; added mass is included only if the scene asks."""

    def __init__(self, scene: Scene):
        g, body, arm = scene.geometry, scene.body, scene.arm
        self.L1, self.L2, self.L3, self.L5 = g.L1_mm, g.L2_mm, g.L3_mm, g.L5_mm
        self.d_t = g.d_t_mm
        self.beta = math.radians(g.beta_deg)
        self.contact_angle = math.radians(g.latched_angle_deg)
        self.m1, self.m2 = body.mass_g, arm.mass_g
        self.x1, self.y1 = body.com_x_mm, body.com_y_mm
        self.x2, self.y2 = arm.com_x_mm, arm.com_y_mm
        r1_sq = self.x1 ** 2 + self.y1 ** 2
        r2_sq = self.x2 ** 2 + self.y2 ** 2
        self.body_inertia_about_a = self.m1 * r1_sq + body.inertia_g_mm2
        self._arm_about_b = self.m2 * r2_sq + arm.inertia_g_mm2
        self._m11_const = self.body_inertia_about_a + self.m2 * self.L1 ** 2 + self._arm_about_b
        self._added = (_AddedMass(scene) if scene.has('added_mass') else
                       _PublishedAddedMass(scene) if scene.has('published_added_mass') else None)
        if self._added is not None:
            self.body_inertia_about_a += self._added.body_about_a

    # --- tendon -------------------------------------------------------------------------------
    def tendon(self, th1: float, th3: float) -> TendonGeometry:
        return TendonGeometry(*tendon_terms(self.L1, self.L2, self.d_t, self.beta, th1, th3))

    def tendon_length(self, th1: float, th3: float) -> float:
        return self.tendon(th1, th3).length

    # --- inertia ------------------------------------------------------------------------------
    def mass(self, th3: float) -> MassMatrix:
        c, s = math.cos(th3), math.sin(th3)
        a = self.L1 * (self.x2 * s - self.y2 * c)
        da = self.L1 * (self.x2 * c + self.y2 * s)
        m2 = self.m2
        m11 = self._m11_const + 2 * m2 * a
        m12 = -m2 * a - self._arm_about_b
        m22 = self._arm_about_b
        dm11, dm12, dm22 = 2 * m2 * da, -m2 * da, 0.0
        if self._added is not None:
            a11, a12, a22, da11, da12 = self._added.matrix(c, s)
            m11, m12, m22 = m11 + a11, m12 + a12, m22 + a22
            dm11, dm12 = dm11 + da11, dm12 + da12
        return MassMatrix(m11, m12, m22, dm11, dm12, dm22)

    def body_kinetic_energy(self, w1: float) -> float:
        return 0.5 * self.body_inertia_about_a * w1 * w1

    # --- points -------------------------------------------------------------------------------
    def tip_speed(self, th3: float, w1: float, w3: float) -> float:
        """|v_tip| in mm/ms = m/s (physics.md)."""
        w2 = w1 - w3
        sq = (self.L1 ** 2 * w1 * w1 + self.L3 ** 2 * w2 * w2
              - 2 * self.L1 * self.L3 * w1 * w2 * math.cos(th3))
        return math.sqrt(max(sq, 0.0))

    def tip_power_rate(self, th3: float, w1: float, w3: float, a1: float, a3: float) -> float:
        """d/dt (v_tip^2 / 2): positive while the tip speeds up."""
        L1, L3 = self.L1, self.L3
        w2, a2 = w1 - w3, a1 - a3
        c, s = math.cos(th3), math.sin(th3)
        return (L1 * L1 * w1 * a1 + L3 * L3 * w2 * a2
                - L1 * L3 * ((a1 * w2 + w1 * a2) * c - w1 * w2 * s * w3))

    def arm_point_velocity(self, r: float, th3: float, w1: float, w3: float):
        """Velocity of the point at distance r along the arm, in the arm's (along, normal) axes,
        and the Jacobian rows of each component with respect to (w1, w3)."""
        c, s = math.cos(th3), math.sin(th3)
        j_t = (self.L1 * s, 0.0)
        j_n = (r - self.L1 * c, -r)
        return j_t[0] * w1, j_n[0] * w1 + j_n[1] * w3, j_t, j_n

    def points(self, th1: float, th3: float) -> dict:
        """World positions (mm) of pivots a and b, tendon point c, guide d, tip and both COMs."""
        b = (self.L1 * math.cos(th1), self.L1 * math.sin(th1))
        axis = th1 + math.pi - th3
        across = axis - 0.5 * math.pi
        tip = (b[0] + self.L3 * math.cos(axis), b[1] + self.L3 * math.sin(axis))
        c_angle = axis - self.beta
        c = (b[0] + self.L2 * math.cos(c_angle), b[1] + self.L2 * math.sin(c_angle))
        com1 = (self.x1 * math.sin(th1) + self.y1 * math.cos(th1),
                -self.x1 * math.cos(th1) + self.y1 * math.sin(th1))
        com2 = (b[0] + self.x2 * math.cos(across) + self.y2 * math.cos(axis),
                b[1] + self.x2 * math.sin(across) + self.y2 * math.sin(axis))
        return {'a': (0.0, 0.0), 'b': b, 'c': c, 'd': (self.d_t, 0.0), 'tip': tip,
                'com_body': com1, 'com_arm': com2}


class _AddedMass:
    """Entrained fluid as strip theory: each strip of a plate of width w moving normal to itself
    carries rho * pi * w^2 / 4 per unit length. The arm blade spans r in [L5, L3] from b; the
    body plate spans [0, L1] from a. Only normal motion entrains fluid (thin plates)."""

    def __init__(self, scene: Scene):
        g, rho = scene.geometry, scene.medium.density_g_per_mm3
        blade_width = scene.arm.blade_area_mm2 / (g.L3_mm - g.L5_mm)
        body_width = scene.body.area_mm2 / g.L1_mm
        self.per_mm_arm = rho * math.pi * blade_width ** 2 / 4.0
        per_mm_body = rho * math.pi * body_width ** 2 / 4.0
        self.body_about_a = per_mm_body * g.L1_mm ** 3 / 3.0
        lo, hi = g.L5_mm, g.L3_mm
        self.k0, self.k1, self.k2 = hi - lo, (hi ** 2 - lo ** 2) / 2, (hi ** 3 - lo ** 3) / 3
        self.L1 = g.L1_mm

    def matrix(self, c: float, s: float):
        """Arm-blade added inertia (a11, a12, a22) and d/dtheta3 of a11, a12; the body's is
        constant and sits in the body's inertia about a."""
        m, L1, k0, k1, k2 = self.per_mm_arm, self.L1, self.k0, self.k1, self.k2
        a11 = m * (k2 - 2 * L1 * c * k1 + L1 * L1 * c * c * k0) + self.body_about_a
        a12 = -m * (k2 - L1 * c * k1)
        a22 = m * k2
        da11 = m * (2 * L1 * s * k1 - 2 * L1 * L1 * c * s * k0)
        da12 = -m * L1 * s * k1
        return a11, a12, a22, da11, da12


PUBLISHED_LENGTH_SCALE = 1.8      # the authors' calibration of their added-mass lengths


class _PublishedAddedMass:
    """Entrained fluid in the form of the authors' published simulation (their Fig. S12 run), to
    reproduce it: elliptic plates whose added masses act at the centres of mass. The arm blade
    (length l from the point L5 at the tendon attachment's angle to the tip, width w = S_a / l)
    adds m_n = rho pi w l^2 / 4 to the arm COM's motion normal to the arm, m_n / 64 along it
    (aspect ratio 1/8) and rho pi w l^4 (1 - 1/64)^2 / 128 of inertia; the body plate (L1 by
    S_b / L1, with half again below it) adds 3/2 rho pi w L1^2 / 4 to its COM's motion and
    9/8 rho pi w L1^4 / 128 of inertia. Masses are scaled by 1.8, inertias by 1.8^3, as in
    theirs. The velocity terms are the consistent ones of this M(theta3)."""

    def __init__(self, scene: Scene):
        g, rho, s = scene.geometry, scene.medium.density_g_per_mm3, PUBLISHED_LENGTH_SCALE
        beta = math.radians(g.beta_deg)
        blade = math.hypot(g.L3_mm - g.L5_mm * math.cos(beta), g.L5_mm * math.sin(beta))
        width = scene.arm.blade_area_mm2 / blade
        normal = rho * math.pi * width * blade ** 2 / 4.0
        self.m_normal = normal * s
        self.m_along = normal / 64.0 * s
        self.arm_inertia = (rho * math.pi * width * blade ** 4 * (1 - 1 / 64) ** 2 / 128.0
                            * s ** 3)
        body_width = scene.body.area_mm2 / g.L1_mm
        body_mass = 1.5 * rho * math.pi * body_width * g.L1_mm ** 2 / 4.0 * s
        body_inertia = 1.125 * rho * math.pi * body_width * g.L1_mm ** 4 / 128.0 * s ** 3
        self.body_about_a = body_mass * scene.body.com_y_mm ** 2 + body_inertia
        self.L1 = g.L1_mm
        self.x2, self.y2 = scene.arm.com_x_mm, scene.arm.com_y_mm

    def matrix(self, c: float, s: float):
        """(a11, a12, a22) and d/dtheta3 of a11, a12, as _AddedMass.matrix."""
        L1, x2, y2 = self.L1, self.x2, self.y2
        jn1, jt1 = y2 - L1 * c, L1 * s + x2          # COM velocity rows: (jn1, -y2), (jt1, -x2)
        mn, mt, inertia = self.m_normal, self.m_along, self.arm_inertia
        a11 = mn * jn1 * jn1 + mt * jt1 * jt1 + inertia + self.body_about_a
        a12 = -mn * y2 * jn1 - mt * x2 * jt1 - inertia
        a22 = mn * y2 * y2 + mt * x2 * x2 + inertia
        da11 = 2 * mn * jn1 * L1 * s + 2 * mt * jt1 * L1 * c
        da12 = -mn * y2 * L1 * s - mt * x2 * L1 * c
        return a11, a12, a22, da11, da12
