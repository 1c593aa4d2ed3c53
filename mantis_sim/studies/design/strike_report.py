"""Human-readable output of a simulated trial: summary text, CSV trajectory, plot."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from mantis_sim.hybrid import PHASES
from mantis_sim.results import SimulationResult

PHASE_COLOURS = {'I': '#4c72b0', 'II': '#dd8452', 'III': '#55a868', 'IV': '#c44e52'}


def _fmt(value, spec: str, unit: str = '') -> str:
    return 'not reached' if value is None else f'{value:{spec}}{unit}'


def summary_text(result: SimulationResult) -> str:
    m = result.metrics
    lines = [f'scene {m["scene"]}: effects {", ".join(m["effects"]) or "none"}',
             f'solver {m["solver"]} rtol {m["rtol"]:g}: {m["wall_time_s"] * 1e3:.1f} ms wall, '
             f'{m["rhs_evals"]} right-hand-side evaluations',
             'phase  start (s)      duration']
    if m.get('rigid_tendon_limit'):
        lines.insert(2, m['rigid_tendon_limit'])
    for p in PHASES:
        duration = m['phase_duration_s'][p]
        text = 'not reached' if duration is None else (
            f'{duration * 1e3:.3f} ms' if duration < 0.1 else f'{duration:.4f} s')
        lines.append(f'{p:5s}  {_fmt(m["phase_start_s"][p], ".6f"):12s}   {text}')
    share = m['arm_kinetic_energy_share_at_peak']
    lines += [
        f'peak tip speed        {m["peak_tip_speed_mps"]:.3f} m/s'
        + ('' if m['strike_reached'] else f'  (no strike: {m["reason"]})'),
        f'peak angular speeds   body {m["peak_body_speed_radps"]:.1f} rad/s, '
        f'arm {m["peak_arm_speed_radps"]:.1f} rad/s (relative to the body)',
        f'max spring energy     {m["max_spring_energy_mJ"]:.3f} mJ',
        f'peak tendon force     {m["peak_tendon_force_N"]:.3f} N',
        f'arm share of KE       {_fmt(share * 100 if share is not None else None, ".1f", " %")}',
        f'tendon work in IV     {_fmt(m["tendon_work_phase_IV_mJ"], ".4f", " mJ")}',
        f'energy balance        residual {m["energy_balance_residual_mJ"]:.2e} mJ',
    ]
    return '\n'.join(lines)


TRAJECTORY_COLUMNS = (
    ('time_s', 't_ms', 1e-3), ('theta1_rad', 'theta1', 1.0), ('theta3_rad', 'theta3', 1.0),
    ('omega1_radps', 'omega1', 1e3), ('omega3_radps', 'omega3', 1e3),
    ('tendon_force_N', 'tendon_force_N', 1.0), ('contact_torque_Nm', 'contact_torque_Nmm', 1e-3),
    ('tip_speed_mps', 'tip_speed_mps', 1.0), ('spring_energy_J', 'spring_energy_mJ', 1e-3),
    ('kinetic_energy_J', 'kinetic_energy_mJ', 1e-3), ('drive_work_J', 'drive_work_mJ', 1e-3),
    ('dissipated_J', 'dissipated_mJ', 1e-3),
)


def write_trajectory_csv(result: SimulationResult, path: Path) -> None:
    """One row per integrator step, SI units, with the phase of each sample."""
    tr = result.trajectory
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow([name for name, _, _ in TRAJECTORY_COLUMNS] + ['phase'])
        columns = [getattr(tr, attr) * scale for _, attr, scale in TRAJECTORY_COLUMNS]
        for i in range(len(tr.t_ms)):
            writer.writerow([f'{c[i]:.10g}' for c in columns] + [tr.phase[i]])


def plot_trial(result: SimulationResult, path: Path) -> None:
    """Angular speeds over the whole trial and over the strike, and the energy budget."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    tr, m = result.trajectory, result.metrics
    t_s = tr.t_ms * 1e-3
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    peak = m['peak_time_s']
    window = (t_s > peak - 0.012) & (t_s < peak + 0.002) if peak else np.ones_like(t_s, bool)
    for ax, mask, scale, unit in ((axes[0], np.ones_like(t_s, bool), 1.0, 's'),
                                  (axes[1], window, 1e3, 'ms')):
        for p in PHASES:
            sel = mask & (tr.phase == p)
            if sel.any():
                ax.plot(t_s[sel] * scale, tr.omega1[sel] * 1e3, '-', color=PHASE_COLOURS[p],
                        label=f'phase {p}')
                ax.plot(t_s[sel] * scale, tr.omega3[sel] * 1e3, '--', color=PHASE_COLOURS[p])
        ax.set_xlabel(f'time ({unit})')
        ax.set_ylabel('angular speed (rad/s): body solid, arm dashed')
    axes[0].set_title(f'{m["scene"]}: whole trial')
    axes[1].set_title('strike (phases III-IV)')
    axes[0].legend(loc='upper left')
    ax = axes[2]
    ax.plot(t_s[window] * 1e3, tr.spring_energy_mJ[window], label='spring')
    ax.plot(t_s[window] * 1e3, tr.kinetic_energy_mJ[window], label='kinetic')
    ax.plot(t_s[window] * 1e3, tr.dissipated_mJ[window] - tr.dissipated_mJ[window][0],
            label='dissipated in window')
    ax.set_xlabel('time (ms)')
    ax.set_ylabel('energy (mJ)')
    ax.set_title(f'peak tip speed {m["peak_tip_speed_mps"]:.1f} m/s')
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
