"""What a study measures of each trial, as `mantis analyze --json` and the bag name it: the
force and the stage give the first three at once; the markers (a simulated camera's, or a
tracker export attached later) the last two."""
from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np


@dataclass(frozen=True)
class Quantity:
    name: str
    label: str          # in words, for a figure's axis and the report
    unit: str
    source: str         # 'force' (the load cell and the stage) or 'markers'
    low_cause: str      # the likely cause, in words, of a value below its forecast interval
    high_cause: str     # ... and above it

    @property
    def axis(self) -> str:
        return f'{self.label} ({self.unit})'


QUANTITIES = {q.name: q for q in (
    Quantity('peak_tendon_force_N', 'peak tendon force', 'N', 'force',
             'the latch let go under less load than the twin expects: the arm seated shallow '
             'on the latch, a worn latch face, or a load-cell offset (tare)',
             'the latch held more load than the twin expects: the arm seated deep on the '
             'latch, or a stiffer tendon'),
    Quantity('loading_work_mJ', 'loading work', 'mJ', 'force',
             'less energy went in before the release: the arm seated shallow on the latch, '
             'or the tendon took up its slack late',
             'more energy went in before the release: the arm seated deep on the latch, or a '
             'tendon that stretches more than the twin\'s'),
    Quantity('release_time_s', 'pull to release', 's', 'force',
             'released early in the pull: a shallow seat on the latch, or a faster pull than '
             'planned (check the stage)',
             'released late in the pull: a deep seat on the latch, slack in the tendon, or a '
             'slower pull than planned (check the stage)'),
    Quantity('peak_tip_speed_mps', 'peak tip speed', 'm/s', 'markers',
             'the strike lost speed: less energy stored (see the loading work), drag or '
             'friction at the arm, or markers lost in the tracking',
             'the strike ran faster than the twin allows: more energy stored, or the '
             'tracking\'s scale (mm per pixel) is off'),
    Quantity('max_spring_energy_mJ', 'spring energy stored', 'mJ', 'markers',
             'the body turned less than forecast: a shallow seat on the latch, or a weaker '
             'spring',
             'the body turned further than forecast: a deep seat on the latch, or a stiffer '
             'spring'),
)}

@dataclass(frozen=True)
class MeasurementError:
    """How a rig measures a quantity, relative to the truth: measured = true (1 + e), e one of
    ``points`` (equally likely): a normal's midpoint quantiles, or a measured chain's own."""
    points: tuple

    @classmethod
    def normal(cls, bias: float, sd: float, n: int = 15) -> MeasurementError:
        """bias + sd z at the midpoints of n equal parts of a standard normal."""
        z = NormalDist()
        return cls(tuple(bias + sd * z.inv_cdf((k + 0.5) / n) for k in range(n)))

    @property
    def bias(self) -> float:
        return float(np.mean(self.points))

    @property
    def sd(self) -> float:
        return float(np.std(self.points))


#: The rig's measuring chain, which a forecast of a measured value carries beside the robots'
#: own scatter (no bias: the identified scenes' discrepancy holds what the real rig's
#: measurement adds to the physics): the tip speed as the analysis of a 19,000 frames/s film
#: finds it (its 80 % intervals 0.5-0.85 m/s wide at 28-31 m/s,
#: docs/analysis_intervals_benchmark.md); the stored energy likewise (0.05 mJ wide, but the
#: body's angle also carries the tracker's calibration: 0.5 %); the force through the load
#: cell's noise and the ADC, the work and the release time through the release's detection
#: in the force stream (its 1 ms blocks) and the stage's position (2 %, 1 %).
RIG_ERROR = {'peak_tendon_force_N': MeasurementError.normal(0.0, 0.01),
             'loading_work_mJ': MeasurementError.normal(0.0, 0.02),
             'release_time_s': MeasurementError.normal(0.0, 0.01),
             'peak_tip_speed_mps': MeasurementError.normal(0.0, 0.01),
             'max_spring_energy_mJ': MeasurementError.normal(0.0, 0.005)}
#: The simulated rig's measuring chain (its load cell, stage, camera and the analysis of its
#: bag) against the true robot of each trial: the 20 midpoint quantiles of its relative errors
#: over 110 trials of 12 simulated studies of their own (bench/bench_study_calibration.py
#: --chain, seeds 100-111; docs/study.md). Not normal: the work and the release time run long
#: by the pull's start (the stage ramps up from rest at the slack position, where the twin's
#: pull is already moving), by up to 3.7 %; the tip speed short by the analysis's smoothing of
#: the strike's peak, -0.45 % typically, -1.6 % on some strikes.
SIMULATED_RIG_ERROR = {q: MeasurementError(points) for q, points in {
    'peak_tendon_force_N': (
        -0.00273, -0.00201, -0.00111, -0.00084, -0.00062, -0.00035, -0.00009, 0.00009,
        0.00021, 0.00041, 0.00056, 0.00064, 0.00078, 0.00091, 0.00107, 0.00124, 0.00148,
        0.00183, 0.00215, 0.00311),
    'loading_work_mJ': (
        0.00037, 0.00175, 0.00285, 0.00333, 0.00392, 0.00414, 0.00447, 0.00519, 0.00616,
        0.00677, 0.00759, 0.00780, 0.00892, 0.01006, 0.01244, 0.01507, 0.01867, 0.02747,
        0.03175, 0.03683),
    'release_time_s': (
        0.00180, 0.00203, 0.00261, 0.00321, 0.00335, 0.00337, 0.00360, 0.00378, 0.00387,
        0.00402, 0.00455, 0.00500, 0.00696, 0.00826, 0.00960, 0.01192, 0.01327, 0.01442,
        0.02030, 0.02566),
    'peak_tip_speed_mps': (
        -0.01640, -0.01124, -0.00768, -0.00636, -0.00580, -0.00550, -0.00536, -0.00514,
        -0.00490, -0.00466, -0.00454, -0.00439, -0.00417, -0.00392, -0.00377, -0.00343,
        -0.00328, -0.00302, -0.00224, -0.00153),
    'max_spring_energy_mJ': (
        -0.00024, -0.00018, -0.00016, -0.00014, -0.00013, -0.00012, -0.00010, -0.00009,
        -0.00008, -0.00007, -0.00005, -0.00004, -0.00003, -0.00002, -0.00000, 0.00000,
        0.00002, 0.00003, 0.00006, 0.00009),
}.items()}
#: The measuring chain of each rig a study runs on (the supervisor's `backend`).
MEASUREMENT = {'hardware': RIG_ERROR, 'sim': SIMULATED_RIG_ERROR}


#: The trial conditions in words, for axes and prompts.
CONDITION_LABELS = {'d_t_mm': ('guide distance', 'mm'), 'pull_speed_mm_s': ('pull speed', 'mm/s'),
                    'contact_angle_deg': ('contact angle', 'deg'), 'medium': ('medium', '')}


def condition_axis(name: str) -> str:
    label, unit = CONDITION_LABELS[name]
    return f'{label} ({unit})' if unit else label


__all__ = ['CONDITION_LABELS', 'MEASUREMENT', 'MeasurementError', 'QUANTITIES', 'Quantity',
           'RIG_ERROR', 'SIMULATED_RIG_ERROR', 'condition_axis']
