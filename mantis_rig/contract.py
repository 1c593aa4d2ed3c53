"""The rig's ROS contract, declared once: every topic (relative name, message type, QoS), every
service, every node name and every parameter of mantis_rig. Everything else takes its names
from here; ``docs/ros_interfaces.md`` holds a section generated from this module
(``python -m mantis_rig.contract``), which a test compares with it.

Names are relative (no leading '/'): a node resolves them in its own namespace, so
``--ros-args -r __ns:=/rig2`` (or ``mantis bringup``'s namespace) runs a second rig beside the
first in one ROS domain. A bag holds the fully resolved names it was recorded with
(``/rig2/loadcell/force_block``); readers find a contract topic in a bag by its name relative to
the rig's namespace (:func:`bag_namespace`, :func:`resolve`).

QoS: one profile per kind of stream (:class:`StreamQos`); publishers and subscribers of a topic
both take theirs from its kind, so they always match (reliability and durability are what DDS
matches; nothing reports a mismatch between two of our nodes, mantis_rig/runtime/lean_node.py).
Every kind is reliable: there are no best-effort publishers.

No ROS import at module level (rclpy is imported only to build a QoSProfile), and nothing of
mantis_rig beyond the parameter checks, which import what they need when they run.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math


# ============================================================================ QoS
@dataclass(frozen=True)
class StreamQos:
    """The QoS of one kind of stream. ``depth`` is the keep-last history of the publishers
    and of the subscribers; ``queue`` (if set) is the subscribers' history where it must be
    deeper than what a late joiner is given (the latched state: a late joiner gets the current
    state only, a subscriber must still not lose a change that follows another at once).
    Depth takes no part in QoS matching."""

    kind: str
    doc: str
    depth: int
    transient_local: bool = False
    queue: int | None = None

    @property
    def subscriber_depth(self) -> int:
        return self.queue or self.depth

    def _profile(self, depth: int):
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=(DurabilityPolicy.TRANSIENT_LOCAL if self.transient_local
                                      else DurabilityPolicy.VOLATILE))

    def publisher(self):
        """The rclpy QoSProfile a publisher of this kind offers (and a bag stores)."""
        return self._profile(self.depth)

    def subscriber(self):
        """The rclpy QoSProfile a subscription of this kind asks for."""
        return self._profile(self.subscriber_depth)

    def describe(self) -> str:
        durability = 'transient local' if self.transient_local else 'volatile'
        queue = f', subscribers {self.queue}' if self.queue else ''
        return f'reliable, {durability}, keep last {self.depth}{queue}'


SENSOR_QOS = StreamQos('sensor', 'measurements streamed by a device (room for bursts: marker '
                       'blocks, a stalled subscriber)', depth=1000)
# A publisher's keep-last history is memory held for the node's life: 1000 blocks of 1000
# frames (88 kB each) held 88 MB after 140 trials of one bring-up. The camera's whole buffer
# (1 s at its 37,000 frames/s) is 37 blocks.
MARKER_QOS = StreamQos('markers', 'a camera buffer\'s marker blocks, published at once after '
                       'the trigger (room for the whole buffer: 1 s at 37,000 frames/s is 37 '
                       'blocks of 1000 frames)', depth=64)
COMMAND_QOS = StreamQos('command', 'commands to the stage', depth=10)
STATUS_QOS = StreamQos('status', 'diagnostics', depth=100)
STATE_QOS = StreamQos('state', 'the latched current state: a late joiner gets the latest',
                      depth=1, transient_local=True, queue=10)
CLOCK_QOS = StreamQos('clock', 'simulated time (rclpy\'s time source subscribes best effort, '
                      'which a reliable publisher serves)', depth=10)
QOS_KINDS = (SENSOR_QOS, MARKER_QOS, COMMAND_QOS, STATUS_QOS, STATE_QOS, CLOCK_QOS)


# ============================================================================ nodes
SIM_WORLD_NODE = 'sim_world_node'
STAGE_NODE = 'stage_node'
LOADCELL_NODE = 'loadcell_node'
CAMERA_NODE = 'camera_node'
SUPERVISOR_NODE = 'supervisor_node'
#: the device nodes, in bring-up order (the stage first: it is stopped first in an emergency)
DEVICE_NODES = (STAGE_NODE, LOADCELL_NODE, CAMERA_NODE)
#: the nodes of the stack, in start order
RIG_NODES = (SIM_WORLD_NODE, *DEVICE_NODES, SUPERVISOR_NODE)
#: the process that holds the world and the device nodes in sim mode (nodes.sim_rig)
SIM_RIG_PROCESS = 'sim_rig'
#: the guards that enforce the force ceiling beside the supervisor's own monitor
FORCE_GUARD_NODES = (STAGE_NODE, LOADCELL_NODE)
#: side nodes (executors.SideNode): named <owner>_<suffix>, in the owner's namespace
RECORDER_SUFFIX = 'recorder'
FORCE_GUARD_SUFFIX = 'force_guard'
HEARTBEAT_SUFFIX = 'heartbeat'
PACING_SUFFIX = 'pacing'
#: nodes of the command-line tools
TRIAL_CLIENT_NODE = 'mantis_trial_client'
LIVE_RELAY_NODE = 'mantis_live'
REPLAY_NODE = 'mantis_replay'
STUDY_NODE = 'mantis_study'
#: `ros2 run mantis_rig replay_node`
REPLAY_NODE_EXECUTABLE = 'replay_node'
TOOL_NODES = (TRIAL_CLIENT_NODE, LIVE_RELAY_NODE, REPLAY_NODE, REPLAY_NODE_EXECUTABLE)


def side_node_name(owner: str, suffix: str) -> str:
    return f'{owner}_{suffix}'


# ============================================================================ topics, services
@dataclass(frozen=True)
class Topic:
    name: str            # relative
    type_name: str       # e.g. std_msgs/msg/Float64
    qos: StreamQos
    publisher: str       # who publishes it
    doc: str

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True)
class Service:
    name: str            # relative
    type_name: str
    server: str
    doc: str

    def __str__(self) -> str:
        return self.name


JOINT_STATE = Topic('stage/joint_state', 'sensor_msgs/msg/JointState', SENSOR_QOS, STAGE_NODE,
                    "name ['stage'], position m, velocity m/s, effort [0.0] (not measured, "
                    'never empty); at `joint_state_rate_hz` while active')
VELOCITY_COMMAND = Topic('stage/velocity_command', 'std_msgs/msg/Float64', COMMAND_QOS,
                         f'{SUPERVISOR_NODE}, {LOADCELL_NODE}',
                         'move at this velocity, m/s (0 = stop); checked against the speed '
                         'ceiling (stage_node subscribes)')
POSITION_COMMAND = Topic('stage/position_command', 'std_msgs/msg/Float64', COMMAND_QOS,
                         SUPERVISOR_NODE, 'move to this position, m, at `move_speed_m_per_s` '
                         '(stage_node subscribes)')
FORCE_BLOCK = Topic('loadcell/force_block', 'std_msgs/msg/Float64MultiArray', SENSOR_QOS,
                    LOADCELL_NODE, 'full-rate samples: data[0] first-sample time s, data[1] '
                    'period s, data[2:] forces N (mantis_rig/recording/force_block.py)')
WRENCH = Topic('loadcell/wrench', 'geometry_msgs/msg/WrenchStamped', SENSOR_QOS, LOADCELL_NODE,
               'decimated to `wrench_rate_hz`; wrench.force.x = tendon tension N')
TRIGGER_TIME = Topic('camera/trigger_time', 'sensor_msgs/msg/TimeReference', SENSOR_QOS,
                     CAMERA_NODE, 'one per trigger: header.stamp ROS time, time_ref device '
                     'time, source `camera`')
MARKERS = Topic('camera/markers', 'std_msgs/msg/Float64MultiArray', MARKER_QOS, CAMERA_NODE,
                'marker frames of the recorded window, m (simulation, imported tracking; '
                'mantis_rig/recording/marker_block.py)')
SUPERVISOR_STATE = Topic('supervisor/state', 'std_msgs/msg/String', STATE_QOS, SUPERVISOR_NODE,
                         'the trial state: idle, configuring, homing, taking_up_slack, taring, '
                         'arming, pulling, released, stopping, returning, done, aborted, '
                         'waiting_for_relatch (after a strike: a person re-latches the robot)')
HEARTBEAT = Topic('supervisor/heartbeat', 'std_msgs/msg/Header', COMMAND_QOS, SUPERVISOR_NODE,
                  'the supervisor is alive: every 50 ms (HEARTBEAT_PERIOD_S) from a thread of '
                  'its own; stamp: its steady clock (CLOCK_MONOTONIC); stage_node stops a '
                  'motion it commanded when it lapses `supervisor_heartbeat_timeout_s` (not '
                  'recorded)')
#: the supervisor's heartbeat period (s, steady clock)
HEARTBEAT_PERIOD_S = 0.05
PROGRESS = Topic('progress', 'std_msgs/msg/Header', COMMAND_QOS,
                 f'{SUPERVISOR_NODE}, {STAGE_NODE}',
                 'how far a consumer whose reactions must come in time on the rig\'s clock has '
                 'got: frame_id names it (`supervisor_node/trial`: the trial thread, sent at '
                 'each of its polls; `stage_node/force_guard`), stamp = the rig time up to which '
                 'it has heard the force stream and acted on it; stamp 0: it waits for nothing '
                 'now. The simulated world waits for each (`max_lead_s`), so that a starved '
                 'consumer slows the world rather than hearing a release late (not recorded)')


def heartbeat_source(node_name: str, pid: int) -> str:
    """A heartbeat's frame_id: the supervisor's name and its process. A stage node in the same
    process does not watch it: a supervisor that froze would have frozen the stage node with
    it, and a late beat there is only the two starving each other of the interpreter."""
    return f'{node_name}@{pid}'


def heartbeat_source_pid(frame_id: str) -> int | None:
    """The process a heartbeat came from (None for a frame_id without one)."""
    _, sep, pid = frame_id.rpartition('@')
    return int(pid) if sep and pid.isdigit() else None
def world_status_name(node_name: str = SIM_WORLD_NODE) -> str:
    """The simulated world's status on /diagnostics (time_s, phase, the robot's conditions)."""
    return f'{node_name}: world'


DIAGNOSTICS = Topic('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', STATUS_QOS,
                    f'{SIM_WORLD_NODE}, the device nodes, {SUPERVISOR_NODE}',
                    '1 Hz and on every state change; a status name starts with its node name')
#: stage_node's diagnostics: how many moves the stage stopped or refused itself (a soft travel
#: limit, a limit switch, a command outside its envelope), and the last one's reason; the
#: supervisor ends a trial when the count grows
MOTION_STOPS_KEY = 'motion_stops'
LAST_MOTION_STOP_KEY = 'last_motion_stop'
CLOCK = Topic('clock', 'rosgraph_msgs/msg/Clock', CLOCK_QOS,
              f'{SIM_WORLD_NODE}, `mantis replay --clock`',
              'simulated time (the world\'s; a replay\'s log time)')
JOINT_ANGLES = Topic('analysis/joint_angles', 'sensor_msgs/msg/JointState', SENSOR_QOS,
                     '`mantis import-tracking` (bag only)',
                     'joint angles a tracker exported beside its markers, rad')

#: every topic a trial's bag holds (the recorder's)
TRIAL_TOPICS = (JOINT_STATE, VELOCITY_COMMAND, POSITION_COMMAND, FORCE_BLOCK, WRENCH,
                TRIGGER_TIME, MARKERS, SUPERVISOR_STATE, DIAGNOSTICS)
TOPICS = (*TRIAL_TOPICS, HEARTBEAT, PROGRESS, CLOCK, JOINT_ANGLES)
TOPIC_BY_NAME = {t.name: t for t in TOPICS}

_TRIGGER = 'std_srvs/srv/Trigger'
STAGE_HOME = Service('stage/home', _TRIGGER, STAGE_NODE, 'home the stage (blocks until homed)')
STAGE_STOP = Service('stage/stop', _TRIGGER, STAGE_NODE, 'stop the stage at once')
TARE = Service('loadcell/tare', _TRIGGER, LOADCELL_NODE,
               'make the current reading zero (tendon slack)')
CAMERA_ARM = Service('camera/arm', _TRIGGER, CAMERA_NODE,
                     'arm with `frame_rate_hz`, `pre_trigger_s`, `post_trigger_s`')
CAMERA_TRIGGER = Service('camera/trigger', _TRIGGER, CAMERA_NODE, 'trigger now')
START_TRIAL = Service('supervisor/start_trial', _TRIGGER, SUPERVISOR_NODE,
                      'run one trial; answers at once (the message names the bag)')
ABORT = Service('supervisor/abort', _TRIGGER, SUPERVISOR_NODE, 'abort the running trial')
STUDY_CONTINUE = Service('study/continue', _TRIGGER, STUDY_NODE,
                         '`mantis study` on hardware: go on with the next trial (as Enter does)')
SERVICES = (STAGE_HOME, STAGE_STOP, TARE, CAMERA_ARM, CAMERA_TRIGGER, START_TRIAL, ABORT,
            STUDY_CONTINUE)
#: the Trigger services the supervisor calls on the device nodes
DEVICE_SERVICES = (STAGE_HOME, STAGE_STOP, TARE, CAMERA_ARM, CAMERA_TRIGGER)

#: the standard per-node services and topics the stack uses (relative to the node's name)
GET_STATE = 'get_state'
CHANGE_STATE = 'change_state'
SET_PARAMETERS = 'set_parameters'
GET_PARAMETERS = 'get_parameters'
SET_PARAMETERS_ATOMICALLY = 'set_parameters_atomically'
TRANSITION_EVENT = 'transition_event'


def node_interface(node: str, interface: str) -> str:
    """A node's standard service or topic (lifecycle, parameters), relative: the node's
    full name, without the leading '/', then the interface."""
    return f'{node}/{interface}'


# ============================================================================ namespaces
def resolve(name, namespace: str = '/') -> str:
    """The fully qualified name of a relative contract name in ``namespace``."""
    name = str(name)
    if name.startswith('/'):
        raise ValueError(f'{name!r} is absolute; contract names are relative')
    namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return f'{namespace}/{name}'


def relative(full_name: str, namespace: str = '/') -> str:
    """``full_name`` relative to ``namespace`` (ValueError if it is not under it)."""
    prefix = resolve('', namespace)
    if not full_name.startswith(prefix):
        raise ValueError(f'{full_name} is not in the namespace {namespace}')
    return full_name[len(prefix):]


def bag_namespace(topic_names) -> str:
    """The namespace in which a bag's contract topics were recorded ('/' or e.g. '/rig2'):
    the one under which most of its topics are contract topics; '/' if none is."""
    votes: dict[str, int] = {}
    for full in topic_names:
        for topic in TOPICS:
            suffix = '/' + topic.name
            if full.endswith(suffix):
                namespace = full[:-len(suffix)] or '/'
                votes[namespace] = votes.get(namespace, 0) + 1
    if not votes:
        return '/'
    return max(votes, key=lambda ns: (votes[ns], ns == '/'))


def find_topic(full_name: str) -> Topic | None:
    """The contract topic that ``full_name`` is in whatever namespace, or None."""
    return next((t for t in sorted(TOPICS, key=lambda t: -len(t.name))
                 if full_name == '/' + t.name or full_name.endswith('/' + t.name)), None)


def contract_topic(full_name: str, namespace: str = '/') -> Topic | None:
    """The contract topic that ``full_name`` is in ``namespace``, or None."""
    try:
        return TOPIC_BY_NAME.get(relative(full_name, namespace))
    except ValueError:
        return None


# ============================================================================ parameters
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
    (the `backend` parameter's check, and hardware.backends' before it builds a device)."""
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
MEDIA = ('air', 'water', 'vacuum')
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
#: the trial conditions the simulated world builds each latching's robot from
#: (mantis_sim.trial_conditions); the supervisor sets them before each simulated trial, and the world
#: takes them only while its robot is latched and unloaded
WORLD_CONDITIONS = (
    ParamSpec('d_t_mm', 23.0, 'mm', 'the robot\'s tendon guide distance from the body pivot '
              '(geometry.d_t_mm); settable while the robot is latched and the stage has not '
              'moved since', (1.0, 100.0), from_scene=True),
    ParamSpec('contact_angle_deg', 3.0, 'deg', 'the robot\'s contact angle, as recorded (the '
              'shim; geometry.contact_angle_deg): the arm sits at it + the latch offset drawn '
              'from the spread; settable as d_t_mm', (0.0, 15.0), from_scene=True),
    ParamSpec('medium', 'air', '', 'the medium the robot strikes in (medium.name and its '
              'density); settable as d_t_mm', choices=MEDIA, from_scene=True),
)
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
    ParamSpec('pull_speed_mm_s', 2.33, 'mm/s', 'stage pull speed during the trial',
              (0.05, MAX_SPEED_MM_S)),
    ParamSpec('medium', 'air', '', 'medium around the robot', choices=MEDIA),
    ParamSpec('d_t_mm', 23.0, 'mm', 'tendon guide distance from the body pivot', (1.0, 100.0)),
    ParamSpec('contact_angle_deg', 3.0, 'deg', 'contact angle (shim)', (-45.0, 45.0)),
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
CONDITION_KEYS = ('pull_speed_mm_s', 'medium', 'd_t_mm', 'contact_angle_deg', FORCE_CEILING.name,
                  TRAVEL.name, 'operator_note', 'scene', 'backend')
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


