"""The `mantis` command line (`mantis_rig.cli:main`), one module per command family: `sim`
(sim, scenes, bench), `replay`, `import_tracking`, `analyze`, `recover`, `trial` (trial,
bringup), `sweep` (sweep, sweep-plot); `options` holds what several of them share."""
from .main import build_parser, main

__all__ = ['build_parser', 'main']
