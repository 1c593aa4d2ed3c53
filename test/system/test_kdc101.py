"""The real KDC101 stage backend against an emulated KDC101 on a pseudo-terminal."""
import logging
import re
import threading
import time

from fakes.kdc101_emulator import (
    HW_START_UPDATEMSGS,
    MOD_SET_CHANENABLESTATE,
    MOT_MOVE_ABSOLUTE,
    MOT_MOVE_HOME,
    MOT_MOVE_VELOCITY,
    MOT_SET_HOMEPARAMS,
    fds_open_on,
)
import numpy as np
from polling import wait_until
import pytest
import serial

from mantis_rig.hardware.apt_units import (
    Z8_COUNTS_PER_MM,
    Z8_DATASHEET_COUNTS_PER_MM,
    AptScale,
)
from mantis_rig.hardware.device_interfaces import (
    ConfigurationError,
    DeviceError,
    ForceBlock,
    SafetyLimitError,
    StageLimits,
)
from mantis_rig.hardware.kdc101 import Kdc101Stage
from mantis_rig.trial.stage_guard import StageGuard

pytestmark = pytest.mark.timeout(30)

MM = 1e-3
# The protocol's scaling figures for the Z8 (shared/docs/rig.md), written out, not derived.
VELOCITY_UNITS_PER_MM_S = 772981.4
ACCELERATION_UNITS_PER_MM_S2 = 263.84


def kdc101_threads():
    return [t for t in threading.enumerate() if t.name.startswith(('kdc101', 'stage-guard'))]


@pytest.fixture(autouse=True)
def nothing_left_running():
    yield
    assert kdc101_threads() == [], 'a driver or emulator thread outlived the test'


@pytest.fixture
def make_stage():
    stages = []

    def make(port, open_=True, **kwargs):
        options = dict(reply_timeout_s=1.0, stop_timeout_s=1.0, status_timeout_s=1.5)
        options.update(kwargs)
        stages.append(Kdc101Stage(port, **options))
        if open_:
            stages[-1].open()
        return stages[-1]

    yield make
    for stage in stages:
        stage.close()


def assert_link_closed(stage, emulator=None):
    assert stage._port is None
    assert not [t for t in threading.enumerate() if t.name.startswith('kdc101-io')]
    if emulator is not None:       # the driver's fd on the pty is closed, not just forgotten
        assert len(fds_open_on(emulator.port)) == 1, 'the driver left its port fd open'



# --- unit conversions -----------------------------------------------------------------------

def test_scale_follows_the_protocol_definition_for_the_z8():
    scale = AptScale()
    assert scale.counts_per_mm == 34554.96
    assert scale.velocity_per_mm_s == pytest.approx(VELOCITY_UNITS_PER_MM_S, abs=0.1)
    assert scale.acceleration_per_mm_s2 == pytest.approx(ACCELERATION_UNITS_PER_MM_S2, abs=0.005)
    assert scale.position_to_counts(10 * MM) == 345550
    assert scale.velocity_to_units(1 * MM) == 772981
    assert scale.velocity_to_units(2.4 * MM) == round(2.4 * 772981.37)
    assert scale.acceleration_to_units(4 * MM) == round(4 * 263.8443)
    assert scale.counts_to_position_m(34555) == pytest.approx(1.0000012 * MM, rel=1e-7)
    assert scale.units_to_velocity_m_per_s(772981) == pytest.approx(1 * MM, rel=1e-6)


def test_datasheet_counts_per_mm_rescales_everything():
    scale = AptScale(Z8_DATASHEET_COUNTS_PER_MM)
    ratio = 34304 / 34554.96
    assert scale.position_to_counts(1 * MM) == 34304
    assert scale.velocity_per_mm_s == pytest.approx(772981.4 * ratio, rel=1e-6)
    assert scale.acceleration_per_mm_s2 == pytest.approx(263.84 * ratio, rel=1e-4)


def test_explicit_scales_override_the_derived_ones():
    stage = Kdc101Stage('/dev/null', counts_per_mm=Z8_COUNTS_PER_MM,
                        velocity_per_mm_s=700000.0, acceleration_per_mm_s2=250.0)
    assert stage.scale.velocity_to_units(1 * MM) == 700000
    assert stage.scale.acceleration_to_units(2 * MM) == 500
    with pytest.raises(ConfigurationError, match='counts_per_mm'):
        AptScale(0.0)


def test_datasheet_counts_per_mm_reaches_the_controller(make_emulator, make_stage):
    emu = make_emulator(position_mm=2.0, homed=True)
    stage = make_stage(emu.port, counts_per_mm=34304)
    stage.move_to(3 * MM, 2.4 * MM)
    # the emulated actuator really has 34,554.96 counts/mm: the data sheet figure is short
    assert emu.position_mm == pytest.approx(3 * 34304 / 34554.96, abs=1e-4)
    assert stage.state().position_m == pytest.approx(3 * MM, abs=1e-7)
    assert emu.velparams['max_velocity'] == round(2.4 * 772981.37 * 34304 / 34554.96)


