"""`mantis trial` and `mantis bringup` without ROS: the options into a stack's configuration,
and how a node process on its way out is told from a device fault once a trial of a
multi-process stack has been aborted (mantis_rig.stack.stack_runs._name_a_dying_process)."""
import time

import pytest

from mantis_rig.cli import trial_commands as cli_trial
from mantis_rig.cli.main import build_parser
from mantis_rig.faults import StackError
from mantis_rig.runtime.stopping import PROCESS_STOPPING
from mantis_rig.stack import stack_runs
from mantis_rig.trial.supervisor_settings import ConditionError


@pytest.fixture
def short_grace(monkeypatch):
    """The grace and the wait for a node on its way out, shortened: what is tested is which of
    them applies, not their length."""
    monkeypatch.setattr(stack_runs, 'DYING_PROCESS_GRACE_S', 0.1)
    monkeypatch.setattr(stack_runs, 'SHUT_DOWN_NODE_EXIT_S', 1.5)


class SlowlyEndingStack:
    """A stack whose rig process ends (check_processes raises) ``ends_after_s`` from now, or
    never."""

    processes = ['sim_rig']

    def __init__(self, ends_after_s=None):
        self.ends_at = None if ends_after_s is None else time.monotonic() + ends_after_s

    def check_processes(self):
        if self.ends_at is not None and time.monotonic() >= self.ends_at:
            raise StackError('sim_rig (exit 143) ended during the trial')


@pytest.mark.parametrize('reason', [
    f'device fault: stage_node: device error: move to 10 mm was stopped at 13 mm '
    f'({PROCESS_STOPPING}: interrupted by SIGTERM)',
    'device fault: camera_node: left the active state (now shuttingdown)'])
def test_a_process_on_its_way_out_is_waited_for_past_the_grace(reason, short_grace):
    stack = SlowlyEndingStack(ends_after_s=2 * stack_runs.DYING_PROCESS_GRACE_S)
    with pytest.raises(StackError, match='sim_rig'):
        stack_runs._name_a_dying_process(stack, lambda: reason)


def test_another_abort_is_reported_after_the_grace(short_grace):
    stack = SlowlyEndingStack()
    started = time.monotonic()
    stack_runs._name_a_dying_process(stack, lambda: 'force ceiling 12 N exceeded')
    assert stack_runs.DYING_PROCESS_GRACE_S <= time.monotonic() - started \
        < stack_runs.SHUT_DOWN_NODE_EXIT_S


@pytest.mark.parametrize('namespace', ['/rig2', '/lab/rig_2'])
def test_a_rig_runs_in_the_namespace_given(namespace, tmp_path):
    args = build_parser().parse_args(['trial', '--out', str(tmp_path), '--namespace', namespace])
    assert cli_trial.stack_config(args).namespace == namespace


@pytest.mark.parametrize('namespace', ['rig2', '/2rig', '/rig-2', '/rig2/', '//rig'])
def test_a_namespace_that_is_not_one_is_refused_naming_it(namespace, tmp_path):
    args = build_parser().parse_args(['bringup', '--namespace', namespace])
    with pytest.raises(ConditionError, match=f'--namespace {namespace!r}: expected an absolute'):
        cli_trial.stack_config(args)


def _sim_config(tmp_path, *sets):
    argv = ['trial', '--out', str(tmp_path)]
    for item in sets:
        argv += ['--set', item]
    return cli_trial.stack_config(build_parser().parse_args(argv))


def test_a_simulated_trial_records_the_scenes_conditions_unless_set(tmp_path):
    """The contact angle is the scene's recorded one, not where the arm sits (contact angle +
    latch offset): the simulated world builds its robot from what the supervisor records."""
    shimmed = _sim_config(tmp_path, 'geometry.latch_offset_deg=2').supervisor
    assert (shimmed['d_t_mm'], shimmed['contact_angle_deg'], shimmed['medium'],
            shimmed['pull_speed_mm_s']) == (23.0, 3.0, 'air', 2.33)
    assert _sim_config(tmp_path, 'd_t_mm=19', 'geometry.contact_angle_deg=5').supervisor[
        'd_t_mm'] == 19.0
    assert _sim_config(tmp_path, 'geometry.contact_angle_deg=5').supervisor[
        'contact_angle_deg'] == 5.0


def test_conditions_the_simulated_world_cannot_take_are_refused_before_the_start(tmp_path):
    from mantis_sim.parameters import ParameterError
    with pytest.raises(ParameterError, match='medium = vacuum: scene air_23mm_rig simulates '
                                             'the fluid around the robot'):
        _sim_config(tmp_path, 'medium=vacuum')
    with pytest.raises(ParameterError, match='contact_angle_deg = 14.0: .* puts the latched '
                                             'arm at 16 degrees'):
        _sim_config(tmp_path, 'contact_angle_deg=14', 'geometry.latch_offset_deg=2')
