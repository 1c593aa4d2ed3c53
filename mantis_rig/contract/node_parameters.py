"""The rig's node parameters, declared once: each one's name, default, unit, meaning and
allowed range (:class:`ParamSpec`), node by node; the stage's envelope and the one force ceiling
and travel limit every guard obeys; the trial conditions the supervisor records, taken from
their one definition (mantis_sim.trial_conditions).

Imports nothing of mantis_rig above the devices: the parameter checks import what they need
(the scene loader, the DAQ's channel parser) when they run.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from mantis_sim.trial_conditions import CONDITION_BY_KEY, CONDITION_KEYS, MEDIA, Condition

from .ros_names import (
    CAMERA_NODE,
    FORCE_BLOCK,
    HEARTBEAT,
    JOINT_STATE,
    LOADCELL_NODE,
    POSITION_COMMAND,
    PROGRESS,
    SIM_WORLD_NODE,
    STAGE_NODE,
    SUPERVISOR_NODE,
    WRENCH,
)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a node: name, default, unit ('' for none), what it means, and its
    allowed range (inclusive) or choices. ``at_configure``: a device node applies it at
    configure and refuses a change while configured. ``check`` raises InputError (or the
    device's ConfigurationError) with the reason for a value a range cannot express."""

    name: str
    default: object
    unit: str
    doc: str
    range: tuple | None = None
    choices: tuple | None = None
    at_configure: bool = False
    check: Callable | None = None
    #: the default is the scene's own value (the node declares it once its scene is loaded);
    #: ``default`` then only gives the type, and the published scene's value
    from_scene: bool = False

    @property
    def low(self):
        return None if self.range is None else self.range[0]

    @property
    def high(self):
        return None if self.range is None else self.range[1]

    @property
    def description(self) -> str:
        """The text of the ROS parameter descriptor."""
        return self.doc + (f' [{self.unit}]' if self.unit else '')

    @property
    def type_name(self) -> str:
        if isinstance(self.default, bool):
            return 'bool'
        if isinstance(self.default, int):
            return 'integer'
        if isinstance(self.default, float):
            return 'double'
        if isinstance(self.default, (list, tuple)):
            return 'string array'
        return 'string'


def check_backend(backend: str) -> str:
    """`backend` if it is one of BACKENDS, else a ConfigurationError naming the valid ones
    (the `backend` parameter's check, and mantis_rig.backends' before it builds a device)."""
    if backend not in BACKENDS:
        from mantis_rig.faults import ConfigurationError
        raise ConfigurationError(f'unknown backend {backend!r}; valid backends: '
                                 f'{", ".join(BACKENDS)}')
    return backend


def _check_scene(value) -> None:
    from mantis_sim.scene import load_scene
    load_scene(value)


def _check_overrides(items) -> None:
    from mantis_sim.errors import InputError
    for item in items or []:
        if item and '=' not in item:
            raise InputError(f'override {item!r} is not key=value')


def _check_channel(value) -> None:
    from mantis_rig.hardware.nidaq import parse_ai_channel
    parse_ai_channel(value)


def _check_lines(value) -> None:
    from mantis_rig.hardware.nidaq import parse_trigger_output
    parse_trigger_output(value)


BACKENDS = ('sim', 'hardware')
DEFAULT_SCENE = 'air_23mm_rig'
DEFAULT_SERIAL_PORT = '/dev/ttyUSB0'
DEFAULT_TRIGGER_OUTPUT = 'Dev1/port0/line0'
# the stage driver's envelope (mantis_rig.hardware.device_interfaces.StageLimits, checked by a test)
STAGE_MAX_SPEED_M_PER_S = 2.4e-3
STAGE_TRAVEL_M = (0.5e-3, 24.5e-3)
MAX_SPEED_MM_S = STAGE_MAX_SPEED_M_PER_S * 1e3
MAX_TRAVEL_MM = (STAGE_TRAVEL_M[1] - STAGE_TRAVEL_M[0]) * 1e3

#: the one force ceiling (mantis_rig.trial.safety_limits): the supervisor's parameter, and the
#: same parameter on each of FORCE_GUARD_NODES
FORCE_CEILING = ParamSpec(
    'force_ceiling_n', 30.0, 'N', 'tendon force above which the stage is stopped; one value '
    'for every guard: supervisor, stage driver and load-cell monitor',
    (0.5, 100.0))                           # under the load cell's 111 N capacity
FORCE_CEILING_NAME = FORCE_CEILING.name
#: the one travel limit of a pull (mantis_rig.trial.safety_limits): the supervisor's parameter,
#: and the same parameter on stage_node, whose every pull the controller ends there
TRAVEL = ParamSpec(
    'travel_mm', 8.0, 'mm', 'a pull goes at most this far from where it starts: the supervisor '
    'aborts there, and the stage controller itself is told to stop there (every pull is '
    'executed as a move to its start + travel_mm)', (0.1, MAX_TRAVEL_MM))
