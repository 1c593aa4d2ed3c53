"""Device nodes in the simulated rig (issue 4): a simulated pull through the ROS interfaces, and
the ways the nodes refuse bad input or fail. All nodes share one MultiThreadedExecutor in one
process, on a private rclpy context (test/conftest.py keeps DDS on loopback and gives each
test a domain of its own)."""
from __future__ import annotations

import math
import os
import re
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import WrenchStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
import numpy as np
import pytest
import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Float64, Float64MultiArray, Header
from std_srvs.srv import Trigger

from mantis_rig.contract import (
    CAMERA_ARM,
    CAMERA_NODE,
    CAMERA_TRIGGER,
    DIAGNOSTICS,
    FORCE_BLOCK,
    FORCE_CEILING_NAME,
    HEARTBEAT,
    HEARTBEAT_AGE_KEY,
    HEARTBEAT_PERIOD_S,
    JOINT_STATE,
    LOADCELL_NODE,
    MARKERS,
    MOTION_STOPS_KEY,
    SIM_WORLD_NODE,
    STAGE_HOME,
    STAGE_NODE,
    STAGE_STOP,
    TARE,
    TRIGGER_TIME,
    VELOCITY_COMMAND,
    WRENCH,
    resolve,
)
from mantis_rig.hardware.device_interfaces import DeviceError
from mantis_rig.nodes.camera_node import CameraNode
from mantis_rig.nodes.loadcell_node import LoadcellNode
from mantis_rig.nodes.stage_node import StageNode
from mantis_rig.recording.force_block import force_block_from_msg, force_block_to_msg
from mantis_rig.recording.marker_block import concatenate, marker_block_from_msg
from mantis_rig.runtime.executors import Spinner, light_executor
from mantis_rig.simulated.sim_rig import SimRig
from mantis_rig.simulated.world_port import WorldPort

PULL_M_PER_S = 2.33e-3
RATE_HZ = 20_000.0
TIMEOUT_S = 120.0
THREADS = 8           # fewer starve the stream callbacks in this all-in-one process
# The test plays the supervisor: it must see the release and trigger the camera while the
# camera's buffer still holds the strike. PRE_TRIGGER_S / REAL_TIME_FACTOR is its budget in
# wall time (1.6 s here), generous on a busy machine.
REAL_TIME_FACTOR = 0.5
FRAME_RATE_HZ = 5_000.0
PRE_TRIGGER_S = 0.8
POST_TRIGGER_S = 0.05


class Rig:
    """A context on a ROS domain of its own (nodes of another Rig never hear these), an
    executor for device nodes spinning in a thread, and a client node that records topics.

    The client spins on a SingleThreadedExecutor of its own: on a MultiThreadedExecutor its
    subscriptions (one mutually exclusive callback group) kept the executor busy-waiting while
    one of them ran (rclpy's known cost, issue 11), which starved the world of the GIL: a
    pull at 0.5x advanced at 0.1x."""

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(os.environ['ROS_DOMAIN_ID']))
        self.executor = MultiThreadedExecutor(num_threads=THREADS, context=self.context)
        self.nodes = []
        self.client = Node('test_client', context=self.context)
        self.nodes.append(self.client)
        client_executor = light_executor(self.context)
        client_executor.add_node(self.client)
        self.lock = threading.Lock()
        self.received = {}
        self.clients = {}
        for topic, msg_type in ((resolve(FORCE_BLOCK), Float64MultiArray),
                                (resolve(WRENCH), WrenchStamped),
                                (resolve(MARKERS), Float64MultiArray),
                                (resolve(TRIGGER_TIME), TimeReference),
                                (resolve(JOINT_STATE), JointState),
                                (resolve(DIAGNOSTICS), DiagnosticArray)):
            self.received[topic] = []
            self.client.create_subscription(msg_type, topic, self._recorder(topic), 1000)
        self.velocity = self.client.create_publisher(Float64, resolve(VELOCITY_COMMAND), 10)
        self.spinners = [Spinner(self.executor, 'rig'), Spinner(client_executor, 'client')]

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def add_sim_rig(self, parameters):
        """The simulated rig's world and device nodes (backend sim), spun as the stack spins
        them: the world on a light executor, the device nodes on threads of their own."""
        sim_rig = SimRig(parameters, context=self.context)
        world_executor = light_executor(self.context)
        device_executor = MultiThreadedExecutor(num_threads=THREADS, context=self.context)
        sim_rig.add_to(world_executor, device_executor)
        self.spinners += [Spinner(world_executor, 'sim-world'),
                          Spinner(device_executor, 'sim-devices')]
        self.nodes.append(sim_rig)
        return sim_rig

    def _recorder(self, topic):
        def record(msg):
            with self.lock:
                self.received[topic].append(msg)
        return record

    def messages(self, topic):
        with self.lock:
            return list(self.received[topic])

    def call(self, srv_type, name, request=None, timeout_s=TIMEOUT_S):
        """Call a service (its client is kept: discovering a new one takes a while)."""
        if name not in self.clients:
            self.clients[name] = self.client.create_client(srv_type, name)
        client = self.clients[name]
        assert client.wait_for_service(timeout_sec=timeout_s), f'no service {name}'
        future = client.call_async(request or srv_type.Request())
        deadline = time.monotonic() + timeout_s
        while not future.done():
            assert time.monotonic() < deadline, f'{name} did not answer'
            time.sleep(0.01)
        return future.result()

    def transition(self, node_name, transition_id):
        request = ChangeState.Request(transition=Transition(id=transition_id))
        return self.call(ChangeState, f'/{node_name}/change_state', request).success

    def state(self, node_name):
        return self.call(GetState, f'/{node_name}/get_state').current_state.label

    def wait_for(self, predicate, what, timeout_s=TIMEOUT_S):
        deadline = time.monotonic() + timeout_s
        while True:
            result = predicate()
            if result:
                return result
            assert time.monotonic() < deadline, f'timed out waiting for {what}'
            time.sleep(0.02)

    def diagnostics(self, name_prefix):
        return [s for array in self.messages(resolve(DIAGNOSTICS)) for s in array.status
                if s.name.startswith(name_prefix)]

    def close(self):
        """Stop spinning and destroy the nodes; what was received stays readable."""
        for spinner in self.spinners:
            spinner.stop(timeout_s=10.0)
        for node in reversed(self.nodes):
            node.destroy_node()
        rclpy.shutdown(context=self.context)


