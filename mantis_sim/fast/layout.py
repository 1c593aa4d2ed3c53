"""The compiled engine's view of a scene: one float64 vector of the model's constants.

The names below are the vector's indices; `pack` fills it from a built `Model` (so that both
engines read the same numbers: the Python model is where they are derived and documented).
Units as the model's: g, mm, ms, rad, N.
"""
from __future__ import annotations

import math

import numpy as np

FIELDS = (
    # geometry and inertia (mantis_sim.mechanism)
    'L1', 'L2', 'L3', 'L5', 'D_T', 'BETA', 'CONTACT', 'M1', 'M2', 'X1', 'Y1', 'X2', 'Y2',
    'M11_CONST', 'ARM_ABOUT_B', 'BODY_ABOUT_A',
    # added mass: kind 0 none, 1 strip theory, 2 the authors' published form
    'ADDED_KIND', 'ADDED_BODY_ABOUT_A', 'STRIP_PER_MM', 'STRIP_K0', 'STRIP_K1', 'STRIP_K2',
    'PUB_M_NORMAL', 'PUB_M_ALONG', 'PUB_ARM_INERTIA',
    # applied forces (mantis_sim.forces)
    'SPRING_K', 'SPRING_REST',
    'HINGE_ON', 'HINGE_K', 'HINGE_REST',
    'DAMPING_ON', 'DAMPING_C1', 'DAMPING_C3',
    'GRAVITY_ON', 'GRAVITY_X', 'GRAVITY_Y',
    'DRAG_ON', 'DRAG_BLADE', 'DRAG_BODY', 'STRIP_R0', 'STRIP_R1', 'STRIP_R2',
    'STRIP_A0', 'STRIP_A1', 'STRIP_A2', 'DRAG_EPS_SQ', 'DRAG_EDGE_ON', 'DRAG_RISE',
    'LIFT_TWICE',
    'AIRLOAD_ON', 'AIRLOAD_HALF_RHO_AREA', 'AIRLOAD_ALONG', 'AIRLOAD_ACROSS',
    'AIRLOAD_BLADE_T', 'AIRLOAD_BLADE_N',
    # tendon and pivot (mantis_sim.model)
    'RIGID', 'UNILATERAL', 'SATURATION', 'K_T', 'C_T', 'FRICTION_LEVER', 'KINETIC_LEVER',
    'KAPPA', 'L_FREE0',
    # drive: kind 0 constant pull, 1 ramped pull, 2 commanded knots (passed beside)
    # (a strike of mantis_sim.world sees the commanded stage from its latch: world time
    # DRIVE_T0 ms, pulled DRIVE_X0 mm)
    'DRIVE_KIND', 'DRIVE_V', 'DRIVE_A', 'DRIVE_TAU', 'DRIVE_T_RAMP', 'DRIVE_T0', 'DRIVE_X0',
)
INDEX = {name: i for i, name in enumerate(FIELDS)}
SIZE = len(FIELDS)
DRIVE_CONSTANT, DRIVE_RAMPED, DRIVE_KNOTS = 0, 1, 2

# The kinds of event function (hybrid.HybridSimulator._event_specs): value + a constant.
(EV_LATCH_MARGIN, EV_SLIP, EV_RECONTACT, EV_ARM_STOPS, EV_STRETCH, EV_TENSION,
 EV_TAUT_TENSION, EV_OVERCENTER, EV_MAX_CONTRACTION, EV_PEAK) = range(10)


