"""The compiled engine (mantis_sim.fast) against the Python model it mirrors.

Term by term: the dynamics of every mode and every event function at random states agree with
the Python model's to rounding, on scenes that between them switch on every effect. Run by run:
the compiled Radau and scipy's integrators converge to the same strike. And where the engine
cannot take a scene, it says so in one line and scipy's Radau runs instead.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from mantis_sim import fast
from mantis_sim.fast import equations as eq
from mantis_sim.fast import layout
from mantis_sim.fast.segment import mode_vector
from mantis_sim.hybrid import HybridSimulator, Mode
from mantis_sim.model import MECHANICAL_EFFECTS
from mantis_sim.results import simulate
from mantis_sim.scene import load_scene

# Between them every mechanical effect, both added-mass forms, both tendons and all drives.
SCENES = {
    'reference_water_23mm': [],                       # added mass, no gravity
    'published_s12': [],                              # the authors' air load and added mass
    'air_23mm': [],                                   # compliant tendon, pivot friction, ramp
    'air_23mm_rig': ['effects=[gravity, joint_damping, hinge_stiffness, fluid_drag, '
                     'tendon_slack, contact_restitution, stage_profile, '
                     'tendon_force_saturation]', 'tendon.saturation_N=40'],
}
MODES = [Mode(True, True), Mode(True, False), Mode(True, True, stuck_at=0.3),
         Mode(False, True), Mode(False, False), Mode(False, True, slip=-1.0),
         Mode(False, True, saturated=True)]


def test_the_vector_names_are_the_kernels_constants():
    for name, index in layout.INDEX.items():
        assert getattr(eq, name) == index, name


def test_the_scenes_here_switch_on_every_mechanical_effect():
    on = set()
    for name, overrides in SCENES.items():
        on |= set(load_scene(name, overrides).effects)
    assert set(MECHANICAL_EFFECTS) <= on


def _started(name, overrides):
    sim = HybridSimulator(load_scene(name, [*overrides, 'integration.solver=DOP853']))
    sim.start()
    fast_segments = fast.segments_for(sim.model)
    return sim, fast_segments


def _random_states(rng, count):
    """(t ms, full state): body and arm angles about the strike's, rates up to a strike's."""
    for _ in range(count):
        yield (float(rng.uniform(0.0, 3000.0)),
               (float(rng.uniform(1.4, 2.6)), float(rng.uniform(0.0, 2.8)),
                float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-2.0, 2.0)),
                float(rng.uniform(0.0, 50.0)), float(rng.uniform(0.0, 20.0))))


_EVENTS = ((layout.EV_LATCH_MARGIN, 0.0), (layout.EV_SLIP, 0.0), (layout.EV_RECONTACT, -0.05),
           (layout.EV_ARM_STOPS, 1e-6), (layout.EV_STRETCH, 0.01), (layout.EV_TENSION, -3.0),
           (layout.EV_TAUT_TENSION, 0.0), (layout.EV_OVERCENTER, 0.0),
           (layout.EV_MAX_CONTRACTION, 0.0), (layout.EV_PEAK, 0.0))
# what an arm held on the body looks for (hybrid._event_specs)
_HELD_EVENTS = (layout.EV_LATCH_MARGIN, layout.EV_SLIP, layout.EV_STRETCH, layout.EV_TENSION)


@pytest.mark.parametrize('name', SCENES)
def test_every_mode_and_event_agrees_with_the_python_model(name):
    sim, compiled = _started(name, SCENES[name])
    p, knots = compiled.params()
    rng = np.random.default_rng(7)
    ws = np.zeros(eq.WS_SIZE)
    d = np.empty(eq.DYN_SIZE)
    scratch = np.empty(eq.DYN_SIZE)
    checked = 0
    for mode in MODES:
        if mode.saturated and sim.model.saturation_N is None:
            continue
        if mode.latched and mode.taut and sim.model.rigid and mode.stuck_at is None:
            # a held arm on a taut rigid tendon: theta1 follows the drive (a Newton solve)
            states = [(t, (2.0, *s[1:])) for t, s in _random_states(rng, 40)]
        else:
            states = list(_random_states(rng, 40))
        specs = [(kind, 1, constant) for kind, constant in _EVENTS
                 if not mode.latched or kind in _HELD_EVENTS]
        if sim._constrained(mode):
            specs = [spec for spec in specs if spec[0] != layout.EV_STRETCH]
        python_events = sim._scipy_events(mode, [('e', *spec) for spec in specs])
        vector = mode_vector(mode)
        for t, s in states:
            expected = sim._state_dynamics(mode, t, s)
            if any(not math.isfinite(v) for v in expected):
                continue
            y = np.array(sim._pack(mode, s), dtype=float)
            ws[eq.WS_THETA1_GUESS] = s[0]
            eq.dynamics(t, y, mode.latched, mode.taut, mode.saturated, vector[3], mode.slip, p,
                        knots, ws, d)
            np.testing.assert_allclose(d, np.array(expected), rtol=1e-9, atol=1e-9,
                                       err_msg=f'{name} {mode} t={t} s={s}')
            for (kind, _, constant), python_event in zip(specs, python_events):
                value = eq.event_value(kind, constant, t, y, d, mode.latched, vector[3], p,
                                       knots, scratch)
                assert value == pytest.approx(python_event(t, y), rel=1e-9, abs=1e-9), \
                    (name, mode, kind)
            checked += 1
    assert checked > 150


@pytest.mark.parametrize('name', ['reference_air_23mm', 'published_s12', 'air_23mm_rig'])
def test_the_compiled_radau_converges_to_scipys_strike(name):
    """At tight tolerances the fast path and scipy's DOP853 give one strike: the same events
    to a microsecond, the same peak tip speed and spring energy to 1e-8."""
    runs = [simulate(load_scene(name, [f'integration.solver={solver}', 'integration.rtol=1e-9']))
            for solver in ('fast', 'DOP853')]
    ours, theirs = (r.metrics for r in runs)
    assert ours['solver'] == 'fast' and theirs['solver'] == 'DOP853'
    assert [n for n, _ in ours['events']] == [n for n, _ in theirs['events']]
    for (_, t_ours), (_, t_theirs) in zip(ours['events'], theirs['events']):
        assert t_ours == pytest.approx(t_theirs, abs=1e-9)        # s
    for key in ('peak_tip_speed_mps', 'max_spring_energy_mJ', 'peak_tendon_force_N'):
        assert ours[key] == pytest.approx(theirs[key], rel=1e-8), key


def test_the_dense_output_passes_through_the_steps():
    result = simulate(load_scene('reference_air_23mm'), dense=True)
    for seg in result.raw.segments:
        for t, s in zip(seg.t[1:-1], seg.states[1:-1]):
            assert np.allclose(seg.dense(t), s, rtol=1e-12, atol=1e-12)


def test_a_scene_it_cannot_take_falls_back_with_one_line(monkeypatch, capsys):
    def refuse(model):
        raise TypeError('the compiled engine has no force term Warp')

    monkeypatch.setattr(layout, 'pack', refuse)
    monkeypatch.setattr(fast, '_said', set())
    m = simulate(load_scene('reference_air_23mm')).metrics
    assert m['solver'] == fast.FALLBACK_SOLVER and m['status'] == 'strike'
    simulate(load_scene('reference_air_23mm'))
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err == ("mantis_sim: the fast engine cannot take this scene: the compiled engine has "
                   "no force term Warp; integrating with scipy's Radau instead\n")


@pytest.mark.parametrize('overrides, limit', [
    (['tendon.stiffness_N_per_mm=1e6'], True),
    ([], False),                                             # 50 N/mm: it matters
    (['tendon.stiffness_N_per_mm=1e6', 'integration.rigid_tendon_below=0'], False),
    (['tendon.stiffness_N_per_mm=1e6', 'integration.solver=Radau'], False),
])
def test_a_tendon_too_stiff_to_show_is_solved_in_its_rigid_limit(overrides, limit):
    """mantis_sim.stiff_tendon: on the fast path a 1e6 N/mm tendon is solved as rigid, and the
    metrics say so with the estimated effect, which is below the scene's threshold; 50 N/mm,
    a threshold of 0 or a scipy solver integrate the compliant tendon."""
    result = simulate(load_scene('air_23mm_compliant', overrides))
    note = result.metrics['rigid_tendon_limit']
    assert result.scene.tendon.model == 'compliant'
    assert result.metrics['status'] == 'strike'
    assert (note is not None) == limit
    if limit:
        effect = float(note.rsplit(' ', 1)[1])
        assert effect < result.scene.integration.rigid_tendon_below
        resolved = simulate(load_scene('air_23mm_compliant', [
            *overrides, 'integration.rigid_tendon_below=0'])).metrics
        assert result.metrics['peak_tip_speed_mps'] == pytest.approx(
            resolved['peak_tip_speed_mps'], rel=1e-4)


def test_a_ctrl_c_inside_a_compiled_call_is_the_keyboard_interrupt():
    """numba hands a Ctrl-C back as SystemErrors nested around the KeyboardInterrupt."""
    from mantis_sim.fast.segment import interruptible

    def nested():
        try:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise SystemError('returned a result with an exception set') from exc
        except SystemError as exc:
            raise SystemError('returned a result with an exception set') from exc

    def a_bug():
        raise SystemError('a bug')

    with pytest.raises(KeyboardInterrupt):
        interruptible(nested)()
    with pytest.raises(SystemError, match='a bug'):
        interruptible(a_bug)()


def _kernel_overloads() -> dict:
    from mantis_sim.fast import radau
    return {name: len(kernel.signatures) for name, kernel in (
        ('integrate', radau.integrate), ('full_states', eq.full_states),
        ('state_dynamics', eq.state_dynamics), ('observe_rows', eq.observe_rows))}


@pytest.mark.parametrize('scene', ['air_23mm', 'reference_air_23mm'])     # compliant, rigid
def test_the_engine_loads_every_kernel_a_strike_calls_without_simulating(scene):
    """warm_up (and the first segments_for) loads each kernel with the argument types a strike
    passes: a strike afterwards, rigid or compliant, dense or not, loads none."""
    fast.warm_up()
    loaded = _kernel_overloads()
    assert all(n >= 1 for n in loaded.values()), loaded
    for dense in (True, False):
        result = simulate(load_scene(scene, ['integration.solver=fast']), dense=dense)
        assert result.metrics['solver'] == 'fast' and result.metrics['strike_reached']
    assert _kernel_overloads() == loaded


def test_a_model_is_left_as_it_was_by_loading_the_engine():
    sim = HybridSimulator(load_scene('air_23mm'))
    before = (sim.model.l_free0, sim.model.theta1_guess, sim.model.rhs_evals)
    loaded = fast._loaded
    try:
        fast._loaded = False                # load again, on this model
        fast.load(sim.model)
    finally:
        fast._loaded = loaded or fast._loaded
    after = (sim.model.l_free0, sim.model.theta1_guess, sim.model.rhs_evals)
    assert math.isnan(before[0]) and math.isnan(after[0]) and before[1:] == after[1:]
