"""The start of IV where the body's turn is below the noise (mantis_rig.analysis.phases): the
tangent along θ̇1's rise is late on a convex rise, and the convexity from overcentering on
bounds the turn from below."""
import numpy as np
import pytest

from mantis_rig.analysis import phases as ph

FRAME_S = 1.0 / 19000.0
LOADING_RADPS = -0.2
OVERCENTERING_S = 0.050
TURN_S = 0.0504


def _rate(t):
    """θ̇1: a clear excursion of the loading early on (where the band's lower exit is found),
    the loading rate until overcentering, then a convex rise through zero at TURN_S."""
    u = np.clip(t - OVERCENTERING_S, 0.0, None)
    k = -LOADING_RADPS / (TURN_S - OVERCENTERING_S) ** 2
    return np.where(t < 0.044, -3.0, LOADING_RADPS + k * u ** 2)


@pytest.mark.parametrize('noise_radps', [0.08, 0.2, 0.3])
def test_the_tangent_is_late_and_the_convexity_bound_early(noise_radps):
    t = np.arange(0.04, 0.06, FRAME_S)
    omega = _rate(t)
    noise = np.full(t.size, noise_radps)
    i_strike = len(t) - 2
    exits = ph.band_exits(t, omega, noise, i_strike, LOADING_RADPS)
    assert not exits.resolved                     # the band is wider than the loading rate
    t_iv, _ = ph.max_contraction(t, omega, noise, i_strike, LOADING_RADPS)
    earliest = ph.max_contraction_earliest(t, exits, LOADING_RADPS, OVERCENTERING_S)
    assert earliest < TURN_S < t_iv
    assert earliest > OVERCENTERING_S


def test_no_bound_where_the_turn_is_resolved_or_overcentering_is_not_before_it():
    t = np.arange(0.04, 0.06, FRAME_S)
    omega = _rate(t)
    noise = np.full(t.size, 0.01)
    exits = ph.band_exits(t, omega, noise, len(t) - 2, LOADING_RADPS)
    assert exits.resolved
    assert np.isnan(ph.max_contraction_earliest(t, exits, LOADING_RADPS, OVERCENTERING_S))
    wide = ph.band_exits(t, omega, np.full(t.size, 0.2), len(t) - 2, LOADING_RADPS)
    assert np.isnan(ph.max_contraction_earliest(t, wide, LOADING_RADPS, 0.059))
    assert np.isnan(ph.max_contraction_earliest(t, wide, LOADING_RADPS, float('nan')))
