"""Two simulated rigs side by side in one ROS domain, each in a namespace of its own.

The contract's names are relative, so a rig brought up in a namespace has every topic, service
and node under it. Here two whole stacks (world, device nodes, supervisor, recorder) run on one
domain: /rig_a in this process (nodes created in the namespace), /rig_b as node processes
started with `-r __ns:=/rig_b` (and rclpy's /clock remapped to the rig's, for the supervisor on
use_sim_time), each with a trial client in its namespace; both trials run at once, and each
rig records its own bag. Nothing may cross: each bag holds only
its own rig's topics, its own trial's states (one pull, one end), only its own pull speed on the
stage's velocity commands (the rigs pull at different speeds), and only diagnostics naming its
own bag. Each bag is then analysed by its names relative to its namespace. Every wait is on a
condition (a state, a closed bag), none on a fixed time.
"""
from pathlib import Path

import pytest
from test_trial import FAST_RETURN, SCENE, TRIAL_TIMEOUT_S, bag_of

from mantis_rig import contract
from mantis_rig.analysis.inputs.bag import read_trial_bag
from mantis_rig.nodes.supervisor_node import STATUS_NAME
from mantis_rig.nodes.trial_client import TrialClient
from mantis_rig.recording import BagReader
from mantis_rig.recording.bag_metadata import wait_closed
from mantis_rig.recording.trial_summary import summarize
from mantis_rig.stack.bringup import Stack, StackConfig

pytestmark = [pytest.mark.timeout(600), pytest.mark.slow, pytest.mark.ros]

RIGS = {'/rig_a': 2.33, '/rig_b': 1.9}       # namespace -> pull speed, mm/s
PROCESSES = {'/rig_a': 'single', '/rig_b': 'multi'}


def start_rig(namespace, pull_speed_mm_s, out: Path):
    # In real time: two rigs at real-time factor 0 on two loaded cores let a supervisor hear
    # its release 8 s of rig time late (its pull then ended at the controller's bound)
    config = StackConfig(scene=SCENE, real_time_factor=1.0, namespace=namespace,
                         processes=PROCESSES[namespace],
                         supervisor={'out': str(out), 'operator_note': f'pytest {namespace}',
                                     'pull_speed_mm_s': pull_speed_mm_s},
                         devices=FAST_RETURN)
    stack = Stack(config, log_dir=out / 'logs')
    client = TrialClient(namespace=namespace)
    stack.add_node(client)
    stack.start()
    return stack, client


def check_own_bag(bag: Path, namespace: str, pull_speed_mm_s: float, other_speed: float):
    reader = BagReader(bag)
    assert reader.complete, reader.problems
    # every topic under this rig's namespace, and every contract topic of a trial there
    assert all(topic.startswith(namespace + '/') for topic in reader.topics), reader.topics
    assert set(reader.topics) == {contract.resolve(t, namespace) for t in contract.TRIAL_TOPICS}
    conditions = reader.metadata('trial_conditions')
    assert conditions['operator_note'] == f'pytest {namespace}'
    assert float(conditions['pull_speed_mm_s']) == pull_speed_mm_s

    def messages(topic):
        return [m.message for m in reader.messages([contract.resolve(topic, namespace)])]

    # one trial's states: one pull and one end, not the other rig's as well
    states = [m.data for m in messages(contract.SUPERVISOR_STATE)]
    assert states.count('pulling') == 1 and states.count('done') == 1, states
    # the stage commands: this rig's pull speed, never the other's
    speeds_mm_s = {round(m.data * 1e3, 6) for m in messages(contract.VELOCITY_COMMAND)}
    assert pull_speed_mm_s in speeds_mm_s and other_speed not in speeds_mm_s, speeds_mm_s
    # the supervisor's diagnostics name this rig's bag only
    named = {kv.value for array in messages(contract.DIAGNOSTICS) for status in array.status
             if status.name == STATUS_NAME for kv in status.values if kv.key == 'bag'}
    assert named <= {str(bag), ''} and str(bag) in named, named
    # analysable by its names relative to the namespace
    summary = summarize(bag)
    assert summary.namespace == namespace
    assert summary.outcome['result'] == 'completed', summary.outcome
    assert summary.force_gaps == [] and summary.force_samples > 0
    assert summary.release_caught
    trial = read_trial_bag(bag)
    assert len(trial.tracks.time_s) == summary.marker_frames > 1000
    assert trial.force_N is not None and trial.conditions['operator_note'] == conditions[
        'operator_note']
    return summary


def test_two_rigs_in_two_namespaces_each_record_only_their_own_trial(ros, tmp_path):
    rigs = {}
    try:
        for namespace, speed in RIGS.items():
            rigs[namespace] = start_rig(namespace, speed, tmp_path / namespace.strip('/'))
        for namespace, (stack, client) in rigs.items():
            assert client.wait_for_supervisor(60.0, stack.check_processes), namespace
        bags = {}
        for namespace, (_, client) in rigs.items():       # both trials run at once
            ok, message = client.start_trial()
            assert ok, message
            bags[namespace] = bag_of(message)
        for namespace, (stack, client) in rigs.items():
            final = client.wait_for_end(TRIAL_TIMEOUT_S, alive=stack.check_processes)
            assert final == 'done', (namespace, client.states)
            assert wait_closed(bags[namespace], 30.0), f'{bags[namespace]} was not closed'
    finally:
        for stack, client in rigs.values():
            stack.stop()
            client.destroy_node()
    assert bags['/rig_a'].parent == tmp_path / 'rig_a'
    for namespace, speed in RIGS.items():
        other = next(s for ns, s in RIGS.items() if ns != namespace)
        check_own_bag(bags[namespace], namespace, speed, other)
