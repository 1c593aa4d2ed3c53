"""What a study measures of each trial, as `mantis analyze --json` and the bag name it: the
force and the stage give the first three at once; the markers (a simulated camera's, or a
tracker export attached later) the last two."""
from __future__ import annotations

from dataclasses import dataclass


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
    """How a rig measures a quantity, relative to the truth: measured = true (1 + bias + e),
    e normal with standard deviation ``sd``."""
    bias: float
    sd: float


#: The rig's measuring chain, which a forecast of a measured value carries beside the robots'
#: own scatter (no bias: the identified scenes' discrepancy holds what the real rig's
#: measurement adds to the physics): the tip speed as the analysis of a 19,000 frames/s film
#: finds it (its 80 % intervals 0.5-0.85 m/s wide at 28-31 m/s,
#: docs/analysis_intervals_benchmark.md); the stored energy likewise (0.05 mJ wide, but the
#: body's angle also carries the tracker's calibration: 0.5 %); the force through the load
#: cell's noise and the ADC, the work and the release time through the release's detection
#: in the force stream (its 1 ms blocks) and the stage's position (2 %, 1 %).
RIG_ERROR = {'peak_tendon_force_N': MeasurementError(0.0, 0.01),
             'loading_work_mJ': MeasurementError(0.0, 0.02),
             'release_time_s': MeasurementError(0.0, 0.01),
             'peak_tip_speed_mps': MeasurementError(0.0, 0.01),
             'max_spring_energy_mJ': MeasurementError(0.0, 0.005)}
#: The simulated rig's measuring chain (its load cell, stage, camera and the analysis of its
#: bag) against the true robot of each trial, measured on 50 trials of 6 simulated studies of
#: their own (bench/bench_study_calibration.py --chain, seeds 100-105; docs/study.md). The work
#: and the release time run long by the pull's start (the stage ramps up from the slack
#: position; the twin's pull is already moving there), the tip speed short by the analysis's
#: smoothing of the strike's peak.
SIMULATED_RIG_ERROR = {'peak_tendon_force_N': MeasurementError(0.0004, 0.0017),
                       'loading_work_mJ': MeasurementError(0.0116, 0.0080),
                       'release_time_s': MeasurementError(0.0091, 0.0069),
                       'peak_tip_speed_mps': MeasurementError(-0.0063, 0.0039),
                       'max_spring_energy_mJ': MeasurementError(-0.0001, 0.0001)}
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
