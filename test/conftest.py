"""Every ROS participant a test starts stays on loopback, on a domain no other test uses.

Each test claims a domain of its own (a lock no parallel pytest run can take) before it starts
any ROS context or process, and gives it back afterwards; module fixtures, set up before that,
run in a domain of their module's own (otherwise in the shell's ROS_DOMAIN_ID, which parallel
workers all inherit). A domain per test, not per session:
a participant that outlives its test (rclpy destroys the DDS participant only when its context
is collected) must not answer the next test's service calls.

The real trials the tests read are the project's own copies under test/data (``data_file``);
a missing one fails the test that needs it, it is never skipped.
"""
import os
from pathlib import Path

import pytest

from mantis_rig.contract import MARKERS, resolve
from mantis_rig.nodes.ros_env import claim_free_domain, release_domain

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')

#: The project's own copies of the real trials (test/data/PROVENANCE.md says where from).
DATA_DIR = Path(__file__).resolve().parent / 'data'


def data_file(rel) -> Path:
    """A fixture file under test/data; a missing one fails the test (it is never skipped)."""
    path = DATA_DIR / rel
    assert path.exists(), f'test fixture missing: {path}'
    return path


def _claimed_domain():
    """Claim a free domain, set ROS_DOMAIN_ID to it while the fixture lasts, give it back."""
    domain = claim_free_domain()
    with pytest.MonkeyPatch.context() as env:
        env.setenv('ROS_DOMAIN_ID', str(domain))
        yield domain
    release_domain(domain)


@pytest.fixture(scope='module', autouse=True)
def module_ros_domain():
    yield from _claimed_domain()


@pytest.fixture(autouse=True)
def own_ros_domain():
    yield from _claimed_domain()


def published_s12_run() -> dict:
    """The authors' published air run (their Fig. S12 .mat under test/data/published_sims):
    time (ms), theta1 and theta3 (rad), their rates (rad/ms), tendon force (N), their logged
    T_switch (ms), the first sample time at their 17 N saturation (ms), and its tip speed (m/s)
    by the model's formula with the run's own L1 and L3."""
    import numpy as np
    import scipy.io as sio

    from mantis_rig.analysis.kinematics import tip_speed_mps
    m = sio.loadmat(data_file('published_sims/figS12_air_23mm.mat'), squeeze_me=True,
                    struct_as_record=False)
    params = m['params']
    tip = tip_speed_mps(params.L_1, params.L_3, m['th3'], m['dth1'] * 1e3, m['dth3'] * 1e3)
    saturated_from_ms = float(m['t'][np.argmax(m['F'] >= 17.0 - 1e-9)])
    return dict(t_ms=m['t'], theta1=m['th1'], theta3=m['th3'], omega1=m['dth1'],
                omega3=m['dth3'], force_N=m['F'], t_switch_ms=float(m['T_switch']), tip_mps=tip,
                saturated_from_ms=saturated_from_ms)


def authors_values() -> dict:
    """{file under test/data: the authors' values for it} (test/data/authors_values.csv)."""
    import csv
    with open(data_file('authors_values.csv'), newline='') as f:
        return {row.pop('file'): {k: (v if k == 'medium' else float(v)) for k, v in row.items()}
                for row in csv.DictReader(f)}


def rewritten_copy(bag, dest, replace=lambda message: message.data, conditions=None):
    """A copy of ``bag`` with the second message on /camera/markers replaced by
    ``replace(message)`` (bytes, CDR) and its trial conditions updated with ``conditions``:
    contents that pass every CRC but are wrong."""
    from mantis_rig.recording import BagReader, BagWriter
    reader = BagReader(bag)
    seen = 0
    with BagWriter(dest, sync_period_s=0) as out:
        for topic, info in reader.topics.items():
            out.add_topic(topic, info.type_name)
        out.add_metadata('trial_conditions',
                         {**(reader.metadata('trial_conditions') or {}), **(conditions or {})})
        for channel, _, message in reader.raw_messages():
            data = message.data
            if channel.topic == resolve(MARKERS):
                seen += 1
                if seen == 2:
                    data = replace(message)
            out.write_serialized(channel.topic, data, message.log_time)
    assert seen >= 2
    return dest
