"""A lab's day on the simulated rig: one bring-up, many trials over /supervisor/start_trial.

Each trial starts from the same place and the simulated operator re-latches the robot once the
stage is back at its start (mantis_sim.world), so every trial strikes. Aborted trials in
between (the force ceiling, an operator's abort) leave the next one able to run: the stage is
returned and the devices whose guards tripped are cleared. A robot nobody re-latched is caught
while the slack is taken up, and a stage stopped at its travel limit ends the trial at once.
"""
import contextlib
import csv
import io
from pathlib import Path
import threading

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
import rclpy

from mantis_rig.cli.main import main
from mantis_rig.contract import (
    FORCE_CEILING_NAME,
    SET_PARAMETERS,
    SIM_WORLD_NODE,
    STAGE_NODE,
    SUPERVISOR_NODE,
    node_interface,
    resolve,
)
from mantis_rig.nodes.trial_client import TrialClient
from mantis_rig.recording.bag_metadata import wait_closed
from mantis_rig.recording.trial_summary import summarize
from mantis_rig.stack.bringup import Stack, StackConfig

SCENE = 'air_23mm_rig'
TRIAL_TIMEOUT_S = 240.0
FAST_RETURN = {STAGE_NODE: {'move_speed_m_per_s': 2.0e-3}}
START_TOLERANCE_M = 0.1e-3            # the supervisor's position_tolerance_mm
SLOW_PULL_MM_S = 0.05                 # an aborted pull's: the abort lands before the strike

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow, pytest.mark.ros]


@contextlib.contextmanager
def session(tmp_path, processes='single', world=None, **supervisor):
    config = StackConfig(scene=SCENE, processes=processes, real_time_factor=0.0,
                         supervisor={'out': str(tmp_path), 'operator_note': 'pytest',
                                     **supervisor},
                         devices=FAST_RETURN, world=world or {})
    stack = Stack(config, log_dir=tmp_path / 'logs')
    client = TrialClient()
    stack.add_node(client)
    try:
        stack.start()
        assert client.wait_for_supervisor(60.0)
        yield stack, client
    finally:
        stack.stop()
        client.destroy_node()


def run_trial(client):
    """(final state, its reason as the bag records it, the closed bag) of one trial started
    over ROS."""
    started, message, final = client.run_trial(timeout_s=TRIAL_TIMEOUT_S)
    assert started, message
    bag = Path(message.rsplit('logging to ', 1)[1])
    # closed by then: the end is published once it is
    assert wait_closed(bag, 30.0), f'{bag} was not closed'
    return final, summarize(bag).outcome['reason'], bag


def set_supervisor(client, name, value):
    """Set one supervisor parameter over ROS, between trials."""
    service = client.create_client(
        SetParameters, resolve(node_interface(SUPERVISOR_NODE, SET_PARAMETERS)))
    assert service.wait_for_service(timeout_sec=30)
    future = service.call_async(SetParameters.Request(parameters=[ParameterMsg(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                        double_value=float(value)))]))
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(30)
    assert future.result().results[0].successful, future.result()
    client.destroy_client(service)


def analysed_rows(out: Path, bags) -> list[dict]:
    """`mantis analyze <bags> --table`: one row per bag."""
    table = out / 'day.csv'
    stderr = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(stderr):
        code = main(['analyze', *map(str, bags), '--table', str(table)])
    assert code == 0, stderr.getvalue()
    with table.open(newline='') as f:
        return list(csv.DictReader(f))


def check_day(rows, bags):
    assert len(rows) == len(bags)
    for row in rows:
        assert row['status'] == 'ok', row
        assert 15.0 < float(row['peak_tip_speed_mps']) < 40.0, row


def test_one_bring_up_many_trials_with_aborts_between(ros, tmp_path):
    done_bags, world_strikes = [], []
    with session(tmp_path) as (stack, client):
        world = stack.node(SIM_WORLD_NODE).world
        start_m = world.stage_position_m()

        def trial_done():
            final, reason, bag = run_trial(client)
            assert final == 'done', reason
            done_bags.append(bag)
            assert abs(world.stage_position_m() - start_m) < START_TOLERANCE_M
            world_strikes.append(world.strikes)

        for _ in range(3):
            trial_done()
        # a force ceiling below the strike's: aborted, the stage back, the guards cleared
        set_supervisor(client, FORCE_CEILING_NAME, 13.0)
        final, reason, bag = run_trial(client)
        assert final == 'aborted' and reason.startswith('force ceiling: '), reason
        assert summarize(bag).outcome['stage_returned'] == 'true'
        set_supervisor(client, FORCE_CEILING_NAME, 30.0)
        trial_done()
        # the operator aborts a pull (a slow one, so that the abort lands before the strike
        # however fast the rig runs): the robot is still latched, the next trial strikes
        pull_speed = client.get_parameters(['pull_speed_mm_s'])['pull_speed_mm_s']
        set_supervisor(client, 'pull_speed_mm_s', SLOW_PULL_MM_S)
        ok, message = client.start_trial()
        assert ok, message
        found = client.wait_for_state(('pulling', 'done', 'aborted'), client.trial_start, 60.0)
        assert found == 'pulling'
        assert client.call('abort')[0]
        assert client.wait_for_end(TRIAL_TIMEOUT_S) == 'aborted'
        bag = Path(message.rsplit('logging to ', 1)[1])
        assert wait_closed(bag, 30.0), f'{bag} was not closed'
        assert 'abort requested' in summarize(bag).outcome['reason']
        set_supervisor(client, 'pull_speed_mm_s', pull_speed)
        trial_done()
    # every strike re-latched the robot: one latch more per strike that happened
    assert world_strikes[:3] == [2, 3, 4] and world_strikes[-1] == world_strikes[-2] + 1
    check_day(analysed_rows(tmp_path, done_bags), done_bags)


def test_one_bring_up_many_trials_with_the_rig_in_its_own_process(tmp_path):
    rclpy.init()
    try:
        bags = []
        with session(tmp_path, processes='multi') as (_, client):
            for _ in range(3):
                final, reason, bag = run_trial(client)
                assert final == 'done', reason
                bags.append(bag)
    finally:
        rclpy.try_shutdown()
    check_day(analysed_rows(tmp_path, bags), bags)


def test_a_robot_nobody_relatched_is_caught_while_taking_up_slack(ros, tmp_path):
    with session(tmp_path, world={'relatch': False}) as (stack, client):
        final, reason, _ = run_trial(client)
        assert final == 'done', reason
        assert client.wait_for_state(('waiting_for_relatch',), client.trial_start, 30.0)
        world = stack.node(SIM_WORLD_NODE).world
        start_m = world.stage_position_m()
        final, reason, bag = run_trial(client)
        assert final == 'aborted'
        assert reason.startswith('the robot is not latched: the tendon force stayed below '
                                 '0.3 N over 2.0 mm of take-up'), reason
        assert abs(world.stage_position_m() - start_m) < START_TOLERANCE_M
        assert summarize(bag).outcome['stage_returned'] == 'true'


def test_a_stage_stopped_at_its_travel_limit_ends_the_trial_at_once(ros, tmp_path):
    with session(tmp_path, world={'relatch': False}, travel_mm=20.0,
                 latch_check_mm=20.0) as (_, client):
        assert run_trial(client)[0] == 'done'
        final, reason, _ = run_trial(client)
    assert final == 'aborted'
    assert reason.startswith('stage stopped: stopped at the forward travel limit'), reason