# --- commands -------------------------------------------------------------------------------

def test_open_identifies_enables_and_starts_status_updates(make_emulator, make_stage):
    emu = make_emulator(position_mm=7.25)
    stage = make_stage(emu.port)
    info = stage.identify()
    assert (info.model, info.serial_number, info.firmware) == ('KDC101', '27000123', '3.0.10')
    assert MOD_SET_CHANENABLESTATE in emu.received and HW_START_UPDATEMSGS in emu.received
    state = stage.state()
    assert state.position_m == pytest.approx(7.25 * MM, abs=1e-7)
    assert (state.moving, state.homed, state.forward_limit, state.reverse_limit) == (
        False, False, False, False)
    assert state.fault is None


@pytest.mark.slow
def test_keepalive_keeps_status_updates_coming(make_emulator, make_stage):
    emu = make_emulator(ack_timeout_s=1.0)
    stage = make_stage(emu.port, keepalive_period_s=0.3)
    time.sleep(2.5)
    assert emu.acks_received >= 3
    assert emu.sending_status
    sent = emu.status_sent
    assert wait_until(lambda: emu.status_sent > sent, 2.0)
    assert stage.state().position_m == pytest.approx(5 * MM, abs=1e-7)


def test_emulator_stops_status_updates_without_acks(make_emulator):
    emu = make_emulator(ack_timeout_s=0.5)
    with serial.Serial(emu.port, 115200, timeout=0.1) as port:
        port.write(bytes([0x11, 0x00, 0x00, 0x00, 0x50, 0x01]))     # HW_START_UPDATEMSGS
        assert len(port.read(20)) == 20
        assert wait_until(lambda: not emu.sending_status, 3.0)
        time.sleep(0.3)
        port.reset_input_buffer()
        assert port.read(20) == b''


@pytest.mark.slow
def test_missing_status_updates_end_the_link(make_emulator, make_stage):
    emu = make_emulator(ack_timeout_s=0.5)
    stage = make_stage(emu.port, keepalive_period_s=30.0, status_timeout_s=1.0)
    assert wait_until(lambda: stage._failure is not None, 5.0)
    with pytest.raises(DeviceError, match=r'no status update .* for \d+\.\d s \(limit 1 s\)'):
        stage.state()
    assert_link_closed(stage, emu)


@pytest.mark.slow
def test_home(make_emulator, make_stage):
    emu = make_emulator(position_mm=3.0)            # stored home velocity: 20 mm/s
    stored = dict(emu.homeparams)
    stage = make_stage(emu.port)
    stage.home(timeout_s=20.0)
    assert MOT_MOVE_HOME in emu.received
    # the homing velocity was brought under the ceiling before MOT_MOVE_HOME, the rest kept
    assert emu.received.index(MOT_SET_HOMEPARAMS) < emu.received.index(MOT_MOVE_HOME)
    assert emu.homeparams == dict(stored, home_velocity=round(2.0 * VELOCITY_UNITS_PER_MM_S))
    state = stage.state()
    assert state.homed and not state.moving
    assert state.position_m == pytest.approx(0.0, abs=1e-7)
    assert emu.position_mm == pytest.approx(0.0, abs=1e-6)


def test_move_to_sets_velocity_and_arrives(make_emulator, make_stage):
    emu = make_emulator(position_mm=2.0, homed=True)
    stage = make_stage(emu.port)
    stage.move_to(3.0 * MM, 2.4 * MM, timeout_s=10.0)
    assert MOT_MOVE_ABSOLUTE in emu.received
    assert emu.velparams == {'min_velocity': 0, 'acceleration': round(4 * 263.8443),
                             'max_velocity': round(2.4 * 772981.37)}
    assert emu.position_mm == pytest.approx(3.0, abs=1e-4)
    state = stage.state()
    assert state.position_m == pytest.approx(3.0 * MM, abs=1e-7)
    assert not state.moving and state.fault is None


def test_move_needs_a_homed_stage(make_emulator, make_stage):
    emu = make_emulator(position_mm=2.0, homed=False)
    stage = make_stage(emu.port)
    with pytest.raises(DeviceError, match='not homed'):
        stage.move_to(3.0 * MM, 1 * MM)
    with pytest.raises(DeviceError, match='not homed'):
        stage.move_at(1 * MM)
    assert MOT_MOVE_ABSOLUTE not in emu.received and MOT_MOVE_VELOCITY not in emu.received


@pytest.mark.parametrize('velocity_mm_s', [2.0, -2.0])
def test_move_at_then_stop(make_emulator, make_stage, velocity_mm_s):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    stage.move_at(velocity_mm_s * MM)
    assert emu.velparams['max_velocity'] == round(2.0 * VELOCITY_UNITS_PER_MM_S)
    assert emu.velparams['acceleration'] == round(4 * ACCELERATION_UNITS_PER_MM_S2)
    assert emu.speed_mm_s == pytest.approx(2.0, rel=1e-6)   # the emulator's own conversion
    assert wait_until(lambda: abs(stage.state().position_m - 10 * MM) > 0.2 * MM)
    state = stage.state()
    assert state.moving
    assert state.velocity_m_per_s == pytest.approx(velocity_mm_s * MM, abs=0.1 * MM)
    stage.stop()
    assert not emu.moving
    stopped_mm = emu.position_mm
    assert (stopped_mm - 10.0) * velocity_mm_s > 0
    time.sleep(0.3)
    assert emu.position_mm == stopped_mm
    assert wait_until(lambda: not stage.state().moving, 2.0)


