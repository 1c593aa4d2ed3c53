"""Issue 30, part 5: scenes that ran for minutes with no word, and designs that ask more of the
rig than it can give.

- An explicit solver on a stiff compliant tendon is refused before it starts (bad input, exit
  2) with the stiffness, the steps it needs at least and the solver to use; the scenes that run
  today are not refused. Any run stops at a budget of right-hand sides (the backstop), naming
  it and what to do.
- A peak tendon force beyond the load cell's range (the scene's loadcell.capacity_N) or above
  the rig's force ceiling (mantis_rig.contract.FORCE_CEILING) is a warning of the result: in
  the metrics, `mantis sim`'s text and --json, and a sweep's table.
No assertion on time: the refusal is checked by its message, the backstop with a small budget.
"""
import json

import pytest

from mantis_rig.cli import main as mantis
from mantis_rig.cli.sim import ceiling_warning
from mantis_rig.contract import FORCE_CEILING
from mantis_sim import hybrid
from mantis_sim.errors import InputError
from mantis_sim.hybrid import HybridSimulator, StiffSceneError
from mantis_sim.model import SimulationError
from mantis_sim.results import simulate
from mantis_sim.scene import available_scenes, load_scene

COMPLIANT = 'air_23mm_compliant'
STIFF_RK45 = ['tendon.stiffness_N_per_mm=1e7', 'integration.solver=RK45']
# reference_air_23mm's rigid tendon with a spring 12 times stiffer: ~430 N at the peak, in
# ~30 ms of computing; the nominal strike peaks at 18.6 N.
OVER_FORCE = ['spring.k_Nmm_per_rad=597']


# --- (a) the stiff tendon on an explicit solver ----------------------------------------------
def test_an_explicit_solver_on_a_stiff_tendon_is_refused_up_front():
    scene = load_scene(COMPLIANT, STIFF_RK45)
    with pytest.raises(StiffSceneError) as info:
        simulate(scene)
    assert isinstance(info.value, InputError)
    text = str(info.value)
    for words in ('tendon.stiffness_N_per_mm = 1e+07', 'RK45', 'steps', 'budget',
                  hybrid.IMPLICIT_ADVICE):
        assert words in text, text


def test_the_stiff_scene_on_the_command_line_is_one_line_and_exit_2(capsys):
    code = mantis(['sim', '--scene', COMPLIANT, '--set', 'tendon.stiffness_N_per_mm=1e7',
                   '--set', 'integration.solver=RK45'])
    captured = capsys.readouterr()
    assert code == 2, captured.err
    assert captured.out == ''
    assert captured.err.count('\n') == 1 and 'Traceback' not in captured.err
    assert captured.err.startswith('mantis sim: integration.solver = RK45')
    assert 'integration.solver=fast' in captured.err


@pytest.mark.parametrize('solver', ['RK23', 'DOP853'])
def test_every_explicit_solver_is_refused_on_the_stiff_tendon(solver):
    with pytest.raises(StiffSceneError, match=f'integration.solver = {solver} '):
        HybridSimulator(load_scene(COMPLIANT, ['tendon.stiffness_N_per_mm=1e7',
                                               f'integration.solver={solver}']))


@pytest.mark.parametrize('name', sorted(available_scenes()))
@pytest.mark.parametrize('solver', [None, 'RK23', 'RK45', 'DOP853', 'Radau', 'LSODA'])
def test_the_shipped_scenes_are_not_refused(name, solver):
    """Each shipped scene with its own solver, or any other: their tendons (rigid, or ~50 N/mm
    compliant) leave an explicit solver a few hundred steps at its stability limit."""
    overrides = [f'integration.solver={solver}'] if solver else []
    HybridSimulator(load_scene(name, overrides))


def test_a_rigid_tendon_is_not_refused_for_its_unused_stiffness():
    """air_23mm_rig's tendon is rigid: its stiffness_N_per_mm is not simulated, and RK45 runs
    the scene as fast as at any stiffness (the command of the issue: a strike in ~1 s)."""
    HybridSimulator(load_scene('air_23mm_rig', STIFF_RK45))


@pytest.mark.parametrize('solver', ['fast', 'Radau'])
def test_a_very_stiff_tendon_on_radau_runs_well_within_the_budget(solver):
    """air_23mm_compliant at 1e6 N/mm on an implicit Radau (the compiled one of its scene, and
    scipy's): not refused, it strikes, and its cost stays far below the backstop."""
    m = simulate(load_scene(COMPLIANT, ['tendon.stiffness_N_per_mm=1e6',
                                        f'integration.solver={solver}'])).metrics
    assert m['solver'] == solver and m['status'] == 'strike'
    assert m['rhs_evals'] < hybrid.MAX_RHS_EVALS / 50


