"""Simulated trials end to end: the whole node stack, the supervisor's sequence, the bag.

1. air_23mm in one process: every contract topic in the bag, a gap-free force stream, the
   strike inside the camera frames, the bag decoded by the independent `rosbags` reader; bad
   service calls and parameters during the trial are refused and leave it intact.
2. The same with every node its own process, through `mantis trial --processes multi`.
3. A force ceiling below the trial's peak aborts with the stage stopped and the reason in the
   bag; a supervisor killed with SIGKILL mid-trial leaves a bag readable up to the kill.
4. Bad command lines (unknown scene, backend, parameter out of range) exit 2 with the reason.

Timing is generous: the machine may be slow and busy. The world runs at real-time factor
MANTIS_TEST_RTF (default 1) where a test acts during the trial; the others run at real-time
factor 0 (as fast as the stack keeps up). When the machine cannot keep up, simulated time slips.
"""
import os
from pathlib import Path
import re
import subprocess
import sys
import threading
import time
import warnings

import numpy as np
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_typestore

from mantis_rig.contract import (
    FORCE_BLOCK,
    FORCE_CEILING_NAME,
    JOINT_STATE,
    MARKERS,
    SET_PARAMETERS,
    SIM_WORLD_NODE,
    STAGE_NODE,
    SUPERVISOR_NODE,
    SUPERVISOR_STATE,
    VELOCITY_COMMAND,
    node_interface,
    resolve,
)
from mantis_rig.nodes.recorder import TRIAL_TOPICS
from mantis_rig.nodes.trial_client import TrialClient
from mantis_rig.recording import BagReader, TruncatedBagWarning, recover_bag
from mantis_rig.recording.bag_metadata import wait_closed
from mantis_rig.recording.marker_block import concatenate, marker_block_from_msg
from mantis_rig.recording.trial_summary import summarize
from mantis_rig.stack.bringup import Stack, StackConfig

REPO = Path(__file__).resolve().parents[2]
SCENE = 'reference_air_23mm'
RTF = float(os.environ.get('MANTIS_TEST_RTF', '1.0'))
FAST = 0.0      # real-time factor 0: as fast as the stack keeps up (what is not about pacing)
TRIAL_TIMEOUT_S = 240.0
FAST_RETURN = {STAGE_NODE: {'move_speed_m_per_s': 2.0e-3}}

pytestmark = [pytest.mark.timeout(600), pytest.mark.slow, pytest.mark.ros]


def start_stack(tmp_path, processes='single', rtf=RTF, **supervisor):
    config = StackConfig(scene=SCENE, processes=processes,
                         real_time_factor=rtf,
                         supervisor={'out': str(tmp_path), 'operator_note': 'pytest',
                                     **supervisor},
                         devices=FAST_RETURN)
    stack = Stack(config, log_dir=tmp_path / 'logs')
    client = TrialClient()
    stack.add_node(client)
    stack.start()
    return stack, client


def wait_for(client, state, mark=0, timeout=TRIAL_TIMEOUT_S):
    found = client.wait_for_state((state, 'done', 'aborted'), mark, timeout)
    assert found == state, f'expected {state}, the supervisor went {client.states}'


def set_parameter(client, name, value):
    """Set one supervisor parameter over ROS; (successful, reason)."""
    service = client.create_client(
        SetParameters, resolve(node_interface(SUPERVISOR_NODE, SET_PARAMETERS)))
    assert service.wait_for_service(timeout_sec=30)
    request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
    future = service.call_async(request)
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(30)
    result = future.result().results[0]
    client.destroy_client(service)
    return result.successful, result.reason


def bag_of(message):
    assert message.startswith('trial started; logging to '), message
    return Path(message.rsplit('logging to ', 1)[1])


