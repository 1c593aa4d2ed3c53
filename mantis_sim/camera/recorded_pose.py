"""A pose function recorded once, for filming later (``docs/simulated_rig.md``, "Filming").

The simulated world keeps its history for a couple of seconds and, at real-time factor 0, runs
on while a film renders: the poses a film needs are taken from it at once (:func:`record_frames`:
at every frame time and one frame interval on each side, which covers every exposure's
sub-frames, and :data:`SAMPLES_PER_FRAME` samples per frame interval where the mechanism moves,
the strike), and the renderer (:mod:`.render`) reads them back through :class:`RecordedPose`,
which interpolates linearly between the samples. The samples hold the frame times themselves,
so a marker at a frame's time is the world's; between samples it stays within 0.01 px of the
world's (``test/unit/test_recorded_pose.py``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .render import Pose

__all__ = ['SAMPLES_PER_FRAME', 'RecordedPose', 'record_frames', 'record_pose']

#: samples per frame interval on the recorded grid
SAMPLES_PER_FRAME = 16
#: how far (s) a time asked for may lie outside the grid (float rounding of its ends)
EDGE_TOLERANCE_S = 1e-9


@dataclass(frozen=True)
class RecordedPose:
    """Poses sampled at ``times_s`` (increasing), callable as a pose function: ``pose(times)``
    interpolates each point linearly; a time outside the samples raises ValueError."""

    times_s: np.ndarray
    pose: Pose
    medium: str = 'air'            # what the robot struck in (the film's look)

    def __post_init__(self):
        times = np.asarray(self.times_s, float)
        if times.ndim != 1 or times.size < 2 or not np.all(np.diff(times) > 0):
            raise ValueError('a recorded pose needs at least two increasing sample times')
        for name, xy in (('a', self.pose.a_mm), ('b', self.pose.b_mm),
                         ('tip', self.pose.tip_mm), *self.pose.markers_mm.items()):
            if np.shape(xy) != (times.size, 2):
                raise ValueError(f'recorded pose: {name} has shape {np.shape(xy)}, expected '
                                 f'({times.size}, 2)')

    @property
    def start_s(self) -> float:
        return float(self.times_s[0])

    @property
    def stop_s(self) -> float:
        return float(self.times_s[-1])

    def __call__(self, times_s) -> Pose:
        times = np.atleast_1d(np.asarray(times_s, float))
        if times.size and (times.min() < self.start_s - EDGE_TOLERANCE_S
                           or times.max() > self.stop_s + EDGE_TOLERANCE_S):
            raise ValueError(f'asked for the pose at {times.min():.6f}..{times.max():.6f} s; '
                             f'recorded {self.start_s:.6f}..{self.stop_s:.6f} s')
        p = self.pose
        return Pose(self._at(p.a_mm, times), self._at(p.b_mm, times), self._at(p.tip_mm, times),
                    {name: self._at(xy, times) for name, xy in p.markers_mm.items()})

    def _at(self, xy: np.ndarray, times: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(times, self.times_s, xy[:, 0]),
                                np.interp(times, self.times_s, xy[:, 1])])


def record_frames(pose: Callable[[np.ndarray], Pose], frame_times_s: np.ndarray,
                  tolerance_mm: float, samples_per_frame: int = SAMPLES_PER_FRAME,
                  medium: str = 'air') -> RecordedPose:
    """The poses a film of the frames at ``frame_times_s`` (one frame grid, increasing) needs,
    taken from the pose function ``pose`` now: at every frame time and one frame interval
    before the first and after the last (every exposure's sub-frames lie within), and
    ``samples_per_frame`` per interval wherever some point moves more than ``tolerance_mm``
    from one frame to the next (the strike). Where nothing moves that far, the straight line
    between two frames is within a small part of it of the path; the frames themselves are
    exact. Most of a recording is the slow loading, whose poses cost the most to evaluate
    (the latched robot's state, time by time): sampled once a frame it costs what the marker
    frames cost."""
    frames = np.asarray(frame_times_s, float)
    if frames.ndim != 1 or frames.size < 1:
        raise ValueError('no frame to record the poses of')
    if samples_per_frame < 1 or not tolerance_mm > 0:
        raise ValueError(f'samples per frame {samples_per_frame} and tolerance '
                         f'{tolerance_mm} mm: both must be > 0')
    interval = float(frames[1] - frames[0]) if frames.size > 1 else 1e-3
    coarse = np.concatenate([[frames[0] - interval], frames, [frames[-1] + interval]])
    p = pose(coarse)
    moved = np.zeros(coarse.size - 1)
    for xy in (p.a_mm, p.b_mm, p.tip_mm, *p.markers_mm.values()):
        moved = np.maximum(moved, np.hypot(*np.diff(np.asarray(xy, float), axis=0).T))
    fast = np.flatnonzero(moved > tolerance_mm)
    if fast.size == 0 or samples_per_frame == 1:
        return _copied(coarse, p, medium)
    steps = (np.arange(1, samples_per_frame) / samples_per_frame)
    fine = (coarse[fast][:, None] + np.diff(coarse)[fast][:, None] * steps[None, :]).ravel()
    q = pose(fine)
    times = np.concatenate([coarse, fine])
    order = np.argsort(times, kind='stable')

    def merged(a, b):
        return np.concatenate([np.asarray(a, float), np.asarray(b, float)])[order]
    return RecordedPose(times[order], Pose(merged(p.a_mm, q.a_mm), merged(p.b_mm, q.b_mm),
                                           merged(p.tip_mm, q.tip_mm),
                                           {n: merged(xy, q.markers_mm[n])
                                            for n, xy in p.markers_mm.items()}), medium)


def record_pose(pose: Callable[[np.ndarray], Pose], times_s: np.ndarray,
                medium: str = 'air') -> RecordedPose:
    """Sample the pose function ``pose`` (e.g. ``render.world_poses(world)``) at ``times_s``
    now; the copy does not depend on ``pose`` afterwards."""
    times = np.asarray(times_s, float)
    return _copied(times, pose(times), medium)


def _copied(times: np.ndarray, p: Pose, medium: str) -> RecordedPose:
    return RecordedPose(times.copy(), Pose(np.array(p.a_mm, float), np.array(p.b_mm, float),
                                           np.array(p.tip_mm, float),
                                           {n: np.array(xy, float)
                                            for n, xy in p.markers_mm.items()}), medium)
