"""Conversions between SI units and the APT protocol's integer units for a DC servo axis.

The APT protocol (KDC101/TDC001 family) counts position in encoder counts and expresses
velocity and acceleration per servo sample period T = 2048 / 6e6 s, scaled by 2^16:
    velocity units     = counts/s  * T   * 2^16
    acceleration units = counts/s² * T^2 * 2^16
For a Z8 actuator (34,554.96 counts/mm) that gives ≈ 772,981.4 per mm/s and ≈ 263.84 per mm/s².
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

from mantis_rig.hardware.device_interfaces import ConfigurationError

SAMPLE_PERIOD_S = 2048 / 6e6
FIXED_POINT_SCALE = 2 ** 16
Z8_COUNTS_PER_MM = 34554.96          # the APT protocol document's figure for the Z8 actuators
Z8_DATASHEET_COUNTS_PER_MM = 34304.0  # the MTS25-Z8 data sheet's rounded figure

INT32_MIN, INT32_MAX = -(2 ** 31), 2 ** 31 - 1


def velocity_units_per_mm_s(counts_per_mm: float) -> float:
    return counts_per_mm * SAMPLE_PERIOD_S * FIXED_POINT_SCALE


def acceleration_units_per_mm_s2(counts_per_mm: float) -> float:
    return counts_per_mm * SAMPLE_PERIOD_S ** 2 * FIXED_POINT_SCALE


@dataclass(frozen=True)
class AptScale:
    """Scale factors of one axis. Velocity/acceleration factors default to the protocol's
    definition from `counts_per_mm`; pass them explicitly to override (e.g. from a data sheet).

    `status_velocity_per_mm_s` scales the 16-bit velocity field of MOT_GET_USTATUSUPDATE. The
    protocol document does not pin it down; the default assumes counts per servo sample period
    (velocity units / 2^16), which fits the travel speeds of a Z8 in 16 bits. Check it on the
    hardware before trusting `StageState.velocity_m_per_s`.
    """

    counts_per_mm: float = Z8_COUNTS_PER_MM
    velocity_per_mm_s: Optional[float] = None
    acceleration_per_mm_s2: Optional[float] = None
    status_velocity_per_mm_s: Optional[float] = None

    def __post_init__(self):
        for name in ('counts_per_mm', 'velocity_per_mm_s', 'acceleration_per_mm_s2',
                     'status_velocity_per_mm_s'):
            value = getattr(self, name)
            if value is not None and not (value > 0 and math.isfinite(value)):
                raise ConfigurationError(f'{name} {value!r} must be finite and > 0')
        if self.velocity_per_mm_s is None:
            object.__setattr__(self, 'velocity_per_mm_s',
                               velocity_units_per_mm_s(self.counts_per_mm))
        if self.acceleration_per_mm_s2 is None:
            object.__setattr__(self, 'acceleration_per_mm_s2',
                               acceleration_units_per_mm_s2(self.counts_per_mm))
        if self.status_velocity_per_mm_s is None:
            object.__setattr__(self, 'status_velocity_per_mm_s',
                               self.velocity_per_mm_s / FIXED_POINT_SCALE)

    # --- SI -> device ---
    def position_to_counts(self, position_m: float) -> int:
        return _int32(position_m * 1e3 * self.counts_per_mm, 'position')

    def velocity_to_units(self, velocity_m_per_s: float) -> int:
        return _int32(velocity_m_per_s * 1e3 * self.velocity_per_mm_s, 'velocity')

    def acceleration_to_units(self, acceleration_m_per_s2: float) -> int:
        return _int32(acceleration_m_per_s2 * 1e3 * self.acceleration_per_mm_s2, 'acceleration')

    # --- device -> SI ---
    def counts_to_position_m(self, counts: int) -> float:
        return counts / self.counts_per_mm * 1e-3

    def units_to_velocity_m_per_s(self, units: int) -> float:
        return units / self.velocity_per_mm_s * 1e-3

    def units_to_acceleration_m_per_s2(self, units: int) -> float:
        return units / self.acceleration_per_mm_s2 * 1e-3

    def status_velocity_m_per_s(self, status_units: int) -> float:
        return status_units / self.status_velocity_per_mm_s * 1e-3


def _int32(value: float, what: str) -> int:
    rounded = round(value)
    if not INT32_MIN <= rounded <= INT32_MAX:
        raise ValueError(f'{what} {value:g} device units does not fit the 32-bit APT field')
    return rounded
