"""The twin's forecasts of a study's trials: weighted ensembles of robots laid out over the
latch seat, a day's level read from its earlier strikes, and the effects of the factors."""
import math

import numpy as np
import pytest

from mantis_sim.scene import load_scene
from mantis_sim.studies.rig_study.effects import measured_effects
from mantis_sim.studies.rig_study.judge import judge
from mantis_sim.studies.rig_study.plan import plan_from_mapping
from mantis_sim.studies.rig_study.quantities import RIG_ERROR
from mantis_sim.studies.rig_study.twin_forecast import (
    DAY_QUANTITY,
    StudyForecaster,
    latent_layout,
    robot_quantities,
    simulate_ensemble,
)

CONDITIONS = {'d_t_mm': 23.0, 'pull_speed_mm_s': 2.3}


@pytest.fixture(scope='module')
def twin():
    scene = load_scene('air_23mm_rig')
    ensemble = simulate_ensemble(scene, CONDITIONS, 60, seed=1)
    return scene, StudyForecaster(scene, [ensemble], seed=1), ensemble


def test_the_layout_spans_the_seats_range_with_its_ends():
    x = latent_layout(10, -3.0, 12.0)
    assert x[0] == -3.0 and x[-1] == 12.0 and np.all(np.diff(x) > 0)


def test_a_new_days_forecast_is_a_distribution_over_the_robots(twin):
    _, forecaster, ensemble = twin
    forecast = forecaster.forecast(CONDITIONS)
    assert forecast.weights.sum() == pytest.approx(1.0)
    assert forecast.weights[0] > forecast.weights[1]    # the seats beyond the range's end
    q = forecast.quantiles(DAY_QUANTITY)
    values = list(q.values())
    assert values == sorted(values) and values[0] < values[-1]


def test_a_days_level_is_read_back_from_its_strikes(twin):
    scene, forecaster, _ = twin
    rng = np.random.default_rng(3)
    for level in (-1.0, 4.0):
        strikes = []
        for seat in level + rng.normal(0.0, 1.4, 4):
            values = robot_quantities((scene.with_values(
                {'geometry.d_t_mm': 23.0, 'drive.pull_speed_mm_per_s': 2.3,
                 'geometry.latch_offset_deg': float(np.clip(seat, -3, 12))}), {}, 0.3, 0.5))
            strikes.append((CONDITIONS, values[DAY_QUANTITY]))
        mean, sd = forecaster.day_level(strikes)
        assert abs(mean - level) < 3 * sd + 0.5, (level, mean, sd)
        assert sd < 1.5                   # four strikes say far more than the prior's 3.9


def test_forecasts_of_strikes_drawn_as_the_twin_draws_them_are_calibrated(twin):
    """Days drawn from the spread, strikes about each day's level, each forecast from the day's
    earlier ones: the measured values fall in the central 80 % about 80 % of the time."""
    scene, forecaster, _ = twin
    lat = scene.spread.latent
    rng = np.random.default_rng(11)
    inside, pits = 0, []
    for _ in range(8):
        level = rng.normal(lat.mean, lat.day_sd)
        earlier = []
        for _ in range(6):
            seat = float(np.clip(level + rng.normal(0.0, lat.strike_sd), -3.0, 12.0))
            truth = robot_quantities((scene.with_values(
                {'geometry.d_t_mm': 23.0, 'drive.pull_speed_mm_per_s': 2.3,
                 'geometry.latch_offset_deg': seat}), {}, 0.3, rng.uniform()))
            value = truth[DAY_QUANTITY] * (1 + RIG_ERROR[DAY_QUANTITY].sd
                                           * rng.normal())
            forecast = forecaster.forecast(CONDITIONS, earlier)
            low, high = forecast.quantile(DAY_QUANTITY, [0.1, 0.9])
            inside += low <= value <= high
            pits.append(forecast.pit(DAY_QUANTITY, value))
            earlier.append((CONDITIONS, value))
    assert 0.6 <= inside / 48 <= 0.97
    assert 0.3 < np.mean(pits) < 0.7


def test_a_value_outside_its_95_percent_is_flagged_with_a_cause(twin):
    _, forecaster, _ = twin
    forecast = forecaster.forecast(CONDITIONS)
    low = forecast.quantile('peak_tip_speed_mps', [0.001])[0]
    verdict = judge(forecast, {'peak_tip_speed_mps': low * 0.8, 'loading_work_mJ': None})
    assert verdict.flagged == ('peak_tip_speed_mps',)
    assert verdict.values['peak_tip_speed_mps_flag'] == 'outside'
    assert 'below its 95 % interval' in verdict.cause and 'strike lost speed' in verdict.cause
    assert verdict.values['loading_work_mJ_flag'] == ''
    assert math.isnan(verdict.values['loading_work_mJ_pit'])


def test_measured_effects_recover_a_known_difference_lost_trials_and_all():
    plan = plan_from_mapping({'scene': 'air_23mm_rig', 'repeats': 6, 'seed': 0,
                              'factors': {'d_t_mm': [19, 25], 'pull_speed_mm_s': [1.0, 2.3]}},
                             'plan')
    rng = np.random.default_rng(2)
    rows = [{'d_t_mm': t.conditions['d_t_mm'], 'pull_speed_mm_s': t.conditions['pull_speed_mm_s'],
             'peak_tip_speed_mps': 30.0 - 2.0 * (t.conditions['d_t_mm'] == 25)
             + rng.normal(0, 0.3)} for t in plan.trials()]
    del rows[:5]                              # aborted, never repeated: unbalanced
    effects = measured_effects(plan, rows, 'peak_tip_speed_mps')
    effect, low, high, strikes, sd = effects[('d_t_mm', 25.0)]
    assert low < -2.0 < high and high - low < 1.0
    assert strikes == 19 and sd == pytest.approx(0.3, rel=0.5)
    _, low, high, _, _ = effects[('pull_speed_mm_s', 2.3)]
    assert low < 0.0 < high
