"""The rig's node table: every node of the stack, its module and class, and what it is. Both
the simulated rig in one process (sim_rig) and the stack's bring-up (bringup: one process, or
one per node) build from this one table, and the launch file is checked against it. The names
are the contract's (mantis_rig.contract).

Each node's module (``mantis_rig.nodes.<name>``; the world's in the simulated rig's wing) and
the simulated rig's process are run as ``python -m`` or as the console script of the same name
(setup.py's NODES, checked against ``PROCESS_MODULES`` by a test)."""
from __future__ import annotations

from dataclasses import dataclass
import importlib

from mantis_rig import contract


@dataclass(frozen=True)
class NodeEntry:
    name: str          # node name, and the name of its module and console script
    class_name: str
    role: str          # 'world' (sim only), 'device' (on a backend) or 'supervisor'

    @property
    def module(self) -> str:
        wing = 'simulated' if self.role == 'world' else 'nodes'
        return f'mantis_rig.{wing}.{self.name}'

    def node_class(self):
        return getattr(importlib.import_module(self.module), self.class_name)


NODES = (
    NodeEntry(contract.SIM_WORLD_NODE, 'SimWorldNode', 'world'),
    NodeEntry(contract.STAGE_NODE, 'StageNode', 'device'),
    NodeEntry(contract.LOADCELL_NODE, 'LoadcellNode', 'device'),
    NodeEntry(contract.CAMERA_NODE, 'CameraNode', 'device'),
    NodeEntry(contract.SUPERVISOR_NODE, 'SupervisorNode', 'supervisor'),
)
BY_NAME = {entry.name: entry for entry in NODES}
WORLD = next(entry for entry in NODES if entry.role == 'world')
DEVICES = tuple(entry for entry in NODES if entry.role == 'device')
SUPERVISOR = next(entry for entry in NODES if entry.role == 'supervisor')
#: the process that holds the world and the device nodes in sim mode (simulated.sim_rig)
SIM_RIG_PROCESS = contract.SIM_RIG_PROCESS
#: process name -> the module it runs (``python -m``; setup.py's console scripts)
PROCESS_MODULES = {SIM_RIG_PROCESS: f'mantis_rig.simulated.{SIM_RIG_PROCESS}',
                   **{entry.name: entry.module for entry in NODES if entry.role != 'world'}}
#: the device node that drives the stage (stopped first in an emergency)
STAGE_NODE = contract.STAGE_NODE
assert tuple(entry.name for entry in DEVICES) == contract.DEVICE_NODES