# ----------------------------------------------------------------------------- checks
def check_rosbags_decodes_everything(bag):
    typestore = get_typestore(Stores.ROS2_JAZZY)
    counts = {}
    with RosbagsReader(bag) as reader:
        for connection, _, raw in reader.messages():
            typestore.deserialize_cdr(raw, connection.msgtype)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
    return counts


def marker_frames(bag):
    return concatenate(sorted((marker_block_from_msg(m.message) for m in
                               BagReader(bag).messages([resolve(MARKERS)])),
                              key=lambda f: f.time_s[0]))


def tip_speed_peak_s(frames):
    """Time of the fastest frame-to-frame motion of the arm's outer marker."""
    xy = frames.markers_m['ma2']
    speed = np.hypot(*np.diff(xy, axis=0).T) / np.diff(frames.time_s)
    return frames.time_s[int(np.argmax(speed))]


def check_completed_trial(bag, peak_time_s=None):
    summary = summarize(bag)
    assert summary.complete, BagReader(bag).problems
    assert summary.outcome['result'] == 'completed', summary.outcome
    assert summary.conditions['scene'] == SCENE and summary.conditions['backend'] == 'sim'
    assert summary.conditions['operator_note'] == 'pytest'
    # every topic of the contract, each with messages
    for spec in TRIAL_TOPICS:
        assert summary.topic_counts.get(resolve(spec), 0) > 0, (spec, summary.topic_counts)
    # the full-rate force stream: no gap, rate x duration samples within one block
    assert summary.force_gaps == []
    block = max(m.message.layout.dim[0].size
                for m in BagReader(bag).messages([resolve(FORCE_BLOCK)]))
    assert summary.force_rate_hz == pytest.approx(20_000.0)
    assert abs(summary.force_samples - summary.force_rate_hz * summary.force_duration_s) <= block
    # the stream covers the trial from before the pull to after the stop
    assert summary.force_start_s < summary.state_time('pulling') < summary.release_s
    # the camera's frames contain the strike
    frames = marker_frames(bag)
    assert len(frames) == summary.marker_frames > 1000
    peak = tip_speed_peak_s(frames) if peak_time_s is None else peak_time_s
    assert frames.time_s[0] < peak < frames.time_s[-1]
    assert summary.release_caught
    assert summary.peak_force_n > 12.0
    # the stage went back to where the pull started
    states = [m.message for m in BagReader(bag).messages([resolve(JOINT_STATE)])]
    pull_s = summary.state_time('pulling')
    # where it stood when the pull began: the last state before it (the stage at rest), not the
    # first after it, which a busy machine publishes with the stage already under way
    start = [s.position[0] for s in states
             if s.header.stamp.sec + s.header.stamp.nanosec * 1e-9 <= pull_s][-1]
    assert abs(states[-1].position[0] - start) < 50e-6
    assert abs(states[-1].position[0] - start) < abs(max(s.position[0] for s in states) - start)
    # the independent reader opens the bag and decodes every message of every topic
    counts = check_rosbags_decodes_everything(bag)
    assert counts == {t: n for t, n in summary.topic_counts.items() if n}
    return summary


# ----------------------------------------------------------------------------- 1 and 4
def test_air_23mm_trial_in_one_process(ros, tmp_path):
    stack, client = start_stack(tmp_path)
    try:
        mark = len(client.states)
        ok, message = client.call('start_trial')
        assert ok, message
        bag = bag_of(message)
        wait_for(client, 'pulling', mark)
        # bad input while the trial runs: refused with the reason, the trial goes on
        assert client.call('start_trial') == (
            False, 'a trial is already in progress (state pulling)') or \
            client.states[-1] != 'pulling'
        ok, reason = set_parameter(client, 'pull_speed_mm_s', 50.0)
        assert not ok and 'pull_speed_mm_s' in reason, reason
        ok, reason = set_parameter(client, FORCE_CEILING_NAME, 20.0)
        assert not ok and 'a trial is in progress' in reason, reason
        wait_for(client, 'done', mark)
        assert wait_closed(bag, 30.0), f'{bag} was not closed'
        peak_time_s = stack.node(SIM_WORLD_NODE).world.last_strike.peak_time_s
        # it struck: once its log is closed the supervisor waits for the robot's re-latch
        assert client.wait_for_state(('waiting_for_relatch',), mark, 30.0)
        assert client.call('abort') == (
            False, 'no trial in progress (state waiting_for_relatch)')
    finally:
        stack.stop()
        client.destroy_node()
    assert np.isfinite(peak_time_s)
    summary = check_completed_trial(bag, peak_time_s)
    assert summary.states[-1][0] == 'done'
    assert [s for s, _ in summary.states if s in ('pulling', 'released', 'returning')] == \
        ['pulling', 'released', 'returning']


