"""What accuracy costs in time: every solver over a ladder of tolerances, against a reference.

The reference is the scene solved by two different high-order methods (DOP853, explicit order
8, and Radau, implicit order 5) at their tightest tolerances; their disagreement is printed, so
the error floor of the table is known.
"""
from __future__ import annotations

from dataclasses import dataclass
import statistics

from mantis_sim.fast import warm_up
from mantis_sim.results import simulate
from mantis_sim.scene import load_scene

# scipy's solvers, and the fast path (the compiled Radau of mantis_sim.fast)
SOLVERS = ('RK23', 'RK45', 'DOP853', 'LSODA', 'Radau', 'BDF', 'fast')
TOLERANCES = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
# Implicit methods with finite-difference Jacobians get slow at tight tolerances; beyond these
# they add nothing to the front.
TIGHTEST = {'Radau': 1e-9, 'BDF': 1e-9}


@dataclass
class Row:
    solver: str
    rtol: float
    wall_ms: float
    rhs_evals: int
    tip_speed_error: float          # relative
    phase_iv_error_us: float        # |t_IV - t_IV,ref| in microseconds
    energy_residual_mJ: float
    pareto: bool = False


@dataclass
class Table:
    scene: str
    reference_tip_speed_mps: float
    reference_phase_iv_s: float
    reference_disagreement: float   # relative, tip speed, DOP853 vs Radau
    reference_phase_iv_disagreement_us: float
    rows: list


def _run_scene(scene_name: str, solver: str, rtol: float, overrides=()):
    scene = load_scene(scene_name, [*overrides, f'integration.solver={solver}',
                                    f'integration.rtol={rtol!r}'])
    return simulate(scene).metrics


def accuracy_table(scene_name: str, repeats: int = 5, overrides=()) -> Table:
    """``overrides``: scene parameters set first (``key=value``, as `mantis sim --set`)."""
    def run(solver, rtol):
        return _run_scene(scene_name, solver, rtol, overrides)
    warm_up()           # the fast path's first strike in a process loads the engine
    ref_a = run('DOP853', 1e-12)
    ref_b = run('Radau', 1e-11)
    v_ref, t_ref = ref_a['peak_tip_speed_mps'], ref_a['phase_start_s']['IV']
    disagreement = abs(ref_b['peak_tip_speed_mps'] - v_ref) / v_ref
    disagreement_iv_us = abs(ref_b['phase_start_s']['IV'] - t_ref) * 1e6
    rows = []
    for solver in SOLVERS:
        for rtol in TOLERANCES:
            if rtol < TIGHTEST.get(solver, 0.0):
                continue
            runs = [run(solver, rtol) for _ in range(repeats)]
            m = runs[0]
            t_iv = m['phase_start_s']['IV']
            rows.append(Row(solver, rtol, statistics.median(r['wall_time_s'] for r in runs) * 1e3,
                            m['rhs_evals'], abs(m['peak_tip_speed_mps'] - v_ref) / v_ref,
                            abs(t_iv - t_ref) * 1e6 if t_iv is not None else float('inf'),
                            m['energy_balance_residual_mJ']))
    for row in rows:
        row.pareto = not any(o.wall_ms < row.wall_ms and o.tip_speed_error < row.tip_speed_error
                             for o in rows)
    return Table(scene_name, v_ref, t_ref, disagreement, disagreement_iv_us, rows)


def format_table(table: Table, markdown: bool = False) -> str:
    head = (f'{table.scene}: reference peak tip speed {table.reference_tip_speed_mps:.9f} m/s, '
            f'phase IV at {table.reference_phase_iv_s:.9f} s (DOP853 1e-12 vs Radau 1e-11 '
            f'differ by {table.reference_disagreement:.1e} in tip speed, '
            f'{table.reference_phase_iv_disagreement_us:.1e} us in phase IV)')
    cols = ('solver', 'rtol', 'wall ms (median)', 'RHS evals', 'tip speed rel. error',
            'phase IV error (us)', 'energy residual (mJ)', 'Pareto')
    body = [(r.solver, f'{r.rtol:.0e}', f'{r.wall_ms:.1f}', str(r.rhs_evals),
             f'{r.tip_speed_error:.1e}', f'{r.phase_iv_error_us:.2g}',
             f'{r.energy_residual_mJ:.1e}', '*' if r.pareto else '') for r in table.rows]
    if markdown:
        lines = [head, '', '| ' + ' | '.join(cols) + ' |', '|' + '---|' * len(cols)]
        lines += ['| ' + ' | '.join(row) + ' |' for row in body]
        return '\n'.join(lines)
    widths = [max(len(c), *(len(row[i]) for row in body)) for i, c in enumerate(cols)]
    fmt = '  '.join(f'{{:>{w}}}' for w in widths)
    return '\n'.join([head, fmt.format(*cols)] + [fmt.format(*row) for row in body])


def plot_tables(tables: dict, path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(tables), figsize=(6.5 * len(tables), 8.6), squeeze=False)
    for col, (name, table) in enumerate(tables.items()):
        for row, (attr, label, goal) in enumerate((
                ('tip_speed_error', 'relative error in peak tip speed', 1e-3),
                ('phase_iv_error_us', 'error in phase IV start (us)', None))):
            ax = axes[row][col]
            for solver in SOLVERS:
                rows = [r for r in table.rows if r.solver == solver]
                ax.loglog([r.wall_ms for r in rows],
                          [max(getattr(r, attr), 1e-14) for r in rows], 'o-', label=solver)
            if row == 0:
                front = sorted((r for r in table.rows if r.pareto), key=lambda r: r.wall_ms)
                ax.loglog([r.wall_ms for r in front],
                          [max(r.tip_speed_error, 1e-14) for r in front], 'k:', lw=2,
                          label='Pareto front')
                ax.axhline(goal, color='grey', lw=0.8)
                ax.set_title(f'{name}: goal 0.1 % within 50 ms (grey lines)')
            else:
                ax.set_title(f'{name}: phase IV start')
            ax.axvline(50, color='grey', lw=0.8)
            ax.set_xlabel('median wall time per trial (ms)')
            ax.set_ylabel(label)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
