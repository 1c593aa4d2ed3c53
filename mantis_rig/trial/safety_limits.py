"""The rig's safety limits, each defined once.

The force ceiling is set once (the trial's conditions: the scene's default, `--set
force_ceiling_n=...` or the supervisor's parameter) and every guard that enforces it gets that
value: the supervisor's own monitor, the stage driver's guard (stage_node) and the load cell's
monitor (loadcell_node). The stack starts those nodes with it and the supervisor sets it on
them again before each trial, so a change between trials reaches them all.

The travel limit of a pull (`travel_mm`, the trial's condition) is enforced twice, from one
value: the supervisor aborts a pull that has gone that far, and the stage controller itself
stops there. The supervisor sets the same `travel_mm` on stage_node before each trial (as the
force ceiling), and stage_node executes every pull (a velocity command in the pull direction)
as a move to where the pull starts + travel_mm, which the controller (the KDC101's
MOT_MOVE_ABSOLUTE, the simulated world's move) ends at rest there even when every process of
the stack is dead (PULL_BOUND_NODES).

A pull also needs a live supervisor: stage_node stops a motion the supervisor commanded when
its heartbeat (contract.HEARTBEAT, every HEARTBEAT_PERIOD_S) lapses for
`supervisor_heartbeat_timeout_s` (0.4 s by default, checked every 50 ms: the stop is sent at
most 0.45 s after the last heartbeat).

The stage's speed ceiling and soft travel limits are the driver's envelope
(`mantis_rig.hardware.device_interfaces.StageLimits`); the supervisor's pull speed and travel are
checked against that same envelope.
"""
from __future__ import annotations

from mantis_rig.contract import (
    FORCE_CEILING,
    FORCE_GUARD_NODES,
    HEARTBEAT_PERIOD_S,
    STAGE_NODE,
    TRAVEL,
)

# the parameter is declared in mantis_rig.contract (FORCE_CEILING); these are its parts
FORCE_CEILING_NAME = FORCE_CEILING.name
FORCE_CEILING_DEFAULT_N = FORCE_CEILING.default
FORCE_CEILING_RANGE_N = FORCE_CEILING.range          # under the load cell's 111 N capacity
FORCE_CEILING_DESCRIPTION = FORCE_CEILING.description

# the travel limit (mantis_rig.contract TRAVEL): the supervisor's, and the stage controller's
TRAVEL_NAME = TRAVEL.name
TRAVEL_DEFAULT_MM = TRAVEL.default
#: the nodes the supervisor gives the trial's travel limit before each trial
PULL_BOUND_NODES = (STAGE_NODE,)

__all__ = ['FORCE_CEILING_DEFAULT_N', 'FORCE_CEILING_DESCRIPTION', 'FORCE_CEILING_NAME',
           'FORCE_CEILING_RANGE_N', 'FORCE_GUARD_NODES', 'HEARTBEAT_PERIOD_S',
           'PULL_BOUND_NODES', 'TRAVEL_DEFAULT_MM', 'TRAVEL_NAME']
