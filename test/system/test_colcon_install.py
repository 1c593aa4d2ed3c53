"""The ROS install path (issue 12), as a Jazzy user takes it: `colcon build` of the package (in
.venv-colcon, colcon and the runtime dependencies from PyPI, made by `scripts/bootstrap.sh
--test`), then, from the install space alone, the simulated stack started by its installed
executables with the README's parameters, one trial through the supervisor's service, the bag
written, the scenes found as mantis_sim's installed package data, the launch file in share;
the ament index entry; and package.xml (format 3, an exec_depend for every ROS package and
Python library the code and the launch file import)."""
import ast
import os
from pathlib import Path
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from mantis_rig.contract import (
    CAMERA_NODE,
    FORCE_BLOCK,
    JOINT_STATE,
    LOADCELL_NODE,
    MARKERS,
    STAGE_NODE,
    SUPERVISOR_NODE,
    resolve,
)
from mantis_rig.recording import BagReader

REPO = Path(__file__).resolve().parents[2]
COLCON_VENV = REPO / '.venv-colcon'
PACKAGE = 'mantis_rig'

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow, pytest.mark.ros]

# A trial as a user runs it with `ros2 service call /supervisor/start_trial std_srvs/srv/Trigger`
# and watches /supervisor/state; run by the install space's Python.
CLIENT = '''
import sys, time
import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from std_msgs.msg import String
from std_srvs.srv import Trigger
rclpy.init()
node = Node('colcon_check_client')
states = []
node.create_subscription(String, '/supervisor/state', lambda m: states.append(m.data),
                         QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL))
client = node.create_client(Trigger, '/supervisor/start_trial')
if not client.wait_for_service(timeout_sec=90):
    sys.exit('no /supervisor/start_trial')
future = client.call_async(Trigger.Request())
rclpy.spin_until_future_complete(node, future, timeout_sec=60)
print('answer:', future.result().success, future.result().message, flush=True)
deadline = time.monotonic() + 150
while time.monotonic() < deadline and not (states and states[-1] in ('done', 'aborted')):
    rclpy.spin_once(node, timeout_sec=0.2)
print('state:', states[-1] if states else None, flush=True)
'''


