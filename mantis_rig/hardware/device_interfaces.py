"""Device interfaces of the rig: what a node may ask of a stage, a force DAQ and a camera trigger.

Every quantity is SI (m, s, N, V). Each device has a real backend (hardware) and a simulated
backend (driven by mantis_sim); nodes only see these interfaces. All devices are context
managers: leaving the `with` block releases the device even after an error.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field, fields
import math
from typing import Optional

import numpy as np

# the device faults, under mantis_rig.faults.RigFault; imported from here by the backends
from mantis_rig.faults import ConfigurationError, DeviceError, SafetyLimitError  # noqa: F401

# The rig's hardware envelope (shared/docs/rig.md): no configuration may go beyond it.
STAGE_TRAVEL_M = 25e-3                 # MTS25/M-Z8 travel, 0 at the home (reverse) end
STAGE_MAX_SPEED_M_PER_S = 2.4e-3       # MTS25/M-Z8 maximum speed
LOADCELL_CAPACITY_N = 111.0            # Futek LSB302, 25 lb


class Device(abc.ABC):
    """Common life cycle: open() acquires the device, close() releases it (idempotent)."""

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device (open the port or task) and check that it answers."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device. Safe to call twice and after a failed open()."""

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()
        return False


# --- translation stage -----------------------------------------------------------------------

@dataclass(frozen=True)
class StageInfo:
    model: str
    serial_number: str
    firmware: str


@dataclass(frozen=True)
class StageState:
    position_m: float
    velocity_m_per_s: float
    moving: bool
    homed: bool
    forward_limit: bool
    reverse_limit: bool
    fault: Optional[str] = None


@dataclass(frozen=True)
class StageLimits:
    """Safety envelope enforced inside the driver layer, whatever the caller asks."""

    min_position_m: float = 0.5e-3
    max_position_m: float = 24.5e-3
    max_speed_m_per_s: float = 2.4e-3
    max_acceleration_m_per_s2: float = 4.0e-3

    def __post_init__(self):
        """Refuse an envelope that is not inside the stage's travel and speed."""
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ConfigurationError(f'stage limit {f.name} {value!r} must be a finite number')
        travel_mm = STAGE_TRAVEL_M * 1e3
        if self.min_position_m < 0.0:
            raise ConfigurationError(
                f'soft travel limit min_position_m {self.min_position_m * 1e3:g} mm is outside '
                f'the stage travel [0, {travel_mm:g}] mm')
        if self.max_position_m > STAGE_TRAVEL_M:
            raise ConfigurationError(
                f'soft travel limit max_position_m {self.max_position_m * 1e3:g} mm is outside '
                f'the stage travel [0, {travel_mm:g}] mm')
        if not self.min_position_m < self.max_position_m:
            raise ConfigurationError(
                f'soft travel limits are empty: min_position_m {self.min_position_m * 1e3:g} mm '
                f'must be below max_position_m {self.max_position_m * 1e3:g} mm')
        if not 0.0 < self.max_speed_m_per_s <= STAGE_MAX_SPEED_M_PER_S:
            raise ConfigurationError(
                f'speed ceiling max_speed_m_per_s {self.max_speed_m_per_s * 1e3:g} mm/s must be '
                f'> 0 and at most the stage maximum {STAGE_MAX_SPEED_M_PER_S * 1e3:g} mm/s')
        if not self.max_acceleration_m_per_s2 > 0.0:
            raise ConfigurationError(
                f'max_acceleration_m_per_s2 {self.max_acceleration_m_per_s2 * 1e3:g} mm/s² '
                f'must be > 0 mm/s²')

    def check_position(self, position_m: float) -> None:
        if not (self.min_position_m <= position_m <= self.max_position_m):
            raise ConfigurationError(
                f'stage position {position_m * 1e3:.4f} mm is outside the soft travel limits '
                f'[{self.min_position_m * 1e3:.3f}, {self.max_position_m * 1e3:.3f}] mm')

    def check_bound(self, velocity_m_per_s: float, here_m: float, bound_m: float) -> None:
        """Refuse a bound for a move at velocity_m_per_s from here_m that is not ahead of the
        stage in the direction of travel, or not inside the soft limits."""
        self.check_position(bound_m)
        if (bound_m - here_m) * velocity_m_per_s <= 0:
            raise ConfigurationError(
                f'bound {bound_m * 1e3:.4f} mm of a move at {velocity_m_per_s * 1e3:+.4f} mm/s '
                f'is not ahead of the stage at {here_m * 1e3:.4f} mm')

    def check_speed(self, speed_m_per_s: float) -> None:
        if not (0.0 <= abs(speed_m_per_s) <= self.max_speed_m_per_s):
            raise ConfigurationError(
                f'stage speed {abs(speed_m_per_s) * 1e3:.4f} mm/s exceeds the ceiling '
                f'{self.max_speed_m_per_s * 1e3:.3f} mm/s')


