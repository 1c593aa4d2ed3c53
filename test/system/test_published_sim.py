"""The published_s12 scene against the authors' published simulation (issue 14): their
parameters, their forms of the arm's air load and of the added mass in air, and a tendon that
yields at 17 N, over the strike, against the issue's goals. This model's curves are taken from
the integrator's continuous solution at their sample times."""
from conftest import published_s12_run
import numpy as np
import pytest

from mantis_sim.results import simulate
from mantis_sim.scene import load_scene

T_SWITCH_LAG_MS = 0.19          # their T_switch is logged this long after the arm leaves contact


@pytest.fixture(scope='module')
def published():
    run = published_s12_run()
    t, tip = run['t_ms'], run['tip_mps']
    return dict(t=t, F=run['force_N'], tip=tip, arm=np.abs(run['omega3']).max() * 1e3,
                saturated_from=run['saturated_from_ms'],
                unlatch=run['t_switch_ms'] - T_SWITCH_LAG_MS,
                iv=float(t[np.argmin(run['theta1'])]), peak=float(t[np.argmax(tip)]))


@pytest.fixture(scope='module')
def ours():
    return simulate(load_scene('published_s12', ['integration.rtol=1e-9']), dense=True)


def test_the_events_are_within_0_2_ms(published, ours):
    m = ours.metrics
    assert abs(m['phase_start_s']['II'] * 1e3 - published['unlatch']) < 0.2
    assert abs(m['phase_start_s']['IV'] * 1e3 - published['iv']) < 0.2
    assert abs(m['peak_time_s'] * 1e3 - published['peak']) < 0.2


def test_the_tendon_force_matches_until_the_strike(published, ours):
    """Within 0.02 N through loading, unlatching and phase III (to 1591 ms), at their sample
    times on this model's continuous solution."""
    t = published['t']
    loading = (t >= ours.trajectory.t_ms[0]) & (t <= 1591.0)
    force = ours.tendon_force_at(t[loading])
    assert np.abs(force - published['F'][loading]).max() < 0.02


def test_peak_speeds_are_within_1_percent(published, ours):
    """Their air load with their quarter-turned velocity (PublishedArmAirLoad): +0.37 % and
    +0.49 % today; with the velocity taken as the true one it was +1.07 % and +1.14 %."""
    tip = ours.metrics['peak_tip_speed_mps'] / published['tip'].max() - 1
    arm = ours.metrics['peak_arm_speed_radps'] / published['arm'] - 1
    assert abs(tip) < 0.01 and abs(arm) < 0.01, (tip, arm)


def test_the_force_saturates_at_17_n(ours):
    assert ours.metrics['peak_tendon_force_N'] == pytest.approx(17.0, abs=1e-9)
    assert 'saturate' in [name for name, _ in ours.metrics['events']]


def test_the_tendon_force_is_within_0_2_n_up_to_its_saturation(published, ours):
    """0.147 N at most, at their last sample before 17 N, where the force rises at 35 N/ms
    (0.203 N with their pull speed rounded to 2.32885 mm/s)."""
    t, F = published['t'], published['F']
    before = (t >= ours.trajectory.t_ms[0]) & (t < published['saturated_from'])
    force = ours.tendon_force_at(t[before])
    assert np.abs(force - F[before]).max() < 0.2


def test_the_published_terms_are_opt_in(ours):
    """No other scene changes: air_23mm keeps the consistent forms."""
    published_terms = {'published_arm_air_load', 'published_added_mass',
                       'tendon_force_saturation'}
    assert published_terms <= set(ours.metrics['effects'])
    assert not published_terms & set(simulate(load_scene('reference_air_23mm')).metrics['effects'])
