"""The robot's spread (mantis_sim.spread): its draws, its scene section and its scores; the
mixed model that fits it (studies/spread_fit) on latents of known spread; the forecasts'
scores on forecasts of known calibration."""
import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
import yaml

from mantis_sim.parameters import ParameterError
from mantis_sim.scene import load_scene, scene_from_dict
from mantis_sim.spread import QUANTILE_LEVELS, Spread, crps, pit, quantiles
from mantis_sim.studies.real_strikes import forecast, spread_fit
from mantis_sim.studies.real_strikes.fidelity import SimulatedStrike
from mantis_sim.studies.real_strikes.identify import IdentificationError
from mantis_sim.studies.real_strikes.strikes import RealStrike

GROUPS = ('air_19mm', 'air_23mm', 'water_23mm')


def section(**changes) -> dict:
    """A valid spread section, with changes at dotted paths ('latent.day_sd': -1)."""
    doc = {'latent': {'key': 'geometry.latch_offset_deg', 'mean': 2.0, 'mean_std_error': 0.5,
                      'day_sd': 3.0, 'strike_sd': 1.0, 'range': [-5.0, 12.0], 'day_dof': 10,
                      'days': {'0801319': {'offset': 5.0, 'sd': 0.5}}},
           'parameters': {'arm.blade_drag_broadside': {'value': 1.2, 'std_error': 0.1,
                                                       'bounds': [0.2, 8.0]},
                          'damping.body_Nmm_ms_per_rad': {'value': 0.0, 'std_error': 2.0,
                                                          'bounds': [0.0, 300.0]}},
           'correlation': {'arm.blade_drag_broadside': {'damping.body_Nmm_ms_per_rad': -0.5},
                           'damping.body_Nmm_ms_per_rad': {'arm.blade_drag_broadside': -0.5}},
           'discrepancy': {'peak_tip_speed_mps': {'bias': 0.01, 'bias_std_error': 0.005,
                                                  'sd': 0.04}},
           'climatology': {'peak_tip_speed_mps': [26.0, 27.0, 24.0]},
           'provenance': {'fitted_by': 'a test'}}
    for path, value in changes.items():
        *parents, last = path.split('.')
        node = doc
        for p in parents:
            node = node[p]
        node[last] = value
    return doc


def test_draws_are_the_seed_s_and_survive_the_scene_file():
    spread = Spread.from_mapping(section(), 'test')
    again = Spread.from_mapping(yaml.safe_load(yaml.safe_dump(spread.to_mapping())), 'test')
    a = spread.draw(50, np.random.default_rng(7), 3.0)
    b = again.draw(50, np.random.default_rng(7), 3.0)
    c = spread.draw(50, np.random.default_rng(8), 3.0)
    assert a.values == b.values and a.values != c.values
    assert np.array_equal(a.factors['peak_tip_speed_mps'], b.factors['peak_tip_speed_mps'])
    assert set(a.values[0]) == {'geometry.latch_offset_deg', 'arm.blade_drag_broadside',
                                'damping.body_Nmm_ms_per_rad'}


def test_the_latent_scatters_by_day_and_strike_and_an_arm_stops_at_the_latch():
    wide = Spread.from_mapping(section(**{'latent.day_dof': None}), 'test')
    offsets = np.array([v['geometry.latch_offset_deg']
                        for v in wide.draw(20000, np.random.default_rng(1), 3.0).values])
    # mean 2 +- 0.5, day 3, strike 1: sd sqrt(9 + 1 + 0.25), cut at the latched arm's 0 degrees
    assert offsets.min() == pytest.approx(-3.0) and offsets.max() <= 12.0
    assert np.mean(offsets == -3.0) == pytest.approx(0.059, abs=0.006)   # P(z < -5 / 3.2)
    assert np.median(offsets) == pytest.approx(2.0, abs=0.1)
    assert np.std(offsets[offsets > -1.0]) < 3.2
    # with a handful of days, a new day's spread has heavier tails than the fitted sd says
    few_days = Spread.from_mapping(section(**{'latent.day_dof': 3}), 'test')
    heavy = np.array([v['geometry.latch_offset_deg']
                      for v in few_days.draw(20000, np.random.default_rng(1), 3.0).values])
    assert np.mean(heavy == 12.0) > 2 * np.mean(offsets == 12.0)