SCENE = 'air_23mm_rig'


def sim_overrides(**extra):
    return [Parameter('backend', value='sim'), Parameter('scene', value=SCENE),
            *(Parameter(k, value=v) for k, v in extra.items())]


def released(blocks, window=20, jump_n=1.0):
    """The 1 ms mean force moved by more than 1 N from the previous 1 ms (the release)."""
    force = np.concatenate([b.force_n for b in blocks[-3:]])
    means = force[:force.size // window * window].reshape(-1, window).mean(axis=1)
    return bool(np.any(np.abs(np.diff(means)) > jump_n))


def release_index(forces, window=20, jump_n=1.0):
    """Index of the first sample of the first 1 ms whose mean moved by > 1 N."""
    means = forces[:forces.size // window * window].reshape(-1, window).mean(axis=1)
    jumps = np.flatnonzero(np.abs(np.diff(means)) > jump_n)
    assert jumps.size, 'no release in the force stream'
    return (jumps[0] + 1) * window


def pull(rig, velocity_m_per_s=PULL_M_PER_S, attempts=10, wait_s=1.0):
    """Command the pull until /stage/joint_state shows the stage moving, as the supervisor
    does: stage_node refuses a pull (a WARN) until its own force feed has had a reading, which
    can come after the node is active."""
    for _ in range(attempts):
        rig.velocity.publish(Float64(data=velocity_m_per_s))
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            states = rig.messages(resolve(JOINT_STATE))
            if states and states[-1].velocity[0] > 0.0:
                return
            time.sleep(0.01)
    raise AssertionError(f'the stage never took the pull ({attempts} commands)')


@pytest.fixture(scope='module')
def trial():
    """Pull at 2.33 mm/s through the nodes until the release, trigger the camera, stop."""
    rig = Rig()
    try:
        rig.add_sim_rig({
            SIM_WORLD_NODE: {'real_time_factor': REAL_TIME_FACTOR},
            LOADCELL_NODE: {'scene': SCENE, 'seed': 3},
            STAGE_NODE: {'scene': SCENE},
            CAMERA_NODE: {'scene': SCENE, 'frame_rate_hz': FRAME_RATE_HZ,
                            'pre_trigger_s': PRE_TRIGGER_S, 'post_trigger_s': POST_TRIGGER_S}})
        for name in (STAGE_NODE, LOADCELL_NODE, CAMERA_NODE):
            assert rig.transition(name, Transition.TRANSITION_CONFIGURE), name
            assert rig.transition(name, Transition.TRANSITION_ACTIVATE), name
            assert rig.state(name) == 'active'
        assert rig.call(Trigger, resolve(CAMERA_ARM)).success
        pull(rig)
        blocks = []

        def release_seen():
            with rig.lock:
                new = rig.received[resolve(FORCE_BLOCK)][len(blocks):]
            blocks.extend(force_block_from_msg(m) for m in new)
            return len(blocks) >= 3 and released(blocks)

        # discovered before they are needed
        for name in (resolve(CAMERA_TRIGGER), resolve(STAGE_STOP)):
            rig.clients[name] = rig.client.create_client(Trigger, name)
            assert rig.clients[name].wait_for_service(timeout_sec=TIMEOUT_S)
        rig.wait_for(release_seen, 'the release in the force stream')
        rig.velocity.publish(Float64(data=0.0))
        trigger = rig.call(Trigger, resolve(CAMERA_TRIGGER))
        stop = rig.call(Trigger, resolve(STAGE_STOP))
        rig.wait_for(lambda: rig.messages(resolve(MARKERS)), 'marker frames')
        rig.wait_for(lambda: rig.messages(resolve(JOINT_STATE))[-1].velocity[0] == 0.0,
                     'the stage to report a stop')
        # 1 Hz of wall time: a report in phase IV can come before the peak is found, so wait
        # for one that has both (the test below reads the last report)
        rig.wait_for(lambda: any(
            values.get('phase') == 'IV' and math.isfinite(float(values.get('peak_time_s', 'nan')))
            for values in ({kv.key: kv.value for kv in s.values}
                           for s in rig.diagnostics(SIM_WORLD_NODE))),
            'sim_world_node to report phase IV and the peak on /diagnostics')
        time.sleep(0.5)                      # the rest of the marker blocks, a few more samples
    finally:
        rig.close()
    return dict(rig=rig, trigger=trigger, stop=stop)


@pytest.mark.slow
def test_force_stream_rises_and_drops_at_the_release_without_gaps(trial):
    rig = trial['rig']
    blocks = [force_block_from_msg(m) for m in rig.messages(resolve(FORCE_BLOCK))]
    assert len(blocks) > 20
    for before, after in zip(blocks, blocks[1:]):
        assert after.period_s == before.period_s == round(1e9 / RATE_HZ) / 1e9
        assert after.t0_s == pytest.approx(before.t0_s + before.force_n.size * before.period_s,
                                           abs=1e-9)
    t = np.concatenate([b.t0_s + b.period_s * np.arange(b.force_n.size) for b in blocks])
    f = np.concatenate([b.force_n for b in blocks])
    release = release_index(f)
    assert t[release] > t[0] + 0.2
    assert 7.0 < np.median(f[:release - 20]) < 13.0          # phase I: 11.3 -> 8.8 N
    peak = release - 40 + int(np.argmax(f[release - 40:release + 200]))
    assert 13.0 < f[peak] < 25.0                             # the unlatching spike
    assert f[peak:peak + 200].min() < f[peak] - 3.0          # and the drop after it (10 ms)
    wrenches = rig.messages(resolve(WRENCH))
    assert len(wrenches) > 0.5 * (t[-1] - t[0]) * 200.0
    assert 7.0 < np.median([w.wrench.force.x for w in wrenches]) < 13.0


def test_camera_frames_cover_the_strike(trial):
    rig, trigger = trial['rig'], trial['trigger']
    assert trigger.success, trigger.message
    assert trial['stop'].success, trial['stop'].message
    (stamp,) = rig.messages(resolve(TRIGGER_TIME))
    trigger_s = stamp.time_ref.sec + stamp.time_ref.nanosec * 1e-9
    assert stamp.header.stamp == stamp.time_ref            # sim: ROS time is the world's time
    assert stamp.source == 'camera'
    frames = concatenate(marker_block_from_msg(m) for m in rig.messages(resolve(MARKERS)))
    assert set(frames.markers_m) == {'mb1', 'mb2', 'mb3', 'ma1', 'ma2'}
    assert frames.time_s[0] == pytest.approx(trigger_s - PRE_TRIGGER_S, abs=1e-3)
    assert frames.time_s[-1] == pytest.approx(trigger_s + POST_TRIGGER_S, abs=1e-3)
    assert len(frames) == pytest.approx((PRE_TRIGGER_S + POST_TRIGGER_S) * FRAME_RATE_HZ, abs=2)
    blocks = [force_block_from_msg(m) for m in rig.messages(resolve(FORCE_BLOCK))]
    f = np.concatenate([b.force_n for b in blocks])
    release_s = blocks[0].t0_s + release_index(f) / RATE_HZ
    assert frames.time_s[0] < release_s < frames.time_s[-1]
    arm = frames.markers_m['ma2']
    assert np.all(np.abs(arm) < 0.1)                         # metres, not millimetres
    travel = np.linalg.norm(arm - arm[0], axis=1).max()
    assert travel > 3e-3                                     # the strike swings the arm


def test_stage_state_and_diagnostics_while_pulling(trial):
    rig = trial['rig']
    states = rig.messages(resolve(JOINT_STATE))
    assert states and states[0].name == ['stage']
    positions = [s.position[0] for s in states]
    assert max(positions) > positions[0] + 0.2e-3
    assert max(s.velocity[0] for s in states) == pytest.approx(PULL_M_PER_S, rel=0.01)
    assert states[-1].velocity[0] == 0.0                     # stopped
    assert list(states[-1].effort) == [0.0]
    for name in (STAGE_NODE, LOADCELL_NODE, CAMERA_NODE):
        statuses = rig.diagnostics(name)
        assert statuses, name
        assert all(s.level == DiagnosticStatus.OK for s in statuses), \
            [(s.name, s.message) for s in statuses if s.level != DiagnosticStatus.OK]
    stage_values = [{kv.key: kv.value for kv in s.values} for s in rig.diagnostics(STAGE_NODE)]
    assert any(v.get('homed') == 'true' for v in stage_values)
    world = [{kv.key: kv.value for kv in s.values} for s in rig.diagnostics(SIM_WORLD_NODE)]
    assert world and world[-1]['phase'] == 'IV' and float(world[-1]['peak_time_s']) > 0


def test_force_ceiling_stops_the_stage():
    """A ceiling below the unlatching spike (~16 N as the load cell sees it): the load-cell node
    stops the stage and reports ERROR.

    The stage's own stale-force guard is given 5 s here: at 5x on a loaded machine the force
    blocks reached the stage 0.64 s (simulated) late once, its 0.5 s guard faulted first, and
    this test is about the load cell's ceiling (the delivery lag itself is issue 11)."""
    rig = Rig()
    try:
        sim_rig = rig.add_sim_rig({
            SIM_WORLD_NODE: {'real_time_factor': 5.0},
            STAGE_NODE: {'scene': SCENE, 'max_force_age_s': 5.0},
            LOADCELL_NODE: {'scene': SCENE, FORCE_CEILING_NAME: 13.0}})
        for name in (STAGE_NODE, LOADCELL_NODE):
            assert rig.transition(name, Transition.TRANSITION_CONFIGURE), name
            assert rig.transition(name, Transition.TRANSITION_ACTIVATE), name
        pull(rig)
        errors = rig.wait_for(lambda: [s for s in rig.diagnostics(LOADCELL_NODE)
                                       if s.level == DiagnosticStatus.ERROR], 'the ceiling')
        assert 'above the ceiling 13.000 N' in errors[0].message
        rig.wait_for(lambda: sim_rig.world.stage_velocity_m_per_s() == 0.0, 'the stage to stop',
                     30.0)
        assert sim_rig.world.last_strike, 'the ceiling tripped before the release'
        assert rig.state(STAGE_NODE) == 'active'
    finally:
        rig.close()


def test_a_pull_ends_at_its_bound_and_the_stage_says_so():
    """stage_node executes a pull as a move to where it starts + travel_mm, which the world
    ends at rest there with nobody stopping it: a motion stop on /diagnostics (the supervisor
    ends its trial on it). Nobody commands a stop here."""
    rig = Rig()
    try:
        sim_rig = rig.add_sim_rig({
            SIM_WORLD_NODE: {'real_time_factor': 0.0},
            STAGE_NODE: {'scene': SCENE, 'max_force_age_s': 5.0, 'travel_mm': 0.5},
            LOADCELL_NODE: {'scene': SCENE}})
        for name in (STAGE_NODE, LOADCELL_NODE):
            assert rig.transition(name, Transition.TRANSITION_CONFIGURE), name
            assert rig.transition(name, Transition.TRANSITION_ACTIVATE), name
        world = sim_rig.world
        start_m = world.stage_position_m()
        pull(rig)
        ended = rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                                      if 'the pull reached its bound' in s.message],
                             'the pull to end at its bound', 60.0)
        assert ended[0].level == DiagnosticStatus.WARN
        assert f'its start {start_m * 1e3:.4f} mm + travel_mm 0.5 mm' in ended[0].message
        assert {kv.key: kv.value for kv in ended[0].values}[MOTION_STOPS_KEY] == '1'
        assert world.stage_velocity_m_per_s() == 0.0
        assert world.stage_position_m() == pytest.approx(start_m + 0.5e-3, abs=1e-9)
    finally:
        rig.close()