@pytest.mark.parametrize('streams_status', [True, False], ids=['streaming', 'polled'])
def test_a_bounded_pull_ends_at_its_bound_with_the_driver_gone(make_emulator, make_stage,
                                                              streams_status):
    """A pull with a bound is sent to the controller as MOT_MOVE_ABSOLUTE to the bound, at the
    pull speed as its maximum velocity: the stage stops there, at rest, with nobody sending a
    stop (the driver's process dead: no more messages, acks or polls, its port closed)."""
    emu = make_emulator(position_mm=10.0, homed=True, streams_status=streams_status)
    stage = make_stage(emu.port)
    stage.move_at(2.0 * MM, bound_m=10.8 * MM)
    assert wait_until(lambda: emu.mode == 'absolute', 2.0)
    assert MOT_MOVE_ABSOLUTE in emu.received and MOT_MOVE_VELOCITY not in emu.received
    assert emu.velparams['max_velocity'] == round(2.0 * VELOCITY_UNITS_PER_MM_S)
    assert emu.speed_mm_s == pytest.approx(2.0, rel=1e-6)
    assert wait_until(lambda: stage.state().moving and emu.position_mm > 10.2)
    stage._shutdown()                       # as a SIGKILL leaves it: not a word more
    assert_link_closed(stage, emu)
    time.sleep(0.05)                         # what was on the line has been read
    sent = len(emu.received)
    assert wait_until(lambda: not emu.moving, 5.0)
    assert emu.received[sent:] == []
    assert emu.position_mm == pytest.approx(10.8, abs=1e-4)
    time.sleep(0.2)
    assert emu.position_mm == pytest.approx(10.8, abs=1e-4)


