"""sim_rig: the simulated rig in one process, behind the same device interfaces as the real one.

As ros2_control loads a mock system into its controller manager, a SimRig holds the simulated
world (sim_world_node: its time-stepping and /clock) and the three device nodes with their
simulated backends. The backends reach the world by direct calls (a LocalWorldPort) and every
node's clock is the world's (a SharedSimClock, no /clock subscriptions). Outside the process
the rig is exactly what the real one offers: the device nodes' topics and services.

    ros2 run mantis_rig sim_rig --ros-args -p real_time_factor:=1.0 -p scene:=air_23mm_rig

Parameters go to each node by its name (`stage_node`, `loadcell_node`, `camera_node`,
`sim_world_node`) in a params file (`--params-file`), or to every node that has them with
`-p <name>:=<value>`; the device nodes get `backend` sim. The device nodes come up
unconfigured: the supervisor configures them.
"""
from __future__ import annotations

import sys

from rclpy.parameter import Parameter

from mantis_rig.contract import LOADCELL_NODE
from mantis_rig.runtime.executors import (
    Spinner,
    light_executor,
    run_node,
    spin_in_slices,
    threaded_executor,
)
from mantis_rig.runtime.stopping import PROCESS_STOPPING, StopRequested
from mantis_rig.simulated.local_world import LocalWorldPort
from mantis_rig.simulated.shared_clock import SharedSimClock
from mantis_rig.stack.node_table import DEVICES, STAGE_NODE, WORLD

DEVICE_THREADS = 8       # the device nodes' blocking services and backends waiting for the world


def _overrides(values: dict) -> list:
    return [Parameter(k, value=v) for k, v in values.items()]


class SimRig:
    """The world and the three simulated device nodes.

    `parameters`: node name -> parameter overrides (each device node's `backend` is sim).
    `context`: the rclpy context (default the global one). `namespace`: the rig's (default:
    the process's, '/' unless remapped with `-r __ns:=...`)."""

    def __init__(self, parameters: dict | None = None, context=None,
                 namespace: str | None = None):
        parameters = parameters or {}
        self.clock = SharedSimClock()
        self.nodes = []
        try:
            self.world_node = self._add(WORLD.node_class()(
                node_name=WORLD.name, context=context, namespace=namespace,
                parameter_overrides=_overrides(parameters.get(WORLD.name, {}))))
            self.world_node.clock_listeners.append(self.clock.on_clock)
            port = LocalWorldPort(self.world_node.runner)
            for entry in DEVICES:
                values = {**parameters.get(entry.name, {}), 'backend': 'sim'}
                values.pop('use_sim_time', None)       # the shared clock is the world's
                self._add(entry.node_class()(
                    node_name=entry.name, context=context, namespace=namespace,
                    parameter_overrides=_overrides(values),
                    world_port=port, sim_clock=self.clock))
            # the world paces itself by the load cell's stream and the force guard's progress:
            # both in this process, told by direct calls, not through the pacing node
            self.node(LOADCELL_NODE).on_block_published = \
                self.world_node.take_force_stream_directly()
            self.node(STAGE_NODE).report_progress_to(self.world_node.note_progress)
        except BaseException:
            self.destroy_node()
            raise

    def _add(self, node):
        self.nodes.append(node)
        return node

    @property
    def world(self):
        return self.world_node.world

    def node(self, name: str):
        return next(n for n in self.nodes if n.get_name() == name)

    def add_to(self, light, devices) -> None:
        """The world on an executor whose callbacks never block (`light`), the device nodes on
        one with threads (`devices`)."""
        light.add_node(self.world_node)
        for node in self.nodes[1:]:
            devices.add_node(node)

    def emergency_stop(self, cause: str = '') -> None:
        """Stop the simulated stage now, from any thread (a signal handler)."""
        for node in self.nodes:
            if node.get_name() == STAGE_NODE:
                node.emergency_stop(cause)

    def spin(self, check_stop=lambda: None) -> None:
        """Spin until the context shuts down (a process of its own): the device nodes in a
        thread, the world here, where ``check_stop()`` raises the stop a signal asked for."""
        light = light_executor(self.world_node.context)
        devices = threaded_executor(DEVICE_THREADS, self.world_node.context)
        self.add_to(light, devices)
        spinner = Spinner(devices, 'sim-rig-devices')
        try:
            spin_in_slices(light, check_stop)
        except StopRequested as stop:
            # first: stopping the threads below may take seconds
            self.emergency_stop(f'{PROCESS_STOPPING}: {stop.reason}')
            raise
        finally:
            spinner.stop()
            light.shutdown(timeout_sec=0)

    def destroy_node(self) -> None:
        """Stop the stage, take the device nodes down (releasing their devices), then the
        world."""
        self.emergency_stop()
        for node in reversed(self.nodes):
            release(node)
            node.destroy_node()
        self.nodes = []


def release(node) -> None:
    """Take a lifecycle node to finalized so that it releases its device (nothing for another
    node)."""
    shutdown = getattr(node, 'trigger_shutdown', None)
    if shutdown is None:
        return
    try:
        shutdown()
    except Exception:           # noqa: BLE001 - already finalized, or no shutdown from here
        pass


def main(args=None) -> int:
    return run_node(SimRig, args)


if __name__ == '__main__':
    sys.exit(main())


__all__ = ['SimRig']