TRAVEL_NAME = TRAVEL.name
#: the stage's diagnostics: how long since the supervisor's last heartbeat, and the longest
#: gap between two heard since the node was activated (s, steady clock)
HEARTBEAT_AGE_KEY = 'supervisor_heartbeat_age_s'
HEARTBEAT_MAX_GAP_KEY = 'supervisor_heartbeat_max_gap_s'
#: ... and the longest between two heartbeats' stamps (the supervisor's own pauses)
HEARTBEAT_MAX_SEND_GAP_KEY = 'supervisor_heartbeat_max_send_gap_s'

DEVICE_COMMON_PARAMETERS = (
    ParamSpec('backend', 'sim', '', 'device backend: sim or hardware', choices=BACKENDS,
              at_configure=True, check=check_backend),
    ParamSpec('scene', DEFAULT_SCENE, '', 'sim: scene whose sensor models the simulated '
              f'device uses (the same scene as {SIM_WORLD_NODE})', at_configure=True,
              check=_check_scene),
    ParamSpec('set', [], '', f'sim: scene overrides, key=value each (as given to '
              f'{SIM_WORLD_NODE})', at_configure=True, check=_check_overrides),
    ParamSpec('seed', 0, '', 'sim: random seed of the sensor noise', (0, 2**31 - 1),
              at_configure=True),
)


def _guard(who: str) -> ParamSpec:
    return ParamSpec(FORCE_CEILING.name, FORCE_CEILING.default, FORCE_CEILING.unit,
                     f'{who}: {FORCE_CEILING.doc}', FORCE_CEILING.range)


STAGE_PARAMETERS = (
    ParamSpec('serial_port', DEFAULT_SERIAL_PORT, '', 'hardware: KDC101 serial port',
              at_configure=True),
    ParamSpec('stage_serial_number', '', '', 'hardware: the KDC101 by its serial number '
              '(27...), or "auto" for the only KDC101 on the machine; when set, it chooses the '
              'port instead of serial_port (mantis doctor lists the controllers)',
              at_configure=True),
    ParamSpec('counts_per_mm', 34554.96, 'counts/mm', 'hardware: encoder counts per mm (Z8: '
              '34554.96 per the APT protocol, 34304 per the stage data sheet)', (1e3, 1e6),
              at_configure=True),
    ParamSpec('move_speed_m_per_s', 1.0e-3, 'm/s', f'speed of {POSITION_COMMAND} moves',
              (1e-6, STAGE_MAX_SPEED_M_PER_S)),
    ParamSpec('joint_state_rate_hz', 100.0, 'Hz', f'{JOINT_STATE} rate (read at activate)',
              (1.0, 1000.0)),
    _guard('the stage driver\'s guard'),
    ParamSpec(TRAVEL.name, TRAVEL.default, TRAVEL.unit, f'the stage controller\'s bound: '
              f'{TRAVEL.doc}', TRAVEL.range),
    ParamSpec('supervisor_heartbeat_timeout_s', 0.4, 's', f'a motion commanded while the '
              f'supervisor\'s {HEARTBEAT} is heard (a pull, a move) is stopped once that lapses '
              f'this long (steady clock; checked every 50 ms)', (0.1, 0.45)),
    ParamSpec('max_force_age_s', 0.5, 's', 'a pull needs a force reading at most this old; a '
              'pull whose readings stop is stopped', (0.05, 10.0), at_configure=True),
)
LOADCELL_PARAMETERS = (
    ParamSpec('channel', 'Dev1/ai0', '', 'hardware: analog input channel', at_configure=True,
              check=_check_channel),
    ParamSpec('sample_rate_hz', 20_000.0, 'Hz', 'sample rate', (1.0, 2e6), at_configure=True),
    ParamSpec('block_size', 200, 'samples', f'samples per {FORCE_BLOCK} message',
              (1, 1_000_000), at_configure=True),
    ParamSpec('newtons_per_volt', 11.12, 'N/V', 'amplifier scale (IAA100: 10 V at 111 N)',
              (1e-6, 1e6), at_configure=True),
    _guard('the load cell\'s monitor'),
    ParamSpec('wrench_rate_hz', 200.0, 'Hz', f'{WRENCH} rate', (0.1, 10_000.0)),
)
CAMERA_PARAMETERS = (
    ParamSpec('frame_rate_hz', 19_000.0, 'frames/s', 'frame rate (read at arm)',
              (1.0, 37_000.0)),
    ParamSpec('pre_trigger_s', 0.05, 's', 'recorded time before the trigger (read at arm)',
              (0.0, 1.0)),
    ParamSpec('post_trigger_s', 0.05, 's', 'recorded time after the trigger (read at arm)',
              (0.0, 1.0)),
    ParamSpec('lines', DEFAULT_TRIGGER_OUTPUT, '', 'hardware: trigger output, a DO line '
              '(Dev1/port0/line0) or a counter (Dev1/ctr0)', at_configure=True,
              check=_check_lines),
    ParamSpec('film_dir', '', '', 'sim: film the next recording into this folder (an absolute '
              'path; read at arm): video.cine, calibration.yaml, truth.csv, written whole or '
              'not at all after its marker frames are published; \'\': no film. Refused on '
              'hardware, whose camera records itself'),
)
def _recorded(condition: Condition) -> ParamSpec:
    """The supervisor's parameter for a trial condition: its range, up to the stage's speed
    ceiling where the condition leaves the top to the rig."""
    low, high = condition.range or (None, None)
    return ParamSpec(condition.key, condition.default, condition.unit, condition.doc,
                     None if condition.range is None else (low, MAX_SPEED_MM_S if high is None
                                                           else high),
                     choices=condition.choices)