def test_a_bounded_pull_reports_its_end_and_can_be_stopped_short(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    stage.move_at(2.4 * MM, bound_m=10.3 * MM)
    assert wait_until(lambda: emu.position_mm > 10.29 and not stage.state().moving, 5.0)
    assert not emu.moving
    state = stage.state()
    assert state.position_m == pytest.approx(10.3 * MM, abs=1e-7) and state.fault is None
    stage.move_at(2.0 * MM, bound_m=12.0 * MM)
    assert wait_until(lambda: emu.position_mm > 10.5)
    stage.stop()
    assert not emu.moving and emu.position_mm < 12.0
    # refused before anything is sent: a bound behind the stage, or beyond the soft limit
    sent = len(emu.received)
    with pytest.raises(ConfigurationError, match='not ahead of the stage'):
        stage.move_at(2.0 * MM, bound_m=10.0 * MM)
    with pytest.raises(ConfigurationError, match='outside the soft travel limits'):
        stage.move_at(2.0 * MM, bound_m=24.9 * MM)
    assert [m for m in emu.received[sent:] if m in (MOT_MOVE_ABSOLUTE, MOT_MOVE_VELOCITY)] == []


def test_move_at_zero_stops_and_stop_is_harmless_when_stopped(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    stage.stop()
    stage.stop()
    stage.move_at(1 * MM)
    assert wait_until(lambda: emu.moving, 2.0)
    stage.move_at(0.0)
    assert not emu.moving


# --- status: streamed, or polled when the controller does not stream -------------------------

POLL_LOG = 'polling it with MOT_REQ_DCSTATUSUPDATE at 10 Hz'


def polling_log_lines(caplog):
    return [r for r in caplog.records if r.name == 'mantis_rig.hardware.kdc101'
            and POLL_LOG in r.getMessage()]


def test_a_streaming_controller_is_not_polled(make_emulator, make_stage, caplog):
    emu = make_emulator(position_mm=4.0)
    with caplog.at_level(logging.INFO, logger='mantis_rig.hardware.kdc101'):
        stage = make_stage(emu.port)
    assert stage.status_mode == 'streaming'
    assert emu.status_requests_answered == 1          # open()'s one request, no polls
    assert polling_log_lines(caplog) == []


def test_a_controller_that_does_not_stream_is_polled(make_emulator, make_stage, caplog):
    emu = make_emulator(position_mm=10.0, homed=True, streams_status=False)
    with caplog.at_level(logging.INFO, logger='mantis_rig.hardware.kdc101'):
        stage = make_stage(emu.port)           # status_timeout_s 1.5 s
    assert stage.status_mode == 'polling'
    (line,) = polling_log_lines(caplog)
    assert line.levelno == logging.INFO and emu.port in line.getMessage()
    assert not emu.sending_status
    # 20 polls answered (2 s at 10 Hz, past the 1.5 s status limit) and the link holds
    answered = emu.status_requests_answered
    assert wait_until(lambda: emu.status_requests_answered >= answered + 20, 20.0)
    assert stage.state().position_m == pytest.approx(10 * MM, abs=1e-7)
    assert stage._failure is None

    stage.move_at(2 * MM)                      # positions follow the move, from polls alone
    assert wait_until(lambda: stage.state().position_m > 10.2 * MM)
    assert stage.state().moving
    stage.stop()
    assert not emu.moving
    assert wait_until(lambda: not stage.state().moving
                      and abs(stage.state().position_m / MM - emu.position_mm) < 1e-4)
    stage.move_to(11 * MM, 2.4 * MM, timeout_s=10.0)
    assert emu.position_mm == pytest.approx(11.0, abs=1e-4)
    assert wait_until(lambda: abs(stage.state().position_m - 11 * MM) < 1e-7)
    assert stage.status_mode == 'polling' and len(polling_log_lines(caplog)) == 1


def test_a_polled_controller_that_stops_answering_ends_the_link(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True, streams_status=False)
    stage = make_stage(emu.port)
    assert stage.status_mode == 'polling'
    emu.answers_status_requests = False
    assert wait_until(lambda: stage._failure is not None, 10.0)
    with pytest.raises(DeviceError, match=r'no status update from the KDC101 on .* for '
                                          r'\d+\.\d s \(limit 1\.5 s\), although polled with '
                                          r'MOT_REQ_DCSTATUSUPDATE at 10 Hz; port closed'):
        stage.state()
    assert_link_closed(stage, emu)


def test_a_controller_that_gives_status_neither_way_fails_at_open(make_emulator, make_stage):
    emu = make_emulator(streams_status=False, answers_status_requests=False)
    stage = make_stage(emu.port, open_=False, status_timeout_s=10.0)
    with pytest.raises(DeviceError, match=r'no status update \(neither streamed after '
                                          r'HW_START_UPDATEMSGS nor in reply to '
                                          r'MOT_REQ_DCSTATUSUPDATE\) from the KDC101 on .* '
                                          r'within 1 s; port closed'):
        stage.open()
    assert_link_closed(stage, emu)
    assert stage.status_mode is None


@pytest.mark.parametrize('kwargs, pattern', [
    (dict(poll_rate_hz=0.0), r'poll_rate_hz 0\.0 Hz must be finite and > 0 Hz'),
    (dict(poll_rate_hz=1.0), r'poll_rate_hz 1 Hz is too slow for status_timeout_s 1\.5 s'),
    (dict(stream_wait_s=1.0), r'stream_wait_s 1\.0 s .* at most half of status_timeout_s'),
])
def test_bad_status_settings_are_refused(kwargs, pattern):
    with pytest.raises(ConfigurationError, match=pattern):
        Kdc101Stage('/dev/null', **kwargs)


@pytest.mark.slow
@pytest.mark.parametrize('streams_status, mode', [(True, 'streaming'), (False, 'polling')])
def test_a_trials_stage_sequence(make_emulator, make_stage, streams_status, mode):
    """What a trial asks of the stage (trial/sequence.py through stage_node): home, move to the
    start, pull at a velocity, stop, move back."""
    emu = make_emulator(position_mm=1.0, streams_status=streams_status)
    stage = make_stage(emu.port)
    assert stage.status_mode == mode
    stage.home(timeout_s=20.0)
    assert stage.state().homed and emu.position_mm == pytest.approx(0.0, abs=1e-6)
    stage.move_to(2 * MM, 2.4 * MM, timeout_s=10.0)
    assert emu.position_mm == pytest.approx(2.0, abs=1e-4)
    stage.move_at(1 * MM)
    assert wait_until(lambda: stage.state().position_m > 2.3 * MM)
    assert stage.state().moving and emu.moving
    stage.stop()
    assert not emu.moving and emu.position_mm > 2.3
    stage.move_to(2 * MM, 2.4 * MM, timeout_s=10.0)
    assert emu.position_mm == pytest.approx(2.0, abs=1e-4)
    assert wait_until(lambda: abs(stage.state().position_m - 2 * MM) < 1e-7
                      and not stage.state().moving)
    assert stage._failure is None


# --- configuration refused at call time -----------------------------------------------------

@pytest.mark.parametrize('call, pattern', [
    (lambda s: s.move_to(5 * MM, 2.5 * MM), r'2\.5000 mm/s .* 2\.400 mm/s'),
    (lambda s: s.move_at(-3 * MM), r'3\.0000 mm/s .* 2\.400 mm/s'),
    (lambda s: s.move_to(30 * MM, 1 * MM), r'30\.0000 mm .* \[0\.500, 24\.500\] mm'),
    (lambda s: s.move_to(0.2 * MM, 1 * MM), r'0\.2000 mm .* \[0\.500, 24\.500\] mm'),
    (lambda s: s.move_to(5 * MM, 0.0), r'0\.0000 mm/s must be positive'),
])
def test_bad_configuration_is_refused(make_emulator, make_stage, call, pattern):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    with pytest.raises(ConfigurationError, match=pattern):
        call(stage)
    assert MOT_MOVE_ABSOLUTE not in emu.received and MOT_MOVE_VELOCITY not in emu.received
    assert not emu.moving


def test_move_at_outward_beyond_a_soft_limit_is_refused(make_emulator, make_stage):
    emu = make_emulator(position_mm=0.0, homed=True)
    stage = make_stage(emu.port)
    with pytest.raises(ConfigurationError, match=r'0\.0000 mm, at or beyond .* 0\.500 mm'):
        stage.move_at(-1 * MM)
    assert MOT_MOVE_VELOCITY not in emu.received
    stage.move_to(1 * MM, 2.4 * MM)        # moving back inside the envelope is allowed
    assert emu.position_mm == pytest.approx(1.0, abs=1e-4)


# --- limits during motion -------------------------------------------------------------------

@pytest.mark.parametrize('start_mm, velocity_mm_s, limit_mm', [
    (24.3, 1.0, 24.5), (0.7, -1.0, 0.5)])
def test_velocity_move_stops_at_the_soft_limit(make_emulator, make_stage,
                                               start_mm, velocity_mm_s, limit_mm):
    emu = make_emulator(position_mm=start_mm, homed=True)
    stage = make_stage(emu.port)
    stage.move_at(velocity_mm_s * MM)
    assert wait_until(lambda: stage.state().fault is not None, 5.0)
    assert wait_until(lambda: not emu.moving, 2.0)
    state = stage.state()
    assert f'passed the soft travel limit {limit_mm:.3f} mm' in state.fault
    assert 'stage stopped' in state.fault
    overshoot_mm = (emu.position_mm - limit_mm) * velocity_mm_s
    assert 0.0 < overshoot_mm < 0.5          # stopped well before the hardware switch
    assert not (state.forward_limit or state.reverse_limit)


def test_hardware_limit_during_move_to_raises_and_stops(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    emu.limit_switch_at(10.5, forward=True)
    with pytest.raises(SafetyLimitError,
                       match=r'forward hardware limit switch hit at 10\.5000 mm during the '
                             r'move to 12\.0000 mm; stage stopped'):
        stage.move_to(12 * MM, 2.4 * MM, timeout_s=10.0)
    assert not emu.moving
    assert emu.position_mm == pytest.approx(10.5, abs=1e-4)
    assert stage.state().forward_limit
    stage.move_to(10 * MM, 2.4 * MM, timeout_s=10.0)     # the link survives; back off the switch
    assert emu.position_mm == pytest.approx(10.0, abs=1e-4)
    assert not stage.state().forward_limit


def test_hardware_limit_during_velocity_move_is_reported(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    emu.limit_switch_at(9.7, forward=False)
    stage.move_at(-2 * MM)
    assert wait_until(lambda: stage.state().fault is not None, 5.0)
    state = stage.state()
    assert 'reverse hardware limit switch hit at 9.7000 mm' in state.fault
    assert state.reverse_limit and not state.moving
    assert not emu.moving


# --- faults ---------------------------------------------------------------------------------

def test_no_reply_at_open(make_emulator, make_stage):
    emu = make_emulator()
    emu.mute()
    stage = make_stage(emu.port, open_=False, reply_timeout_s=0.3)
    with pytest.raises(DeviceError,
                       match=r'no HW_GET_INFO reply to HW_REQ_INFO from the KDC101 on '
                             + re.escape(emu.port) + r' within 0\.3 s; port closed'):
        stage.open()
    assert_link_closed(stage, emu)


def test_move_timeout_stops_the_stage_and_closes(make_emulator, make_stage):
    emu = make_emulator(position_mm=2.0, homed=True)
    stage = make_stage(emu.port)
    with pytest.raises(DeviceError,
                       match=r'no MOT_MOVE_COMPLETED for the move to 4\.0000 mm .* within '
                             r'0\.4 s; port closed'):
        stage.move_to(4 * MM, 0.5 * MM, timeout_s=0.4)
    assert_link_closed(stage, emu)
    assert wait_until(lambda: not emu.moving, 2.0), 'the stage was left moving'


def test_device_falling_silent_mid_move(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port, status_timeout_s=0.8)
    stage.move_at(1 * MM)
    emu.mute()
    with pytest.raises(DeviceError, match=r'no status update from the KDC101'):
        assert wait_until(lambda: stage.state() is None, 5.0)
    assert_link_closed(stage, emu)


def test_garbled_reply(make_emulator, make_stage):
    emu = make_emulator()
    stage = make_stage(emu.port)
    emu.garble_next()
    with pytest.raises(DeviceError, match=r'garbled reply from the KDC101: unknown message '
                                          r'0x5aa5 \(header bytes a5 5a de ad be ef\)'):
        stage.identify()
    assert_link_closed(stage, emu)
    with pytest.raises(DeviceError, match='garbled'):
        stage.state()


def test_garbled_status_update_while_idle(make_emulator, make_stage):
    emu = make_emulator()
    stage = make_stage(emu.port)
    emu.garble_next(replies_only=False)
    with pytest.raises(DeviceError, match='garbled reply'):
        assert wait_until(lambda: stage.state() is None, 5.0)
    assert_link_closed(stage, emu)


def test_truncated_reply(make_emulator, make_stage):
    emu = make_emulator()
    stage = make_stage(emu.port, frame_timeout_s=0.3)
    emu.truncate_next(keep_bytes=10)
    # the next message may be the HW_GET_INFO reply or a periodic status update: either way the
    # truncation must be named, with the byte counts, and the link closed
    with pytest.raises(DeviceError, match=r'truncated [A-Z_]+ message from the KDC101: '
                                          r'got 4 of \d+ data bytes within 0\.3 s'):
        stage.identify()
    assert_link_closed(stage, emu)


def test_truncated_header(make_emulator, make_stage):
    emu = make_emulator(position_mm=2.0, homed=True)
    stage = make_stage(emu.port, frame_timeout_s=0.3)
    emu.truncate_next(keep_bytes=3)
    with pytest.raises(DeviceError, match=r'truncated message header from the KDC101: got 3 '
                                          r'of 6 bytes'):
        stage.move_to(3 * MM, 1 * MM)
    assert_link_closed(stage, emu)


def test_too_short_message_is_a_clear_error_not_a_struct_error(make_emulator, make_stage):
    emu = make_emulator()
    stage = make_stage(emu.port)
    emu.shorten_next(data_bytes=4)          # the next status update carries 4 of 14 data bytes
    with pytest.raises(DeviceError, match=r'malformed MOT_GET_DCSTATUSUPDATE message from the '
                                          r'KDC101 \(4 data bytes: 91 04 04 00 81 50'):
        assert wait_until(lambda: stage.state() is None, 5.0)
    assert_link_closed(stage, emu)


def test_port_vanishing_mid_move(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    stage.move_at(1 * MM)
    emu.vanish()
    with pytest.raises(DeviceError, match=r'KDC101 port .* (vanished|failed while sending)'):
        assert wait_until(lambda: stage.state() is None, 5.0)
    assert_link_closed(stage, emu)
    with pytest.raises(DeviceError, match='cannot stop the stage: KDC101 port .* is not open'):
        stage.stop()


def test_port_vanishing_before_a_command(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    emu.vanish()
    with pytest.raises(DeviceError, match=r'KDC101 port .* (vanished|failed while sending)'):
        stage.move_to(11 * MM, 1 * MM)
    assert_link_closed(stage, emu)


def stall_after_each_write(stage):
    """pyserial's write timeout as a stalled process meets it: the bytes are handed over,
    then the timeout has passed."""
    write = stage._port.write

    def write_then_time_out(data):
        write(data)
        raise serial.SerialTimeoutException('Write timeout')
    stage._port.write = write_then_time_out


def test_a_write_timeout_after_the_bytes_left_is_not_a_link_failure(make_emulator, make_stage):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    stall_after_each_write(stage)
    stage.move_to(11 * MM, 1 * MM)
    assert emu.position_mm == pytest.approx(11.0, abs=1e-3)


def test_a_write_timeout_with_bytes_stuck_in_the_queue_fails_the_link(make_emulator, make_stage,
                                                                     monkeypatch):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = make_stage(emu.port)
    stall_after_each_write(stage)
    monkeypatch.setattr(type(stage._port), 'out_waiting', property(lambda port: 6))
    with pytest.raises(DeviceError, match=r'failed while sending .*Write timeout'):
        stage.move_to(11 * MM, 1 * MM)
    assert_link_closed(stage, emu)


def test_missing_port(make_stage):
    stage = make_stage('/dev/no-such-kdc101', open_=False)
    with pytest.raises(DeviceError, match='cannot open KDC101 port /dev/no-such-kdc101'):
        stage.open()
    assert_link_closed(stage)


def test_wrong_device_model(make_emulator, make_stage):
    emu = make_emulator(model=b'TDC001')
    stage = make_stage(emu.port, open_=False)
    with pytest.raises(DeviceError, match=r"is a 'TDC001', not a KDC101"):
        stage.open()
    assert_link_closed(stage, emu)


# --- life cycle -----------------------------------------------------------------------------

def test_close_is_idempotent_and_stops_a_moving_stage(make_emulator):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = Kdc101Stage(emu.port)
    stage.close()                       # never opened
    with stage:
        stage.move_at(1 * MM)
        assert wait_until(lambda: emu.moving, 2.0)
    assert wait_until(lambda: not emu.moving, 2.0)
    assert_link_closed(stage, emu)
    stage.close()
    with pytest.raises(DeviceError, match='not open'):
        stage.state()


def test_reopen_after_a_failure(make_emulator, make_stage):
    emu = make_emulator(position_mm=4.0, homed=True)
    stage = make_stage(emu.port)
    emu.garble_next()
    with pytest.raises(DeviceError, match='garbled'):
        stage.identify()
    stage.open()
    assert stage.state().position_m == pytest.approx(4 * MM, abs=1e-7)


def test_homing_speed_is_a_parameter_under_the_ceiling(make_emulator, make_stage):
    emu = make_emulator(position_mm=1.0)
    stage = make_stage(emu.port, homing_speed_m_per_s=1.0 * MM)
    stage.home(timeout_s=20.0)
    assert emu.homeparams['home_velocity'] == round(VELOCITY_UNITS_PER_MM_S)
    assert stage.state().homed
    with pytest.raises(ConfigurationError, match=r'3\.0000 mm/s exceeds the ceiling 2\.400 mm/s'):
        Kdc101Stage(emu.port, homing_speed_m_per_s=3.0 * MM)


# --- the safety envelope itself is refused at configure time ---------------------------------

@pytest.mark.parametrize('kwargs, fragments', [
    (dict(max_position_m=26 * MM), ['max_position_m 26 mm', '[0, 25] mm']),
    (dict(min_position_m=-1 * MM), ['min_position_m -1 mm', '[0, 25] mm']),
    (dict(min_position_m=10 * MM, max_position_m=5 * MM), ['10 mm', 'below', '5 mm']),
    (dict(max_speed_m_per_s=3 * MM), ['3 mm/s', 'stage maximum 2.4 mm/s']),
    (dict(max_speed_m_per_s=0.0), ['0 mm/s', '> 0']),
    (dict(max_acceleration_m_per_s2=-1.0), ['max_acceleration_m_per_s2', '> 0']),
    (dict(max_position_m=float('nan')), ['max_position_m nan', 'finite']),
])
def test_limits_outside_the_stage_are_refused(kwargs, fragments):
    with pytest.raises(ConfigurationError) as info:
        StageLimits(**kwargs)
    for fragment in fragments:
        assert fragment in str(info.value)


def test_limits_at_the_stage_envelope_are_accepted():
    limits = StageLimits(min_position_m=0.0, max_position_m=25 * MM, max_speed_m_per_s=2.4 * MM)
    assert limits.max_position_m == 25 * MM


@pytest.mark.parametrize('kwargs, pattern', [
    (dict(counts_per_mm=0.0), r'counts_per_mm 0\.0 must be finite and > 0'),
    (dict(velocity_per_mm_s=-1.0), r'velocity_per_mm_s -1\.0 must be finite and > 0'),
    (dict(reply_timeout_s=0.0), r'reply_timeout_s 0\.0 s must be finite and > 0 s'),
    (dict(stop_timeout_s=float('inf')), r'stop_timeout_s inf s'),
])
def test_bad_driver_settings_are_refused(kwargs, pattern):
    with pytest.raises(ConfigurationError, match=pattern):
        Kdc101Stage('/dev/null', **kwargs)


# --- the force ceiling: StageGuard around the real driver -----------------------------------

@pytest.fixture
def make_guard(make_emulator, make_stage):
    guards = []

    def make(position_mm=10.0, **kwargs):
        emu = make_emulator(position_mm=position_mm, homed=True)
        guard = StageGuard(make_stage(emu.port), 20.0, **kwargs)
        guard.open()
        guards.append(guard)
        return guard, emu

    yield make
    for guard in guards:
        guard.close()


def test_force_ceiling_stops_a_velocity_pull_and_latches(make_guard):
    guard, emu = make_guard(max_force_age_s=None)
    assert guard.observe_force(5.0) is None
    guard.move_at(1 * MM)
    assert wait_until(lambda: emu.moving, 2.0)

    trip = guard.observe_force(np.array([5.0, 25.0, 7.0]))
    assert isinstance(trip, SafetyLimitError)
    assert 'force 25.000 N above the ceiling 20 N; stage stopped' in str(trip)
    assert not emu.moving                        # stopped before observe_force returned
    assert 'force 25.000 N above the ceiling 20 N' in guard.state().fault
    assert guard.observe_force(30.0) is None     # latched: no second trip, no stop storm

    stopped_mm = emu.position_mm
    with pytest.raises(SafetyLimitError, match=r'velocity move at \+1\.0000 mm/s refused: '
                                               r'force 25\.000 N above'):
        guard.move_at(1 * MM)
    with pytest.raises(SafetyLimitError, match=r'move to 12\.0000 mm refused'):
        guard.move_to(12 * MM, 1 * MM)
    assert emu.position_mm == stopped_mm

    guard.move_to(9.5 * MM, 2.4 * MM, timeout_s=10.0)   # slackening stays allowed
    assert emu.position_mm == pytest.approx(9.5, abs=1e-4)
    with pytest.raises(SafetyLimitError, match=r'latest force 30\.000 N is still above'):
        guard.clear_force_trip()
    guard.observe_force(ForceBlock(t0_s=0.0, period_s=1e-4, force_n=np.full(10, 2.0),
                                   first_index=0))
    guard.clear_force_trip()
    assert guard.state().fault is None
    guard.move_at(1 * MM)
    assert wait_until(lambda: emu.moving, 2.0)
    guard.stop()
    assert not emu.moving


def test_force_ceiling_cuts_a_blocking_move_short(make_guard):
    guard, emu = make_guard(max_force_age_s=None)
    guard.observe_force(1.0)
    errors = []

    def move():
        try:
            guard.move_to(20 * MM, 1 * MM, timeout_s=30.0)
        except Exception as exc:     # noqa: BLE001 - handed to the test thread
            errors.append(exc)

    mover = threading.Thread(target=move, name='kdc101-test-mover')
    mover.start()
    assert wait_until(lambda: emu.moving and emu.position_mm > 10.05, 5.0)
    guard.observe_force(ForceBlock(t0_s=0.0, period_s=1e-4, force_n=np.array([19.0, 21.5]),
                                   first_index=0))
    mover.join(timeout=10.0)
    assert not mover.is_alive()
    (error,) = errors
    assert isinstance(error, SafetyLimitError)
    assert 'force 21.500 N above the ceiling 20 N' in str(error)
    assert not emu.moving and emu.position_mm < 19.0


def test_non_finite_force_trips(make_guard):
    guard, emu = make_guard(max_force_age_s=None)
    assert 'non-finite force reading nan N' in str(guard.observe_force([1.0, float('nan')]))
    with pytest.raises(SafetyLimitError, match='non-finite'):
        guard.move_at(1 * MM)


def test_no_pull_without_fresh_force_readings(make_guard):
    guard, emu = make_guard(max_force_age_s=1.0)
    with pytest.raises(SafetyLimitError, match='refused: no force reading yet'):
        guard.move_at(1 * MM)
    assert MOT_MOVE_VELOCITY not in emu.received
    guard.move_at(-1 * MM)                       # slackening needs no force reading
    assert wait_until(lambda: emu.moving, 2.0)
    guard.stop()

    guard.observe_force(1.0)
    guard.move_at(1 * MM)                        # then the readings stop coming
    assert wait_until(lambda: guard.tripped is not None, 10.0)
    assert re.search(r'no force reading for \d+\.\d\d s \(limit 1 s\)', str(guard.tripped))
    assert wait_until(lambda: not emu.moving, 5.0)
    assert 'cannot be enforced; stage stopped' in guard.state().fault


def test_guard_pull_direction_can_be_reversed(make_guard):
    guard, emu = make_guard(pull_direction=-1, max_force_age_s=None)
    guard.observe_force(50.0)
    with pytest.raises(SafetyLimitError, match=r'velocity move at -1\.0000 mm/s refused'):
        guard.move_at(-1 * MM)
    guard.move_at(1 * MM)
    assert wait_until(lambda: emu.moving, 2.0)
    guard.stop()


def test_guard_keeps_the_stage_limits(make_guard):
    guard, emu = make_guard(max_force_age_s=None)
    guard.observe_force(0.0)
    with pytest.raises(ConfigurationError, match=r'2\.5000 mm/s exceeds the ceiling'):
        guard.move_at(2.5 * MM)
    with pytest.raises(ConfigurationError, match=r'30\.0000 mm is outside'):
        guard.move_to(30 * MM, 1 * MM)
    assert not emu.moving


def test_guard_close_releases_driver_and_watchdog(make_emulator):
    emu = make_emulator(position_mm=10.0, homed=True)
    stage = Kdc101Stage(emu.port)
    with StageGuard(stage, 20.0) as guard:
        assert [t for t in kdc101_threads() if t.name.startswith('stage-guard')]
        guard.observe_force(1.0)
        guard.move_at(1 * MM)
        assert wait_until(lambda: emu.moving, 2.0)
    assert wait_until(lambda: not emu.moving, 2.0)
    assert_link_closed(stage, emu)
    assert not [t for t in kdc101_threads() if t.name.startswith('stage-guard')]


@pytest.mark.parametrize('kwargs, pattern', [
    (dict(force_ceiling_n=0.0), r'force ceiling 0\.0 N must be > 0 N'),
    (dict(force_ceiling_n=150.0), r'150\.0 N .* load cell capacity 111 N'),
    (dict(force_ceiling_n=20.0, pull_direction=0), r'pull direction 0'),
    (dict(force_ceiling_n=20.0, max_force_age_s=-1.0), r'max_force_age_s -1\.0 s'),
])
def test_bad_guard_settings_are_refused(kwargs, pattern):
    with pytest.raises(ConfigurationError, match=pattern):
        StageGuard(Kdc101Stage('/dev/null'), **kwargs)


def test_backends_wrap_the_hardware_stage_in_a_guard():
    from mantis_rig import backends
    guarded = backends.make_stage('hardware', serial_port='/dev/null', force_ceiling_n=15.0)
    assert isinstance(guarded, StageGuard) and isinstance(guarded.stage, Kdc101Stage)
    assert guarded.force_ceiling_n == 15.0 and guarded.max_force_age_s == 0.5
    assert isinstance(backends.make_stage('hardware', serial_port='/dev/null'), Kdc101Stage)
