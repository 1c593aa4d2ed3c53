"""`mantis start|abort|state` against a running rig, in the root namespace and in one of its
own: parameters set before the start, a trial followed to its end, an abort from another
`mantis` process's point of view, the state as JSON; bad input refused before anything is sent
(exit 2, one line); no rig (exit 3, one line). Every wait is on a state, none on a fixed time.
"""
import contextlib
import io
import json
import os
from pathlib import Path
import subprocess
import sys

import pytest
from test_session import FAST_RETURN, SCENE

from mantis_rig.cli.main import main
from mantis_rig.nodes.trial_client import TrialClient
from mantis_rig.recording import BagReader
from mantis_rig.stack.bringup import Stack, StackConfig

TRIAL_TIMEOUT_S = 240.0

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow, pytest.mark.ros]


@contextlib.contextmanager
def rig(tmp_path, namespace=''):
    config = StackConfig(scene=SCENE, real_time_factor=0.0, namespace=namespace,
                         supervisor={'out': str(tmp_path / 'default'), 'operator_note': 'pytest'},
                         devices=FAST_RETURN)
    stack = Stack(config, log_dir=tmp_path / 'logs')
    client = TrialClient(namespace=namespace)
    stack.add_node(client)
    try:
        stack.start()
        assert client.wait_for_supervisor(60.0)
        yield client
    finally:
        stack.stop()
        client.destroy_node()


def mantis(*argv):
    """(exit status, stdout lines, stderr lines) of `mantis *argv` run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue().splitlines(), err.getvalue().splitlines()


def state(*where) -> dict:
    code, out, err = mantis('state', *where, '--json')
    assert code == 0 and len(out) == 1, (out, err)
    return json.loads(out[0])


def test_start_state_and_abort_a_running_rig(ros, tmp_path):
    with rig(tmp_path) as client:
        assert state() == {
            'namespace': '/', 'state': 'idle', 'reason': '', 'trials': 0, 'bag': '',
            'last_abort_reason': ''}
        # parameters set first (d_t_mm typed a double from "19"), the trial followed to its end
        code, out, err = mantis('start', '--set', 'd_t_mm=19', '--set',
                                f'out={tmp_path / "day"}', '--wait')
        assert code == 0, err
        assert len(out) == 2 and out[0].startswith(f'bag: {tmp_path / "day"}/trial_'), out
        assert out[1] == 'done', out
        bag = Path(out[0][len('bag: '):])
        reader = BagReader(bag)
        assert reader.complete and reader.metadata('trial_conditions')['d_t_mm'] == '19.0'
        now = state()
        assert now['state'] in ('done', 'waiting_for_relatch') and now['trials'] == 1
        assert now['bag'] == str(bag)
        assert client.get_parameters(['d_t_mm', 'out']) == {'d_t_mm': 19.0,
                                                           'out': str(tmp_path / 'day')}

        # an abort mid-pull (a slow one), asked by `mantis abort`; the start came from this
        # process's client
        assert client.set_parameters({'pull_speed_mm_s': 0.05}) == (True, '')
        ok, message = client.start_trial()
        assert ok, message
        assert client.wait_for_state(('pulling', 'done', 'aborted'), client.trial_start,
                                     TRIAL_TIMEOUT_S) == 'pulling'
        code, out, err = mantis('abort')
        assert code == 0 and out == ['aborting: abort requested (/supervisor/abort)'], (out, err)
        assert client.wait_for_end(TRIAL_TIMEOUT_S) == 'aborted'
        now = state()
        assert now['state'] == 'aborted' and now['trials'] == 2
        assert now['reason'] == now['last_abort_reason'] == 'abort requested (/supervisor/abort)'
        code, out, err = mantis('abort')        # nothing left to abort
        assert code == 1 and err == ['mantis abort: no trial in progress (state aborted)'], err

        # bad input: refused before anything is sent, in one line
        code, out, err = mantis('start', '--set', 'nope=1')
        assert code == 2 and len(err) == 1 and not out
        assert err[0].startswith("mantis start: --set 'nope=1': unknown supervisor parameter "
                                 "'nope'"), err
        code, out, err = mantis('start', '--set', 'pull_speed_mm_s=9')
        assert (code, out, err) == (2, [], [
            'mantis start: pull_speed_mm_s = 9.0 mm/s is outside [0.05, 2.4] mm/s'])
        # a value that does not go with the supervisor's others: nothing is set either
        code, out, err = mantis('start', '--set', 'd_t_mm=21', '--set',
                                'pre_trigger_s=0.99')
        assert code == 2 and len(err) == 1 and 'camera buffer' in err[0], err
        assert client.get_parameters(['d_t_mm', 'pre_trigger_s'])['d_t_mm'] == 19.0
        assert state()['trials'] == 2

        # the client's own refusals and the supervisor's, each naming the parameter
        assert client.set_parameters({'d_t_mm': 20}) == (True, '')
        ok, why = client.set_parameters({'operator_note': 'x', 'pull_speed_mm_s': 9.0})
        assert not ok and why.startswith('pull_speed_mm_s: '), why
        assert client.set_parameters({'nope': 1}) == \
            (False, 'nope: not a parameter of the supervisor')

        # no rig there: one line, exit 3
        code, out, err = mantis('state', '--namespace', '/nowhere',
                                '--reach-timeout', '2')
        assert code == 3 and not out and len(err) == 1, err
        assert err[0].startswith('mantis state: no supervisor answered at '
                                 '/nowhere/supervisor/start_trial within 2 s'), err


def test_a_rig_in_a_namespace_from_another_process(ros, tmp_path):
    """`mantis start --wait` as a process of its own (the same ROS_DOMAIN_ID), aborted by
    `mantis abort`: exit 1, the final state and reason printed."""
    where = ('--namespace', '/rig_c')
    with rig(tmp_path, '/rig_c') as client:
        assert state(*where)['state'] == 'idle'
        start = subprocess.Popen(
            [sys.executable, '-m', 'mantis_rig.cli.main', 'start', *where, '--wait',
             '--set', f'out={tmp_path / "ns"}', '--set', 'pull_speed_mm_s=0.05'],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
        try:
            assert client.wait_for_state(('pulling', 'done', 'aborted'), 0,
                                         TRIAL_TIMEOUT_S) == 'pulling', client.states
            code, out, err = mantis('abort', *where)
            assert code == 0, err
            out, err = start.communicate(timeout=TRIAL_TIMEOUT_S)
        finally:
            start.kill()
        assert start.returncode == 1, (out, err)
        lines = out.splitlines()
        assert lines[0].startswith(f'bag: {tmp_path / "ns"}/trial_'), lines
        assert lines[1:] == ['aborted: abort requested (/rig_c/supervisor/abort)'], lines
        now = state(*where)
        assert now['namespace'] == '/rig_c' and now['state'] == 'aborted'
        assert now['bag'] == lines[0][len('bag: '):] and now['trials'] == 1
        assert BagReader(now['bag']).complete