def _simulated(spec: ParamSpec) -> ParamSpec:
    """The world's parameter for a trial condition: the scene's value by default, and the
    range the simulated world can build its robot at."""
    condition = CONDITION_BY_KEY[spec.name]
    return ParamSpec(spec.name, condition.default, condition.unit, spec.doc,
                     condition.simulated_range, choices=condition.choices, from_scene=True)


#: the trial conditions the simulated world builds each latching's robot from
#: (mantis_sim.trial_conditions); the supervisor sets them before each simulated trial, and the
#: world takes them only while its robot is latched and unloaded
WORLD_CONDITIONS = tuple(_simulated(spec) for spec in (
    ParamSpec('d_t_mm', 0.0, 'mm', 'the robot\'s tendon guide distance from the body pivot '
              '(geometry.d_t_mm); settable while the robot is latched and the stage has not '
              'moved since'),
    ParamSpec('contact_angle_deg', 0.0, 'deg', 'the robot\'s contact angle, as recorded (the '
              'shim; geometry.contact_angle_deg): the arm sits at it + the latch offset drawn '
              'from the spread; settable as d_t_mm'),
    ParamSpec('medium', '', '', 'the medium the robot strikes in (medium.name and its '
              'density); settable as d_t_mm'),
))
WORLD_PARAMETERS = (
    ParamSpec('scene', DEFAULT_SCENE, '', 'mantis_sim scene name (see `mantis scenes`) or '
              'YAML path'),
    ParamSpec('set', [], '', 'scene overrides, key=value each (as `mantis simulate --set`)'),
    ParamSpec('seed', 0, '', 'seed of the session\'s robots when the scene has a spread: the '
              'day drawn once, where the arm sits drawn at each latching (mantis_sim.robots; '
              'sensor noise is seeded in the device nodes)', (0, 2**31 - 1)),
    ParamSpec('draw_robots', True, '', 'draw each latching\'s robot from the scene\'s spread '
              '(a scene without one: always its own robot)'),
    ParamSpec('real_time_factor', 1.0, '', 'simulated seconds per wall second (0: as fast as '
              'it can)', (0.0, 1000.0)),
    ParamSpec('step_s', 0.01, 's', 'simulated time per world step', (1e-4, 0.1)),
    ParamSpec('max_lead_s', 0.05, 's', 'simulated time the world may run ahead of the load '
              f'cell\'s {FORCE_BLOCK} stream, and of each consumer\'s {PROGRESS}, while the '
              'force streams (0: no limit)', (0.0, 10.0)),
    ParamSpec('relatch', True, '', 'the operator re-latches the robot once the stage is back '
              'at its start after a strike (false: forgets, which the supervisor\'s latch '
              'check must catch)'),
    *WORLD_CONDITIONS,
)
#: the supervisor's parameters: the trial conditions (CONDITION_KEYS), then the procedure
SUPERVISOR_PARAMETERS = (
    *(_recorded(condition) for condition in CONDITION_BY_KEY.values()),
    FORCE_CEILING,
    TRAVEL,
    ParamSpec('operator_note', '', '', 'free text stored with the trial'),
    ParamSpec('scene', '', '', 'simulated scene (sim backend) or rig description'),
    ParamSpec('backend', 'sim', '', 'device backend the stack runs with', choices=BACKENDS),
    # procedure
    ParamSpec('out', 'trials', '', 'directory under which each trial gets its bag directory'),
    ParamSpec('tare', False, '', 'tare the load cell after taking up slack (hardware: true)'),
    ParamSpec('slack_force_n', 0.3, 'N', 'the tendon counts as taut above this force',
              (0.01, 5.0)),
    ParamSpec('slack_speed_mm_s', 0.2, 'mm/s', 'stage speed while taking up slack',
              (0.01, MAX_SPEED_MM_S)),
    ParamSpec('latch_check_mm', 2.0, 'mm', 'a tendon still slack after this much take-up '
              'means the robot is not latched: the trial aborts and asks for a re-latch',
              (0.05, MAX_TRAVEL_MM)),
    ParamSpec('supervisor_force_monitor', True, '', 'the supervisor aborts above '
              f'{FORCE_CEILING.name} itself (false only to test the guards beneath it)'),
    ParamSpec('release_jump_n', 1.0, 'N', 'release: 1 ms mean force moves by more than this',
              (0.05, 50.0)),
    ParamSpec('frame_rate_hz', 19000.0, 'frames/s', 'camera frame rate', (1.0, 37000.0)),
    ParamSpec('pre_trigger_s', 0.3, 's', 'camera frames kept before the trigger (detection '
              'latency must stay below it)', (0.0, 1.0)),
    ParamSpec('post_trigger_s', 0.05, 's', 'camera frames kept after the trigger', (0.0, 1.0)),
    ParamSpec('expect_markers', True, '', 'wait for the marker frames of the window '
              '(simulation)'),
    ParamSpec('video', False, '', 'simulation: the camera films each trial\'s recorded window '
              'into <bag>/video/ (docs/simulated_rig.md, Filming); the trial does not wait for '
              'the film'),
    ParamSpec('phase_timeout_s', 60.0, 's', 'wall time any one phase may take before an abort',
              (1.0, 3600.0)),
    ParamSpec('position_tolerance_mm', 0.1, 'mm', 'a move has arrived when the stage rests '
              'this close to its target', (0.001, 1.0)),
    ParamSpec('start_position_mm', -1.0, 'mm', 'move here before the trial (<0: stay where the '
              'stage is)', (-1.0, 25.0)),
)
#: the keys of a trial's recorded conditions (the bag's ``trial_conditions``): the trial
#: conditions, then the limits it ran under, the operator's note, the scene and the backend
RECORDED_CONDITION_KEYS = (*CONDITION_KEYS, FORCE_CEILING.name, TRAVEL.name, 'operator_note',
                           'scene', 'backend')
