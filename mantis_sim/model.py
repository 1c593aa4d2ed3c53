"""The assembled equations of motion of one scene, in each contact/tendon mode.

M(q) qddot + c(q, qdot) = Q_applied(q, qdot) - F grad l_t(q) + lambda e3

- F >= 0 is the tendon tension; with a rigid tendon it is the multiplier of the moving
  constraint l_t(q) = l_free(t), with a compliant one F = k_t (l_t - l_free) + c_t d/dt(...).
- lambda >= 0 is the contact torque holding the arm on the body (latched: theta3 = phi_c).

The rigid constraint is kept in full coordinates with its multiplier (index reduction plus a
Baumgarte correction). Its Jacobian grad l_t = (l_1, l_3) keeps full rank through overcentering
(l_3 = 0), where reduced coordinates with theta1 independent would divide by l_3.
"""
from __future__ import annotations

from contextlib import contextmanager
import math
from typing import NamedTuple, Optional

import numpy as np

from .drive import make_drive
from .forces import (
    FluidDrag,
    Gravity,
    HingeStiffness,
    JointDamping,
    PublishedArmAirLoad,
    TorsionSpring,
)
from .mechanism import Mechanism
from .scene import Scene

MECHANICAL_EFFECTS = ('gravity', 'joint_damping', 'hinge_stiffness', 'fluid_drag', 'added_mass',
                      'tendon_slack', 'contact_restitution', 'stage_profile',
                      'published_arm_air_load', 'published_added_mass',
                      'tendon_force_saturation', 'pivot_friction')


class SimulationError(RuntimeError):
    """The model cannot go on (inconsistent start, no convergence); says where and why."""


class Dynamics(NamedTuple):
    """Everything the model knows at one instant (g, mm, ms, rad; N, N mm, mJ/ms)."""

    th1: float
    th3: float
    w1: float
    w3: float
    a1: float
    a3: float
    tension_N: float
    contact_torque_Nmm: float
    stage_power: float          # F * stage velocity: work done by the drive
    loss_power: float           # dissipated by damping, drag and tendon damping


def kinetic_lever(scene: Scene) -> float:
    """The pivot's braking lever while the arm slides, mm (scene.hinge)."""
    hinge = scene.hinge
    if hinge.kinetic_friction_lever_mm is not None:
        return hinge.kinetic_friction_lever_mm
    return hinge.friction_lever_mm * hinge.kinetic_friction_ratio