def test_a_strike_of_a_day_seen_sits_about_that_days_level():
    spread = Spread.from_mapping(section(**{'latent.day_dof': None}), 'test')
    def offsets(day, strike_dof=None):
        s = spread if strike_dof is None else Spread.from_mapping(
            section(**{'latent.day_dof': None, 'latent.strike_dof': strike_dof}), 'test')
        return np.array([v['geometry.latch_offset_deg']
                         for v in s.draw(20000, np.random.default_rng(4), 3.0, day).values])
    seen = offsets('0801319')
    # the day's level 2 + 5 within 0.5, a strike's scatter 1 about it
    assert np.mean(seen) == pytest.approx(7.0, abs=0.03)
    assert np.std(seen) == pytest.approx(math.hypot(0.5, 1.0), rel=0.03)
    new_day = offsets('20261127')
    assert np.median(new_day) == pytest.approx(2.0, abs=0.1) and np.std(new_day) > 2.5
    # a within-day scatter fitted on few degrees of freedom has heavier tails
    far = np.mean(np.abs(seen - 7.0) > 3.0)
    assert np.mean(np.abs(offsets('0801319', 3) - 7.0) > 3.0) > 3 * far


def test_parameters_keep_their_correlation_and_their_bounds():
    doc = section()
    doc['parameters']['damping.body_Nmm_ms_per_rad']['value'] = 5.0
    spread = Spread.from_mapping(doc, 'test')
    draws = spread.draw(20000, np.random.default_rng(2), 3.0).values
    drag = np.array([v['arm.blade_drag_broadside'] for v in draws])
    body = np.array([v['damping.body_Nmm_ms_per_rad'] for v in draws])
    assert np.corrcoef(drag, body)[0, 1] == pytest.approx(-0.5, abs=0.03)
    assert np.std(drag) == pytest.approx(0.1, rel=0.05)
    at_zero = Spread.from_mapping(section(), 'test').draw(2000, np.random.default_rng(2), 3.0)
    body = np.array([v['damping.body_Nmm_ms_per_rad'] for v in at_zero.values])
    assert body.min() == 0.0 and 0.4 < np.mean(body == 0.0) < 0.6     # clipped at its bound


def test_the_discrepancy_multiplies_about_its_bias():
    spread = Spread.from_mapping(section(), 'test')
    factors = spread.draw(20000, np.random.default_rng(3), 3.0).factors['peak_tip_speed_mps']
    assert np.mean(factors) == pytest.approx(1.01, abs=0.002)
    assert np.std(factors) == pytest.approx(math.hypot(0.04, 0.005), rel=0.05)


@pytest.mark.parametrize('changes, message', [
    ({'latent.day_sd': -1.0}, 'latent day_sd = -1.0 must be a finite number >= 0'),
    ({'latent.mean': 'two'}, "latent mean = 'two' is not a number"),
    ({'latent.range': [1.0]}, 'is not [low, high]'),
    ({'nonsense': 1}, 'unknown key(s) nonsense'),
    ({'discrepancy.peak_speed': {'sd': 0.1}}, "discrepancy of 'peak_speed'"),
    ({'correlation.arm.blade_drag_broadside': {'damping.body_Nmm_ms_per_rad': 0.3}},
     'must be symmetric'),
    ({'correlation.arm.blade_drag_broadside': {'geometry.L2_mm': 0.3}},
     'both must be distinct parameters'),
    ({'parameters.arm.blade_drag_broadside.std_error': math.nan}, 'must be a finite number'),
    ({'latent.days': {11620: {'offset': 1.0, 'sd': 0.5}}}, 'must be a string (quote it)'),
    ({'latent.days': {'011620': {'offset': 1.0}}}, 'must be a mapping with offset and sd'),
    ({'latent.days': {'011620': {'offset': 1.0, 'sd': -0.5}}}, 'sd = -0.5 must be a finite'),
    ({'latent.strike_dof': 0.5}, 'latent strike_dof = 0.5 must be a finite number >= 1'),
])
def test_a_broken_spread_is_refused_naming_what_is_wrong(changes, message):
    doc = section()
    for path, value in changes.items():
        if path.startswith('correlation.arm.'):
            doc['correlation']['arm.blade_drag_broadside'] = value
        elif path.startswith('parameters.arm.'):
            doc['parameters']['arm.blade_drag_broadside']['std_error'] = value
        else:
            doc = section(**{path: value})
    with pytest.raises(ParameterError, match='mine: spread') as caught:
        Spread.from_mapping(doc, 'mine')
    assert message in str(caught.value)


def test_a_scene_file_carries_its_spread_and_refuses_a_broken_one():
    base = yaml.safe_load(_scene_path('air_23mm').read_text(encoding='utf-8'))
    assert scene_from_dict(base, 'x').spread is not None
    base['spread'] = {'latent': 3}
    with pytest.raises(ParameterError, match='spread: latent must be a mapping'):
        scene_from_dict(base, 'x')


