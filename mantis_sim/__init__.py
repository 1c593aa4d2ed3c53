"""mantis_sim: the simulator of one design of the mantis-shrimp four-bar (no ROS imports).

The top level is the physics of one strike: the parameters and scenes (`parameters`, `scene`,
`scenes/*.yaml`), the mechanism, forces, drive and model (`mechanism`, `forces`, `drive`,
`model`), the hybrid integration (`hybrid`, the compiled engine `fast/`, `stiff_tendon`), its
result (`results`), the rig's twin in simulated time (`world`, `sensors`, `conditions`), and the
spread of one design with its robots drawn from it (`spread`, `robots`). Studies of many
strikes are in `studies/`, which the top level never imports.

What users need, from here::

    from mantis_sim import load_scene, simulate
    result = simulate(load_scene('air_23mm'))          # a SimulationResult

The names below are loaded when first used (PEP 562), so that a process importing only
`mantis_sim.errors` (every `mantis` command) does not pay for numpy and the model.
"""
from __future__ import annotations

import importlib

#: name -> the module that defines it (the one place each is defined)
_PUBLIC = {
    'simulate': 'results',
    'SimulationResult': 'results',
    'load_scene': 'scene',
    'Scene': 'scene',
    'World': 'world',
    'Spread': 'spread',              # a design's spread: Spread.draw draws its robots' values
    'design_spread': 'robots',       # N robots of one design drawn from it and simulated
    'DesignSpread': 'robots',
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted({*globals(), *__all__})
