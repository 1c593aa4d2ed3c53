"""The analysis's intervals (mantis_rig.analysis.intervals): the basic bootstrap reflects the
re-trackings' deviations about the trial's value, the estimator's choices widen it either way,
a time is widened by a frame; the re-tracking keeps the tracker's step and lost positions."""
import numpy as np
import pytest

from mantis_rig.analysis.inputs import MarkerTracks
from mantis_rig.analysis.intervals import _basic_bootstrap, _interval, _tracked_again
from mantis_sim.errors import InputError


def test_the_interval_reflects_the_deviations_and_holds_every_choice():
    noisy = list(np.linspace(10.0, 12.0, 101))            # re-trackings read high by 0 .. 2
    noise = _basic_bootstrap(10.0, noisy)
    # the 10 % and 90 % quantiles are 10.2 and 11.8: reflected about 10, 8.2 .. 9.8
    assert noise == pytest.approx((8.2, 9.8))
    interval = _interval(10.0, noise, [])
    assert interval.low == pytest.approx(8.2) and interval.high == pytest.approx(9.8)
    # a choice 0.5 above: the value may be 0.5 off either way
    widened = _interval(10.0, noise, [10.5, float('nan')], resolution=0.1)
    assert widened.low == pytest.approx(8.1) and widened.high == pytest.approx(10.6)
    assert widened.holds(10.55) and not widened.holds(10.7)
    far = _interval(10.0, noise, [6.0])
    assert far.low == pytest.approx(6.0) and far.high == pytest.approx(14.0)
    assert np.isnan(_interval(float('nan'), noise, []).low)
    assert np.isnan(_basic_bootstrap(10.0, [11.0])[0])               # too few re-trackings
    assert np.isnan(_interval(10.0, _basic_bootstrap(10.0, [11.0]), []).low)


def test_a_re_tracking_keeps_the_step_and_the_lost_positions():
    xy = np.round(np.random.default_rng(1).uniform(0, 5, (2000, 2)) / 0.017) * 0.017
    xy[10] = np.nan
    tracks = MarkerTracks(time_s=np.arange(2000) / 19000.0, frames=np.arange(2000),
                          markers_mm={'mb1': xy}, handedness='left', source={})
    again = _tracked_again(tracks, np.random.default_rng(2), 0.017)
    moved = again.markers_mm['mb1']
    assert np.isnan(moved[10]).all() and np.isfinite(np.delete(moved, 10, axis=0)).all()
    steps = moved[np.isfinite(moved)] / 0.017
    assert np.allclose(steps, np.round(steps))
    # moved by as much as tracking moves a position: rounding (1/12) and jitter (0.3 steps)
    deviation = np.delete(moved - xy, 10, axis=0) / 0.017
    assert np.mean(deviation ** 2) == pytest.approx(1 / 12 + 0.09, rel=0.25)
    with pytest.raises(InputError, match='show no tracker step'):
        _tracked_again(tracks, np.random.default_rng(2), 0.0)


def test_a_terminal_sees_the_analyses_counted_and_a_log_does_not():
    import io

    from mantis_rig.cli.analyze import _analyses_shown

    class Terminal(io.StringIO):
        def isatty(self):
            return True
    terminal = Terminal()
    show = _analyses_shown(terminal)
    for done in (1, 2, 3):
        show(done, 3)
    assert terminal.getvalue() == ''.join(f'\ranalyze: intervals, analysis {n} of 3'
                                          for n in (1, 2, 3)) + '\n'
    assert _analyses_shown(io.StringIO()) is None
