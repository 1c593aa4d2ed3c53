"""The supervisor's logic without devices: force monitor, trial conditions, the trial state
machine against a fake rig, and the supervisor node's refusals over ROS."""
import threading
import time

import numpy as np
import pytest

from mantis_rig.contract import (
    CAMERA_NODE,
    FORCE_CEILING_NAME,
    LOADCELL_NODE,
    SIM_WORLD_NODE,
    STAGE_NODE,
    SUPERVISOR_STATE,
    TRAVEL_NAME,
    resolve,
)
from mantis_rig.trial.force_monitor import ForceMonitor
from mantis_rig.trial.sequence import DEVICE_NODES, Pending, TrialSequence
from mantis_rig.trial.supervisor_settings import ConditionError, TrialConditions, check_value

RATE = 20_000.0


# --------------------------------------------------------------------------- force monitor
def _feed(monitor, forces, t0=1.0, block=200):
    for i in range(0, len(forces), block):
        monitor.feed(t0 + i / RATE, 1 / RATE, forces[i:i + block])


def test_monitor_detects_the_release_jump_not_the_slow_pull():
    t = np.arange(40_000) / RATE
    forces = 11.3 - 1.2 * t + np.random.default_rng(0).normal(0, 0.01, t.size)
    forces[30_000:] += 8.0                         # the strike, at t0 + 1.5 s
    monitor = ForceMonitor(ceiling_n=30.0)
    _feed(monitor, forces[:1000])
    monitor.arm_release()
    _feed(monitor, forces[1000:], t0=1.0 + 1000 / RATE)
    assert monitor.release_t_s == pytest.approx(2.5, abs=2e-3)
    assert monitor.samples == 40_000 and not monitor.gaps
    assert monitor.duration_s == pytest.approx(2.0)
    assert monitor.ceiling_hit is None and monitor.peak_n > 17


def test_monitor_counts_gaps_and_ceiling():
    monitor = ForceMonitor(ceiling_n=5.0)
    monitor.feed(0.0, 1 / RATE, np.ones(100))
    monitor.feed(200 / RATE, 1 / RATE, np.r_[np.ones(50), 6.0 * np.ones(50)])
    assert monitor.gaps == [(pytest.approx(100 / RATE), 100)]
    assert monitor.ceiling_hit == (pytest.approx(250 / RATE), 6.0)
    assert monitor.release_t_s is None             # not armed


# --------------------------------------------------------------------------- conditions
def test_conditions_refuse_out_of_range_values_with_the_reason():
    TrialConditions().validate()
    with pytest.raises(ConditionError, match=r'pull_speed_mm_s = 5.0 mm/s is outside'):
        TrialConditions(pull_speed_mm_s=5.0).validate()
    with pytest.raises(ConditionError, match='backend = .warp. is not one of sim, hardware'):
        check_value('backend', 'warp')
    with pytest.raises(ConditionError, match='camera buffer'):
        TrialConditions(pre_trigger_s=0.8, post_trigger_s=0.5).validate()
    assert TrialConditions(operator_note='x').metadata()['operator_note'] == 'x'


