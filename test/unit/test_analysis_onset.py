"""The unlatching's start from the arm's departure (mantis_rig.analysis.onset): a departure of
the released arm's form, under noise, is put back to its start within its interval; a creep
off the latch, or no departure, leaves the level crossing standing."""
import numpy as np
import pytest

from mantis_rig.analysis.onset import Onset, departure_form, unlatch_onset

FRAME_S = 1.0 / 19000.0
NOISE_RAD = 5.5e-4                  # as the simulated camera's arm angle at 0.1 px steps
START_S = 0.02


def _moving_average(y, frames=9):
    return np.convolve(y, np.ones(frames) / frames, mode='same')


def _departure(seed, rate_per_s=1200.0, gain=4e5):
    """Angles of an arm released at START_S (rad), with white noise; its crossing of three
    noise sds, found as the analysis finds it (the smoothed angle's last frame near its floor)."""
    t = np.arange(0.0, 0.03, FRAME_S)
    clean = gain * departure_form(rate_per_s, t - START_S)
    raw = clean + np.random.default_rng(seed).normal(0.0, NOISE_RAD, t.size)
    smooth = _moving_average(raw)
    near_floor = np.nonzero(smooth[:-20] <= smooth[100:-20].min() + 3.0 * NOISE_RAD)[0]
    return t, raw, smooth, float(t[near_floor[-1]])


def test_the_form_is_a_cube_at_first_and_zero_before_its_start():
    tau = np.array([-1e-3, 0.0, 1e-6, 2e-3])
    assert departure_form(1200.0, tau)[:2] == pytest.approx([0.0, 0.0])
    assert departure_form(1200.0, tau)[2] == pytest.approx(1e-18, rel=1e-6)
    assert departure_form(0.0, tau)[3] == pytest.approx(8e-9)
    x = 1200.0 * 2e-3
    assert departure_form(1200.0, tau)[3] == pytest.approx(6 * (np.sinh(x) - x) / 1200.0 ** 3)


def test_a_released_arm_is_put_back_to_its_start_within_its_interval():
    held, errors = 0, []
    for seed in range(12):
        t, raw, smooth, crossing_s = _departure(seed)
        assert crossing_s - START_S > 1e-3          # the level crossing is milliseconds late
        onset = unlatch_onset(t, raw, smooth, NOISE_RAD, crossing_s, len(t) - 1)
        assert isinstance(onset, Onset)
        low, high, _ = onset.interval(0.8)
        assert low <= onset.start_s <= high
        held += low <= START_S <= high
        errors.append(onset.start_s - START_S)
    assert np.median(np.abs(errors)) < 0.5e-3, errors
    assert 7 <= held <= 12, held                    # an 80 % interval, over 12 departures


def test_a_creep_off_the_latch_or_none_leaves_the_crossing():
    t = np.arange(0.0, 0.5, FRAME_S)
    rng = np.random.default_rng(3)
    creep = np.clip(t - 0.1, 0.0, None) * 0.05 + rng.normal(0.0, NOISE_RAD, t.size)
    assert unlatch_onset(t, creep, _moving_average(creep), NOISE_RAD, 0.13, len(t) - 1) is None
    flat = rng.normal(0.0, NOISE_RAD, t.size)
    assert unlatch_onset(t, flat, _moving_average(flat), NOISE_RAD, 0.2, len(t) - 1) is None


def test_lost_frames_are_left_out_of_the_fit():
    t, raw, smooth, crossing_s = _departure(0)
    whole = unlatch_onset(t, raw, smooth, NOISE_RAD, crossing_s, len(t) - 1)
    raw = raw.copy()
    raw[int(0.015 / FRAME_S)::7] = np.nan           # every seventh frame lost from 15 ms on
    gappy = unlatch_onset(t, raw, smooth, NOISE_RAD, crossing_s, len(t) - 1)
    assert gappy is not None and abs(gappy.start_s - whole.start_s) < 0.5e-3
