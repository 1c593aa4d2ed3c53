"""Spring, kinetic and tendon energies (g, mm, ms internally: energies in mJ).

Model θ1 from the tracked body angle: θ1_model = θ1_cam + offset. The spring zero θ1₀ = π + α
is defined against the model's x axis (pivot a → guide hole d), which the camera does not see.
The caller fixes the offset with one of:
- ``guide_direction_cam_rad``: direction a → d measured in the right-handed camera frame
  (y flipped from the tracker's), then θ1_model = θ1_cam − guide_direction_cam_rad. The
  analysis default is 0: the camera's x axis runs from the pivot towards the guide, as on the
  simulated rig and in the authors' published θ1; or
- ``theta1_start_rad``: the model θ1 at the first frame (a set-up angle, e.g. 2.4812 rad in
  the simulation's reference parameters).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class InertiaParams:
    """Masses (g), inertias about the COM (g·mm²), COM offsets in each body's frame (mm)."""

    m1_g: float = 0.53
    I1_gmm2: float = 28.08
    com1_mm: tuple[float, float] = (6.53, 10.98)
    m2_g: float = 0.115
    I2_gmm2: float = 2.76
    com2_mm: tuple[float, float] = (1.36, 3.78)


def model_theta1(theta1_cam_rad: np.ndarray, theta1_start_rad: float | None = None,
                 guide_direction_cam_rad: float | None = None) -> np.ndarray:
    if guide_direction_cam_rad is not None:
        return theta1_cam_rad - guide_direction_cam_rad
    if theta1_start_rad is None:
        raise ValueError('need theta1_start_rad or guide_direction_cam_rad to map θ1')
    return theta1_cam_rad - theta1_cam_rad[0] + theta1_start_rad


def spring_energy_mJ(theta1_rad: np.ndarray, k_s_Nmm_per_rad: float,
                     theta1_rest_rad: float) -> np.ndarray:
    return 0.5 * k_s_Nmm_per_rad * (theta1_rad - theta1_rest_rad) ** 2


def kinetic_energies_mJ(L1_mm: float, theta3_rad: np.ndarray, omega1_radps: np.ndarray,
                        omega3_radps: np.ndarray, inertia: InertiaParams,
                        ) -> tuple[np.ndarray, np.ndarray]:
    """(body, arm) kinetic energy from the mass matrix of physics.md."""
    w1 = 1e-3 * omega1_radps   # rad/ms
    w3 = 1e-3 * omega3_radps
    x2, y2 = inertia.com2_mm
    r1_sq = inertia.com1_mm[0] ** 2 + inertia.com1_mm[1] ** 2
    r2_sq = x2 ** 2 + y2 ** 2
    a = L1_mm * (x2 * np.sin(theta3_rad) - y2 * np.cos(theta3_rad))
    body = 0.5 * (inertia.m1_g * r1_sq + inertia.I1_gmm2) * w1 ** 2
    arm11 = inertia.m2_g * (L1_mm ** 2 + r2_sq + 2.0 * a) + inertia.I2_gmm2
    arm12 = -inertia.m2_g * (r2_sq + a) - inertia.I2_gmm2
    arm22 = inertia.m2_g * r2_sq + inertia.I2_gmm2
    arm = 0.5 * arm11 * w1 ** 2 + arm12 * w1 * w3 + 0.5 * arm22 * w3 ** 2
    return body, arm


def tendon_length_mm(theta1_rad: np.ndarray, theta3_rad: np.ndarray, L1_mm: float,
                     L2_mm: float, beta_rad: float, d_t_mm: float) -> np.ndarray:
    lt_sq = (L1_mm ** 2 + L2_mm ** 2 + d_t_mm ** 2
             - 2.0 * L1_mm * L2_mm * np.cos(theta3_rad + beta_rad)
             - 2.0 * d_t_mm * (L1_mm * np.cos(theta1_rad)
                               - L2_mm * np.cos(theta1_rad - theta3_rad - beta_rad)))
    return np.sqrt(lt_sq)


def tendon_work_mJ(force_N: np.ndarray, tendon_length_mm: np.ndarray) -> np.ndarray:
    """Cumulative work done on the mechanism by the tension, −∫F dl_t (N·mm = mJ)."""
    dl = np.diff(tendon_length_mm)
    f_mid = 0.5 * (force_N[1:] + force_N[:-1])
    return np.concatenate([[0.0], np.cumsum(-f_mid * dl)])
