"""The rig's node stack on a ROS 2 Jazzy install: what `mantis bringup --backend sim|hardware
--processes multi` starts, with the same parameters.

    ros2 launch mantis_rig mantis_rig.launch.py                      # the simulated rig
    ros2 launch mantis_rig mantis_rig.launch.py backend:=hardware out:=/data/trials
    ros2 service call /supervisor/start_trial std_srvs/srv/Trigger   # then, one trial

sim: the `sim_rig` process (the simulated world and the three device nodes) and
`supervisor_node` on the world's clock (use_sim_time), its trial conditions taken from the
scene as `mantis bringup` takes them; hardware: `stage_node`, `loadcell_node`, `camera_node`
and `supervisor_node`, a process each. One params file with a section per node, as
`mantis bringup` writes it. The device nodes come up unconfigured; the supervisor configures
and activates them. Other supervisor parameters: `ros2 param set /supervisor_node ...`.

A node process that ends ends the stack (as `mantis bringup` does): an OnProcessExit handler per
node (mantis_rig.stack.watchdog.LaunchWatch) logs one line naming the process and the signal or
exit status, gives that line to the supervisor as its trial's abort reason, stops the stage at
the KDC101's port when the stage node's own process died on hardware, and shuts the launch down
(the other nodes get SIGINT: the stage node stops the stage, the supervisor aborts its trial and
closes its log). A node process frozen (stopped, SIGSTOP) is found every WATCH_PERIOD_S from its
/proc state, killed, and reported the same way. A node that hangs while running is not found
by the launch file (`mantis bringup` finds it from its /diagnostics); the stage node's own
supervisor heartbeat stops a pull whose supervisor has gone quiet.

Checked only statically (test/unit/test_launch_file.py parses this file: its executables against
setup.py's console scripts, its parameters against the nodes' declared ones and against
`mantis bringup`'s); `ros2 launch` is not installable from PyPI, so it has not been run here.
The functions above `generate_launch_description` use nothing from `launch`: the check
runs them (with the names they take from mantis_rig.contract).
"""
import os
import signal
import tempfile

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
    TimerAction,
)
from launch.event_handlers import OnProcessExit, OnShutdown
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
import yaml

from mantis_rig.contract import (
    DEFAULT_SCENE,
    DEVICE_NODES,
    SIM_RIG_PROCESS,
    SIM_WORLD_NODE,
    STAGE_NODE,
    SUPERVISOR_NODE,
)
from mantis_rig.runtime.stopping import STOP_REASON_ENV
from mantis_rig.stack.watchdog import LaunchWatch

WATCH_PERIOD_S = 0.5        # how often the node processes' /proc state is looked at

# launch argument -> (default, description); the defaults are `mantis bringup`'s
ARGUMENTS = {
    'backend': ('sim', 'device backends: sim or hardware'),
    'scene': (DEFAULT_SCENE, 'simulated scene (sim backend; see `mantis scenes`)'),
    'seed': ('0', 'sensor noise seed (sim backend)'),
    'real_time_factor': ('1.0', 'simulated seconds per wall second (sim backend; 0: as fast '
                                'as the stack keeps up)'),
    'out': ('trials', 'directory under which each trial gets its bag directory'),
}


def processes(backend):
    """The executables, in start order: the rig's, then the supervisor's."""
    rig = [SIM_RIG_PROCESS] if backend == 'sim' else list(DEVICE_NODES)
    return rig + [SUPERVISOR_NODE]


def scene_conditions(scene):
    """The trial conditions a simulated scene states, as `mantis bringup` takes them (the
    contact angle as recorded; the world adds the latch offset to seat the arm)."""
    from mantis_sim.scene import load_scene
    from mantis_sim.trial_conditions import conditions_of_scene

    return conditions_of_scene(load_scene(scene))


def node_parameters(backend, scene, seed, real_time_factor, out):
    """node name -> its parameters (the params file's sections)."""
    overrides = ['']          # `set`: no scene override (an empty list would have no type)
    params = {}
    if backend == 'sim':
        params[SIM_WORLD_NODE] = {'scene': scene, 'seed': seed, 'set': list(overrides),
                                    'real_time_factor': real_time_factor}
    for name in DEVICE_NODES:
        params[name] = {'backend': backend, 'scene': scene, 'seed': seed,
                        'set': list(overrides)}
    supervisor = {'backend': backend, 'scene': scene, 'out': out}
    if backend == 'sim':
        supervisor.update(scene_conditions(scene))
        supervisor['use_sim_time'] = True
    params[SUPERVISOR_NODE] = supervisor
    return params


def _stack(context):
    value = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    backend = value['backend']
    if backend not in ('sim', 'hardware'):
        raise ValueError(f'backend:={backend}: sim or hardware')
    params = node_parameters(backend, value['scene'], int(value['seed']),
                             float(value['real_time_factor']), value['out'])
    handle, path = tempfile.mkstemp(prefix='mantis_stack_', suffix='.yaml')
    with os.fdopen(handle, 'w') as f:
        yaml.safe_dump({name: {'ros__parameters': values} for name, values in params.items()},
                       f)
    names = processes(backend)
    watch = LaunchWatch(backend, params.get(STAGE_NODE, {}), path + '.reason')
    nodes = [Node(package='mantis_rig', executable=name, output='screen', parameters=[path],
                  additional_env={STOP_REASON_ENV: path + '.reason'})
             for name in processes(backend)]
    handlers = [RegisterEventHandler(OnProcessExit(
        target_action=node, on_exit=lambda event, context, name=name: _ended(
            watch, name, event, context))) for name, node in zip(names, nodes)]
    handlers.append(RegisterEventHandler(OnShutdown(
        on_shutdown=lambda event, context: watch.shutting_down())))
    return nodes + handlers + [_look_for_frozen(watch, dict(zip(names, nodes)))]


def _ended(watch, name, event, context):
    """A node process ended: the first one's line, logged, and the launch shut down."""
    if getattr(context, 'is_shutdown', False):
        watch.shutting_down()
    line = watch.on_exit(name, event.returncode)
    if line is None:
        return None
    return [LogInfo(msg=f'mantis launch: {line}'), EmitEvent(event=Shutdown(reason=line))]


def _look_for_frozen(watch, nodes):
    """Every WATCH_PERIOD_S: a node process frozen (stopped) is killed; its exit handler then
    reports it as frozen and ends the stack."""
    def look(context):
        pids = {name: (node.process_details or {}).get('pid') for name, node in nodes.items()}
        name = watch.frozen(pids)
        if name is not None:
            os.kill(pids[name], signal.SIGKILL)
        return [_look_for_frozen(watch, nodes)] if watch.fault is None else None
    return TimerAction(period=WATCH_PERIOD_S, actions=[OpaqueFunction(function=look)])


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in ARGUMENTS.items()]
        + [OpaqueFunction(function=_stack)])
