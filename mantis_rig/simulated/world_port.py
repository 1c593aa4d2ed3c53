"""How the simulated backends reach the simulated world (mantis_sim.world.World).

The backends (sim_stage, sim_force, sim_camera) only see a WorldPort: a LocalWorldPort, which
wraps a World that a WorldRunner thread advances in simulated time, in the same process (the
simulated rig, mantis_rig.simulated.sim_rig). Times are simulated seconds.
"""
from __future__ import annotations

import abc
from typing import TYPE_CHECKING

import numpy as np

from mantis_rig.hardware.device_interfaces import DeviceError

if TYPE_CHECKING:
    from mantis_sim.camera.recorded_pose import RecordedPose


class WorldPort(abc.ABC):
    @abc.abstractmethod
    def now_s(self) -> float:
        """The simulated time the world has reached."""

    @abc.abstractmethod
    def wait_until(self, t_s: float, timeout_s: float) -> None:
        """Block until the world has reached t_s; DeviceError after timeout_s of wall time."""

    @abc.abstractmethod
    def set_stage_velocity(self, velocity_m_per_s: float) -> None:
        """Command the simulated stage; takes effect at the world's current time."""

    @abc.abstractmethod
    def move_stage_to(self, position_m: float, speed_m_per_s: float) -> None:
        """Start a move of the simulated stage to position_m, ending at rest on it."""

    @abc.abstractmethod
    def stage_state(self) -> tuple[float, float]:
        """(position m, velocity m/s) of the simulated stage now."""

    @abc.abstractmethod
    def tendon_force(self, t0_s: float, period_s: float, n: int,
                     timeout_s: float) -> np.ndarray:
        """True tendon tension N at t0_s + i * period_s (i < n); blocks until simulated."""

    @abc.abstractmethod
    def marker_frames(self, times_s: np.ndarray, timeout_s: float) -> dict:
        """True marker positions (name -> (n, 2) m, camera frame) at times_s; blocks until
        simulated. Times older than the world's history raise DeviceError."""

    def record_frames(self, frame_times_s: np.ndarray, tolerance_mm: float,
                      timeout_s: float) -> RecordedPose:
        """The mechanism's true pose for filming the frames at frame_times_s, taken at once
        (the world forgets and runs on while a film renders): a
        mantis_sim.camera.recorded_pose.RecordedPose (record_frames: every frame, and finer
        where a point moves more than tolerance_mm a frame), with the medium the robot struck
        in; blocks until simulated one frame past the last. A port that cannot give it raises
        DeviceError."""
        raise DeviceError(f'{type(self).__name__} cannot give the poses a film needs')


class WorldTimeout(DeviceError):
    """The simulated world did not reach the asked time in the allowed wall time."""
