"""A trial's conditions and procedure settings: the supervisor's parameters (no ROS).

Each entry of PARAMETERS is one supervisor parameter: name, default, unit, description and its
allowed range or choices. The supervisor declares them with descriptors built from this table,
so ROS refuses an out-of-range value with the reason; ``TrialConditions.validate`` applies the
same checks (and the ones across parameters) to a whole set, e.g. for the command line.
The trial conditions (the first group) go into the bag's ``trial_conditions`` record.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields
import math

from mantis_rig.hardware.interfaces import StageLimits
from mantis_rig.trial.safety_limits import (
    FORCE_CEILING_DEFAULT_N,
    FORCE_CEILING_DESCRIPTION,
    FORCE_CEILING_RANGE_N,
)
from mantis_sim.errors import InputError

BACKENDS = ('sim', 'hardware')
_STAGE = StageLimits()                      # the driver's envelope: speed ceiling and travel
MAX_SPEED_MM_S = _STAGE.max_speed_m_per_s * 1e3
MAX_TRAVEL_MM = (_STAGE.max_position_m - _STAGE.min_position_m) * 1e3
MEDIA = ('air', 'water', 'vacuum')


@dataclass(frozen=True)
class Spec:
    default: object
    unit: str
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple | None = None


PARAMETERS = {
    # trial conditions
    'pull_speed_mm_s': Spec(2.33, 'mm/s', 'stage pull speed during the trial', 0.05,
                            MAX_SPEED_MM_S),
    'medium': Spec('air', '', 'medium around the robot', choices=MEDIA),
    'd_t_mm': Spec(23.0, 'mm', 'tendon guide distance from the body pivot', 1.0, 100.0),
    'contact_angle_deg': Spec(3.0, 'deg', 'contact angle (shim)', -45.0, 45.0),
    'force_ceiling_n': Spec(FORCE_CEILING_DEFAULT_N, 'N', FORCE_CEILING_DESCRIPTION,
                            *FORCE_CEILING_RANGE_N),
    'travel_mm': Spec(8.0, 'mm', 'abort when the pull has gone this far', 0.1, MAX_TRAVEL_MM),
    'operator_note': Spec('', '', 'free text stored with the trial'),
    'scene': Spec('', '', 'simulated scene (sim backend) or rig description'),
    'backend': Spec('sim', '', 'device backend the stack runs with', choices=BACKENDS),
    # procedure
    'out': Spec('trials', '', 'directory under which each trial gets its bag directory'),
    'tare': Spec(False, '', 'tare the load cell after taking up slack (hardware: true)'),
    'slack_force_n': Spec(0.3, 'N', 'the tendon counts as taut above this force', 0.01, 5.0),
    'slack_speed_mm_s': Spec(0.2, 'mm/s', 'stage speed while taking up slack', 0.01,
                             MAX_SPEED_MM_S),
    'supervisor_force_monitor': Spec(True, '', 'the supervisor aborts above force_ceiling_n '
                                     'itself (false only to test the guards beneath it)'),
    'release_jump_n': Spec(1.0, 'N', 'release: 1 ms mean force moves by more than this',
                           0.05, 50.0),
    'frame_rate_hz': Spec(19000.0, 'frames/s', 'camera frame rate', 1.0, 37000.0),
    'pre_trigger_s': Spec(0.3, 's', 'camera frames kept before the trigger (detection '
                          'latency must stay below it)', 0.0, 1.0),
    'post_trigger_s': Spec(0.05, 's', 'camera frames kept after the trigger', 0.0, 1.0),
    'expect_markers': Spec(True, '', 'wait for the marker frames of the window (simulation)'),
    'phase_timeout_s': Spec(60.0, 's', 'wall time any one phase may take before an abort',
                            1.0, 3600.0),
    'position_tolerance_mm': Spec(0.1, 'mm', 'a move has arrived when the stage rests this '
                                  'close to its target', 0.001, 1.0),
    'start_position_mm': Spec(-1.0, 'mm', 'move here before the trial (<0: stay where the '
                              'stage is)', -1.0, 25.0),
}
CONDITION_KEYS = ('pull_speed_mm_s', 'medium', 'd_t_mm', 'contact_angle_deg', 'force_ceiling_n',
                  'travel_mm', 'operator_note', 'scene', 'backend')


class ConditionError(InputError):
    """A trial condition or setting is out of range; the message says which and why."""


def check_value(name: str, value) -> None:
    """Raise ConditionError if ``value`` is not allowed for parameter ``name``."""
    spec = PARAMETERS.get(name)
    if spec is None:
        raise ConditionError(f'unknown trial parameter {name!r}; known: '
                             f'{", ".join(PARAMETERS)}')
    if spec.choices is not None and value not in spec.choices:
        raise ConditionError(f'{name} = {value!r} is not one of {", ".join(spec.choices)}')
    if spec.low is not None:
        if not isinstance(value, (int, float)) or isinstance(value, bool) \
                or not math.isfinite(value) or not spec.low <= value <= spec.high:
            raise ConditionError(f'{name} = {value!r} {spec.unit} is outside '
                                 f'[{spec.low}, {spec.high}] {spec.unit}')


@dataclass(frozen=True)
class TrialConditions:
    pull_speed_mm_s: float = PARAMETERS['pull_speed_mm_s'].default
    medium: str = PARAMETERS['medium'].default
    d_t_mm: float = PARAMETERS['d_t_mm'].default
    contact_angle_deg: float = PARAMETERS['contact_angle_deg'].default
    force_ceiling_n: float = PARAMETERS['force_ceiling_n'].default
    travel_mm: float = PARAMETERS['travel_mm'].default
    operator_note: str = ''
    scene: str = ''
    backend: str = 'sim'
    out: str = 'trials'
    tare: bool = False
    slack_force_n: float = PARAMETERS['slack_force_n'].default
    slack_speed_mm_s: float = PARAMETERS['slack_speed_mm_s'].default
    release_jump_n: float = PARAMETERS['release_jump_n'].default
    frame_rate_hz: float = PARAMETERS['frame_rate_hz'].default
    pre_trigger_s: float = PARAMETERS['pre_trigger_s'].default
    post_trigger_s: float = PARAMETERS['post_trigger_s'].default
    expect_markers: bool = True
    supervisor_force_monitor: bool = True
    phase_timeout_s: float = PARAMETERS['phase_timeout_s'].default
    position_tolerance_mm: float = PARAMETERS['position_tolerance_mm'].default
    start_position_mm: float = PARAMETERS['start_position_mm'].default

    @classmethod
    def from_mapping(cls, values: dict) -> TrialConditions:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in known})

    def validate(self) -> TrialConditions:
        for name, value in asdict(self).items():
            check_value(name, value)
        if self.pre_trigger_s + self.post_trigger_s > 1.0:
            raise ConditionError(f'pre_trigger_s + post_trigger_s = '
                                 f'{self.pre_trigger_s + self.post_trigger_s} s exceeds the '
                                 f'camera buffer (1 s)')
        return self

    def metadata(self) -> dict:
        """The ``trial_conditions`` record: every parameter, as strings."""
        return {k: str(v) for k, v in asdict(self).items()}
