"""The day-state fit on a made-up model (a fake mapper: the strike's values are a known
function of the day's hold), where the answer is known and each run takes milliseconds."""
import math

import pytest

from mantis_sim.scene import load_scene
from mantis_sim.studies.real_strikes import day_state as ds
from mantis_sim.studies.real_strikes import identify as ident
from mantis_sim.studies.real_strikes.fidelity import SimulatedStrike
from mantis_sim.studies.real_strikes.strikes import RealStrike

SCENE = load_scene('air_23mm')          # its hold: about 0.06 mm


def energy_mJ(hold_mm):
    return 100.0 * math.exp(8.0 * hold_mm)


def made_up_mapper(function, tasks):
    assert function is ident.simulate_task
    out = []
    for scene, strike, _, values in tasks:
        hold = scene.with_values(values).hinge.friction_lever_mm
        out.append(SimulatedStrike(strike.trial, 'strike', '', 25.0 + 10.0 * hold,
                                   energy_mJ(hold)))
    return out


def strikes_of(holds_mm: dict, tip_speed=True):
    out = []
    for day, hold in holds_mm.items():
        for k in range(3):
            out.append(RealStrike(f'{day}_{k}', 'air', 23.0, 3.0, 1.0 + k, day,
                                  peak_tip_speed_mps=25.0 + 10.0 * hold if tip_speed else None,
                                  spring_energy_mJ=energy_mJ(hold)))
    return out


def fit(holds_mm, key=ds.HOLD_KEY, iterations=5, tip_speed=True):
    param = ident.parse_free_parameter(key, {'air_23mm': SCENE}, option='--key')
    model = ds.DayStateFit({'air_23mm': SCENE}, strikes_of(holds_mm, tip_speed), param,
                           ident.Weights(), made_up_mapper)
    return model, {s.day: s for s in model.fit(iterations)}


def test_a_day_close_to_the_scene_is_moved_to_its_own_value():
    """Steps of a few percent of the value are taken, with the key's whole range as bounds."""
    _, states = fit({'a': 0.056, 'b': 0.064})
    assert states['a'].value == pytest.approx(0.056, abs=1e-4)
    assert states['b'].value == pytest.approx(0.064, abs=1e-4)
    assert not states['a'].at_bound and states['a'].strikes == 3


def test_a_step_that_overshoots_is_halved_back():
    """From the scene's 0.06 mm the first Gauss-Newton step towards 0.6 mm of this steep model
    lands far beyond it (at the upper bound), where the cost is worse."""
    _, states = fit({'far': 0.6}, iterations=40, tip_speed=False)
    assert states['far'].value == pytest.approx(0.6, abs=1e-3)


def test_a_day_beyond_the_bounds_ends_at_them_and_says_so():
    _, states = fit({'high': 0.3, 'low': 0.1}, key=f'{ds.HOLD_KEY}=0.08:0.2')
    assert states['high'].value == pytest.approx(0.2) and states['high'].at_bound
    # the scene's 0.06 lies below the bounds asked for: the fit starts within them
    assert states['low'].value == pytest.approx(0.1, abs=1e-3)


def test_leaving_one_strike_out_predicts_it_from_its_day_and_skips_missing_values():
    model, _ = fit({'a': 0.03, 'b': 0.09}, tip_speed=False)
    left_out = model.leave_one_out()
    assert len(left_out) == 6
    summary = ds.left_out_summary(left_out)['air_23mm']
    assert summary['spring_energy_own_day'] < 0.2 * summary['spring_energy_shared']
    assert math.isnan(summary['tip_speed_shared'])      # none measured: no error, no crash