#: the supervisor sets these on camera_node before each arm
CAMERA_WINDOW_PARAMETERS = ('frame_rate_hz', 'pre_trigger_s', 'post_trigger_s', 'film_dir')
#: where a trial's film goes, in its bag directory (the supervisor's ``video``); beside it,
#: ``<film folder>.failed`` holds why the camera could not film
FILM_FOLDER = 'video'
FILM_FAILED_SUFFIX = '.failed'

#: node -> its own parameters (ROS's use_sim_time aside)
NODE_PARAMETERS = {
    SIM_WORLD_NODE: WORLD_PARAMETERS,
    STAGE_NODE: DEVICE_COMMON_PARAMETERS + STAGE_PARAMETERS,
    LOADCELL_NODE: DEVICE_COMMON_PARAMETERS + LOADCELL_PARAMETERS,
    CAMERA_NODE: DEVICE_COMMON_PARAMETERS + CAMERA_PARAMETERS,
    SUPERVISOR_NODE: SUPERVISOR_PARAMETERS,
}


__all__ = [
    'ParamSpec', 'check_backend', 'BACKENDS', 'DEFAULT_SCENE', 'DEFAULT_SERIAL_PORT',
    'DEFAULT_TRIGGER_OUTPUT', 'MEDIA', 'STAGE_MAX_SPEED_M_PER_S', 'STAGE_TRAVEL_M',
    'MAX_SPEED_MM_S', 'MAX_TRAVEL_MM', 'FORCE_CEILING', 'FORCE_CEILING_NAME', 'TRAVEL',
    'TRAVEL_NAME', 'HEARTBEAT_AGE_KEY', 'HEARTBEAT_MAX_GAP_KEY', 'HEARTBEAT_MAX_SEND_GAP_KEY',
    'DEVICE_COMMON_PARAMETERS', 'STAGE_PARAMETERS', 'LOADCELL_PARAMETERS', 'CAMERA_PARAMETERS',
    'WORLD_CONDITIONS', 'WORLD_PARAMETERS', 'SUPERVISOR_PARAMETERS', 'RECORDED_CONDITION_KEYS',
    'CAMERA_WINDOW_PARAMETERS', 'FILM_FOLDER', 'FILM_FAILED_SUFFIX', 'NODE_PARAMETERS',
]