class FakeSupervisorHeartbeat:
    """The supervisor's heartbeat, from the test's client, until freeze() (as a SIGSTOP would
    leave it) or resume()."""

    def __init__(self, rig):
        self._pub = rig.client.create_publisher(Header, resolve(HEARTBEAT),
                                                HEARTBEAT.qos.publisher())
        self._beating = threading.Event()
        self._done = threading.Event()
        self.last_s = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._beating.set()
        self._thread.start()

    def _run(self):
        while not self._done.wait(HEARTBEAT_PERIOD_S):
            if self._beating.is_set():
                self._pub.publish(Header(frame_id='fake supervisor'))
                self.last_s = time.monotonic()

    def freeze(self):
        self._beating.clear()
        time.sleep(2 * HEARTBEAT_PERIOD_S)        # the beat that may have been on its way
        return self.last_s

    def resume(self):
        self._beating.set()

    def close(self):
        self._done.set()
        self._thread.join()


def test_a_pull_stops_when_the_supervisors_heartbeat_lapses():
    """The stage node stops a pull it was given while a supervisor's heartbeat was heard once
    that heartbeat lapses, says why, refuses the next command while it stays silent, and takes
    one again once it beats. The pull's bound (travel_mm 15) is far: only the lapse stops it."""
    rig = Rig()
    heartbeat = None
    try:
        sim_rig = rig.add_sim_rig({
            SIM_WORLD_NODE: {'real_time_factor': 1.0},
            STAGE_NODE: {'scene': SCENE, 'max_force_age_s': 5.0, 'travel_mm': 15.0},
            LOADCELL_NODE: {'scene': SCENE}})
        for name in (STAGE_NODE, LOADCELL_NODE):
            assert rig.transition(name, Transition.TRANSITION_CONFIGURE), name
            assert rig.transition(name, Transition.TRANSITION_ACTIVATE), name
        heartbeat = FakeSupervisorHeartbeat(rig)
        rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE) if HEARTBEAT_AGE_KEY in
                              {kv.key for kv in s.values}], 'the stage to hear the heartbeat')
        world = sim_rig.world
        start_m = world.stage_position_m()
        pull(rig)
        rig.wait_for(lambda: world.stage_position_m() > start_m + 0.2e-3, 'the pull', 30.0)
        last_beat = heartbeat.freeze()
        frozen_at_m = world.stage_position_m()
        stopped = rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                                        if 'supervisor heartbeat lost' in s.message],
                               'the lapse to stop the stage', 30.0)
        stop_heard_s = time.monotonic()
        rig.wait_for(lambda: world.stage_velocity_m_per_s() == 0.0, 'the stage at rest', 30.0)
        stopped_at_m = world.stage_position_m()
        status = stopped[0]
        values = {kv.key: kv.value for kv in status.values}
        assert status.level == DiagnosticStatus.WARN
        assert re.search(r'supervisor heartbeat lost for 0\.\d\d s \(limit 0\.4 s\): the pull at '
                         r'2\.3300 mm/s was stopped', status.message), status.message
        assert values[MOTION_STOPS_KEY] == '1'
        assert stopped_at_m < start_m + 15e-3           # its bound was not what stopped it
        print(f'heartbeat lapse: stop reported {stop_heard_s - last_beat:.2f} s after the last '
              f'beat; {(stopped_at_m - frozen_at_m) * 1e3:.3f} mm pulled after it')
        # silent: a new command is refused, the stage stays
        rig.velocity.publish(Float64(data=PULL_M_PER_S))
        rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                              if 'refused: supervisor heartbeat lost' in s.message],
                     'the refusal', 30.0)
        time.sleep(0.3)
        assert world.stage_velocity_m_per_s() == 0.0
        heartbeat.resume()
        time.sleep(0.3)
        pull(rig)
    finally:
        if heartbeat is not None:
            heartbeat.close()
        rig.close()


