"""`mantis sweep --accuracy REL`: the loosest tolerance of the fast path that reaches REL on the
sweep's own designs.

A sample of the designs (SAMPLE, spread over the list; the base scene if there are none) is
solved by the fast path at REFERENCE_RTOL, then at each tolerance of the ladder from the
loosest; the first whose worst relative error over the sample, in peak tip speed and in spring
energy alike, is MARGIN times inside REL is taken. Judged on the designs, not the base scene:
at rtol 1e-3 the base air_23mm is within 2e-5 of converged while designs across its ranges
were seen 2e-3 off in spring energy (docs/sweep_benchmark.md). The fast path is the cheapest
row of every work-precision table (`mantis bench accuracy`) by a factor of 20 or more, so no
scipy solver is tried; its agreement with the judge (scipy's Radau at rtol 1e-10) is measured
by bench/bench_sweep.py.
"""
from __future__ import annotations

from dataclasses import dataclass
import statistics
import time

from mantis_sim.model import SimulationError
from mantis_sim.results import simulate
from mantis_sim.scene import load_scene

from .sweep import SweepError

SAMPLE = 8
REFERENCE_RTOL = 1e-11
LADDER = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9)
MARGIN = 3.0
COMPARED = ('peak_tip_speed_mps', 'max_spring_energy_mJ')


@dataclass
class Setting:
    solver: str
    rtol: float
    wall_ms: float              # median over the sample, the simulation itself
    worst_error: float          # relative, the worst of COMPARED over the sample
    sampled: int
    measured_s: float

    def overrides(self) -> list:
        return [f'integration.solver={self.solver}', f'integration.rtol={self.rtol!r}']

    def __str__(self) -> str:
        return (f'{self.solver} at rtol {self.rtol:g}, within {self.worst_error:.1e} of the '
                f'converged peak tip speed and spring energy on the worst of {self.sampled} '
                f'sampled designs, {self.wall_ms:.1f} ms a strike (chosen in '
                f'{self.measured_s:.1f} s)')


def sample(designs: list[dict], count: int = SAMPLE) -> list[dict]:
    """Up to ``count`` designs spread evenly over the list (the base scene if it is empty)."""
    if not designs:
        return [{}]
    step = max(1, len(designs) // count)
    return designs[::step][:count]


def choose_setting(scene_name: str, overrides: list, rel_error: float,
                   designs: list[dict] | None = None) -> Setting:
    if not 0.0 < rel_error < 1.0:
        raise SweepError(f'--accuracy {rel_error:g}: a relative error between 0 and 1, e.g. '
                         f'1e-3')
    started = time.monotonic()
    base = load_scene(scene_name, [*overrides, 'integration.solver=fast'])
    chosen = sample(designs or [])

    def run(values: dict, rtol: float):
        try:
            return simulate(base.with_values({**values, 'integration.rtol': rtol})).metrics
        except SimulationError:
            return None

    reference = [run(values, REFERENCE_RTOL) for values in chosen]
    best = float('inf')
    for rtol in LADDER:
        runs = [run(values, rtol) for values in chosen]
        errors = [abs(m[key] / ref[key] - 1.0) for m, ref in zip(runs, reference)
                  if m is not None and ref is not None and m['strike_reached']
                  and ref['strike_reached'] for key in COMPARED]
        if not errors:
            raise SweepError(f'--accuracy {rel_error:g}: none of the {len(chosen)} sampled '
                             f'designs of {scene_name} strikes, so none can be judged')
        worst = max(errors)
        best = min(best, worst)
        if worst * MARGIN <= rel_error:
            wall_ms = statistics.median(m['wall_time_s'] for m in runs if m is not None) * 1e3
            return Setting('fast', rtol, wall_ms, worst, len(chosen),
                           time.monotonic() - started)
    raise SweepError(f'--accuracy {rel_error:g}: no tolerance of the fast path reaches it on '
                     f'{scene_name} with a margin of {MARGIN:g} (best: {best:.1e} at rtol '
                     f'{LADDER[-1]:g})')