class Stage(Device):
    """A linear translation stage. Positive velocity increases the position."""

    limits: StageLimits

    @abc.abstractmethod
    def identify(self) -> StageInfo: ...

    @abc.abstractmethod
    def home(self, timeout_s: float = 60.0) -> None:
        """Home and block until homed; raise DeviceError on timeout or fault."""

    @abc.abstractmethod
    def move_to(self, position_m: float, speed_m_per_s: float, timeout_s: float = 60.0) -> None:
        """Move to an absolute position at the given speed and block until it is reached."""

    @abc.abstractmethod
    def move_at(self, velocity_m_per_s: float, bound_m: Optional[float] = None) -> None:
        """Start moving at a constant velocity (sign gives direction); returns at once.

        With ``bound_m`` (a position ahead in the direction of travel, inside the soft limits)
        the move is a bounded one: the controller itself is told to stop there, as an absolute
        move at this speed that ends at rest on ``bound_m``, so that the stage stops there
        even if nothing commands it again (its driver's process dead). Without, the stage
        moves until stopped or until the driver's soft-limit check stops it."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop at once (abort). Never raises for an already stopped stage."""

    @abc.abstractmethod
    def state(self) -> StageState: ...


# --- force DAQ --------------------------------------------------------------------------------

@dataclass(frozen=True)
class DaqConfig:
    channel: str = 'Dev1/ai0'
    sample_rate_hz: float = 20_000.0
    input_range_v: float = 10.0
    newtons_per_volt: float = 11.12      # Futek IAA100 set to 10 V at 111 N (25 lb)
    offset_v: float = 0.0                # tare: the voltage read with the tendon slack
    block_size: int = 1000               # samples per read


@dataclass(frozen=True)
class ForceBlock:
    """A block of consecutive load-cell samples, SI: sample i [N] was taken at
    t0_s + i * period_s [s].

    The rig's one type of force data: a DAQ's read (device clock), and the same block on
    /loadcell/force_block and in bags (ROS time; recording.force_block carries it).
    """

    t0_s: float
    period_s: float
    force_n: np.ndarray
    first_index: Optional[int] = None    # index of the first sample since start() (DAQ reads)
    overrun: bool = False                 # samples were lost before this block

    @property
    def end_s(self) -> float:
        """The time one period after its last sample, s: where the next block starts."""
        return self.t0_s + self.period_s * self.force_n.size


class ForceDaq(Device):
    max_sample_rate_hz: float

    @abc.abstractmethod
    def configure(self, config: DaqConfig) -> None:
        """Validate and apply; raise ConfigurationError naming the value and the limit."""

    @abc.abstractmethod
    def start(self) -> None: ...

    @abc.abstractmethod
    def stop(self) -> None: ...

    @abc.abstractmethod
    def read_block(self, timeout_s: float = 1.0) -> ForceBlock:
        """The next block of `block_size` samples, in order, none skipped."""

    @abc.abstractmethod
    def tare(self, duration_s: float = 0.2) -> float:
        """Average the input for a while, make that zero force; return the new offset in V."""


# --- camera trigger -----------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraConfig:
    frame_rate_hz: float = 19_000.0
    pre_trigger_s: float = 0.05
    post_trigger_s: float = 0.05


@dataclass(frozen=True)
class CameraStatus:
    armed: bool
    triggered: bool
    trigger_time_s: Optional[float] = None


@dataclass
class MarkerFrames:
    """Marker positions per frame, SI: metres in the camera frame (the tracker's convention:
    left-handed, image y down, unless a bag's trial conditions say otherwise), times in
    seconds; a lost marker is NaN.

    The rig's one type of marker data: the simulated camera's recording (device clock), and
    the same frames on /camera/markers and in bags (ROS time; recording.marker_block carries
    them). The analysis reads them as MarkerTracks, in millimetres like the tracker's exports.
    """

    time_s: np.ndarray                     # (n,)
    markers_m: dict = field(default_factory=dict)    # name -> (n, 2) array; mb1..mb3, ma1, ma2

    def __len__(self) -> int:
        return len(self.time_s)


def check_camera_config(config: CameraConfig, max_frame_rate_hz: float) -> None:
    """Refuse a frame rate outside (0, max] and pre/post-trigger durations that are not >= 0."""
    rate_hz = config.frame_rate_hz
    if not rate_hz > 0:
        raise ConfigurationError(f'frame rate {rate_hz} frames/s must be > 0 frames/s')
    if rate_hz > max_frame_rate_hz:
        raise ConfigurationError(f'frame rate {rate_hz:g} frames/s exceeds the camera '
                                 f'ceiling {max_frame_rate_hz:g} frames/s')
    for name in ('pre_trigger_s', 'post_trigger_s'):
        value = getattr(config, name)
        if not (value >= 0 and math.isfinite(value)):
            raise ConfigurationError(f'{name} {value} s must be finite and ≥ 0 s')


class FilmError(DeviceError):
    """A camera that films its recorded window (the simulated one: `film_dir`) could not; the
    message says why."""


class CameraTrigger(Device):
    max_frame_rate_hz: float

    @abc.abstractmethod
    def arm(self, config: CameraConfig) -> None: ...

    @abc.abstractmethod
    def trigger(self) -> float:
        """Fire the trigger now; return its time in seconds (device clock)."""

    @abc.abstractmethod
    def status(self) -> CameraStatus: ...

    def frame_timestamps(self) -> Optional[np.ndarray]:
        """Frame times in seconds where the hardware reports them, else None."""
        return None

    def marker_frames(self) -> Optional[MarkerFrames]:
        """Marker tracks of the recorded window where the backend has them (simulation)."""
        return None