# --------------------------------------------------------------------------- fake rig
class FakeRig:
    """A rig in simulated time: pulling 3 mm unlatches (force jumps by 7 N), the tendon then
    stiffens at 50 N/mm. Steps of 10 ms feed 200-sample force blocks to the sequence."""

    def __init__(self, force0=11.3, release_mm=3.0, homed=True):
        self.seq = None
        self.t = 0.0
        self.pos, self.v, self.target = 0.010, 0.0, None
        self.origin = 0.010
        self.force0, self.release_mm = force0, release_mm
        self.released_at_pos = None
        self.lifecycle = dict.fromkeys(DEVICE_NODES, 'unconfigured')
        self.refuse = {}
        self.calls, self.states, self.stops = [], [], 0
        self.homed = homed
        self.camera = None
        self.parameters = {}
        self.trigger_t = None
        self.markers_sent = False
        self.progress = []
        self.fed_until_s = None
        self._run = threading.Event()

    # RigPort
    def now_s(self):
        return self.t

    def get_state(self, node):
        return Pending((True, self.lifecycle[node]), done=True)

    def change_state(self, node, transition):
        if (node, transition) in self.refuse:
            return Pending((False, self.refuse[node, transition]), done=True)
        self.lifecycle[node] = {'configure': 'inactive', 'activate': 'active'}[transition]
        return Pending((True, ''), done=True)

    def call(self, service):
        self.calls.append(service)
        if service in self.refuse:
            return Pending((False, self.refuse[service]), done=True)
        if service == 'camera/trigger':
            self.trigger_t = self.t
            self.seq.on_camera_trigger(self.t)
        if service == 'stage/home':
            self.pos, self.homed = 0.0, True
        if service == 'stage/stop':
            self.v, self.target = 0.0, None
        return Pending((True, 'ok'), done=True)

    def set_camera(self, frame_rate_hz, pre_trigger_s, post_trigger_s, film_dir=''):
        self.camera = (frame_rate_hz, pre_trigger_s, post_trigger_s)
        self.film_dir = film_dir
        return Pending((True, ''), done=True)

    def set_parameters(self, node, values):
        # what each node was given, and in which lifecycle state (the world has none)
        self.parameters.setdefault(node, []).append((dict(values), self.lifecycle.get(node)))
        if node in self.refuse:
            return Pending((False, self.refuse[node]), done=True)
        if node == SIM_WORLD_NODE:          # the world's status: the robot at them, now
            self.seq.on_world_status({'time_s': f'{self.t:.4f}', **{
                k: f'{v:g}' if isinstance(v, float) else v for k, v in values.items()}})
        return Pending((True, ''), done=True)

    def move_at(self, v):
        self.v, self.target = v, None

    def move_to(self, p):
        self.target = p

    def stop_stage(self):
        self.stops += 1
        self.v, self.target = 0.0, None

    def publish_state(self, state, reason):
        self.states.append(state)

    def report_progress(self, rig_time_s):
        # what the trial said it had acted on, beside what it could have heard by then
        self.progress.append((rig_time_s, self.t, self.fed_until_s))

    # the world
    def force(self, pos):
        pulled_mm = (pos - self.origin) * 1e3
        if self.released_at_pos is None and pulled_mm >= self.release_mm:
            self.released_at_pos = pos
        if self.released_at_pos is None:
            return self.force0 - 0.5 * max(pulled_mm, 0)
        return self.force0 + 7.0 + 50.0 * (pos - self.released_at_pos) * 1e3

    def step(self, dt=0.01):
        n = round(dt * RATE)
        if self.target is not None:
            dx = self.target - self.pos
            self.v = np.sign(dx) * min(abs(dx) / dt, 2e-3) if abs(dx) > 1e-9 else 0.0
        positions = self.pos + self.v * np.arange(1, n + 1) / RATE
        forces = np.array([self.force(p) for p in positions])
        t0 = self.t
        self.pos = positions[-1]
        self.t += dt
        if self.target is not None and abs(self.target - self.pos) < 1e-9:
            self.v, self.target = 0.0, None
        seq = self.seq
        self.fed_until_s = t0 + n / RATE
        seq.on_force_block(t0, 1 / RATE, forces)
        seq.on_stage_state(self.pos, self.v)
        if self.trigger_t is not None and not self.markers_sent and self.camera \
                and self.t > self.trigger_t + self.camera[2]:
            self.markers_sent = True
            seq.on_markers(self.trigger_t - self.camera[1], self.trigger_t + self.camera[2], 100)

    def run_world(self):
        while not self._run.is_set():
            self.step()
            time.sleep(0.001)

    def start(self, seq):
        self.seq = seq
        seq.on_stage_homed(self.homed)
        self.step()
        threading.Thread(target=self.run_world, daemon=True).start()
        return self

    def halt(self):
        self._run.set()


def run_trial(rig=None, timeout=30.0, before=None, **conditions):
    rig = rig or FakeRig()
    closed = []
    seq = TrialSequence(rig, TrialConditions(**conditions), closed.append)
    rig.start(seq)
    if before:
        before(rig, seq)
    seq.start()
    assert seq.finished.wait(timeout)
    rig.halt()
    assert closed == [seq.outcome]
    return rig, seq, seq.outcome


