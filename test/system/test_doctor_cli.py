"""`mantis doctor --backend sim` as CI runs it: the command in a process of its own
(moved out of test/unit/test_doctor.py, whose tests start no process)."""
import os
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_mantis_doctor_sim_end_to_end(tmp_path):
    """What CI runs: the command in a process of its own, exit 0."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    result = subprocess.run([sys.executable, '-m', 'mantis_rig.cli', 'doctor', '--backend',
                             'sim'], cwd=tmp_path, env={**env, 'PYTHONPATH': REPO},
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == 'mantis doctor: backend sim, parameters defaults'
    assert not [line for line in lines if line.startswith('FAIL')], result.stdout
    assert lines[-1].endswith('0 FAIL; the stage was not moved (--move to home and jog it)')
