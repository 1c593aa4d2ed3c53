"""A trial's conditions and procedure settings: the supervisor's parameters (no ROS).

Each entry of PARAMETERS is one supervisor parameter (a mantis_rig.contract.ParamSpec: name,
default, unit, description and its allowed range or choices). The supervisor declares them
with descriptors built from this table, so ROS refuses an out-of-range value with the reason;
``TrialConditions.validate`` applies the same checks (and the ones across parameters) to a
whole set, e.g. for the command line.
The trial conditions (the first group) go into the bag's ``trial_conditions`` record.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields
import math

from mantis_rig.contract import (  # noqa: F401 - the names this module has always offered
    BACKENDS,
    FORCE_CEILING,
    MAX_SPEED_MM_S,
    MAX_TRAVEL_MM,
    MEDIA,
    RECORDED_CONDITION_KEYS,
    SUPERVISOR_PARAMETERS,
    ParamSpec,
)
from mantis_sim.errors import InputError

#: name -> ParamSpec of each supervisor parameter (mantis_rig.contract)
PARAMETERS = {spec.name: spec for spec in SUPERVISOR_PARAMETERS}


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
    force_ceiling_n: float = FORCE_CEILING.default
    travel_mm: float = PARAMETERS['travel_mm'].default
    operator_note: str = ''
    scene: str = ''
    backend: str = 'sim'
    out: str = 'trials'
    tare: bool = False
    slack_force_n: float = PARAMETERS['slack_force_n'].default
    slack_speed_mm_s: float = PARAMETERS['slack_speed_mm_s'].default
    latch_check_mm: float = PARAMETERS['latch_check_mm'].default
    release_jump_n: float = PARAMETERS['release_jump_n'].default
    frame_rate_hz: float = PARAMETERS['frame_rate_hz'].default
    pre_trigger_s: float = PARAMETERS['pre_trigger_s'].default
    post_trigger_s: float = PARAMETERS['post_trigger_s'].default
    expect_markers: bool = True
    video: bool = False
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
        if self.video and self.backend != 'sim':
            raise ConditionError(f'video = true films with the simulated camera; the '
                                 f'{self.backend} camera records the strike itself (save its '
                                 f'recording and attach it: mantis study attach)')
        return self

    def metadata(self) -> dict:
        """The ``trial_conditions`` record: every parameter, as strings."""
        return {k: str(v) for k, v in asdict(self).items()}