def _scene_path(name):
    from mantis_sim.scene import available_scenes
    return available_scenes()[name]


@pytest.mark.parametrize('group', GROUPS)
def test_the_shipped_group_scenes_carry_the_spread_fitted_to_the_training_strikes(group):
    spread = load_scene(group).spread
    assert spread is not None
    assert spread.provenance['fitted_by'] == 'mantis identify --spread'
    assert spread.provenance['strikes'] == 32 and spread.provenance['recording_days'] == 13
    assert spread.latent.key == 'geometry.latch_offset_deg'
    assert spread.latent.day_sd > spread.latent.strike_sd > 0    # days differ most
    assert {d.metric for d in spread.discrepancy} == {'peak_tip_speed_mps', 'spring_energy_mJ'}
    assert len(spread.climatology['peak_tip_speed_mps']) == {'air_19mm': 8, 'air_23mm': 18,
                                                             'water_23mm': 6}[group]


# --------------------------------------------------------------------------------- scores
def test_crps_of_a_point_is_its_error_and_of_a_normal_its_closed_form():
    assert crps(np.array([3.0]), 5.0) == pytest.approx(2.0)
    rng = np.random.default_rng(4)
    sample = rng.normal(0.0, 2.0, 200_000)
    z = 0.7 / 2.0
    phi = math.exp(-z * z / 2) / math.sqrt(2 * math.pi)
    cdf = 0.5 * (1 + math.erf(z / math.sqrt(2)))
    exact = 2.0 * (z * (2 * cdf - 1) + 2 * phi - 1 / math.sqrt(math.pi))
    assert crps(sample, 0.7) == pytest.approx(exact, rel=0.01)
    assert math.isnan(crps(np.array([np.nan]), 1.0))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=40), st.floats(-1e3, 1e3))
def test_crps_is_never_negative_nor_worse_than_the_mean_error(samples, observed):
    x = np.array(samples)
    score = crps(x, observed)
    assert -1e-9 * (1 + np.abs(x).max()) <= score <= np.mean(np.abs(x - observed)) + 1e-9
    assert 0.0 <= pit(x, observed) <= 1.0


def test_quantiles_are_the_nineteen_levels_in_order():
    q = quantiles(np.arange(101.0))
    assert list(q) == [f'q{5 * k:02d}' for k in range(1, 20)] and len(QUANTILE_LEVELS) == 19
    assert q['q05'] == pytest.approx(5.0) and q['q95'] == pytest.approx(95.0)
    assert all(math.isnan(v) for v in quantiles(np.array([np.nan])).values())


def _strike(i, group='air_23mm', speed=26.0, energy=100.0):
    return RealStrike(f't{i}', group.split('_')[0], 23.0, 3.0, 2.3, f'd{i % 4}', speed, energy)


def test_calibrated_forecasts_cover_as_they_claim_and_beat_a_wide_climatology():
    rng = np.random.default_rng(5)
    forecasts = []
    for i in range(400):
        centre = rng.normal(26.0, 2.0)
        measured = rng.normal(centre, 1.0)
        samples = rng.normal(centre, 1.0, 300)
        forecasts.append(forecast.StrikeForecast(
            _strike(i, speed=measured, energy=100.0),
            {'peak_tip_speed_mps': samples, 'spring_energy_mJ': samples * 4},
            0, {'peak_tip_speed_mps': tuple(rng.normal(26.0, 2.2, 30)),
                'spring_energy_mJ': (100.0,)}))
    scores = forecast.scores(forecasts)['peak_tip_speed_mps']['all']
    assert scores['strikes'] == 400
    assert scores['coverage_50'] == pytest.approx(0.5, abs=0.07)
    assert scores['coverage_80'] == pytest.approx(0.8, abs=0.06)
    assert scores['crps_ratio'] < 0.75
    assert sum(scores['pit_histogram']) == 400 and min(scores['pit_histogram']) > 20


def test_prediction_rows_have_the_columns_a_lab_reads():
    f = forecast.StrikeForecast(_strike(0), {'peak_tip_speed_mps': np.linspace(20, 30, 50),
                                            'spring_energy_mJ': np.full(50, np.nan)}, 50, {})
    row = forecast.prediction_rows([f])[0]
    assert list(row)[:5] == ['trial', 'group', 'day_seen', 'tip_speed_mps_measured',
                             'tip_speed_mps_q05']
    assert [k for k in row if k.startswith('spring_energy_mJ_q')] == [
        f'spring_energy_mJ_q{5 * k:02d}' for k in range(1, 20)]
    assert row['tip_speed_mps_q50'] == pytest.approx(25.0)
    assert math.isnan(row['spring_energy_mJ_q50']) and row['robots_not_struck'] == 50


