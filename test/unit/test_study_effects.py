"""The twin's forecast of a study's effects (effect_forecast), on ensembles whose values are
known functions of the arm's seat, and the advice on repeats."""
import math

import pytest

from mantis_sim.scene import load_scene
from mantis_sim.studies.rig_study.effects import Effect, _with_more_repeats, twin_effects
from mantis_sim.studies.rig_study.figures import effects_figure
from mantis_sim.studies.rig_study.plan import plan_from_mapping
from mantis_sim.studies.rig_study.quantities import MeasurementError
from mantis_sim.studies.rig_study.twin_forecast import Ensemble, StudyForecaster, latent_layout

ROBOTS = 401
LOWER, UPPER = -3.0, 12.0          # the latch offset's range at a contact angle of 3 degrees
WORK_PER_DEG = -3.0                 # loading work (mJ) per degree of seat


def _ensemble(d_t_mm: float, speed_at_seat) -> Ensemble:
    seats = latent_layout(ROBOTS, LOWER, UPPER)
    return Ensemble({'d_t_mm': d_t_mm}, seats, LOWER, UPPER,
                    {'loading_work_mJ': 40.0 + WORK_PER_DEG * seats,
                     'peak_tip_speed_mps': speed_at_seat(seats)})


def _forecaster(measurement=None, **speeds):
    scene = load_scene('air_23mm_rig')
    ensembles = [_ensemble(float(d), f) for d, f in speeds.items()]
    return StudyForecaster(scene, ensembles, seed=3, measurement=measurement or {})


PLAN = plan_from_mapping({'scene': 'air_23mm_rig', 'factors': {'d_t_mm': [19, 25]},
                          'repeats': 4, 'order': 'as-listed', 'seed': 0}, 'plan')


def _rows(level_deg: float, per_level: int = 4) -> list:
    """A day's strikes at both guide distances, their loading work that of seat ``level``."""
    return [{'d_t_mm': d, 'day': 'd1', 'loading_work_mJ': 40.0 + WORK_PER_DEG * level_deg}
            for d in (19.0, 25.0) for _ in range(per_level)]


def test_a_linear_twin_forecasts_the_difference_and_the_scatter_of_its_estimate():
    forecaster = _forecaster(**{'19': lambda x: 30.0 + 0.2 * x, '25': lambda x: 28.0 + 0.2 * x})
    rows = _rows(1.0)
    effect, low, high = twin_effects(PLAN, forecaster, 'peak_tip_speed_mps', rows)[
        ('d_t_mm', 25.0)]
    assert effect == pytest.approx(-2.0, abs=0.02)
    # each strike's seat scatters by the spread's within-day sd about the day's level, shared
    # by both levels: the difference of two means of 4 carries 0.2 * sd * sqrt(1/4 + 1/4)
    sd = 0.2 * forecaster.belief.latent.strike_sd * math.sqrt(0.5)
    assert (high - low) / 2 == pytest.approx(1.96 * sd, rel=0.15)


def test_the_effect_is_this_days_where_it_depends_on_the_seat():
    """The guide's effect is 0.3 m/s per degree of seat: a day seated at 4 degrees differs by
    1.2 m/s, whatever the mean over all days."""
    forecaster = _forecaster(**{'19': lambda x: 30.0 + 0.0 * x, '25': lambda x: 30.0 + 0.3 * x})
    for level in (-1.0, 4.0):
        effect, low, high = twin_effects(PLAN, forecaster, 'peak_tip_speed_mps',
                                         _rows(level, per_level=8))[('d_t_mm', 25.0)]
        assert effect == pytest.approx(0.3 * level, abs=0.15)
        assert low < 0.3 * level < high


def test_the_measuring_chain_widens_and_moves_the_forecast():
    speeds = {'19': lambda x: 30.0 + 0.0 * x, '25': lambda x: 28.0 + 0.0 * x}
    exact = twin_effects(PLAN, _forecaster(**speeds), 'peak_tip_speed_mps', _rows(0.0))
    chain = {'peak_tip_speed_mps': MeasurementError.normal(-0.01, 0.01)}
    measured = twin_effects(PLAN, _forecaster(chain, **speeds), 'peak_tip_speed_mps',
                            _rows(0.0))
    _, low, high = exact[('d_t_mm', 25.0)]
    assert high - low < 1e-9                       # no scatter in the twin: none forecast
    effect, low, high = measured[('d_t_mm', 25.0)]
    assert effect == pytest.approx(-2.0 * 0.99, abs=0.02)      # the bias scales both levels
    sd = 0.01 * math.sqrt(30.0 ** 2 / 4 + 28.0 ** 2 / 4)
    assert (high - low) / 2 == pytest.approx(1.96 * sd, rel=0.15)


def _effect(low: float, high: float, residual_sd: float) -> Effect:
    return Effect('d_t_mm', 25.0, 19.0, 'peak_tip_speed_mps', (low + high) / 2, low, high, 8,
                  residual_sd, -1.0, -1.5, -0.5, 0.0)


def test_an_unresolved_effect_is_never_advised_zero_more_repeats():
    # a difference of 1 m/s against a scatter of 0.5 m/s needs 4 strikes a level (80 %
    # power, 5 %): 2 combinations a level, so 2 repeats; 4 were run and it still straddles 0
    effect = _with_more_repeats(_effect(-0.9, 0.1, 0.5), 1.0, 2.0, repeats_run=4)
    assert effect.more_repeats == 1
    # a scatter of 2 m/s needs 63 strikes a level: 32 repeats, 4 run, 28 more
    effect = _with_more_repeats(_effect(-3.0, 1.0, 2.0), 1.0, 2.0, repeats_run=4)
    assert effect.more_repeats == 28
    assert math.isinf(_with_more_repeats(_effect(-3.0, 1.0, 2.0), None, 2.0, 4).more_repeats)


def test_the_effects_figure_is_a_grid_readable_at_report_size(tmp_path):
    effects = [Effect(f, lv, ref, q, 1.0, 0.5, 1.5, 8, 0.3, 1.1, 0.4, 1.6, 0.0)
               for q in ('peak_tendon_force_N', 'loading_work_mJ', 'release_time_s',
                         'peak_tip_speed_mps', 'max_spring_energy_mJ')
               for f, ref, lv in (('d_t_mm', 19.0, 23.0), ('contact_angle_deg', 2.0, 5.0))]
    path = effects_figure(effects, tmp_path / 'effects.png')
    import matplotlib.image
    height, width = matplotlib.image.imread(path).shape[:2]
    assert width <= 1400 and height >= 0.5 * width      # 2 columns, 3 rows: not a strip
