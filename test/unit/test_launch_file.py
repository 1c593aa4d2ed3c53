"""A static check of launch/mantis_rig.launch.py: `launch` and `launch_ros` are not installable
from PyPI, so the file is never run here. It is parsed with `ast` (never imported); its
launch-free functions (the processes, the parameters) are compiled out of it and called. Checked:
every executable it starts is one of setup.py's console scripts, and is what
`mantis bringup --processes multi` starts; every parameter it passes is one the node declares
(from the nodes' own parameter tables); the parameters are `mantis bringup`'s, value for value,
with the same defaults; setup.py installs the file to share/mantis_rig/launch. What this does not
show: that `ros2 launch` accepts the file and the stack comes up under it."""
import ast
from pathlib import Path

import pytest

from mantis_rig.cli import build_parser
from mantis_rig.cli.trial_commands import stack_config
from mantis_rig.contract import STAGE_NODE
from mantis_rig.nodes.device_node import COMMON_PARAMETERS
from mantis_rig.simulated import sim_world_node
from mantis_rig.stack.node_table import (
    BY_NAME,
    DEVICES,
    PROCESS_MODULES,
    SIM_RIG_PROCESS,
    SUPERVISOR,
    WORLD,
)
from mantis_rig.trial.supervisor_settings import PARAMETERS as SUPERVISOR_PARAMETERS
from mantis_sim.trial_conditions import CONDITION_KEYS

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / 'launch' / 'mantis_rig.launch.py'
LAUNCH_FREE = ('ARGUMENTS', 'DEVICE_NODES', 'processes', 'scene_conditions', 'node_parameters')
BACKENDS = ('sim', 'hardware')


def launch_tree() -> ast.Module:
    return ast.parse(LAUNCH_FILE.read_text(encoding='utf-8'), str(LAUNCH_FILE))


def launch_free_part() -> dict:
    """The launch file's module-level names that use nothing of `launch`, compiled on their own
    and run: nothing else of the file is executed."""
    wanted = []
    for node in launch_tree().body:
        if isinstance(node, ast.ImportFrom) and node.module.startswith('mantis_rig'):
            wanted.append(node)          # the contract's names
        elif isinstance(node, ast.FunctionDef) and node.name in LAUNCH_FREE:
            wanted.append(node)
        elif isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id in LAUNCH_FREE for t in node.targets):
            wanted.append(node)
    namespace: dict = {}
    exec(compile(ast.Module(body=wanted, type_ignores=[]), str(LAUNCH_FILE), 'exec'), namespace)
    missing = [name for name in LAUNCH_FREE if name not in namespace]
    assert not missing, f'the launch file no longer defines {missing}'
    return namespace


def console_scripts() -> set:
    """setup.py's console scripts, read from its source: NODES (those whose module exists) and
    the literal entries of console_scripts."""
    tree = ast.parse((REPO / 'setup.py').read_text(encoding='utf-8'))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == 'NODES'
                                                for t in node.targets):
            for name, target in ast.literal_eval(node.value).items():
                module = REPO.joinpath(*target.split(':')[0].split('.')).with_suffix('.py')
                if module.exists():
                    names.add(name)
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == 'console_scripts':
                    names |= {item.value.split('=')[0].strip() for item in value.elts
                              if isinstance(item, ast.Constant)}
    return names


def declared_parameters(node_name: str) -> set:
    """The parameters the node declares, from its own table; rclpy declares use_sim_time on
    every node."""
    if node_name == WORLD.name:
        names = {spec.name for spec in sim_world_node.PARAMETERS}
    elif node_name == SUPERVISOR.name:
        names = set(SUPERVISOR_PARAMETERS)
    else:
        names = {spec.name for spec in COMMON_PARAMETERS + BY_NAME[node_name].node_class()
                 .PARAMETERS}
    return names | {'use_sim_time'}


