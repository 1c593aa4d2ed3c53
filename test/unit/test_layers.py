"""The suite's layers hold (docs/testing.md): every test module is in test/unit, test/ros or
test/system, and a unit test that starts a process or a ROS context fails."""
from pathlib import Path
import subprocess

import pytest

TEST_DIR = Path(__file__).resolve().parents[1]


def test_every_test_module_is_in_a_layer():
    loose = sorted(p.name for p in TEST_DIR.glob('test_*.py'))
    assert not loose, f'test modules outside test/unit, test/ros, test/system: {loose}'
    layers = {p.parent.name for p in TEST_DIR.glob('*/test_*.py')}
    assert layers <= {'unit', 'ros', 'system'}, layers


def test_a_unit_test_starting_a_process_fails():
    with pytest.raises(AssertionError, match='a unit test starts no subprocess'):
        subprocess.run(['true'], check=False)


def test_a_unit_test_starting_a_ros_context_fails():
    import rclpy
    context = rclpy.Context()
    with pytest.raises(AssertionError, match='a unit test starts no ROS context'):
        rclpy.init(context=context)
    assert not context.ok()


def test_the_markers_are_registered(pytestconfig):
    registered = {line.split(':')[0] for line in pytestconfig.getini('markers')}
    assert {'slow', 'ros'} <= registered