# ============================================================================ the document
DOC_BEGIN = '<!-- contract: generated by `python -m mantis_rig.contract`; do not edit -->'
DOC_END = '<!-- contract: end -->'


def _default_text(spec: ParamSpec) -> str:
    if spec.from_scene:
        return "the scene's"
    value = spec.default
    if isinstance(value, float) and math.isfinite(value) and value == int(value) \
            and abs(value) < 1e6:
        return f'{value:g}' if abs(value) >= 1e-3 or value == 0 else repr(value)
    return repr(value) if not isinstance(value, str) else (f'`{value}`' if value else "''")


def _allowed_text(spec: ParamSpec) -> str:
    if spec.choices:
        return ', '.join(spec.choices)
    if spec.range:
        low, high = (f'{v}' if isinstance(v, int) else f'{v:g}' for v in spec.range)
        return f'{low} – {high}'
    return ''


def markdown() -> str:
    """The contract's section of docs/ros_interfaces.md."""
    lines = [DOC_BEGIN, '', '### Topics', '',
             'Names are relative to the rig\'s namespace (`/` unless the rig runs in one, e.g. '
             '`-r __ns:=/rig2`).', '',
             '| topic | type | QoS | published by | meaning |', '|---|---|---|---|---|']
    for t in TOPICS:
        lines.append(f'| `{t.name}` | `{t.type_name}` | {t.qos.kind} | {t.publisher} | '
                     f'{t.doc} |')
    lines += ['', '### QoS kinds', '', '| kind | profile | for |', '|---|---|---|']
    lines += [f'| {q.kind} | {q.describe()} | {q.doc} |' for q in QOS_KINDS]
    lines += ['', '### Services', '', '| service | type | served by | meaning |',
              '|---|---|---|---|']
    lines += [f'| `{s.name}` | `{s.type_name}` | {s.server} | {s.doc} |' for s in SERVICES]
    lines += ['', 'And each node\'s standard ones: `<node>/get_state`, `<node>/change_state`, '
              '`<node>/transition_event` (device nodes: lifecycle), `<node>/set_parameters`, '
              '`<node>/set_parameters_atomically`.',
              '', '### Nodes', '']
    lines += [f'- `{name}`' for name in RIG_NODES]
    lines += [f'- `{SIM_RIG_PROCESS}` (process): `{SIM_WORLD_NODE}` and the device nodes',
              '- tools: ' + ', '.join(f'`{n}`' for n in TOOL_NODES)]
    lines += ['', '### Parameters', '',
              '*c*: applied at configure (a device node refuses a change while configured).', '',
              '| node | parameter | type | default | unit | allowed | meaning |',
              '|---|---|---|---|---|---|---|']
    for node, specs in NODE_PARAMETERS.items():
        for spec in specs:
            flag = ' *c*' if spec.at_configure else ''
            lines.append(f'| `{node}` | `{spec.name}`{flag} | {spec.type_name} | '
                         f'{_default_text(spec)} | {spec.unit} | {_allowed_text(spec)} | '
                         f'{spec.doc} |')
    lines += ['', DOC_END]
    return '\n'.join(lines) + '\n'


def document_section(text: str) -> str | None:
    """The generated section of a document's text, markers included (None if absent)."""
    start, end = text.find(DOC_BEGIN), text.find(DOC_END)
    if start < 0 or end < 0:
        return None
    return text[start:end + len(DOC_END)] + '\n'


def update_document(path) -> bool:
    """Rewrite the generated section of ``path``; True if it changed."""
    from pathlib import Path
    path = Path(path)
    text = path.read_text(encoding='utf-8')
    old = document_section(text)
    if old is None:
        raise ValueError(f'{path} has no generated section ({DOC_BEGIN})')
    new_text = text.replace(old, markdown())
    path.write_text(new_text, encoding='utf-8')
    return new_text != text


if __name__ == '__main__':
    import sys
    if len(sys.argv) > 1:
        changed = update_document(sys.argv[1])
        print(f'{sys.argv[1]}: {"updated" if changed else "up to date"}')
    else:
        sys.stdout.write(markdown())