def pack(model) -> np.ndarray:
    """The vector of a built mantis_sim.model.Model (l_free0 as it is now)."""
    from ..drive import CommandedPull, ConstantPull, RampedPull
    from ..forces import FluidDrag, Gravity, HingeStiffness, JointDamping, PublishedArmAirLoad
    from ..mechanism import _AddedMass, _PublishedAddedMass

    p = np.zeros(SIZE)

    def put(**values):
        for name, value in values.items():
            p[INDEX[name]] = value

    mech = model.mech
    put(L1=mech.L1, L2=mech.L2, L3=mech.L3, L5=mech.L5, D_T=mech.d_t, BETA=mech.beta,
        CONTACT=mech.contact_angle, M1=mech.m1, M2=mech.m2, X1=mech.x1, Y1=mech.y1,
        X2=mech.x2, Y2=mech.y2, M11_CONST=mech._m11_const, ARM_ABOUT_B=mech._arm_about_b,
        BODY_ABOUT_A=mech.body_inertia_about_a)
    added = mech._added
    if isinstance(added, _AddedMass):
        put(ADDED_KIND=1, ADDED_BODY_ABOUT_A=added.body_about_a, STRIP_PER_MM=added.per_mm_arm,
            STRIP_K0=added.k0, STRIP_K1=added.k1, STRIP_K2=added.k2)
    elif isinstance(added, _PublishedAddedMass):
        put(ADDED_KIND=2, ADDED_BODY_ABOUT_A=added.body_about_a, PUB_M_NORMAL=added.m_normal,
            PUB_M_ALONG=added.m_along, PUB_ARM_INERTIA=added.arm_inertia)
    spring = model.terms[0]
    put(SPRING_K=spring.k, SPRING_REST=spring.rest)
    for term in model.terms[1:]:
        if isinstance(term, HingeStiffness):
            put(HINGE_ON=1, HINGE_K=term.k, HINGE_REST=term.rest)
        elif isinstance(term, JointDamping):
            put(DAMPING_ON=1, DAMPING_C1=term.c1, DAMPING_C3=term.c3)
        elif isinstance(term, Gravity):
            put(GRAVITY_ON=1, GRAVITY_X=term.gx, GRAVITY_Y=term.gy)
        elif isinstance(term, FluidDrag):
            (r0, a0), (r1, a1), (r2, a2) = term.strips
            put(DRAG_ON=1, DRAG_BLADE=float(term.blade), DRAG_BODY=term.body_coeff,
                STRIP_R0=r0, STRIP_R1=r1, STRIP_R2=r2, STRIP_A0=a0, STRIP_A1=a1, STRIP_A2=a2,
                DRAG_EPS_SQ=term.eps_sq, DRAG_EDGE_ON=term.drag_edge_on,
                DRAG_RISE=term.drag_rise, LIFT_TWICE=term.lift_twice)
        elif isinstance(term, PublishedArmAirLoad):
            put(AIRLOAD_ON=1, AIRLOAD_HALF_RHO_AREA=term.half_rho_area,
                AIRLOAD_ALONG=term.r_along, AIRLOAD_ACROSS=term.r_across,
                AIRLOAD_BLADE_T=term.blade[0], AIRLOAD_BLADE_N=term.blade[1])
        else:
            raise TypeError(f'the compiled engine has no force term {type(term).__name__}')
    put(RIGID=float(model.rigid), UNILATERAL=float(model.unilateral),
        SATURATION=math.nan if model.saturation_N is None else model.saturation_N,
        K_T=model.k_t, C_T=model.c_t, FRICTION_LEVER=model.friction_lever,
        KINETIC_LEVER=model.kinetic_lever, KAPPA=model.kappa, L_FREE0=model.l_free0)
    drive = model.drive
    if isinstance(drive, ConstantPull):
        put(DRIVE_KIND=DRIVE_CONSTANT, DRIVE_V=drive.v)
    elif isinstance(drive, RampedPull):
        put(DRIVE_KIND=DRIVE_RAMPED, DRIVE_V=drive.v, DRIVE_A=drive.a, DRIVE_TAU=drive.tau,
            DRIVE_T_RAMP=drive.t_ramp)
    elif isinstance(drive, CommandedPull):
        put(DRIVE_KIND=DRIVE_KNOTS)
    elif isinstance(getattr(drive, 'drive', None), CommandedPull):     # world._StrikeDrive
        put(DRIVE_KIND=DRIVE_KNOTS, DRIVE_T0=drive.t0_ms, DRIVE_X0=drive.x0_mm)
    else:
        raise TypeError(f'the compiled engine has no drive {type(drive).__name__}')
    return p


NO_KNOTS = np.zeros((1, 4))


def knots(model) -> np.ndarray:
    """The commanded stage's knots (world t ms, pulled mm, v mm/ms, a mm/ms^2), one row each;
    a row of zeros for the other drives."""
    drive = model.drive
    rows = getattr(drive, 'knots', None) or getattr(getattr(drive, 'drive', None), 'knots', None)
    return np.asarray(rows, dtype=float) if rows else NO_KNOTS