def run_cli(*args, timeout=TRIAL_TIMEOUT_S):
    return subprocess.run([sys.executable, '-m', 'mantis_rig.cli', *args], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


def test_bad_command_lines_exit_2_with_the_reason(tmp_path):
    out = ['--out', str(tmp_path)]
    result = run_cli('trial', '--backend', 'sim', '--scene', 'no_such_scene', *out)
    assert result.returncode == 2 and "unknown scene 'no_such_scene'" in result.stderr
    result = run_cli('trial', '--backend', 'warp', '--scene', SCENE, *out)
    assert result.returncode == 2 and "invalid choice: 'warp'" in result.stderr
    result = run_cli('trial', '--scene', SCENE, '--pull-speed', '9', *out)
    assert result.returncode == 2
    assert 'pull_speed_mm_s = 9.0 mm/s is outside [0.05, 2.4] mm/s' in result.stderr
    result = run_cli('trial', '--scene', SCENE, '--real-time-factor', '-1', *out)
    assert result.returncode == 2 and '--real-time-factor -1.0 must be >= 0' in result.stderr
    result = run_cli('trial', '--scene', SCENE, '--set', 'loadcell.noise_N=-1', *out)
    assert result.returncode == 2 and 'noise_N' in result.stderr
    assert not any(tmp_path.iterdir())            # nothing was started or logged


# ----------------------------------------------------------------------------- 2
def test_air_23mm_trial_with_every_node_its_own_process(tmp_path):
    result = run_cli('trial', '--backend', 'sim', '--scene', SCENE, '--out', str(tmp_path),
                     '--processes', 'multi', '--real-time-factor', str(FAST),
                     '--set', 'operator_note=pytest', '--log-dir', str(tmp_path / 'logs'),
                     timeout=TRIAL_TIMEOUT_S + 60)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    bag = Path(lines[0].removeprefix('bag: '))
    assert bag.parent == tmp_path
    assert 'outcome: completed' in result.stdout
    assert 'release caught: yes' in result.stdout
    assert 'seen from the force stream: pull from' in result.stdout
    check_completed_trial(bag)


# ----------------------------------------------------------------------------- 3
def test_force_ceiling_below_the_peak_aborts(ros, tmp_path):
    stack, client = start_stack(tmp_path, rtf=FAST, force_ceiling_n=13.0)
    try:
        started, message, final = client.run_trial(timeout_s=TRIAL_TIMEOUT_S)
        assert started, message
        assert final == 'aborted'
        bag = bag_of(message)
        assert wait_closed(bag, 30.0), f'{bag} was not closed'
        time.sleep(0.5)                     # let the stage report standing still
        stage = stack.node(SIM_WORLD_NODE).world.stage_velocity_m_per_s()
    finally:
        stack.stop()
        client.destroy_node()
    assert stage == 0.0
    reader = BagReader(bag)
    assert reader.complete
    outcome = reader.metadata('trial_outcome')
    assert outcome['result'] == 'aborted'
    # the supervisor's monitor, or one of the guards given the same ceiling, whichever is first
    assert re.search(r'(> 13\.0 N|above the ceiling 13(\.000)? N)', outcome['reason']), \
        outcome['reason']
    assert outcome['stage_stopped'] == 'true'
    commands = [m.message.data for m in reader.messages([resolve(VELOCITY_COMMAND)])]
    assert commands[-1] == 0.0
    states = [m.message for m in reader.messages([resolve(JOINT_STATE)])]
    assert states[-1].velocity[0] == 0.0
    # stopped first, then returned to the start for the next trial: in the bag before it closed
    assert outcome['stage_returned'] == 'true'
    logged = [m.message.data for m in reader.messages([resolve(SUPERVISOR_STATE)])]
    assert logged[-2:] == ['returning', 'aborted'], logged
    check_rosbags_decodes_everything(bag)


def test_supervisor_killed_mid_trial_leaves_a_readable_bag(ros, tmp_path):
    stack, client = start_stack(tmp_path, processes='multi')
    try:
        mark = len(client.states)
        ok, message = client.call('start_trial', timeout_s=60)
        assert ok, message
        bag = bag_of(message)
        wait_for(client, 'pulling', mark)
        time.sleep(1.0)                     # > the writer's 0.5 s sync period
        stack.processes[SUPERVISOR_NODE].kill()
        stack.processes[SUPERVISOR_NODE].wait()
    finally:
        stack.stop()
        client.destroy_node()
    assert not (bag / 'metadata.yaml').exists()
    with warnings.catch_warnings(record=True):
        warnings.simplefilter('always', TruncatedBagWarning)
        reader = BagReader(bag)
        states = [m.message.data for m in reader.messages([resolve(SUPERVISOR_STATE)])]
        blocks = list(reader.messages([resolve(FORCE_BLOCK)]))
    assert not reader.complete and reader.problems
    assert reader.metadata('trial_conditions')['operator_note'] == 'pytest'
    assert 'pulling' in states and len(blocks) > 10
    report = recover_bag(bag)
    recovered = BagReader(report.output)
    assert recovered.complete
    assert recovered.message_count >= len(blocks) + len(states)
    check_rosbags_decodes_everything(report.output)


def test_one_force_ceiling_reaches_the_stages_own_guard(tmp_path):
    """`--set force_ceiling_n=12` with the supervisor's own monitor off: the stage driver's
    guard, given the same ceiling by the stack and the supervisor (not its default 30 N),
    stops the stage at the first force block above 12 N. In this scene the tendon force falls
    from 11.3 N during the pull, so that block is the release's force spike (peak 17.9 N, which
    the guard's default 30 N would let pass)."""
    result = run_cli('trial', '--backend', 'sim', '--scene', SCENE, '--out', str(tmp_path),
                     '--real-time-factor', str(FAST), '--set', 'force_ceiling_n=12',
                     '--set', 'supervisor_force_monitor=false')
    assert result.returncode == 1, result.stdout + result.stderr
    bag = Path(result.stdout.splitlines()[0].removeprefix('bag: '))
    reader = BagReader(bag)
    outcome = reader.metadata('trial_outcome')
    assert outcome['result'] == 'aborted'
    assert reader.metadata('trial_conditions')['supervisor_force_monitor'] == 'False'
    assert 'above the ceiling 12' in outcome['reason'], outcome['reason']
    assert not outcome['reason'].startswith('force ceiling')    # not the supervisor's monitor
    # the stage node's own report (its diagnostics may come after the bag closed when the
    # load cell's monitor, holding the same ceiling, reported first)
    guard = [line for line in result.stderr.splitlines()
             if '[stage_node]: force guard: force ' in line]
    assert guard, result.stderr
    match = re.search(r'force guard: force ([\d.]+) N above the ceiling 12 N; stage stopped',
                      guard[0])
    assert match, guard[0]
    assert 12.0 < float(match[1]) < 30.0
    assert outcome['stage_stopped'] == 'true'
    commands = [m.message.data for m in reader.messages([resolve(VELOCITY_COMMAND)])]
    assert commands[-1] == 0.0