# --- refusals and faults (no world needed) -------------------------------------------------------

@pytest.fixture
def rig():
    rig = Rig()
    yield rig
    rig.close()


def test_invalid_parameters_are_refused_with_the_reason(rig):
    loadcell = rig.add(LoadcellNode(context=rig.context))
    stage = rig.add(StageNode(context=rig.context))
    camera = rig.add(CameraNode(context=rig.context))
    cases = [
        (loadcell, 'sample_rate_hz', 5e6, 'out of range'),
        (loadcell, FORCE_CEILING_NAME, -1.0, 'out of range'),
        (loadcell, 'channel', 'Dev1/xx', 'does not parse'),
        (loadcell, 'backend', 'simulated', "valid backends: sim, hardware"),
        (loadcell, 'scene', 'no_such_scene', 'unknown scene'),
        (stage, 'move_speed_m_per_s', 0.01, 'out of range'),
        (camera, 'frame_rate_hz', 50_000.0, 'out of range'),
        (camera, 'lines', 'Dev1/port9/line0', 'does not exist'),
    ]
    for node, name, value, reason in cases:
        before = node.get_parameter(name).value
        (result,) = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful, (name, value)
        assert reason in result.reason, result.reason
        assert node.get_parameter(name).value == before
    (ok,) = loadcell.set_parameters([Parameter(FORCE_CEILING_NAME, value=20.0)])
    assert ok.successful