# ------------------------------------------------------------------------ the mixed model
def _latent(strike, value, speed_error=0.0):
    sim = SimulatedStrike(strike.trial, 'strike', '', strike.peak_tip_speed_mps *
                          (1 + speed_error), strike.spring_energy_mJ)
    return spread_fit.StrikeLatent(strike, value, 0.1, False, sim)


def test_the_mixed_model_recovers_the_spread_between_and_within_days():
    rng = np.random.default_rng(6)
    latents, levels = [], {}
    for day in range(40):
        group = GROUPS[day % 2]
        level = levels[f'day{day}'] = {'air_19mm': -1.0, 'air_23mm': 2.0}[group] + rng.normal(
            0.0, 3.0)
        for k in range(4):
            strike = RealStrike(f'{day}-{k}', group.split('_')[0],
                                19.0 if group == 'air_19mm' else 23.0, 3.0, 2.3, f'day{day}',
                                26.0, 100.0)
            latents.append(_latent(strike, level + rng.normal(0.0, 1.0),
                                   rng.normal(0.0, 0.03)))
    model = spread_fit.latent_model(latents, 'geometry.latch_offset_deg')
    assert model.days == 40 and model.strikes == 160 and model.day_dof == 38
    assert model.day_sd == pytest.approx(3.0, abs=2 * model.day_sd_std_error)
    assert model.strike_sd == pytest.approx(1.0, abs=2 * model.strike_sd_std_error)
    for group, truth in (('air_19mm', -1.0), ('air_23mm', 2.0)):
        mean, se = model.means[group]
        assert abs(mean - truth) < 2.5 * se and 0.5 < se < 1.2
    # each day's level, mean + offset, from its four strikes: within about 1 / sqrt(4) of the
    # strikes' scatter, the mean's error mostly pinned
    z = []
    for group, days in model.day_effects.items():
        for day, (offset, sd) in days.items():
            assert 0.45 < sd < 0.6
            z.append((model.means[group][0] + offset - levels[day]) / sd)
    assert len(z) == 40 and 0.5 < np.mean(np.square(z)) < 1.6     # chi-square/40: 1 +- 0.22
    speed = next(d for d in spread_fit.discrepancies(latents) if d.metric == 'peak_tip_speed_mps')
    assert abs(speed.bias) < 3 * speed.bias_std_error
    assert speed.sd == pytest.approx(0.03, rel=0.2)


def test_the_spread_needs_more_than_one_day():
    strikes = [_strike(i) for i in range(3)]
    strikes = [RealStrike(s.trial, 'air', 23.0, 3.0, 2.3, 'one day', 26.0, 100.0)
               for s in strikes]
    with pytest.raises(IdentificationError, match='at least two recording days'):
        spread_fit.latent_model([_latent(s, 1.0) for s in strikes], 'geometry.latch_offset_deg')


# ------------------------------------------------------------------ a simulated session
def test_a_session_draws_its_day_once_and_where_the_arm_sits_at_each_latching():
    from mantis_sim.robots import SessionRobots
    from mantis_sim.world import World
    scene = load_scene('air_23mm_rig')
    robots = SessionRobots(scene, 3)
    offsets = [robots(n).geometry.latch_offset_deg for n in range(1, 41)]
    assert offsets == [SessionRobots(scene, 3)(n).geometry.latch_offset_deg
                       for n in range(1, 41)]
    # about one day's level, scattered as strikes of one day are (sd 1.4 degrees)
    assert 0.7 < np.std(offsets) < 2.2 and len(set(offsets)) > 30   # some at the latch's end
    days = [SessionRobots(scene, seed)(1).geometry.latch_offset_deg for seed in range(40)]
    assert np.std(days) > 2.0                     # days differ more (sd 3.9 degrees)
    # the world strikes each latching with its own robot
    world = World(robots(1), relatch_scene=robots)
    assert world.scene.geometry.latch_offset_deg == offsets[0]
    with pytest.raises(ParameterError, match='has no spread'):
        SessionRobots(load_scene('reference_air_23mm'), 1)


def test_days_that_agree_end_the_day_scatter_at_zero_with_no_standard_error():
    latents = [_latent(RealStrike(f'{d}-{k}', 'water', 23.0, 3.0, 2.3, f'day{d}', 4.6, 100.0),
                       v)
               for d in range(2) for k, v in enumerate((-1.0, 0.2, 1.0))]      # equal days
    model = spread_fit.latent_model(latents, 'geometry.latch_offset_deg')
    assert model.day_sd == 0.0 and math.isnan(model.day_sd_std_error)
    assert model.strike_sd > 0.5
