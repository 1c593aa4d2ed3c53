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

FORCE_CEILING_NAME = 'force_ceiling_n'
FORCE_CEILING_DEFAULT_N = 30.0
FORCE_CEILING_RANGE_N = (0.5, 100.0)          # under the load cell's 111 N capacity
FORCE_CEILING_DESCRIPTION = ('tendon force above which the stage is stopped, N; one value for '
                             'every guard: supervisor, stage driver and load-cell monitor')
FORCE_GUARD_NODES = ('stage_node', 'loadcell_node')   # the guards beside the supervisor's own

__all__ = ['FORCE_CEILING_DEFAULT_N', 'FORCE_CEILING_DESCRIPTION', 'FORCE_CEILING_NAME',
           'FORCE_CEILING_RANGE_N', 'FORCE_GUARD_NODES']