@pytest.fixture(scope='module')
def install(tmp_path_factory):
    """colcon build into a temporary install space; its environment as `. install/setup.sh`
    leaves it."""
    colcon = COLCON_VENV / 'bin' / 'colcon'
    assert colcon.exists(), (f'{colcon} missing: scripts/bootstrap.sh --test makes it (the '
                             f'README\'s test command runs that)')
    work = tmp_path_factory.mktemp('colcon')
    result = subprocess.run(
        [str(colcon), '--log-base', str(work / 'log'), 'build', '--base-paths', str(REPO),
         '--build-base', str(work / 'build'), '--install-base', str(work / 'install')],
        cwd=work, capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stdout + result.stderr
    shell = subprocess.run(['sh', '-c', f'. "{work / "install" / "setup.sh"}" && env -0'],
                           capture_output=True, timeout=60, env=_clean_env())
    assert shell.returncode == 0, shell.stderr
    env = dict(item.split('=', 1) for item in shell.stdout.decode().split('\0') if '=' in item)
    return work / 'install', env


def _clean_env() -> dict:
    """This test process's environment without its own venv: nothing of the source tree."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'VIRTUAL_ENV', 'AMENT_PREFIX_PATH', 'MANTIS_SCENE_PATH')}
    env['PATH'] = os.pathsep.join(p for p in env.get('PATH', '').split(os.pathsep)
                                  if not p.startswith(str(REPO)))
    return env


def test_the_install_space_has_the_executables_the_index_and_the_share_files(install):
    prefix, _ = install
    lib = prefix / PACKAGE / 'lib' / PACKAGE
    for node in (STAGE_NODE, LOADCELL_NODE, CAMERA_NODE, SUPERVISOR_NODE, 'sim_rig',
                 'replay_node', 'mantis'):
        assert os.access(lib / node, os.X_OK), node
    assert (prefix / PACKAGE / 'share' / 'ament_index' / 'resource_index' / 'packages' /
            PACKAGE).exists()
    share = prefix / PACKAGE / 'share' / PACKAGE
    assert (share / 'package.xml').read_bytes() == (REPO / 'package.xml').read_bytes()
    assert sorted(p.name for p in (share / 'config' / 'foxglove').iterdir()) == \
        sorted(p.name for p in (REPO / 'config' / 'foxglove').iterdir())
    assert (share / 'launch' / 'mantis_rig.launch.py').read_bytes() == \
        (REPO / 'launch' / 'mantis_rig.launch.py').read_bytes()
    scenes = (prefix / PACKAGE / 'lib').glob('python*/site-packages/mantis_sim/scenes/*.yaml')
    assert sorted(p.name for p in scenes) == \
        sorted(p.name for p in (REPO / 'mantis_sim' / 'scenes').glob('*.yaml'))


def test_the_installed_package_finds_its_scenes_in_its_package_data(install):
    prefix, env = install
    probe = ('import mantis_rig, mantis_sim.scene as s; print(mantis_rig.__file__); '
             'print(s.__file__); print(s.available_scenes()["air_23mm_rig"])')
    result = subprocess.run([str(COLCON_VENV / 'bin' / 'python'), '-c', probe], env=env,
                            cwd=prefix, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    module, scene_module, scene = result.stdout.split()
    assert module.startswith(str(prefix / PACKAGE / 'lib')), module
    assert scene_module.startswith(str(prefix / PACKAGE / 'lib')), scene_module
    assert scene == str(Path(scene_module).parent / 'scenes' / 'air_23mm_rig.yaml')


def test_a_trial_from_the_installed_executables(install, tmp_path):
    """The README's commands: `ros2 run mantis_rig sim_rig`, `ros2 run mantis_rig
    supervisor_node --ros-args -p use_sim_time:=true -p out:=trials`, then the service."""
    prefix, env = install
    env = {**env, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_DOMAIN_ID': os.environ['ROS_DOMAIN_ID']}
    lib = prefix / PACKAGE / 'lib' / PACKAGE
    trials = tmp_path / 'trials'
    logs = {name: open(tmp_path / f'{name}.log', 'wb') for name in ('rig', 'supervisor')}
    started = [
        subprocess.Popen([str(lib / 'sim_rig')], env=env, cwd=tmp_path, stdout=logs['rig'],
                         stderr=subprocess.STDOUT),
        subprocess.Popen([str(lib / SUPERVISOR_NODE), '--ros-args', '-p',
                          'use_sim_time:=true', '-p', f'out:={trials}'], env=env, cwd=tmp_path,
                         stdout=logs['supervisor'], stderr=subprocess.STDOUT)]
    try:
        client = subprocess.run([str(COLCON_VENV / 'bin' / 'python'), '-c', CLIENT], env=env,
                                cwd=tmp_path, capture_output=True, text=True, timeout=240)
    finally:
        for process in reversed(started):
            process.send_signal(signal.SIGINT)
        for process in started:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
        for log in logs.values():
            log.close()
    output = client.stdout + client.stderr
    assert 'answer: True trial started; logging to' in output, \
        output + (tmp_path / 'supervisor.log').read_text(errors='replace')
    assert 'state: done' in output, output + (tmp_path / 'supervisor.log').read_text()
    statuses = [p.returncode for p in started]
    assert statuses == [130, 130], '\n'.join(
        [f'exit statuses (rig, supervisor): {statuses}']
        + [f'--- {name}.log\n' + (tmp_path / f'{name}.log').read_text(errors='replace')
           for name in ('rig', 'supervisor')])
    bags = [p for p in trials.iterdir() if p.is_dir()]
    assert len(bags) == 1
    reader = BagReader(bags[0])
    assert reader.complete
    assert reader.metadata('trial_outcome')['result'] == 'completed'
    assert {resolve(FORCE_BLOCK), resolve(JOINT_STATE), resolve(MARKERS)} <= set(
        reader.topics)


# ------------------------------------------------------------------ package.xml
# What the code imports, and the package.xml key that provides it (rosdep keys for Python
# libraries; PyPI-only ones are named in package.xml's comment and installed with pip).
ROSDEP_KEYS = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'numba': 'python3-numba',
               'yaml': 'python3-yaml',
               'matplotlib': 'python3-matplotlib', 'serial': 'python3-serial',
               'statsmodels': 'python3-statsmodels', 'cv2': 'python3-opencv'}
PYPI_ONLY = {'mcap', 'mcap_ros2', 'rosbags', 'thorlabs_apt_protocol', 'python_calamine',
             'nidaqmx', 'dask', 'distributed', 'pyarrow', 'threadpoolctl', 'foxglove',
             'pycine'}


def imported_top_levels() -> set:
    names = set()
    for folder in ('mantis_rig', 'mantis_sim', 'launch'):
        for path in (REPO / folder).rglob('*.py'):
            for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
                if isinstance(node, ast.Import):
                    names |= {alias.name.split('.')[0] for alias in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names.add(node.module.split('.')[0])
    return names - {'mantis_rig', 'mantis_sim'} - set(sys.stdlib_module_names)


def test_package_xml_is_format_3_and_declares_what_the_code_imports():
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == PACKAGE
    assert root.find('export/build_type').text == 'ament_python'
    exec_depends = {e.text for e in root.findall('exec_depend')}
    comment = (REPO / 'package.xml').read_text()
    missing = []
    for name in sorted(imported_top_levels()):
        if name in PYPI_ONLY:
            if not any(n in comment for n in (name, name.replace('_', '-'), f'{name}-sdk')):
                missing.append(f'{name} (PyPI: name it in package.xml\'s comment)')
        elif ROSDEP_KEYS.get(name, name) not in exec_depends:
            missing.append(ROSDEP_KEYS.get(name, name))
    assert not missing, f'package.xml lacks an exec_depend for: {missing}'
    unused = {d for d in exec_depends
              if d not in {ROSDEP_KEYS.get(n, n) for n in imported_top_levels()}}
    assert not unused, f'exec_depends the code never imports: {sorted(unused)}'
