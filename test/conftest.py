"""Shared by every layer of the suite: the test data, and the DDS domains of the tests that use
ROS.

The layers (docs/testing.md): ``test/unit`` (no DDS, no subprocess: a guard below fails a unit
test that starts either), ``test/ros`` (ROS nodes, executors and bags in this process) and
``test/system`` (whole programs: node processes, the installed package, clusters, the fuzz
suite and the analyses of every real trial). Tests marked ``slow`` are left out of the inner
loop by ``-m "not slow"``.

ROS isolation: every ROS participant a test starts stays on loopback, on a domain no other test
uses. A test under test/ros, a module marked ``ros`` elsewhere, or a test not yet placed in a
layer (directly under test/) claims a domain of its own (a lock no parallel pytest run can
take) before it starts any ROS context or process, and gives it back afterwards; module
fixtures, set up before that, run in a domain of their module's own (otherwise in the shell's
ROS_DOMAIN_ID, which parallel workers all inherit). A domain per test, not per session: a
participant that outlives its test (rclpy destroys the DDS participant only when its context
is collected) must not answer the next test's service calls. Unit tests claim nothing.

The real trials the tests read are the project's own copies under test/data (``data_file``);
a missing one fails the test that needs it, it is never skipped.
"""
import os
from pathlib import Path
import subprocess

import pytest

from mantis_rig.contract import MARKERS, resolve
from mantis_rig.runtime.ros_env import claim_free_domain, release_domain

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
# UDP on loopback, not Fast DDS's shared memory: the suite kills node processes by design, and
# a killed process's shared-memory ports can leave a later participant matched but deaf
# (eProsima/Fast-DDS#5053, #5469; here: a fault test's observer that heard the supervisor's
# states but none of the stage's joint states, on both of its attempts).
os.environ['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'

#: The project's own copies of the real trials (test/data/PROVENANCE.md says where from).
# the KDC101 emulator's fixtures (make_emulator), for the driver's and mantis doctor's tests
pytest_plugins = ('fakes.kdc101_fixtures',)

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


# --------------------------------------------------------------------------------- layers
TEST_DIR = Path(__file__).resolve().parent
LAYERS = ('unit', 'ros', 'system')


def layer(node) -> str | None:
    """The layer a test or module is in ('unit', 'ros', 'system'); None directly under test/."""
    parts = Path(node.path).resolve().relative_to(TEST_DIR).parts
    return parts[0] if len(parts) > 1 and parts[0] in LAYERS else None


def uses_ros(node) -> bool:
    """Whether a test or module starts ROS participants: everything under test/ros, the
    modules marked ``ros`` elsewhere, and, to be safe, a module not yet placed in a layer."""
    where = layer(node)
    return where == 'ros' or where is None or node.get_closest_marker('ros') is not None


def pytest_collection_modifyitems(config, items):
    for item in items:
        if layer(item) == 'ros':
            item.add_marker(pytest.mark.ros)     # so that -m ros / -m "not ros" select by it
    # The slow modules first, then those holding a slow test, then the rest, each module kept
    # whole: scripts/test.sh hands modules out to its workers in this order (pytest-xdist,
    # --dist loadfile --no-loadscope-reorder). A long module handed out last would run alone at
    # the end while the other workers idle; handed out first, the quick ones fill in around it.
    slow_modules = {item.module for item in items if item.get_closest_marker('slow')}

    def rank(item):
        if item.getparent(pytest.Module).get_closest_marker('slow'):
            return 0
        return 1 if item.module in slow_modules else 2
    items.sort(key=rank)


@pytest.fixture(scope='module', autouse=True)
def module_ros_domain(request):
    if uses_ros(request.node):
        yield from _claimed_domain()
    else:
        yield None


@pytest.fixture(autouse=True)
def own_ros_domain(request):
    if uses_ros(request.node):
        yield from _claimed_domain()
    else:
        yield None


@pytest.fixture(autouse=True)
def unit_tests_start_no_process_and_no_dds(request, monkeypatch):
    """test/unit's rules, enforced: a unit test that starts a process (subprocess, fork,
    multiprocessing) or a ROS context (DDS) fails, naming the layer it belongs in."""
    if layer(request.node) != 'unit':
        yield
        return
    import multiprocessing.process

    import rclpy.context

    def refused(what):
        def refuse(*args, **kwargs):
            raise AssertionError(f'a unit test starts no {what}: move it to test/ros or '
                                 f'test/system (docs/testing.md)')
        return refuse
    monkeypatch.setattr(subprocess.Popen, '_execute_child', refused('subprocess'))
    monkeypatch.setattr(os, 'fork', refused('process (fork)'))
    monkeypatch.setattr(multiprocessing.process.BaseProcess, 'start',
                        refused('process (multiprocessing)'))
    monkeypatch.setattr(rclpy.context.Context, 'init', refused('ROS context (DDS)'))
    yield


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


@pytest.fixture
def ros(own_ros_domain):
    """rclpy's default context for one test, in the test's own domain (claimed first)."""
    import rclpy
    rclpy.init()
    yield
    rclpy.try_shutdown()
