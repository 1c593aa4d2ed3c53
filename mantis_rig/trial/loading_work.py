"""The work the stage does on the tendon while it loads the robot's spring (no ROS): the
latest tendon force times each step of the stage, from the start of the pull to the release.

Kept by the supervisor as the trial runs (its outcome's ``loading_work_mj``), so that a study
reads it from the bag's outcome instead of reading the bag's streams again. The stage reports
its position at ``joint_state_rate_hz`` (100 Hz) and the force moves slowly while the spring
loads, so the sum differs from the integral over the 20 kS/s stream by well under 1 % (the
last step before the release, up to one stage period, is not counted).
"""
from __future__ import annotations


class LoadingWork:
    def __init__(self):
        self.mj = 0.0               # N x mm
        self.started = False
        self._active = False
        self._position_m: float | None = None

    def start(self, position_m: float | None) -> None:
        self.started = self._active = True
        self._position_m = position_m

    def step(self, position_m: float, force_n: float | None) -> None:
        if self._active and force_n is not None and self._position_m is not None:
            self.mj += force_n * (position_m - self._position_m) * 1e3
        self._position_m = position_m

    def stop(self) -> None:
        self._active = False


__all__ = ['LoadingWork']