def test_the_hardware_camera_refuses_to_film_and_the_simulated_one_takes_a_folder(rig):
    """The rig's camera records itself: film_dir is the simulated camera's."""
    hardware = rig.add(CameraNode(context=rig.context, parameter_overrides=[
        Parameter('backend', value='hardware')]))
    (result,) = hardware.set_parameters([Parameter('film_dir', value='/tmp/film')])
    assert not result.successful and 'records the strike itself' in result.reason
    (result,) = hardware.set_parameters([Parameter('film_dir', value='')])
    assert result.successful
    sim = rig.add(CameraNode('camera_node_sim', context=rig.context))
    (result,) = sim.set_parameters([Parameter('film_dir', value='relative/film')])
    assert not result.successful and 'not an absolute path' in result.reason
    (result,) = sim.set_parameters([Parameter('film_dir', value='/tmp/bag/video')])
    assert result.successful


def configure_fails(rig, name):
    """Configure is refused, the node stays unconfigured; its last ERROR on /diagnostics."""
    assert not rig.transition(name, Transition.TRANSITION_CONFIGURE)
    assert rig.state(name) == 'unconfigured'
    errors = rig.wait_for(lambda: [s for s in rig.diagnostics(name)
                                   if s.level == DiagnosticStatus.ERROR], 'an ERROR', 30.0)
    return errors[-1]


