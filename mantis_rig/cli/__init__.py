"""The `mantis` command line (`mantis_rig.cli:main`), one module per command family, each only
turning arguments into a call of its layer's functions: `sim` (sim, scenes, bench), `replay`,
`import_tracking`, `track_command`, `analyze`, `recover_command`, `trial_commands` (trial,
bringup), `control` (start, abort, state), `study`, `sweep_commands` (sweep, sweep-plot),
`doctor`, `real_strike_commands` (identify, compare), `day_state_command`; `options` and
`strike_options` hold what several of them share."""
from .main import build_parser, main

__all__ = ['build_parser', 'main']