def undeclared(params: dict) -> list:
    """'node: parameter' for every parameter passed to a node that does not declare it (or to
    a node the table does not know)."""
    problems = []
    for node_name, values in params.items():
        if node_name not in BY_NAME:
            problems.append(f'{node_name}: not a node of the node table')
            continue
        problems += [f'{node_name}: {name}' for name in values
                     if name not in declared_parameters(node_name)]
    return problems


def launched_parameters(namespace: dict, backend: str) -> dict:
    """node_parameters at the launch arguments' defaults, typed as the launch file types them."""
    defaults = {name: default for name, (default, _) in namespace['ARGUMENTS'].items()}
    return namespace['node_parameters'](backend, defaults['scene'], int(defaults['seed']),
                                        float(defaults['real_time_factor']), defaults['out'])


def bringup_config(backend: str):
    return stack_config(build_parser().parse_args(['bringup', '--backend', backend,
                                                   '--processes', 'multi']))


@pytest.fixture(scope='module')
def launch_file():
    return launch_free_part()


@pytest.mark.parametrize('backend', BACKENDS)
def test_every_executable_is_a_console_script_and_what_bringup_starts(launch_file, backend):
    started = launch_file['processes'](backend)
    scripts = console_scripts()
    assert set(started) <= scripts, f'not console scripts of setup.py: {set(started) - scripts}'
    assert started == bringup_config(backend).process_names()


def test_the_nodes_are_started_from_the_processes_list_of_this_package():
    """The only Node action: package mantis_rig, one per name of processes(backend)."""
    tree = launch_tree()
    calls = [node for node in ast.walk(tree)
             if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'Node']
    assert len(calls) == 1
    keywords = {k.arg: k.value for k in calls[0].keywords}
    assert ast.literal_eval(keywords['package']) == 'mantis_rig'
    loops = [node for node in ast.walk(tree) if isinstance(node, ast.ListComp)
             and calls[0] in ast.walk(node)]
    assert len(loops) == 1
    generator = loops[0].generators[0]
    assert isinstance(keywords['executable'], ast.Name)
    assert generator.target.id == keywords['executable'].id
    assert generator.iter.func.id == 'processes'


@pytest.mark.parametrize('backend', BACKENDS)
def test_every_parameter_passed_is_declared_by_its_node(launch_file, backend):
    params = launched_parameters(launch_file, backend)
    assert undeclared(params) == []
    expected_nodes = {SUPERVISOR.name, *(d.name for d in DEVICES)}
    if backend == 'sim':
        expected_nodes.add(WORLD.name)
    assert set(params) == expected_nodes


def test_the_check_finds_an_undeclared_parameter(launch_file):
    params = launched_parameters(launch_file, 'sim')
    params[STAGE_NODE]['pull_speed_mm_s'] = 2.0        # a supervisor parameter
    params['no_such_node'] = {}
    assert undeclared(params) == ['stage_node: pull_speed_mm_s',
                                  'no_such_node: not a node of the node table']


@pytest.mark.parametrize('backend', BACKENDS)
def test_the_parameters_are_bringups(launch_file, backend):
    assert launched_parameters(launch_file, backend) == \
        bringup_config(backend).node_parameters()


def test_a_scene_with_a_latch_offset_gives_the_supervisor_the_same_conditions(launch_file,
                                                                              tmp_path):
    """The arm of this scene sits 4 degrees past its recorded contact angle: the launch file and
    `mantis bringup` both give the supervisor the contact angle as recorded (the world adds the
    offset), and every other condition the same."""
    scene = tmp_path / 'offset_latch.yaml'
    scene.write_text('name: offset_latch\ndescription: a latch offset of 4 degrees\n'
                     'effects: []\ngeometry: {d_t_mm: 19.0, contact_angle_deg: 3.0, '
                     'latch_offset_deg: 4.0}\nmedium: {name: air}\ntendon: {model: rigid}\n'
                     'drive: {pull_speed_mm_per_s: 1.5}\n',
                     encoding='utf-8')
    launched = launch_file['node_parameters']('sim', str(scene), 0, 1.0, 'trials')
    brought_up = stack_config(build_parser().parse_args(
        ['bringup', '--processes', 'multi', '--scene', str(scene)])).node_parameters()
    for key in CONDITION_KEYS:
        assert launched[SUPERVISOR.name][key] == brought_up[SUPERVISOR.name][key], key
    assert launched[SUPERVISOR.name]['contact_angle_deg'] == 3.0
    assert (launched[SUPERVISOR.name]['d_t_mm'], launched[SUPERVISOR.name]['pull_speed_mm_s']) \
        == (19.0, 1.5)