def test_unknown_backend_fails_configure_with_the_reason_on_diagnostics(rig):
    rig.add(StageNode(context=rig.context,
                      parameter_overrides=[Parameter('backend', value='simulator')]))
    error = configure_fails(rig, STAGE_NODE)
    assert "unknown backend 'simulator'" in error.message
    assert 'sim, hardware' in error.message


def test_a_simulated_device_alone_refuses_to_configure_and_names_the_rig(rig):
    """Outside the simulated rig there is no world for the sim backend to reach."""
    rig.add(LoadcellNode(context=rig.context, parameter_overrides=sim_overrides()))
    error = configure_fails(rig, LOADCELL_NODE)
    assert 'runs inside the simulated rig' in error.message
    assert 'ros2 run mantis_rig sim_rig' in error.message


class FailingWorld(WorldPort):
    """A simulated world that serves a few force blocks, then its link fails."""

    def __init__(self, blocks_before_failure=5):
        self.left = blocks_before_failure
        self.t = 0.0

    def now_s(self):
        return self.t

    def wait_until(self, t_s, timeout_s):
        self.t = max(self.t, t_s)

    def set_stage_velocity(self, velocity_m_per_s):
        pass

    def move_stage_to(self, position_m, speed_m_per_s):
        pass

    def stage_state(self):
        return 0.012, 0.0

    def tendon_force(self, t0_s, period_s, n, timeout_s):
        time.sleep(0.005)
        if self.left <= 0:
            raise DeviceError('simulated world link lost')
        self.left -= 1
        self.t = t0_s + n * period_s
        return np.full(n, 10.0)

    def marker_frames(self, times_s, timeout_s):
        raise DeviceError('no camera here')


