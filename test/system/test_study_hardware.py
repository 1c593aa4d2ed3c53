"""`mantis study` on the hardware layout (issue 39): the KDC101 emulator and the fake NI DAQ
behind the real device nodes and the supervisor, in this process; the person is scripted: the
first prompt answered with Enter, the second through the study's Trigger service."""
import math
import os
import threading
import time

import numpy as np
import pytest
import rclpy
from std_srvs.srv import Trigger

from mantis_rig.contract import STAGE_NODE, STUDY_CONTINUE, resolve
from mantis_rig.nodes.trial_client import TrialClient
from mantis_rig.stack.bringup import Stack, StackConfig
from mantis_rig.study_session.analyst import Analyst
from mantis_rig.study_session.rig import ClientRig, PersonOperator
from mantis_rig.study_session.runner import StudyRunner, StudySetup
from mantis_rig.study_session.session import _continue_node
from mantis_sim.studies.rig_study.plan import plan_from_mapping

RATE_HZ = 20_000.0
NEWTONS_PER_VOLT = 11.12
PERIOD_S = 2.0              # the fake robot loads for 2 s, then lets go (an 8 N drop)

pytestmark = [pytest.mark.timeout(600), pytest.mark.slow, pytest.mark.ros]


def sawtooth_volts(index: np.ndarray) -> np.ndarray:
    """The tendon of a robot that lets go every PERIOD_S: 1 N rising at 4 N/s, paced in real
    time (the fake delivers at once)."""
    time.sleep(index.size / RATE_HZ)
    t = index / RATE_HZ
    return (1.0 + 4.0 * np.mod(t, PERIOD_S)) / NEWTONS_PER_VOLT


def test_a_study_on_the_hardware_rig_asks_the_person(tmp_path, monkeypatch):
    from fakes.kdc101_emulator import Kdc101Emulator
    from fakes_nidaq import FakeDaqSystem
    FakeDaqSystem(signal_v=sawtooth_volts).install(monkeypatch)
    emulator = Kdc101Emulator(position_mm=10.0).start()
    plan = plan_from_mapping({'scene': 'air_23mm_rig', 'factors': {'d_t_mm': [19, 25]},
                              'repeats': 1, 'order': 'as-listed', 'seed': 1, 'robots': 20},
                             'plan')
    out = tmp_path / 'study'
    config = StackConfig(backend='hardware', supervisor={'out': str(out / 'bags'),
                                                         'start_position_mm': 10.0},
                         devices={STAGE_NODE: {'serial_port': emulator.port,
                                               'move_speed_m_per_s': 2.0e-3}})
    said, reader, writer = [], *os.pipe()

    def say(line):
        said.append(line)
        print(line, flush=True)             # shown by pytest when the test fails
    rclpy.init()
    stack = Stack(config)
    client = TrialClient()
    stack.add_node(client)
    node, proceed = _continue_node('')
    stack.add_node(node)
    analyst = Analyst()
    answered = threading.Event()

    def person():
        """Answers every prompt: with Enter, and every second one through the Trigger service."""
        answered_prompts = 0
        while not answered.is_set():
            if sum('press Enter' in line for line in said) <= answered_prompts:
                time.sleep(0.05)
                continue
            if answered_prompts % 2 == 0:
                os.write(writer, b'\n')
            else:
                caller = rclpy.create_node('study_gui')
                service = caller.create_client(Trigger, resolve(STUDY_CONTINUE))
                assert service.wait_for_service(timeout_sec=30.0)
                future = service.call_async(Trigger.Request())
                rclpy.spin_until_future_complete(caller, future, timeout_sec=30.0)
                assert future.result().success
                caller.destroy_node()
            answered_prompts += 1

    try:
        stack.start()
        assert client.wait_for_supervisor(60.0, stack.check_processes)
        operator = PersonOperator(say, resolve(STUDY_CONTINUE),
                                  stdin=os.fdopen(reader, 'r'), proceed=proceed)
        runner = StudyRunner(StudySetup(plan, out), ClientRig(client, stack.check_processes),
                             operator, analyst, say=say, progress=say)
        threading.Thread(target=person, daemon=True).start()
        runner.open()
        rows = runner.run().rows
    finally:
        answered.set()
        stack.stop(reason='test over')
        client.destroy_node()
        node.destroy_node()
        analyst.close()
        rclpy.shutdown()
        emulator.close()
    prompts = [line for line in said if 'press Enter' in line]
    assert 'set the guide distance to 19 mm, re-latch the robot' in prompts[0]
    assert 'set the guide distance to 25 mm (was 19 mm)' in prompts[1]
    assert '/study/continue' in prompts[0]
    assert [r['status'] for r in rows] == ['done', 'done'], said
    for row in rows:
        assert any(f'save its video\'s tracker export as {row["video"]}' in line for line in said)
        for name in ('peak_tendon_force_N', 'loading_work_mJ', 'release_time_s'):
            assert math.isfinite(row[name]) and math.isfinite(row[f'{name}_q50']), (name, row)
        assert row['peak_tip_speed_mps'] is None                # no camera markers on the rig
        assert row['release_time_s'] < PERIOD_S + 0.5