def test_a_trial_runs_through_every_phase_and_returns():
    rig, seq, outcome = run_trial()
    assert rig.states == ['configuring', 'taking_up_slack', 'arming', 'pulling', 'released',
                          'stopping', 'returning', 'done', 'waiting_for_relatch']
    assert outcome['result'] == 'completed' and outcome['reason'] == ''
    assert set(rig.lifecycle.values()) == {'active'}
    assert rig.calls[:2] == ['camera/arm', 'camera/trigger']
    assert rig.camera == (19000.0, 0.3, 0.05)
    assert outcome['release_in_camera_window'] == 'true'
    assert float(outcome['release_time_s']) <= float(outcome['camera_trigger_time_s'])
    assert abs(rig.pos - 0.010) < 20e-6           # back at the start
    assert outcome['force_gaps'] == 0 and outcome['force_samples'] > 20_000
    assert 'pulling@' in outcome['states']


def test_the_trial_reports_only_what_it_has_heard_and_acted_on():
    """Its progress (which the simulated world waits for) never runs ahead of the rig's
    clock or of the force it was fed, never goes back within a trial, goes on while an
    aborted trial returns the stage, and is 0 once the trial has ended."""
    def abort_mid_pull(rig, seq):
        def abort():
            while seq.state != 'pulling':
                time.sleep(0.001)
            time.sleep(0.05)
            seq.abort('operator')
        threading.Thread(target=abort, daemon=True).start()

    for before, result in ((None, 'completed'), (abort_mid_pull, 'aborted')):
        rig, seq, outcome = run_trial(before=before)
        assert outcome['result'] == result, outcome
        *during, (last, _, _) = rig.progress
        assert last == 0.0 and len(during) > 10
        for acted_s, clock_s, fed_s in during:
            assert 0.0 < acted_s <= clock_s
            assert fed_s is None or acted_s <= fed_s
        acted = [a for a, _, _ in during]
        assert acted == sorted(acted)
        returning = dict(seq.state_times)['returning']
        assert max(acted) > returning          # reported while the stage went back


def test_homes_takes_up_slack_and_tares_when_needed():
    rig = FakeRig(force0=0.0, homed=False)
    rig.origin, rig.pos = 0.001, 0.0002
    # slack until 1 mm, then the force rises as the stage moves
    rig.force = lambda pos, f=rig.force: f(pos) + max(0.0, (pos - 0.001) * 1e3) * 4.0
    _, seq, outcome = run_trial(rig, tare=True, start_position_mm=0.5)
    assert rig.states[:6] == ['configuring', 'homing', 'returning', 'taking_up_slack', 'taring',
                              'arming'], outcome
    assert rig.calls[:2] == ['stage/home', 'loadcell/tare'] and rig.stops >= 1
    assert 'loadcell/tare' in rig.calls
    assert outcome['result'] == 'completed', outcome


def test_force_ceiling_aborts_and_stops_the_stage():
    rig, seq, outcome = run_trial(force_ceiling_n=15.0)
    assert outcome['result'] == 'aborted'
    assert outcome['reason'].startswith('force ceiling: ')
    # the ceiling caught the release's jump: it struck, so the robot needs a re-latch
    assert rig.states[-3:] == ['returning', 'aborted', 'waiting_for_relatch']
    assert rig.v == 0.0 and rig.stops >= 1
    assert outcome['stage_returned'] == 'true' and abs(rig.pos - rig.origin) < 1e-4


def test_the_trials_force_ceiling_is_set_on_every_guard_before_it_is_configured():
    """And its travel limit on the stage, whose controller ends every pull there."""
    rig, _, outcome = run_trial(force_ceiling_n=12.5, travel_mm=6.5)
    assert outcome['result'] == 'aborted'
    assert rig.parameters == {
        SIM_WORLD_NODE: [({'d_t_mm': 23.0, 'contact_angle_deg': 3.0, 'medium': 'air'}, None)],
        STAGE_NODE: [({FORCE_CEILING_NAME: 12.5, TRAVEL_NAME: 6.5}, 'unconfigured')],
        LOADCELL_NODE: [({FORCE_CEILING_NAME: 12.5}, 'unconfigured')]}