def test_device_error_takes_the_node_through_its_error_state(rig):
    rig.add(LoadcellNode(context=rig.context, world_port=FailingWorld(),
                         parameter_overrides=sim_overrides()))
    assert rig.transition(LOADCELL_NODE, Transition.TRANSITION_CONFIGURE)
    assert rig.transition(LOADCELL_NODE, Transition.TRANSITION_ACTIVATE)
    errors = rig.wait_for(lambda: [s for s in rig.diagnostics(LOADCELL_NODE)
                                   if 'device released' in s.message], 'on_error', 30.0)
    assert errors[-1].level == DiagnosticStatus.ERROR
    assert 'simulated world link lost' in errors[-1].message
    assert rig.state(LOADCELL_NODE) == 'unconfigured'
    assert len(rig.messages(resolve(FORCE_BLOCK))) == 5
    # it can be configured again
    assert rig.transition(LOADCELL_NODE, Transition.TRANSITION_CONFIGURE)


def test_services_refuse_in_the_wrong_state(rig):
    rig.add(CameraNode(context=rig.context, world_port=FailingWorld(),
                       parameter_overrides=sim_overrides()))
    rig.add(StageNode(context=rig.context, world_port=FailingWorld(),
                      parameter_overrides=sim_overrides()))
    answer = rig.call(Trigger, resolve(CAMERA_TRIGGER))
    assert not answer.success and 'unconfigured' in answer.message
    assert rig.transition(CAMERA_NODE, Transition.TRANSITION_CONFIGURE)
    assert rig.transition(CAMERA_NODE, Transition.TRANSITION_ACTIVATE)
    answer = rig.call(Trigger, resolve(CAMERA_TRIGGER))
    assert not answer.success and 'not armed' in answer.message
    assert rig.transition(STAGE_NODE, Transition.TRANSITION_CONFIGURE)
    answer = rig.call(Trigger, resolve(STAGE_HOME))
    assert not answer.success and 'inactive' in answer.message
    (result,) = rig.nodes[-1].set_parameters([Parameter('serial_port', value='/dev/ttyS3')])
    assert not result.successful and 'applied at configure' in result.reason


# --- hardware backends against the KDC101 emulator and the fake nidaqmx ----------------------

@pytest.mark.slow
@pytest.mark.parametrize('streams_status', [True, False], ids=['streaming', 'polled'])
def test_hardware_stage_node_on_the_kdc101_emulator(rig, streams_status):
    """Also against a controller that ignores HW_START_UPDATEMSGS: the driver polls it."""
    from fakes.kdc101_emulator import Kdc101Emulator
    emulator = Kdc101Emulator(position_mm=5.0, streams_status=streams_status).start()
    try:
        # The stale-force guard gets 5 s: on a loaded machine the feeder's 5 N blocks once
        # reached the node 0.66 s apart and its 0.5 s guard faulted before the 31 N block
        # could trip the ceiling this test is about (test_kdc101 tests the stale guard).
        rig.add(StageNode(context=rig.context, parameter_overrides=[
            Parameter('backend', value='hardware'), Parameter('serial_port', value=emulator.port),
            Parameter('joint_state_rate_hz', value=20.0), Parameter('max_force_age_s', value=5.0)]))
        assert rig.transition(STAGE_NODE, Transition.TRANSITION_CONFIGURE)
        assert rig.transition(STAGE_NODE, Transition.TRANSITION_ACTIVATE)
        rig.wait_for(lambda: rig.messages(resolve(JOINT_STATE)), 'a joint state', 30.0)
        assert rig.messages(resolve(JOINT_STATE))[-1].position[0] == pytest.approx(5e-3, abs=1e-5)
        home = rig.call(Trigger, resolve(STAGE_HOME))
        assert home.success, home.message
        rig.velocity.publish(Float64(data=5e-3))                 # above the 2.4 mm/s ceiling
        refused = rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                                        if s.level == DiagnosticStatus.WARN], 'a refusal', 30.0)
        assert 'exceeds the ceiling' in refused[-1].message
        # the driver-level force guard: no force reading, no pull
        rig.velocity.publish(Float64(data=2e-3))
        refused = rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                                        if 'force reading' in s.message], 'a blind pull refused',
                               30.0)
        assert refused[-1].level == DiagnosticStatus.WARN
        time.sleep(0.5)
        assert abs(rig.messages(resolve(JOINT_STATE))[-1].position[0]) < 0.05e-3   # homed at 0
        # with the load cell's stream below the ceiling the stage pulls
        forces = rig.client.create_publisher(Float64MultiArray, resolve(FORCE_BLOCK), 100)
        feeding = threading.Event()

        def feed(newtons):
            while not feeding.is_set():
                forces.publish(force_block_to_msg(time.time(), 50e-6, np.full(200, newtons)))
                time.sleep(0.01)
        feeder = threading.Thread(target=feed, args=(5.0,), daemon=True)
        feeder.start()
        time.sleep(0.3)
        rig.velocity.publish(Float64(data=2e-3))
        rig.wait_for(lambda: rig.messages(resolve(JOINT_STATE))[-1].position[0] > 0.2e-3,
                     'the stage to move', 30.0)
        if not streams_status:           # the positions came from answered polls
            assert emulator.status_requests_answered > 3
        # a block over the ceiling (30 N) stops it, in the driver layer: an ERROR, latched; the
        # stage stays open and active, and refuses to pull until it is activated again
        feeding.set()
        feeder.join()
        forces.publish(force_block_to_msg(time.time(), 50e-6, np.full(200, 31.0)))
        tripped = rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                                        if 'above the ceiling' in s.message], 'the trip', 30.0)
        assert tripped[-1].level == DiagnosticStatus.ERROR
        rig.wait_for(lambda: not emulator.moving, 'the stage to stop', 30.0)
        assert rig.state(STAGE_NODE) == 'active'
        forces.publish(force_block_to_msg(time.time(), 50e-6, np.full(200, 5.0)))
        rig.velocity.publish(Float64(data=2e-3))
        rig.wait_for(lambda: [s for s in rig.diagnostics(STAGE_NODE)
                              if s.level == DiagnosticStatus.WARN and 'refused' in s.message
                              and 'ceiling' in s.message], 'the latched guard to refuse', 30.0)
        assert not emulator.moving
        assert rig.transition(STAGE_NODE, Transition.TRANSITION_DEACTIVATE)
        assert rig.transition(STAGE_NODE, Transition.TRANSITION_ACTIVATE)     # trip cleared
        released_before = len(device_released(rig, STAGE_NODE))
        emulator.vanish()                                        # the USB cable is pulled
        rig.wait_for(lambda: len(device_released(rig, STAGE_NODE)) > released_before, 'on_error',
                     30.0)
        assert device_released(rig, STAGE_NODE)[-1].level == DiagnosticStatus.ERROR
        rig.wait_for(lambda: rig.state(STAGE_NODE) == 'unconfigured', 'unconfigured', 30.0)
    finally:
        emulator.close()


