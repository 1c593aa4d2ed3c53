"""The comparison's statistics on made-up numbers, where the answer is known."""
import pytest

from mantis_sim.studies.fidelity import SimulatedStrike, day_state_gain
from mantis_sim.studies.strikes import RealStrike


def _simulated(real, slope, offset):
    return SimulatedStrike(real.trial, 'strike', '', 25.0 * (1 + slope[0] * offset),
                           100.0 * (1 + slope[1] * offset))


def test_a_day_s_own_state_removes_an_error_the_day_shares():
    """Two days; every strike of a day off by the same shift of one parameter (the errors
    linear in it): set from the day's other strikes, the shift predicts each one exactly."""
    strikes, base, nudged = [], [], []
    for day, shift in (('a', 0.3), ('b', -0.2)):
        for k in range(3):
            real = RealStrike(f'{day}{k}', 'air', 23.0, 3.0, 1.0 + k, day,
                              peak_tip_speed_mps=25.0, spring_energy_mJ=100.0)
            slope = (0.1 * (k + 1), 0.4)       # d(error)/d(parameter), tip speed and energy
            strikes.append(real)
            base.append(_simulated(real, slope, -shift))      # the scenes miss the day's shift
            nudged.append(_simulated(real, slope, -shift + 0.01))
    gain = day_state_gain(strikes, base, nudged, 0.01)['air_23mm']
    assert gain['strikes'] == 6
    assert gain['spring_energy'][0] == pytest.approx(0.4 * 0.25, rel=0.25)
    assert gain['tip_speed'][1] == pytest.approx(0.0, abs=1e-9)
    assert gain['spring_energy'][1] == pytest.approx(0.0, abs=1e-9)