@pytest.mark.parametrize('solver, advice', [
    ('RK45', "use an implicit solver: integration.solver=fast, or scipy's Radau"),
    ('Radau', 'loosen integration.rtol'),
    ('fast', 'loosen integration.rtol'),
])
def test_a_run_stops_at_its_budget_of_right_hand_sides(monkeypatch, solver, advice):
    """The backstop: a run not refused up front but too costly stops at MAX_RHS_EVALS, with
    the budget, the solver and what to do (here a budget of 500 stops the 50 N/mm tendon
    during its loading)."""
    monkeypatch.setattr(hybrid, 'MAX_RHS_EVALS', 500)
    with pytest.raises(SimulationError) as info:
        simulate(load_scene(COMPLIANT, [f'integration.solver={solver}']))
    text = str(info.value)
    for words in ('budget of 500 right-hand sides', 'MAX_RHS_EVALS', f'solver {solver} ',
                  'phase I', advice):
        assert words in text, text


def test_the_budget_stops_the_command_line_with_exit_1(monkeypatch, capsys):
    monkeypatch.setattr(hybrid, 'MAX_RHS_EVALS', 500)
    assert mantis(['sim', '--scene', COMPLIANT, '--solver', 'RK45']) == 1
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('mantis sim: simulation failed: stopped')
    assert 'integration.solver=fast' in err


# --- (b) more force than the rig can apply ----------------------------------------------------
@pytest.fixture(scope='module')
def over_force():
    return simulate(load_scene('reference_air_23mm', OVER_FORCE))


def test_a_load_beyond_the_load_cell_is_a_warning_of_the_result(over_force):
    m = over_force.metrics
    assert m['peak_tendon_force_N'] > 111.0
    (line,) = m['warnings']
    assert f'peak tendon force {m["peak_tendon_force_N"]:.1f} N' in line
    assert "load cell's range of 111 N (loadcell.capacity_N)" in line
    assert over_force.to_json_dict()['warnings'] == m['warnings']


def test_a_nominal_strike_has_no_warning(capsys):
    assert simulate(load_scene('reference_air_23mm')).metrics['warnings'] == []
    assert mantis(['sim', '--scene', 'reference_air_23mm', '--json']) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)['warnings'] == [] and 'warning' not in captured.err


def test_the_command_line_names_the_load_cell_and_the_force_ceiling(capsys):
    assert mantis(['sim', '--scene', 'reference_air_23mm', '--json',
                   *[a for o in OVER_FORCE for a in ('--set', o)]]) == 0
    captured = capsys.readouterr()
    warnings = json.loads(captured.out)['warnings']
    assert len(warnings) == 2
    assert '111 N (loadcell.capacity_N)' in warnings[0]
    assert 'force_ceiling_n = 30 N by default, at most 100 N' in warnings[1]
    assert 'stops the stage' in warnings[1]
    assert captured.err.splitlines() == [f'warning: {w}' for w in warnings]
    assert mantis(['sim', '--scene', 'reference_air_23mm',
                   *[a for o in OVER_FORCE for a in ('--set', o)]]) == 0
    text = capsys.readouterr().out
    assert [line for line in text.splitlines() if line.startswith('warning: ')] == [
        f'warning: {w}' for w in warnings]


def test_the_force_ceiling_comes_from_the_rig_contract():
    default, top = FORCE_CEILING.default, FORCE_CEILING.range[1]
    assert ceiling_warning(default) == []
    (raise_it,) = ceiling_warning((default + top) / 2)
    assert f'unless {FORCE_CEILING.name} is raised' in raise_it
    (beyond,) = ceiling_warning(top + 1.0)
    assert f'at most {top:g} N' in beyond and 'before this load' in beyond


def test_a_sweep_table_carries_the_warning(tmp_path):
    from mantis_sim.studies.design.sweep import WARNING_COLUMN, read_table, run_sweep
    out = tmp_path / 'sweep.parquet'
    run_sweep('reference_air_23mm', ['integration.solver=LSODA', 'integration.rtol=0.001'],
              [{'spring.k_Nmm_per_rad': 47.7}, {'spring.k_Nmm_per_rad': 597.0}], out,
              workers=0, progress=False)
    nominal, strong = read_table(out)
    assert nominal[WARNING_COLUMN] == ''
    assert '111 N (loadcell.capacity_N)' in strong[WARNING_COLUMN]