def test_the_launch_arguments_default_to_bringups(launch_file):
    args = build_parser().parse_args(['bringup'])
    defaults = {name: default for name, (default, _) in launch_file['ARGUMENTS'].items()}
    assert defaults == {'backend': args.backend, 'scene': args.scene, 'seed': str(args.seed),
                        'real_time_factor': str(args.real_time_factor), 'out': str(args.out)}
    assert launch_file['DEVICE_NODES'] == tuple(d.name for d in DEVICES)
    assert SIM_RIG_PROCESS in launch_file['processes']('sim')


def test_each_process_s_console_script_runs_the_module_bringup_starts():
    """setup.py's NODES (the console scripts `ros2 run` and the launch file start) name the same
    module as the node table's PROCESS_MODULES (what `mantis bringup --processes multi` runs
    with python -m), and each module exists."""
    tree = ast.parse((REPO / 'setup.py').read_text(encoding='utf-8'))
    nodes = next(ast.literal_eval(node.value) for node in ast.walk(tree)
                 if isinstance(node, ast.Assign) and any(
                     isinstance(t, ast.Name) and t.id == 'NODES' for t in node.targets))
    for name, module in PROCESS_MODULES.items():
        assert nodes.get(name) == f'{module}:main', name
        assert REPO.joinpath(*module.split('.')).with_suffix('.py').exists(), module


def test_setup_installs_the_launch_file():
    tree = ast.parse((REPO / 'setup.py').read_text(encoding='utf-8'))
    installed = [node for node in ast.walk(tree) if isinstance(node, ast.Tuple)
                 and len(node.elts) == 2 and isinstance(node.elts[1], ast.List)
                 and any(isinstance(e, ast.Constant) and e.value == 'launch/mantis_rig.launch.py'
                         for e in node.elts[1].elts)]
    assert len(installed) == 1
    # ('share/' + PACKAGE + '/launch', [...])
    assert ast.unparse(installed[0].elts[0]) == "'share/' + PACKAGE + '/launch'"


def test_a_node_process_that_ends_ends_the_launch():
    """Issue 41: every node started gets an OnProcessExit handler that reports through
    watchdog.LaunchWatch (tested in test_watchdog.py) and shuts the launch down; an OnShutdown
    handler marks the launch's own exits; frozen processes are looked for on a timer."""
    tree = launch_tree()
    called = {getattr(node.func, 'id', None) for node in ast.walk(tree)
              if isinstance(node, ast.Call)}
    assert {'OnProcessExit', 'OnShutdown', 'RegisterEventHandler', 'EmitEvent', 'Shutdown',
            'LaunchWatch', 'TimerAction'} <= called
    handlers = [node for node in ast.walk(tree) if isinstance(node, ast.ListComp)
                and any(getattr(n.func, 'id', None) == 'OnProcessExit'
                        for n in ast.walk(node) if isinstance(n, ast.Call))]
    assert len(handlers) == 1          # one per node: zip(names, nodes)
    loop = handlers[0].generators[0]
    assert ast.unparse(loop.iter) == 'zip(names, nodes)'
    source = LAUNCH_FILE.read_text(encoding='utf-8')
    assert 'names = processes(backend)' in source
    assert 'additional_env={STOP_REASON_ENV:' in source