def device_released(rig, node):
    return [s for s in rig.diagnostics(node) if 'device released' in s.message]


def test_hardware_loadcell_node_on_the_fake_daq(rig, monkeypatch):
    from fakes_nidaq import FakeDaqSystem

    def paced_signal(index):                      # the fake delivers at once: pace it
        time.sleep(index.size / RATE_HZ)
        return np.full(index.shape, 0.5)

    system = FakeDaqSystem(signal_v=paced_signal).install(monkeypatch)
    rig.add(LoadcellNode(context=rig.context, parameter_overrides=[
        Parameter('backend', value='hardware'), Parameter('block_size', value=1000)]))
    assert rig.transition(LOADCELL_NODE, Transition.TRANSITION_CONFIGURE)
    assert rig.transition(LOADCELL_NODE, Transition.TRANSITION_ACTIVATE)
    rig.wait_for(lambda: len(rig.messages(resolve(FORCE_BLOCK))) >= 5, 'force blocks', 30.0)
    tare = rig.call(Trigger, resolve(TARE))
    assert tare.success and 'restarted' in tare.message, tare.message
    rig.wait_for(lambda: force_block_from_msg(
        rig.messages(resolve(FORCE_BLOCK))[-1]).force_n.max() < 0.01, 'a tared force', 30.0)
    blocks = [force_block_from_msg(m) for m in rig.messages(resolve(FORCE_BLOCK))]
    assert blocks[0].force_n == pytest.approx(0.5 * 11.12)
    assert abs(blocks[0].t0_s - time.time()) < 60.0      # ROS (wall) time, not monotonic
    # epoch seconds in a float64 resolve ~0.24 us (recording/force_block.py)
    assert abs(blocks[1].t0_s - blocks[0].t0_s - 1000 * blocks[0].period_s) < 1e-6
    system.remove_device()
    errors = rig.wait_for(lambda: [s for s in rig.diagnostics(LOADCELL_NODE)
                                   if 'device released' in s.message], 'on_error', 30.0)
    assert errors[-1].level == DiagnosticStatus.ERROR
    assert rig.state(LOADCELL_NODE) == 'unconfigured'