class Model:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.mech = Mechanism(scene)
        self.drive = make_drive(scene)
        self.terms = [TorsionSpring(scene)]
        if scene.has('hinge_stiffness'):
            self.terms.append(HingeStiffness(scene))
        if scene.has('joint_damping'):
            self.terms.append(JointDamping(scene))
        if scene.has('gravity'):
            self.terms.append(Gravity(self.mech))
        if scene.has('fluid_drag'):
            self.terms.append(FluidDrag(self.mech, scene,
                                        blade=not scene.has('published_arm_air_load')))
        if scene.has('published_arm_air_load'):
            self.terms.append(PublishedArmAirLoad(self.mech, scene))
        self.effects = tuple(e for e in MECHANICAL_EFFECTS if scene.has(e))
        self.rigid = scene.tendon.model == 'rigid'
        self.unilateral = scene.has('tendon_slack')
        self.saturation_N = (scene.tendon.saturation_N
                             if self.rigid and scene.has('tendon_force_saturation') else None)
        self.k_t = scene.tendon.stiffness_N_per_mm
        self.c_t = scene.tendon.damping_N_ms_per_mm
        self.restitution = scene.contact.restitution if scene.has('contact_restitution') else 0.0
        self.friction_lever = (scene.hinge.friction_lever_mm if scene.has('pivot_friction')
                               else 0.0)
        self.kinetic_lever = kinetic_lever(scene) if scene.has('pivot_friction') else 0.0
        self.latch_speed = scene.contact.latch_speed_rad_per_s * 1e-3
        self.contact_angle = self.mech.contact_angle
        self.kappa = scene.integration.baumgarte_per_ms
        self.l_free0 = math.nan
        self.rhs_evals = 0
        self.theta1_guess = scene.initial.theta1_rad

    # --- drive --------------------------------------------------------------------------------
    def free_length(self, t: float) -> tuple[float, float, float]:
        pulled, v, a = self.drive.pulled(t)
        return self.l_free0 - pulled, -v, -a

    # --- applied forces -----------------------------------------------------------------------
    def applied(self, th1, th3, w1, w3):
        q1 = q3 = loss = 0.0
        for term in self.terms:
            f1, f3, p = term(th1, th3, w1, w3)
            q1 += f1
            q3 += f3
            loss += p
        return q1, q3, loss

    def potential_energy(self, th1, th3, t=None) -> float:
        energy = sum(term.potential(th1, th3) for term in self.terms if hasattr(term, 'potential'))
        if not self.rigid and t is not None:
            stretch = self.mech.tendon_length(th1, th3) - self.free_length(t)[0]
            if stretch > 0 or not self.unilateral:
                energy += 0.5 * self.k_t * stretch * stretch
        return energy

    def spring_energy(self, th1) -> float:
        return self.terms[0].potential(th1, 0.0)

    def compliant_tension(self, tg, w1, w3, t, taut: bool):
        """(F, tendon damping loss) of the compliant tendon."""
        if not taut:
            return 0.0, 0.0
        l_free, l_free_dot, _ = self.free_length(t)
        stretch = tg.length - l_free
        rate = tg.d1 * w1 + tg.d3 * w3 - l_free_dot
        tension = self.k_t * stretch + self.c_t * rate
        if self.unilateral and tension < 0.0:
            tension = 0.0
        return tension, (tension - self.k_t * stretch) * rate

    # --- modes ----------------------------------------------------------------------------------
    def latched_constrained(self, t: float, th3: Optional[float] = None) -> Dynamics:
        """Arm held at th3 (the contact, or stuck by friction), taut rigid tendon: no freedom
        left; theta1 follows from l_free(t). contact_torque_Nmm is the torque the latch (or
        the friction) exerts on theta3."""
        self.rhs_evals += 1
        th3 = self.contact_angle if th3 is None else th3
        l_free, l_free_dot, l_free_ddot = self.free_length(t)
        th1, tg = self.solve_theta1(l_free, th3)
        w1 = l_free_dot / tg.d1
        a1 = (l_free_ddot - tg.d11 * w1 * w1) / tg.d1
        m = self.mech.mass(th3)
        q1, q3, loss = self.applied(th1, th3, w1, 0.0)
        c1, c3 = m.velocity_terms(w1, 0.0)
        tension = (q1 - c1 - m.m11 * a1) / tg.d1
        contact = m.m12 * a1 + c3 - q3 + tg.d3 * tension
        return Dynamics(th1, th3, w1, 0.0, a1, 0.0, tension, contact, -tension * l_free_dot, loss)

    def latched_free(self, t, th1, w1, taut: bool, th3: Optional[float] = None) -> Dynamics:
        """Arm held at th3 (default: the contact), tendon slack or compliant: theta1 is the
        one freedom."""
        self.rhs_evals += 1
        th3 = self.contact_angle if th3 is None else th3
        m = self.mech.mass(th3)
        q1, q3, loss = self.applied(th1, th3, w1, 0.0)
        tension = 0.0
        if not self.rigid:
            tg = self.mech.tendon(th1, th3)
            tension, tendon_loss = self.compliant_tension(tg, w1, 0.0, t, taut)
            q1 -= tension * tg.d1
            q3 -= tension * tg.d3
            loss += tendon_loss
        c1, c3 = m.velocity_terms(w1, 0.0)
        a1 = (q1 - c1) / m.m11
        contact = m.m12 * a1 + c3 - q3
        return Dynamics(th1, th3, w1, 0.0, a1, 0.0, tension, contact,
                        -tension * self.free_length(t)[1], loss)

    def unlatched(self, t, th1, th3, w1, w3, taut: bool, saturated: bool = False,
                  slip: float = 1.0) -> Dynamics:
        """Arm free of the body; rigid taut tendon as a constraint, else a force (or none).
        ``saturated``: the rigid tendon yields at its saturation tension (it stretches at that
        constant force; what it takes from the drive's work is booked as loss). With
        pivot_friction the pivot brakes the arm by lever x tension against its motion
        (``slip``: +1 opening, -1 closing)."""
        self.rhs_evals += 1
        m = self.mech.mass(th3)
        q1, q3, loss = self.applied(th1, th3, w1, w3)
        c1, c3 = m.velocity_terms(w1, w3)
        f1, f3 = q1 - c1, q3 - c3
        tension = 0.0
        # friction torque on theta3 per newton of tension, against the way the arm moves: that
        # way is the mode's (``slip``), constant within a segment, so that no sign flips inside
        # an integration step; the simulator ends the segment where w3 crosses zero.
        per_newton = -slip * self.kinetic_lever
        l_free, l_free_dot, l_free_ddot = self.free_length(t)
        if saturated:
            tg = self.mech.tendon(th1, th3)
            tension = self.saturation_N
            f1 -= tension * tg.d1
            f3 -= tension * (tg.d3 - per_newton)
            loss += tension * (tg.d1 * w1 + tg.d3 * w3 - l_free_dot)
            a1, a3 = m.solve(f1, f3)
        elif self.rigid and taut:
            tg = self.mech.tendon(th1, th3)
            rate_error = tg.d1 * w1 + tg.d3 * w3 - l_free_dot
            curvature = tg.d11 * w1 * w1 + 2 * tg.d13 * w1 * w3 + tg.d33 * w3 * w3
            k = self.kappa
            gamma = (l_free_ddot - curvature - 2 * k * rate_error
                     - k * k * (tg.length - l_free))
            # M a = f - F (grad l - per_newton e3): the friction grows with the multiplier F
            u1, u3 = m.solve(tg.d1, tg.d3 - per_newton)
            a1_free, a3_free = m.solve(f1, f3)
            tension = ((tg.d1 * a1_free + tg.d3 * a3_free - gamma)
                       / (tg.d1 * u1 + tg.d3 * u3))
            a1, a3 = a1_free - u1 * tension, a3_free - u3 * tension
        else:
            if not self.rigid:
                tg = self.mech.tendon(th1, th3)
                tension, tendon_loss = self.compliant_tension(tg, w1, w3, t, taut)
                f1 -= tension * tg.d1
                f3 -= tension * (tg.d3 - per_newton)
                loss += tendon_loss
            a1, a3 = m.solve(f1, f3)
        loss += self.kinetic_lever * abs(tension * w3)
        return Dynamics(th1, th3, w1, w3, a1, a3, tension, 0.0, -tension * l_free_dot, loss)

    def friction_limit(self, d: Dynamics) -> float:
        """The most torque the pivot's friction can hold (N mm): lever x tension."""
        return self.friction_lever * abs(d.tension_N)

    def latch_margin(self, d: Dynamics) -> float:
        """How much more opening torque an arm on the body can hold (N mm): the contact
        torque, plus the pivot friction where the scene has it. It lets go at zero."""
        return d.contact_torque_Nmm + self.friction_limit(d)

    # --- helpers --------------------------------------------------------------------------------
    def held_pose(self, times_ms, th3: Optional[float],
                  start_theta1: float) -> tuple[np.ndarray, np.ndarray]:
        """(theta1, omega1) of the arm held at th3 (default: the contact) on a taut rigid
        tendon at each time: latched_constrained's kinematics without its forces, which follow
        from the stage alone."""
        th3 = self.contact_angle if th3 is None else th3
        times_ms = np.asarray(times_ms, dtype=float)
        th1, w1 = np.empty(times_ms.size), np.empty(times_ms.size)
        with self._newton_from(start_theta1):
            for i, t in enumerate(times_ms.tolist()):
                l_free, l_free_dot, _ = self.free_length(t)
                th1[i], tg = self.solve_theta1(l_free, th3)
                w1[i] = l_free_dot / tg.d1
        return th1, w1

    def held_tensions(self, times_ms, th3: Optional[float], start_theta1: float) -> np.ndarray:
        """The tendon tension (N) holding that arm at each time (latched_constrained's)."""
        with self._newton_from(start_theta1):
            return np.array([self.latched_constrained(t, th3).tension_N
                             for t in np.asarray(times_ms, dtype=float).tolist()])

    @contextmanager
    def _newton_from(self, start_theta1: float):
        """theta1's Newton starts from start_theta1 (the root a held segment followed), then
        from the time before; the guess the integrator shares is left as it was."""
        saved, self.theta1_guess = self.theta1_guess, start_theta1
        try:
            yield
        finally:
            self.theta1_guess = saved

    def solve_theta1(self, l_target: float, th3: float):
        """(theta1, its TendonGeometry) with l_t(theta1, th3) = l_target, by Newton from the
        last solution. The geometry of the converged iterate is returned with it, so the
        caller does not evaluate it once more."""
        th1 = self.theta1_guess
        for _ in range(50):
            tg = self.mech.tendon(th1, th3)
            step = (tg.length - l_target) / tg.d1
            if abs(step) < 1e-14:
                self.theta1_guess = th1
                return th1, tg
            th1 -= step
        raise SimulationError(f'the latched pose cannot reach tendon length {l_target:.6f} mm '
                              f'(Newton on theta1 did not converge near {th1:.6f} rad)')

    def initial_tension(self, th1: float, th3: float) -> tuple[float, float]:
        """Static tension F and contact torque lambda holding the start pose (latched, at rest)."""
        tg = self.mech.tendon(th1, th3)
        q1, q3, _ = self.applied(th1, th3, 0.0, 0.0)
        tension = q1 / tg.d1
        return tension, tension * tg.d3 - q3

    def kinetic_energy(self, th3, w1, w3) -> float:
        return self.mech.mass(th3).kinetic_energy(w1, w3)
