"""The rig's safety limits, each defined once.

The force ceiling is set once (the trial's conditions: the scene's default, `--set
force_ceiling_n=...` or the supervisor's parameter) and every guard that enforces it gets that
value: the supervisor's own monitor, the stage driver's guard (stage_node) and the load cell's
monitor (loadcell_node). The stack starts those nodes with it and the supervisor sets it on
them again before each trial, so a change between trials reaches them all.

The stage's speed ceiling and soft travel limits are the driver's envelope
(`mantis_rig.hardware.interfaces.StageLimits`); the supervisor's pull speed and travel are
checked against that same envelope.
"""
from __future__ import annotations

from mantis_rig.contract import FORCE_CEILING, FORCE_GUARD_NODES

# the parameter is declared in mantis_rig.contract (FORCE_CEILING); these are its parts
FORCE_CEILING_NAME = FORCE_CEILING.name
FORCE_CEILING_DEFAULT_N = FORCE_CEILING.default
FORCE_CEILING_RANGE_N = FORCE_CEILING.range          # under the load cell's 111 N capacity
FORCE_CEILING_DESCRIPTION = FORCE_CEILING.description

__all__ = ['FORCE_CEILING_DEFAULT_N', 'FORCE_CEILING_DESCRIPTION', 'FORCE_CEILING_NAME',
           'FORCE_CEILING_RANGE_N', 'FORCE_GUARD_NODES']