def test_a_simulated_trial_sets_its_conditions_on_the_world_before_anything_else():
    rig, _, outcome = run_trial(d_t_mm=19.0, contact_angle_deg=5.0, medium='water')
    assert outcome['result'] == 'completed', outcome
    assert rig.parameters[SIM_WORLD_NODE] == [
        ({'d_t_mm': 19.0, 'contact_angle_deg': 5.0, 'medium': 'water'}, None)]
    rig, _, outcome = run_trial(backend='hardware')       # no world on the real rig
    assert SIM_WORLD_NODE not in rig.parameters


class BuildsTheRobotLate(FakeRig):
    """A world that answers at once but builds the robot at the trial's conditions 0.3 s of
    rig time later (a busy machine, the request on its way): the tendon force steps down by
    1.5 N then, and its status says so."""

    BUILD_AFTER_S = 0.3

    def __init__(self):
        super().__init__()
        self.build_at_s = self.built = None

    def set_parameters(self, node, values):
        if node != SIM_WORLD_NODE:
            return super().set_parameters(node, values)
        self.parameters.setdefault(node, []).append((dict(values), None))
        self.build_at_s, self.built = self.t + self.BUILD_AFTER_S, dict(values)
        return Pending((True, ''), done=True)

    def force(self, pos):
        built = self.build_at_s is not None and self.t >= self.build_at_s
        return super().force(pos) - (1.5 if built else 0.0)

    def step(self, dt=0.01):
        super().step(dt)
        if self.built is not None and self.t >= self.build_at_s:
            values, self.built = self.built, None
            status = {k: str(v) for k, v in values.items()}
            self.seq.on_world_status({'time_s': str(self.t), **status})


def test_the_force_step_of_a_robot_built_late_is_not_taken_for_the_release():
    rig, seq, outcome = run_trial(BuildsTheRobotLate(), d_t_mm=19.0)
    assert outcome['result'] == 'completed', outcome
    pulling_s = dict(seq.state_times)['pulling']
    assert pulling_s >= rig.build_at_s
    # the release 3 mm into the pull, at 2.33 mm/s: not the step when the robot was built
    assert float(outcome['release_time_s']) - pulling_s == pytest.approx(3 / 2.33, abs=0.05)


def test_a_garbled_world_status_matches_nothing_and_breaks_nothing():
    class GarblesFirst(FakeRig):
        def set_parameters(self, node, values):
            if node == SIM_WORLD_NODE:
                for garbled in ({'time_s': 'soon', **{k: str(v) for k, v in values.items()}},
                                {'time_s': '1.0', 'd_t_mm': 'wide', 'medium': None}, {}):
                    self.seq.on_world_status(garbled)
                assert self.seq.world_built_s is None
            return super().set_parameters(node, values)

    rig, seq, outcome = run_trial(GarblesFirst())
    assert outcome['result'] == 'completed', outcome
    assert seq.world_built_s is not None


def test_a_lost_answer_from_the_simulated_world_is_asked_for_again(monkeypatch):
    from mantis_rig.trial import sequence as trial_sequence
    monkeypatch.setattr(trial_sequence, 'QUERY_RETRY_S', 0.2)

    class LosesTheWorldsFirstAnswer(FakeRig):
        def set_parameters(self, node, values):
            answer = super().set_parameters(node, values)
            if node == SIM_WORLD_NODE and len(self.parameters[node]) == 1:
                return Pending()                   # never answered
            return answer
    rig, _, outcome = run_trial(LosesTheWorldsFirstAnswer())
    assert outcome['result'] == 'completed', outcome
    assert len(rig.parameters[SIM_WORLD_NODE]) == 2


def test_conditions_the_simulated_world_refuses_end_the_trial_before_anything_moves():
    rig = FakeRig()
    rig.refuse[SIM_WORLD_NODE] = ('sim_world_node: medium = vacuum: scene air_23mm_rig '
                                  'simulates the fluid around the robot')
    rig, seq, outcome = run_trial(rig, medium='vacuum')
    assert outcome['result'] == 'aborted'
    assert outcome['reason'] == ("the simulated world could not apply the trial's conditions: "
                                 'sim_world_node: medium = vacuum: scene air_23mm_rig '
                                 'simulates the fluid around the robot')
    assert rig.states == ['configuring', 'aborted']
    assert set(rig.lifecycle.values()) == {'unconfigured'}       # nothing brought up
    assert abs(rig.pos - rig.origin) < 1e-9                      # nor moved


