"""Finding a node process that ended, froze or hung (mantis_rig.stack.watchdog), the line that
names it, and the reason handed to the node processes (issue 41). No process is started: the
processes are stand-ins, their /proc state is given."""
import signal

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest

from mantis_rig.faults import StackError
from mantis_rig.runtime import stopping
from mantis_rig.stack import watchdog
from mantis_rig.stack.bringup import StackConfig
from mantis_rig.stack.watchdog import LaunchWatch, ProcessWatch, describe_exit


class FakeProcess:
    def __init__(self, pid, returncode=None):
        self.pid, self.returncode = pid, returncode

    def poll(self):
        return self.returncode


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def status(name):
    return DiagnosticArray(status=[DiagnosticStatus(name=name)])


@pytest.fixture
def states(monkeypatch):
    states = {}
    monkeypatch.setattr(watchdog, 'process_state', lambda pid: states.get(pid, 'S'))
    return states


def make_watch(clock, **processes):
    config = StackConfig(processes='multi')
    return ProcessWatch(processes, config.nodes_of_processes(), clock=clock)


@pytest.mark.parametrize('code, words', [
    (-signal.SIGKILL, 'was killed by SIGKILL'),
    (-signal.SIGSEGV, 'was killed by SIGSEGV'),
    (143, 'exited with status 143 (it stopped itself on SIGTERM)'),
    (1, 'exited with status 1'),
])
def test_an_exit_is_said_in_words(code, words):
    assert describe_exit(code) == words


def test_a_killed_process_is_named_with_its_signal_in_one_plain_line(states):
    clock = Clock()
    watch = make_watch(clock, sim_rig=FakeProcess(10),
                       supervisor_node=FakeProcess(11, -signal.SIGKILL))
    fault = watch.check()
    assert isinstance(fault, StackError) and fault.ended
    assert str(fault) == 'node process supervisor_node was killed by SIGKILL'


def test_a_stopped_process_is_frozen_on_the_second_look(states):
    clock = Clock()
    watch = make_watch(clock, sim_rig=FakeProcess(10), supervisor_node=FakeProcess(11))
    assert watch.check() is None
    states[11] = 'T'
    assert watch.check() is None                 # the first look
    clock.t += watchdog.STOPPED_S / 2
    assert watch.check() is None
    clock.t += watchdog.STOPPED_S
    fault = watch.check()
    assert fault.name == 'supervisor_node' and not fault.ended
    assert 'froze' in fault.line and 'SIGSTOP' in fault.line
    states[11] = 'S'                             # resumed in time: nothing
    watch = make_watch(clock, sim_rig=FakeProcess(10), supervisor_node=FakeProcess(11))
    states[11] = 'T'
    watch.check()
    states[11] = 'R'
    clock.t += 1.0
    assert watch.check() is None


def test_a_node_silent_on_diagnostics_is_hung_and_names_its_process(states):
    clock = Clock()
    watch = make_watch(clock, sim_rig=FakeProcess(10), supervisor_node=FakeProcess(11))
    clock.t += 60.0                      # never heard: not judged (still starting)
    assert watch.check() is None
    watch.on_diagnostics(status('sim_world_node: world'))
    watch.on_diagnostics(status('stage_node: stage'))
    watch.on_diagnostics(status('supervisor_node: trial'))
    watch.on_diagnostics(status('someone_else: x'))          # not a node of the stack
    for _ in range(10):                  # heard every second: fine
        clock.t += 1.0
        watch.on_diagnostics(status('sim_world_node: world'))
        watch.on_diagnostics(status('supervisor_node: trial'))
        if _ < 4:
            watch.on_diagnostics(status('stage_node: stage'))
        assert watch.check() is None or _ >= 8
    fault = watch.check()
    assert fault.name == 'sim_rig' and not fault.ended
    assert 'stage_node was not heard on /diagnostics' in fault.line and '(hung)' in fault.line


def test_an_ended_process_comes_before_a_frozen_one(states):
    clock = Clock()
    states[10] = 'T'
    watch = make_watch(clock, sim_rig=FakeProcess(10), supervisor_node=FakeProcess(11, 143))
    assert watch.check().name == 'supervisor_node'


