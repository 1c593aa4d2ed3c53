"""`mantis sweep --accuracy REL`: the cheapest solver and tolerance that reach REL on the scene.

The scene (with its --set values) is measured as the accuracy benchmark measures it
(mantis_sim.benchmark.accuracy_table: every solver over a ladder of tolerances, errors against
a converged reference), each solver from its loosest tolerance up to the first that reaches REL
(a tighter one of the same solver only costs more), and the fastest row whose peak tip speed is
within REL of the reference is taken. The designs of a sweep vary the scene, so
their errors differ a little from the base scene's; the choice is the base scene's.
"""
from __future__ import annotations

from dataclasses import dataclass
import time

from mantis_sim.benchmark import accuracy_table, cheapest_row

from .sweep import SweepError

REPEATS = 3          # runs per (solver, tolerance): the median wall time decides


@dataclass
class Setting:
    solver: str
    rtol: float
    wall_ms: float
    tip_speed_error: float
    measured_s: float

    def overrides(self) -> list:
        return [f'integration.solver={self.solver}', f'integration.rtol={self.rtol!r}']

    def __str__(self) -> str:
        return (f'{self.solver} at rtol {self.rtol:g}, peak tip speed within '
                f'{self.tip_speed_error:.1e} of the converged value, {self.wall_ms:.1f} ms a '
                f'strike (the cheapest of the work-precision table, measured in '
                f'{self.measured_s:.1f} s)')


def choose_setting(scene_name: str, overrides: list, rel_error: float) -> Setting:
    if not 0.0 < rel_error < 1.0:
        raise SweepError(f'--accuracy {rel_error:g}: a relative error between 0 and 1, e.g. '
                         f'1e-3')
    started = time.monotonic()
    table = accuracy_table(scene_name, repeats=REPEATS, overrides=overrides,
                           enough_error=rel_error)
    row = cheapest_row(table, rel_error)
    if row is None:
        best = min(r.tip_speed_error for r in table.rows)
        raise SweepError(f'--accuracy {rel_error:g}: no solver and tolerance reaches it on '
                         f'{scene_name} (best: {best:.1e}; the reference itself agrees to '
                         f'{table.reference_disagreement:.1e})')
    return Setting(row.solver, row.rtol, row.wall_ms, row.tip_speed_error,
                   time.monotonic() - started)