def test_without_the_supervisors_monitor_the_ceiling_is_left_to_the_guards():
    _, _, outcome = run_trial(force_ceiling_n=15.0, supervisor_force_monitor=False)
    assert outcome['result'] == 'completed', outcome      # the fake rig has no guards


def test_travel_limit_aborts():
    _, _, outcome = run_trial(travel_mm=1.0)
    assert outcome['result'] == 'aborted'
    assert outcome['reason'].startswith('travel limit: the stage moved ')


def test_device_fault_and_operator_abort():
    def fault_when_pulling(rig, seq):
        def watch():
            while seq.state != 'pulling':
                time.sleep(0.001)
            seq.on_device_fault(LOADCELL_NODE, 'DAQ overrun')
        threading.Thread(target=watch, daemon=True).start()
    rig, seq, outcome = run_trial(before=fault_when_pulling)
    assert outcome['reason'] == 'device fault: loadcell_node: DAQ overrun'
    assert rig.v == 0.0
    assert seq.abort('again') == (False, 'no trial in progress (state aborted)')

    def operator(rig, seq):
        assert seq.abort('too early') == (False, 'no trial in progress (state idle)')

        def watch():
            while seq.state != 'pulling':
                time.sleep(0.001)
            assert seq.abort('operator')[0]
            assert seq.abort('twice')[0] is False
        threading.Thread(target=watch, daemon=True).start()
    _, _, outcome = run_trial(before=operator)
    assert outcome['reason'] == 'operator'


def test_failed_bring_up_names_the_device_and_its_reason():
    rig = FakeRig()
    rig.refuse[CAMERA_NODE, 'configure'] = 'transition refused'

    def diagnose(rig, seq):
        seq.on_device_message(CAMERA_NODE, "unknown backend 'warp'")
    _, _, outcome = run_trial(rig, before=diagnose)
    assert outcome['result'] == 'aborted'
    assert outcome['reason'] == ("camera_node configure failed: transition refused "
                                 "(camera_node reports: unknown backend 'warp')")


class LossyRig(FakeRig):
    """Loses the first reply to each node's get_state and to stage_node's configure, as DDS can
    while it is still matching a node that has just started; the transition takes effect."""

    def __init__(self):
        super().__init__()
        self.lost = set()
        self.queries = dict.fromkeys(DEVICE_NODES, 0)

    def get_state(self, node):
        self.queries[node] += 1
        if ('get_state', node) not in self.lost:
            self.lost.add(('get_state', node))
            return Pending()                       # never answered
        return super().get_state(node)

    def change_state(self, node, transition):
        answer = super().change_state(node, transition)
        if (node, transition) == (STAGE_NODE, 'configure') and 'configure' not in self.lost:
            self.lost.add('configure')
            return Pending()
        return answer


def test_lost_lifecycle_replies_are_recovered_by_asking_again(monkeypatch):
    from mantis_rig.trial import sequence as trial_sequence
    monkeypatch.setattr(trial_sequence, 'QUERY_RETRY_S', 0.2)
    rig, seq, outcome = run_trial(LossyRig())
    assert outcome['result'] == 'completed', outcome
    assert set(rig.lifecycle.values()) == {'active'}
    # a second query for each node, and one more for stage_node's unanswered configure
    assert rig.queries == {STAGE_NODE: 3, LOADCELL_NODE: 2, CAMERA_NODE: 2}


def test_an_abort_closes_the_log_once_the_stage_reports_rest():
    rig, seq, outcome = run_trial(force_ceiling_n=15.0)
    assert outcome['stage_stopped'] == 'true'
    _, _, outcome = run_trial(FakeRig(), before=lambda rig, seq: rig.halt(),
                              phase_timeout_s=0.5)
    assert outcome['result'] == 'aborted'
    assert outcome['stage_stopped'] == 'unconfirmed'      # the stage never reported


def test_timeout_when_the_release_never_comes():
    rig = FakeRig(release_mm=100.0)
    _, _, outcome = run_trial(rig, phase_timeout_s=1.0, travel_mm=24.0)
    assert outcome['reason'] == 'timeout: release not detected (state pulling)'
    assert rig.v == 0.0


