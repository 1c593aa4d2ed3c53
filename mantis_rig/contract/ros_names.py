"""The rig's ROS names, declared once: every topic (relative name, message type, QoS kind),
every service, every node name, and how a name resolves in a rig's namespace.

Names are relative (no leading '/'): a node resolves them in its own namespace, so
``--ros-args -r __ns:=/rig2`` (or ``mantis bringup``'s namespace) runs a second rig beside the
first in one ROS domain. A bag holds the fully resolved names it was recorded with
(``/rig2/loadcell/force_block``); readers find a contract topic in a bag by its name relative to
the rig's namespace (:func:`bag_namespace`, :func:`resolve`).

QoS: one profile per kind of stream (:class:`StreamQos`); publishers and subscribers of a topic
both take theirs from its kind, so they always match (reliability and durability are what DDS
matches; nothing reports a mismatch between two of our nodes, mantis_rig/runtime/lean_node.py).
Every kind is reliable: there are no best-effort publishers. No ROS import at module level
(rclpy is imported only to build a QoSProfile).
"""
from __future__ import annotations

from dataclasses import dataclass


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
#: the process that holds the world and the device nodes in sim mode (simulated.sim_rig)
SIM_RIG_PROCESS = 'sim_rig'
#: the guards that enforce the force ceiling beside the supervisor's own monitor
FORCE_GUARD_NODES = (STAGE_NODE, LOADCELL_NODE)
#: side nodes (executors.SideNode): named <owner>_<suffix>, in the owner's namespace
RECORDER_SUFFIX = 'recorder'
FORCE_GUARD_SUFFIX = 'force_guard'
HEARTBEAT_SUFFIX = 'heartbeat'
PACING_SUFFIX = 'pacing'
CLOCK_SUFFIX = 'clock'
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


__all__ = [
    'StreamQos', 'SENSOR_QOS', 'MARKER_QOS', 'COMMAND_QOS', 'STATUS_QOS', 'STATE_QOS',
    'CLOCK_QOS', 'QOS_KINDS', 'SIM_WORLD_NODE', 'STAGE_NODE', 'LOADCELL_NODE', 'CAMERA_NODE',
    'SUPERVISOR_NODE', 'DEVICE_NODES', 'RIG_NODES', 'SIM_RIG_PROCESS', 'FORCE_GUARD_NODES',
    'RECORDER_SUFFIX', 'FORCE_GUARD_SUFFIX', 'HEARTBEAT_SUFFIX', 'PACING_SUFFIX',
    'CLOCK_SUFFIX',
    'TRIAL_CLIENT_NODE', 'LIVE_RELAY_NODE', 'REPLAY_NODE', 'STUDY_NODE', 'REPLAY_NODE_EXECUTABLE',
    'TOOL_NODES', 'side_node_name', 'Topic', 'Service', 'JOINT_STATE', 'VELOCITY_COMMAND',
    'POSITION_COMMAND', 'FORCE_BLOCK', 'WRENCH', 'TRIGGER_TIME', 'MARKERS', 'SUPERVISOR_STATE',
    'HEARTBEAT', 'HEARTBEAT_PERIOD_S', 'PROGRESS', 'heartbeat_source', 'heartbeat_source_pid',
    'world_status_name', 'DIAGNOSTICS', 'MOTION_STOPS_KEY', 'LAST_MOTION_STOP_KEY', 'CLOCK',
    'JOINT_ANGLES', 'TRIAL_TOPICS', 'TOPICS', 'TOPIC_BY_NAME', 'STAGE_HOME', 'STAGE_STOP', 'TARE',
    'CAMERA_ARM', 'CAMERA_TRIGGER', 'START_TRIAL', 'ABORT', 'STUDY_CONTINUE', 'SERVICES',
    'DEVICE_SERVICES', 'GET_STATE', 'CHANGE_STATE', 'SET_PARAMETERS', 'GET_PARAMETERS',
    'SET_PARAMETERS_ATOMICALLY', 'TRANSITION_EVENT', 'node_interface', 'resolve', 'relative',
    'bag_namespace', 'find_topic', 'contract_topic',
]
