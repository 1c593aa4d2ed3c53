"""Every ROS participant a test starts stays on loopback, on a domain no other test uses.

Each test claims a domain of its own (a lock no parallel pytest run can take) before it starts
any ROS context or process, and gives it back afterwards. A domain per test, not per session:
a participant that outlives its test (rclpy destroys the DDS participant only when its context
is collected) must not answer the next test's service calls.
"""
import os

import pytest

from mantis_rig.ros_env import claim_free_domain, release_domain

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


@pytest.fixture(autouse=True)
def own_ros_domain(monkeypatch):
    domain = claim_free_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    yield domain
    release_domain(domain)