class RefusingStageRig(FakeRig):
    """A stage that ignores its first ``refusals`` velocity commands, as stage_node refuses a
    pull until its own force feed has a reading (a WARN on its diagnostics, not a fault)."""

    def __init__(self, refusals, **kwargs):
        super().__init__(**kwargs)
        self.refusals, self.velocity_commands = refusals, []

    def move_at(self, v):
        self.velocity_commands.append(v)
        if len(self.velocity_commands) <= self.refusals:
            self.seq.on_device_message(STAGE_NODE, 'velocity move refused: no force '
                                       'reading yet')
            return
        super().move_at(v)


def test_a_refused_pull_is_sent_again_once_the_stage_can_take_it():
    rig = RefusingStageRig(refusals=1)
    _, _, outcome = run_trial(rig)
    assert outcome['result'] == 'completed', outcome
    assert rig.velocity_commands == [2.33e-3, 2.33e-3]


def test_a_stage_that_never_moves_aborts_the_trial_with_its_reason():
    rig = RefusingStageRig(refusals=10)
    _, _, outcome = run_trial(rig)
    assert outcome['result'] == 'aborted'
    assert outcome['reason'] == ('the pull: the stage did not start moving after 3 velocity '
                                 'commands (stage_node reports: velocity move refused: no '
                                 'force reading yet)')
    assert len(rig.velocity_commands) == 3 and rig.v == 0.0


# --------------------------------------------------------------------------- over ROS
@pytest.fixture
def ros():
    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    thread = threading.Thread(target=executor.spin, daemon=True)
    nodes = []

    def add(node):
        nodes.append(node)
        executor.add_node(node)
        return node
    add.context = context
    thread.start()
    try:
        yield add
    finally:
        for node in nodes:
            if hasattr(node, 'shutdown_trial'):
                node.shutdown_trial()
        executor.shutdown(timeout_sec=5)
        for node in nodes:
            node.destroy_node()
        rclpy.shutdown(context=context)


def test_supervisor_refuses_bad_input_with_the_reason(ros, tmp_path, monkeypatch):
    from rclpy.parameter import Parameter

    from mantis_rig.nodes import rig_client
    from mantis_rig.nodes.supervisor_node import SupervisorNode
    from mantis_rig.nodes.trial_client import TrialClient
    from mantis_rig.recording import BagReader

    with pytest.raises(ConditionError, match="backend = 'warp' is not one of sim, hardware"):
        SupervisorNode(context=ros.context,
                       parameter_overrides=[Parameter('backend', value='warp')])
    monkeypatch.setattr(rig_client, 'SERVICE_WAIT_S', 0.5)
    node = ros(SupervisorNode(context=ros.context, parameter_overrides=[
        Parameter('out', value=str(tmp_path))]))
    client = ros(TrialClient(context=ros.context))
    assert client.call('abort') == (False, 'no trial in progress (state idle)')
    result = node.set_parameters([Parameter('pull_speed_mm_s', value=9.0)])[0]
    assert not result.successful and 'pull_speed_mm_s' in result.reason
    assert '2.4' in result.reason
    result = node.set_parameters([Parameter('medium', value='honey')])[0]
    assert result.reason == "medium = 'honey' is not one of air, water, vacuum"
    assert node.set_parameters([Parameter('operator_note', value='no devices')])[0].successful

    # no device nodes: the trial starts, then aborts naming the missing service
    started, message, final = client.run_trial(timeout_s=30)
    assert started and message.startswith('trial started; logging to ')
    assert final == 'aborted'
    node.sequence.finished.wait(10)
    bag = BagReader(message.rsplit(' ', 1)[-1])
    assert bag.complete
    outcome = bag.metadata('trial_outcome')
    assert outcome['result'] == 'aborted'
    # a simulated trial sets its conditions on the world first: none here
    assert outcome['reason'] == ("the simulated world could not apply the trial's conditions: "
                                 'service /sim_world_node/set_parameters_atomically is not '
                                 'available')
    assert bag.metadata('trial_conditions')['operator_note'] == 'no devices'
    states = [m.message.data for m in bag.messages([resolve(SUPERVISOR_STATE)])]
    assert states[-2:] == ['configuring', 'aborted']


