"""Bring the rig's node stack up: in one process, or one process per node.

``Stack(StackConfig(...)).start()``:

* ``processes='single'``: the rig (the simulated rig, mantis_rig.simulated.sim_rig, or the three
  device nodes on their hardware backends) and supervisor_node constructed here, on the
  world's clock in sim mode. Two executors spin in background threads: a
  MultiThreadedExecutor for the device nodes (their services block) and a
  SingleThreadedExecutor for the world, the supervisor and any node added with add_node() (a
  client), whose callbacks never block (mantis_rig.runtime.executors).
* ``processes='multi'``: the supervisor in one process and the rig in others (sim: one
  ``sim_rig`` process; hardware: one per device node), each ``python -m <its module>
  --ros-args --params-file <stack.yaml>``: they talk over exactly the topics and services of
  the real rig, the supervisor on ``use_sim_time`` in sim mode. They inherit this process's
  environment, hence its ROS domain, each in a process group of its own. stop() signals them
  (the supervisor first, so that it aborts a trial and closes its log; SIGKILL for any still
  running after 2.5 s, the supervisor after SUPERVISOR_GRACE_S). The reason given to stop()
  reaches the node processes (a file named in STOP_REASON_ENV), so that the supervisor aborts
  its trial with it rather than with the signal's name.

A node process that ends, freezes or hangs is found by ``check_processes()`` (a
mantis_rig.stack.watchdog.ProcessWatch: the process's exit, its /proc state, its nodes'
/diagnostics) and ``fail_safe()`` stops the stage, kills a frozen process and ends the stack.

The device nodes come up unconfigured; the supervisor configures and activates them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

from rclpy.parameter import Parameter
import yaml

from mantis_rig.contract import CLOCK, FORCE_CEILING_NAME, FORCE_GUARD_NODES, resolve
from mantis_rig.runtime.executors import (
    STACK_PARENT_ENV,
    Spinner,
    light_executor,
    threaded_executor,
)
from mantis_rig.runtime.memory import limit_malloc_arenas
from mantis_rig.runtime.stopping import STOP_REASON_ENV
from mantis_rig.simulated.sim_rig import DEVICE_THREADS, SimRig, release
from mantis_rig.stack.node_table import (
    DEVICES,
    PROCESS_MODULES,
    SIM_RIG_PROCESS,
    STAGE_NODE,
    SUPERVISOR,
    WORLD,
)
from mantis_rig.stack.watchdog import ProcessFault, ProcessWatch, stage_port, stop_stage_at_port

SUPERVISOR_GRACE_S = 8.0    # its trial's abort: the stage's stop confirmed (2 s), the log closed


@dataclass
class StackConfig:
    backend: str = 'sim'
    scene: str = 'air_23mm_rig'
    scene_overrides: list = field(default_factory=list)     # key=value, as `mantis sim --set`
    seed: int = 0
    real_time_factor: float = 1.0
    processes: str = 'single'
    supervisor: dict = field(default_factory=dict)          # supervisor parameter overrides
    devices: dict = field(default_factory=dict)             # node name -> parameter overrides
    world: dict = field(default_factory=dict)               # sim_world_node parameter overrides
    namespace: str = ''     # the rig's ROS namespace ('': none, i.e. '/'); e.g. '/rig2'

    @property
    def sim(self) -> bool:
        return self.backend == 'sim'

    def node_parameters(self) -> dict:
        """node name -> its parameters, as the params file holds them."""
        params = {}
        # `set` is a string array; an empty list has no type (in a params file, or for a node
        # that reads the parameter unset): [''] means no override to the nodes.
        overrides = list(self.scene_overrides) or ['']
        if self.sim:
            params[WORLD.name] = {'scene': self.scene, 'seed': self.seed,
                                  'set': list(overrides),
                                  'real_time_factor': float(self.real_time_factor),
                                  **self.world}
        # one force ceiling for every guard (mantis_rig.trial.safety_limits)
        ceiling = {FORCE_CEILING_NAME: float(self.supervisor[FORCE_CEILING_NAME])} \
            if FORCE_CEILING_NAME in self.supervisor else {}
        for name in (entry.name for entry in DEVICES):
            params[name] = {'backend': self.backend, 'scene': self.scene, 'seed': self.seed,
                            'set': list(overrides), **self.devices.get(name, {})}
            if name in FORCE_GUARD_NODES:
                params[name].update(ceiling)
        params[SUPERVISOR.name] = {'backend': self.backend, 'scene': self.scene,
                                      **self.supervisor}
        if self.sim:
            params[SUPERVISOR.name]['use_sim_time'] = True
        return params

    @property
    def node_namespace(self) -> str | None:
        """The namespace the nodes are created in (None: the process's own)."""
        return '/' + self.namespace.strip('/') if self.namespace.strip('/') else None

    def params_file_key(self, name: str) -> str:
        """A node's section in the params file: its fully qualified name in a namespace."""
        return f'{self.node_namespace}/{name}' if self.node_namespace else name

    def ros_arguments(self) -> list:
        """What each node process gets beside its params file: in a namespace, the namespace,
        and rclpy's time source (which subscribes to the absolute /clock) remapped to the
        rig's own clock topic."""
        if self.node_namespace is None:
            return []
        return ['-r', f'__ns:={self.node_namespace}',
                '-r', f'{resolve(CLOCK)}:={CLOCK.name}']

    def node_names(self) -> list:
        return list(self.node_parameters())

    def process_names(self) -> list:
        """The processes of the multi-process layout: the rig's, then the supervisor's."""
        rig = [SIM_RIG_PROCESS] if self.sim else [entry.name for entry in DEVICES]
        return rig + [SUPERVISOR.name]

    @property
    def stage_process(self) -> str:
        return SIM_RIG_PROCESS if self.sim else STAGE_NODE

    def nodes_of_processes(self) -> dict:
        """process name -> the names of the nodes it holds (multi-process layout)."""
        if self.sim:
            return {SIM_RIG_PROCESS: [WORLD.name, *(entry.name for entry in DEVICES)],
                    SUPERVISOR.name: [SUPERVISOR.name]}
        return {name: [name] for name in self.process_names()}


def _overrides(values: dict) -> list:
    return [Parameter(k, value=v) for k, v in values.items()]


class Stack:
    def __init__(self, config: StackConfig, log_dir: Path | None = None):
        limit_malloc_arenas()          # before the nodes' threads: a long bring-up stays flat
        self.config = config
        self.log_dir = log_dir
        self.nodes = []                       # the nodes this stack made itself
        self.rig: SimRig | None = None        # the simulated rig's, in one process
        self.processes: dict[str, subprocess.Popen] = {}
        # the supervisor, the world and clients: callbacks that never block
        self.executor = light_executor()
        # the device nodes: blocking services, backends waiting for the world
        self.device_executor = threaded_executor(DEVICE_THREADS)
        self._spinners: list[Spinner] = []
        self._params_file: Path | None = None
        self.watch: ProcessWatch | None = None
        self._watch_node = None
        self.fault: ProcessFault | None = None     # what fail_safe() handled

    # ------------------------------------------------------------------ start
    def start(self) -> Stack:
        if self.config.processes == 'multi':
            self._start_processes()
        else:
            self._start_nodes()
        self._spinners = [Spinner(self.executor, 'stack-executor'),
                          Spinner(self.device_executor, 'stack-devices')]
        return self

    def add_node(self, node) -> None:
        """Add a node whose callbacks never block (a client, a test's probe)."""
        self.executor.add_node(node)

    def _start_nodes(self) -> None:
        params = self.config.node_parameters()
        supervisor_params = params[SUPERVISOR.name]
        try:
            if self.config.sim:
                # the simulated devices read the world directly, and every node's sim time is
                # set by the world, not by /clock subscriptions
                supervisor_params.pop('use_sim_time', None)
                self.rig = SimRig(params, namespace=self.config.node_namespace)
                self.rig.add_to(self.executor, self.device_executor)
            else:
                for entry in DEVICES:
                    self._add(entry.node_class()(
                        node_name=entry.name, namespace=self.config.node_namespace,
                        parameter_overrides=_overrides(params[entry.name])),
                        self.device_executor)
            supervisor = SUPERVISOR.node_class()(
                node_name=SUPERVISOR.name, namespace=self.config.node_namespace,
                parameter_overrides=_overrides(supervisor_params))
            if self.rig is not None:
                self.rig.clock.attach(supervisor)
                # the trial's progress to the world of this process by a call, not /progress
                supervisor.rig.report_progress_to(self.rig.world_node.note_progress)
            self._add(supervisor, self.executor)
        except BaseException:
            self.stop()
            raise

    def _add(self, node, executor) -> None:
        self.nodes.append(node)
        executor.add_node(node)

    def node(self, name: str):
        rig_nodes = self.rig.nodes if self.rig is not None else []
        return next(n for n in (*rig_nodes, *self.nodes) if n.get_name() == name)

    def _start_processes(self) -> None:
        params = {self.config.params_file_key(name): {'ros__parameters': values}
                  for name, values in self.config.node_parameters().items()}
        handle, path = tempfile.mkstemp(prefix='mantis_stack_', suffix='.yaml')
        with os.fdopen(handle, 'w') as f:
            yaml.safe_dump(params, f)
        self._params_file = Path(path)
        self._reason_file.unlink(missing_ok=True)
        env = {**os.environ, STACK_PARENT_ENV: str(os.getpid()),
               STOP_REASON_ENV: str(self._reason_file)}
        for name in self.config.process_names():
            # Each node in a process group of its own: a terminal's Ctrl-C reaches only this
            # process, which stops the nodes in order (stop()); a node whose parent is gone
            # stops itself (executors.run_node).
            self.processes[name] = subprocess.Popen(
                self.command(name), stdout=self._log(name), stderr=subprocess.STDOUT,
                env=env, process_group=0)
        self._start_watch()

    @property
    def _reason_file(self) -> Path:
        return self._params_file.with_suffix('.reason')

    def _start_watch(self) -> None:
        """A ProcessWatch over the node processes, fed by a /diagnostics subscription of a
        node of this process."""
        from diagnostic_msgs.msg import DiagnosticArray

        from mantis_rig.contract import DIAGNOSTICS
        from mantis_rig.runtime.lean_node import LeanNode
        self.watch = ProcessWatch(self.processes, self.config.nodes_of_processes())
        self._watch_node = LeanNode('mantis_stack_watch', namespace=self.config.node_namespace
                                    or '/', start_parameter_services=False)
        self._watch_node.create_subscription(DiagnosticArray, DIAGNOSTICS.name,
                                             self.watch.on_diagnostics,
                                             DIAGNOSTICS.qos.subscriber())
        self.executor.add_node(self._watch_node)

    def command(self, name: str) -> list:
        return [sys.executable, '-m', PROCESS_MODULES[name], '--ros-args',
                '--params-file', str(self._params_file), *self.config.ros_arguments()]

    def _log(self, name: str):
        if self.log_dir is None:
            return subprocess.DEVNULL
        self.log_dir.mkdir(parents=True, exist_ok=True)
        return open(self.log_dir / f'{name}.log', 'wb')

    def check_processes(self) -> None:
        """Raise ProcessFault (a StackError) for a node process that has ended, froze or hung
        (mantis_rig.stack.watchdog), its last output with it; nothing is done about it here
        (fail_safe does that)."""
        if self.watch is None:
            return
        fault = self.watch.check()
        if fault is not None:
            code = self.processes[fault.name].returncode
            if fault.ended and code is not None and 0 <= code <= 128:
                # exited by itself (a crash, bad parameters): its last words say why
                fault.detail = self._log_tail(fault.name).removeprefix(': ')
                fault.args = (fault.line,)
            raise fault

    def fail_safe(self, fault: ProcessFault) -> str:
        """A node process ended, froze or hung: stop the stage first, by the route that is left
        (its node process stops it on the stack's stop signal; a KDC101 whose process is gone
        is stopped at its serial port), kill a frozen or hung process, and note the fault
        (``self.fault``) for stop(), which then ends the stack with the fault's line as the
        trial's abort reason. Returns what was done, in words for the line."""
        self.fault = fault
        process = self.processes.get(fault.name)
        if not fault.ended and process is not None and process.poll() is None:
            process.kill()           # a frozen process takes SIGKILL only
            try:
                process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                pass
        if fault.name == self.config.stage_process and not self.config.sim:
            port = stage_port(self.config.node_parameters()[STAGE_NODE])
            if port is None:
                return 'the stage\'s port could not be found to stop it'
            return stop_stage_at_port(port)
        return ''

    def _log_tail(self, name: str) -> str:
        path = self.log_dir / f'{name}.log' if self.log_dir else None
        if path is None or not path.exists():
            return ''
        lines = path.read_text(errors='replace').strip().splitlines()
        return f': {lines[-1]}' if lines else ''

    def dead_processes(self) -> dict:
        """name -> exit code of every node process that has ended."""
        return {name: p.returncode for name, p in self.processes.items()
                if p.poll() is not None}

    # ------------------------------------------------------------------ stop
    def stop(self, reason: str = 'supervisor shutting down',
             signum: int = signal.SIGINT) -> None:
        """Abort a trial in progress with `reason` (the stage stops, the reason is logged, the
        log closed), then end every node and process. In multi-process mode the supervisor
        process gets `signum` first, then the device processes."""
        for node in self.nodes:
            if node.get_name() == SUPERVISOR.name:
                node.shutdown_trial(reason)
        if self.processes and self._params_file is not None:
            # the reason the node processes stop for (run_node reads it on the signal)
            try:
                self._reason_file.write_text(self.fault.line if self.fault else reason)
            except OSError:
                pass
        supervisor = self.processes.get(SUPERVISOR.name)
        if supervisor is not None:            # first: it aborts a trial and closes its log
            _end_processes([supervisor], signum, SUPERVISOR_GRACE_S)
        _end_processes(self.processes.values(), signum)
        for spinner in self._spinners:
            spinner.stop()
        if self._watch_node is not None:
            self._watch_node.destroy_node()
            self._watch_node = None
        for node in reversed(self.nodes):
            release(node)
            node.destroy_node()
        if self.rig is not None:
            self.rig.destroy_node()
            self.rig = None
        self.nodes = []
        if self._params_file is not None:
            self._params_file.unlink(missing_ok=True)
            self._reason_file.unlink(missing_ok=True)

    def emergency_stop(self) -> None:
        """Stop the stage by the quickest route, from a signal handler: the stage node's
        device in this process, or a SIGTERM to its process (whose handler stops it); every
        other node process gets SIGTERM too and ends by itself."""
        if self.rig is not None:
            self.rig.emergency_stop()
        for node in self.nodes:
            if node.get_name() == STAGE_NODE:
                node.emergency_stop()
        first = self.config.stage_process
        stage = self.processes.get(first)
        ordered = ([stage] if stage is not None else []) + [
            p for name, p in self.processes.items() if name != first]
        for process in ordered:
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


def _end_processes(processes, signum: int, grace_s: float = 2.5) -> None:
    """Send `signum`; a process still running after `grace_s` is killed."""
    processes = list(processes)
    for process in processes:
        if process.poll() is None:
            process.send_signal(signum)
    deadline = time.monotonic() + grace_s
    for process in processes:
        try:
            process.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()