def test_the_processes_nodes_in_each_layout():
    assert StackConfig(processes='multi').nodes_of_processes() == {
        'sim_rig': ['sim_world_node', 'stage_node', 'loadcell_node', 'camera_node'],
        'supervisor_node': ['supervisor_node']}
    assert StackConfig(backend='hardware', processes='multi').nodes_of_processes() == {
        name: [name] for name in ('stage_node', 'loadcell_node', 'camera_node',
                                  'supervisor_node')}


def test_the_stacks_reason_reaches_a_node_process(tmp_path, monkeypatch):
    reason_file = tmp_path / 'stack.reason'
    monkeypatch.setenv(stopping.STOP_REASON_ENV, str(reason_file))
    monkeypatch.setattr(stopping, '_parent_gone', [])
    assert stopping.stop_reason('interrupted by SIGINT (Ctrl-C)') == \
        'interrupted by SIGINT (Ctrl-C)'
    stopping._parent_gone.append("the stack's process (pid 7) froze")
    assert stopping.stop_reason('interrupted by SIGTERM') == "the stack's process (pid 7) froze"
    reason_file.write_text('node process sim_rig was killed by SIGKILL\n')
    assert stopping.stop_reason('interrupted by SIGINT (Ctrl-C)') == \
        'node process sim_rig was killed by SIGKILL'


def test_the_launch_files_watch_reports_the_first_exit_once(tmp_path, monkeypatch):
    stops = []
    monkeypatch.setattr(watchdog, 'stop_stage_at_port',
                        lambda port: stops.append(port) or f'stage stopped at its port {port}')
    reason = tmp_path / 'reason'
    watch = LaunchWatch('hardware', {'serial_port': '/dev/ttyUSB3'}, str(reason))
    line = watch.on_exit('stage_node', -signal.SIGKILL)
    assert line == ('node process stage_node was killed by SIGKILL; stage stopped at its port '
                    '/dev/ttyUSB3, nodes ended')
    assert stops == ['/dev/ttyUSB3']
    assert reason.read_text() == 'node process stage_node was killed by SIGKILL'
    assert watch.on_exit('supervisor_node', 130) is None      # the shutdown's own exits


def test_the_launch_files_watch_kills_and_names_a_frozen_process(tmp_path, states):
    clock = Clock()
    watch = LaunchWatch('sim', {}, str(tmp_path / 'reason'), clock=clock)
    states[21] = 'T'
    assert watch.frozen({'sim_rig': 20, 'supervisor_node': 21}) is None
    clock.t += watchdog.STOPPED_S + 0.01
    assert watch.frozen({'sim_rig': 20, 'supervisor_node': 21}) == 'supervisor_node'
    line = watch.on_exit('supervisor_node', -signal.SIGKILL)
    assert line == ('node process supervisor_node froze (stopped by SIGSTOP or another stop '
                    'signal) and was killed with SIGKILL; stage stopped, nodes ended')


def test_a_launch_shutting_down_reports_nothing(tmp_path):
    watch = LaunchWatch('sim', {}, str(tmp_path / 'reason'))
    watch.shutting_down()
    assert watch.on_exit('sim_rig', 130) is None
    assert not (tmp_path / 'reason').exists()


def test_the_line_says_what_became_of_the_trials_bag(tmp_path):
    from mantis_rig.stack.stack_runs import fault_line
    from mantis_rig.stack.watchdog import ProcessFault
    fault = ProcessFault('supervisor_node', 'was killed by SIGKILL', ended=True)
    bag = tmp_path / 'trial_20261128_070000'
    bag.mkdir()
    assert fault_line(fault, '', []) == ('node process supervisor_node was killed by SIGKILL; '
                                         'stage stopped, nodes ended')
    assert fault_line(fault, '', [bag]) == (
        f"node process supervisor_node was killed by SIGKILL; stage stopped, nodes ended; the "
        f"trial's bag {bag} was not closed (its recorder went with supervisor_node): recover "
        f"it with `mantis recover {bag}`")
    hardware = ProcessFault('stage_node', 'was killed by SIGKILL', ended=True)
    assert fault_line(hardware, 'stage stopped at its port /dev/ttyUSB0 (MOT_MOVE_STOP, '
                      'confirmed)', []) == (
        'node process stage_node was killed by SIGKILL; stage stopped at its port /dev/ttyUSB0 '
        '(MOT_MOVE_STOP, confirmed), nodes ended')