def test_a_trial_needs_room_on_disk_for_its_bag(tmp_path):
    from collections import namedtuple

    from mantis_rig.trial.log_space import estimate_bag_bytes, free_space_problem
    usage = namedtuple('usage', 'total used free')
    conditions = TrialConditions()
    # a full simulated air_23mm trial's bag is 1.5 MB compressed; the estimate is uncompressed
    assert 2e6 < estimate_bag_bytes(conditions) < 20e6
    assert estimate_bag_bytes(TrialConditions(pull_speed_mm_s=0.1)) > \
        estimate_bag_bytes(conditions)                      # a slower pull, a longer log
    plenty = free_space_problem(tmp_path, conditions, lambda path: usage(0, 0, 10**12))
    assert plenty is None
    asked = []
    short = free_space_problem(tmp_path / 'not' / 'yet', conditions,
                               lambda path: asked.append(path) or usage(0, 0, 1_000_000))
    assert asked == [tmp_path]                 # the nearest directory that exists
    assert short.startswith(f'only 1.0 MB free under {tmp_path / "not" / "yet"}; a trial\'s '
                            f'bag needs about ')


def test_successive_ros_domain_claims_move_on():
    """A test never gets the domain the previous one just left (its processes' participants
    may still linger there in discovery)."""
    from mantis_rig.runtime.ros_env import claim_free_domain, release_domain
    first = claim_free_domain()
    release_domain(first)
    second = claim_free_domain()
    release_domain(second)
    assert second != first


def test_a_domain_another_process_just_left_is_not_claimed_next():
    """Parallel test workers: the domain a process has just released (its participants may
    linger in discovery) is the last one any other process claims."""
    import subprocess
    import sys

    from mantis_rig.runtime.ros_env import claim_free_domain, release_domain
    left = subprocess.run(
        [sys.executable, '-c', 'from mantis_rig.runtime.ros_env import claim_free_domain, '
         'release_domain; d = claim_free_domain(); release_domain(d); print(d)'],
        capture_output=True, text=True, check=True)
    mine = claim_free_domain()
    release_domain(mine)
    assert mine != int(left.stdout)


class _SilentSupervisor:
    """A supervisor whose answers to start_trial never arrive (Fast DDS drops a response the
    server cannot yet deliver): the request is held, as if its answer were lost, while the
    diagnostics say, or do not say, that a trial started."""

    def __init__(self, ros, starts_a_trial: bool):
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.node import Node
        from std_srvs.srv import Trigger

        from mantis_rig import contract
        from mantis_rig.nodes.supervisor_node import STATUS_NAME

        self.release = threading.Event()
        self.trials = 0
        node = ros(Node(contract.SUPERVISOR_NODE, context=ros.context))
        group = ReentrantCallbackGroup()
        publisher = node.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                          contract.DIAGNOSTICS.qos.publisher())

        def publish():
            values = {'state': 'configuring' if self.trials else 'idle',
                      'trials': str(self.trials), 'bag': '/data/trial_1' if self.trials else ''}
            publisher.publish(DiagnosticArray(status=[DiagnosticStatus(
                name=STATUS_NAME, values=[KeyValue(key=k, value=v) for k, v in values.items()])]))

        def on_start(request, response):
            self.trials += int(starts_a_trial)
            publish()
            self.release.wait(60)           # the answer is held until the test ends
            response.success, response.message = False, 'too late'
            return response

        node.create_service(Trigger, contract.START_TRIAL.name, on_start, callback_group=group)
        node.create_timer(0.2, publish, callback_group=group)


@pytest.mark.parametrize('starts_a_trial', [True, False])
def test_a_start_whose_answer_is_lost_is_judged_by_the_supervisors_diagnostics(
        ros, starts_a_trial):
    from mantis_rig.nodes.trial_client import ANSWER_GRACE_S, TrialClient

    supervisor = _SilentSupervisor(ros, starts_a_trial)
    client = ros(TrialClient(context=ros.context))
    try:
        assert client.wait_for_supervisor(30.0)
        assert client.supervisor_trials == 0
        called = time.monotonic()
        result = client.call('start_trial', timeout_s=ANSWER_GRACE_S + 3.0)
        waited = time.monotonic() - called
    finally:
        supervisor.release.set()
    if starts_a_trial:
        assert result == (True, 'trial started; logging to /data/trial_1')
        assert waited >= ANSWER_GRACE_S     # the answer had its chance first
    else:
        assert result == (False, '/supervisor/start_trial did not answer within 5.0 s')
