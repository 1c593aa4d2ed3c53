"""A very stiff compliant tendon, solved in its rigid limit when its compliance cannot show.

A tendon of 1e6 N/mm rings at tens of kHz against the linkage's inertia; resolving that ringing
costs an implicit solver four times the rigid tendon's steps, yet the strike does not feel it:
what the tendon's stretch takes from the strike is of the order of the elastic energy it holds
at its peak force, F_max^2 / (2 k), against the spring energy E released. So the fast path
solves the scene with a rigid tendon first and keeps that run when

    effect = SAFETY * F_max^2 / (2 k E_spring)  <  integration.rigid_tendon_below;

otherwise it solves the compliant tendon. SAFETY covers how far the estimate falls below the
true change of peak tip speed (air_23mm_compliant: 2.7x at 1e6 N/mm, 2.9x at 1e4, 4.6x at 50).
"""
from __future__ import annotations

from typing import Optional

from .scene import Scene

SAFETY = 10.0
# Below this stiffness the limit is not even tried: the compliance of the shipped robots' tendon
# changes their strike by more than 1e-4 there (air_23mm_compliant: 5e-4 at 1e4 N/mm, 16 % at
# 50), and the rigid run would be wasted.
TRY_ABOVE_N_PER_MM = 1e4


def rigid_limit(scene: Scene) -> Optional[Scene]:
    """The scene with its tendon rigid, where the fast path may use that limit (else None)."""
    if (scene.integration.solver != 'fast' or scene.tendon.model != 'compliant'
            or scene.integration.rigid_tendon_below <= 0.0
            or scene.tendon.stiffness_N_per_mm < TRY_ABOVE_N_PER_MM
            or scene.has('tendon_force_saturation')):    # a rigid tendon would saturate
        return None
    return scene.with_values({'tendon.model': 'rigid'})


def compliance_effect(scene: Scene, peak_tendon_force_N: float,
                      spring_energy_mJ: float) -> float:
    """The estimated relative effect of the scene's tendon compliance on its strike, from its
    rigid limit's peak tendon force and spring energy (module docstring)."""
    if spring_energy_mJ <= 0.0:
        return float('inf')
    elastic_mJ = peak_tendon_force_N ** 2 / (2.0 * scene.tendon.stiffness_N_per_mm)
    return SAFETY * elastic_mJ / spring_energy_mJ
