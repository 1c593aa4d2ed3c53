"""The NI USB-6363 backends against a fake of nidaqmx, and that fake against the real package."""
from dataclasses import replace
from enum import Enum
import importlib
import importlib.util
import inspect
import os
import sys

import fakes_nidaq
from fakes_nidaq import FakeDaqSystem
import numpy as np
import pytest

from mantis_rig.hardware.device_interfaces import (
    CameraConfig,
    ConfigurationError,
    DaqConfig,
    DeviceError,
)
from mantis_rig.hardware.nidaq import OVERRUN_ERRORS, REMOVED_ERRORS, TIMEOUT_ERRORS
from mantis_rig.hardware.nidaq_force import NidaqForceDaq
from mantis_rig.hardware.nidaq_trigger import NidaqCameraTrigger

VOLTS_PER_SAMPLE = 1e-4
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def ramp_v(index):
    """Every sample different, so a skipped or repeated sample changes the values."""
    return VOLTS_PER_SAMPLE * index


class ManualClock:
    """A host clock the test sets; `step_s` advances it on every reading."""

    def __init__(self, now_s=100.0, step_s=0.0):
        self.now_s, self.step_s = now_s, step_s

    def __call__(self):
        now_s = self.now_s
        self.now_s += self.step_s
        return now_s


@pytest.fixture
def system(monkeypatch):
    return FakeDaqSystem(signal_v=ramp_v).install(monkeypatch)


@pytest.fixture
def clock():
    return ManualClock()


CONFIG = DaqConfig(channel='Dev1/ai0', sample_rate_hz=20_000.0, input_range_v=10.0,
                   newtons_per_volt=11.12, offset_v=0.25, block_size=1000)


def open_daq(clock, config=CONFIG, **kwargs):
    daq = NidaqForceDaq(config, clock_s=clock, **kwargs)
    daq.open()
    return daq


# --- block reads -------------------------------------------------------------------------------

def test_blocks_are_scaled_consecutive_and_timed(system, clock):
    daq = open_daq(clock)
    daq.start()
    blocks = [daq.read_block(timeout_s=0.5) for _ in range(5)]

    period_s = 1 / 20_000
    for k, block in enumerate(blocks):
        index = np.arange(k * 1000, (k + 1) * 1000)
        assert block.first_index == k * 1000
        assert block.overrun is False
        assert block.period_s == pytest.approx(period_s, rel=1e-12)
        assert block.t0_s == pytest.approx(100.0 + k * 1000 * period_s, rel=1e-12)
        np.testing.assert_allclose(block.force_n, (ramp_v(index) - 0.25) * 11.12, atol=1e-12)
    volts = np.concatenate([b.force_n for b in blocks]) / 11.12 + 0.25
    np.testing.assert_allclose(np.diff(volts), VOLTS_PER_SAMPLE, rtol=1e-6)   # none skipped
    assert [r[1:] for r in system.reads] == [(1000, 0.5)] * 5


def test_task_is_set_up_as_configured(system, clock):
    config = replace(CONFIG, channel='Dev1/ai3', input_range_v=2.0)
    daq = open_daq(clock, config, terminal_config='DIFF')
    daq.start()
    (task,) = system.open_tasks()
    (channel,) = task.added_channels
    constants = sys.modules['nidaqmx.constants']
    assert channel['name'] == 'Dev1/ai3'
    assert (channel['min_val'], channel['max_val']) == (-2.0, 2.0)
    assert channel['terminal_config'] is constants.TerminalConfiguration.DIFF
    assert channel['units'] is constants.VoltageUnits.VOLTS
    assert task.in_stream.overwrite is constants.OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES
    assert task.timing.sample_mode is constants.AcquisitionType.CONTINUOUS
    assert task.timing.samps_per_chan >= 10 * config.block_size


def test_period_is_the_rate_daqmx_actually_uses(system, clock):
    daq = open_daq(clock, replace(CONFIG, sample_rate_hz=30_000.0))
    daq.start()
    daq.read_block()
    second = daq.read_block()
    period_s = 3333 / 100e6            # 100 MHz / 3333: DAQmx's 30,003 Hz
    assert second.period_s == pytest.approx(period_s, rel=1e-12)
    assert second.t0_s == pytest.approx(100.0 + 1000 * period_s, rel=1e-12)


def test_blocks_do_not_share_the_read_buffer(system, clock):
    daq = open_daq(clock)
    daq.start()
    first = daq.read_block()
    kept = first.force_n.copy()
    daq.read_block()
    np.testing.assert_array_equal(first.force_n, kept)


def test_input_clipped_at_the_range_reads_as_the_range(monkeypatch, clock):
    FakeDaqSystem(signal_v=lambda index: np.full(index.shape, 7.0)).install(monkeypatch)
    daq = open_daq(clock, replace(CONFIG, input_range_v=5.0, offset_v=0.0,
                                  newtons_per_volt=2.0))
    daq.start()
    np.testing.assert_allclose(daq.read_block().force_n, 10.0)


def test_restart_starts_indices_and_time_again(system, clock):
    daq = open_daq(clock)
    daq.start()
    daq.read_block()
    daq.stop()
    clock.now_s = 200.0
    daq.start()
    block = daq.read_block()
    assert (block.first_index, block.t0_s) == (0, 200.0)


# --- tare --------------------------------------------------------------------------------------

def test_tare_averages_a_finite_acquisition_and_zeroes_the_force(monkeypatch, clock):
    wobble = np.array([0.01, -0.01])
    system = FakeDaqSystem(signal_v=lambda index: 0.37 + wobble[index % 2]).install(monkeypatch)
    daq = open_daq(clock, replace(CONFIG, sample_rate_hz=10_000.0, offset_v=0.0))

    assert daq.tare(duration_s=0.1) == pytest.approx(0.37, abs=1e-12)
    assert daq.config.offset_v == pytest.approx(0.37, abs=1e-12)
    (task,) = system.open_tasks()
    assert system.reads[-1][1] == 1000                     # 0.1 s at 10 kHz
    constants = sys.modules['nidaqmx.constants']
    assert not task.running

    daq.start()
    assert task.timing.sample_mode is constants.AcquisitionType.CONTINUOUS
    force_n = daq.read_block().force_n
    np.testing.assert_allclose(force_n, wobble[np.arange(1000) % 2] * 11.12, atol=1e-9)


def test_tare_is_refused_while_acquiring_or_for_a_bad_duration(system, clock):
    daq = open_daq(clock)
    for duration_s in (0.0, -1.0, float('nan')):
        with pytest.raises(ConfigurationError, match='tare duration'):
            daq.tare(duration_s)
    daq.start()
    with pytest.raises(DeviceError, match='stop'):
        daq.tare(0.1)


# --- faults ------------------------------------------------------------------------------------

@pytest.mark.parametrize('code', [-200279, -200010])
def test_overrun_restarts_and_flags_the_next_block(system, clock, code):
    daq = open_daq(clock)
    daq.start()
    daq.read_block()
    daq.read_block()
    system.inject_overrun(lost_samples=1500, code=code)
    period_s = 1 / 20_000
    clock.now_s = 100.0 + 3500 * period_s       # the host time when the restart returns

    block = daq.read_block()
    assert block.overrun is True
    assert block.first_index == 3500
    assert block.t0_s == pytest.approx(100.0 + 3500 * period_s, rel=1e-12)
    np.testing.assert_allclose(block.force_n, (ramp_v(np.arange(3500, 4500)) - 0.25) * 11.12,
                               atol=1e-12)
    actions = [action for _, action, _ in system.events]
    assert actions[-2:] == ['stop', 'start']
    assert daq.overrun_count == 1

    after = daq.read_block()
    assert (after.first_index, after.overrun) == (4500, False)


def test_an_overrun_right_after_the_restart_is_an_error(system, clock):
    daq = open_daq(clock)
    daq.start()
    system.inject_overrun(lost_samples=10)
    system.inject_overrun(lost_samples=10)
    with pytest.raises(DeviceError, match='overrun again') as info:
        daq.read_block()
    assert '-200279' in str(info.value)
    assert system.open_tasks() == []


def test_timeout_is_a_clear_error_and_keeps_what_arrived(system, clock):
    daq = open_daq(clock)
    daq.start()
    daq.read_block()
    system.inject_timeout(delivered=400)
    with pytest.raises(DeviceError, match='timeout') as info:
        daq.read_block(timeout_s=0.25)
    message = str(info.value)
    assert '0.25 s' in message and '400 samples' in message and '-200284' in message
    assert system.open_tasks()                                  # still acquiring

    block = daq.read_block()
    assert block.first_index == 1000
    np.testing.assert_allclose(block.force_n, (ramp_v(np.arange(1000, 2000)) - 0.25) * 11.12,
                               atol=1e-12)
    assert system.reads[-1][1] == 600                           # only the rest was asked for


def test_device_removed_while_reading_closes_the_task(system, clock):
    daq = open_daq(clock)
    daq.start()
    daq.read_block()
    system.remove_device()
    with pytest.raises(DeviceError, match='disconnected') as info:
        daq.read_block()
    assert '-50405' in str(info.value)
    (task,) = system.tasks
    assert task.closed and task.close_calls == 1
    daq.close()
    assert task.close_calls == 1
    with pytest.raises(DeviceError, match='before start'):
        daq.read_block()


def test_failed_open_leaves_no_task_and_close_is_idempotent(system, clock):
    daq = NidaqForceDaq(replace(CONFIG, channel='Dev2/ai0'), clock_s=clock)
    with pytest.raises(DeviceError, match='-200220'):
        daq.open()
    assert system.tasks and system.open_tasks() == []
    daq.close()
    daq.close()


def test_context_manager_closes_the_task_on_error(system, clock):
    with pytest.raises(RuntimeError, match='boom'):
        with NidaqForceDaq(CONFIG, clock_s=clock) as daq:
            daq.start()
            raise RuntimeError('boom')
    (task,) = system.tasks
    assert task.closed and task.close_calls == 1


def test_life_cycle_misuse_is_refused(system, clock):
    daq = NidaqForceDaq(CONFIG, clock_s=clock)
    with pytest.raises(DeviceError, match='open'):
        daq.start()
    daq.open()
    with pytest.raises(DeviceError, match='before start'):
        daq.read_block()
    daq.start()
    with pytest.raises(DeviceError, match='stop'):
        daq.configure(CONFIG)


def test_configure_when_open_rebuilds_the_task(system, clock):
    daq = open_daq(clock)
    daq.configure(replace(CONFIG, channel='Dev1/ai5'))
    old, new = system.tasks
    assert old.closed and not new.closed
    assert new.added_channels[0]['name'] == 'Dev1/ai5'


# --- configuration refused ---------------------------------------------------------------------

BAD_CONFIGS = [
    ('sample_rate_hz', 2_500_000.0, ['2500000', '2000000']),
    ('sample_rate_hz', 0.0, ['0.0 Hz', '> 0']),
    ('sample_rate_hz', -5.0, ['-5.0 Hz', '> 0']),
    ('sample_rate_hz', float('nan'), ['nan Hz', '> 0']),
    ('input_range_v', 3.0, ['±3.0 V', '±0.1', '±10']),
    ('input_range_v', 20.0, ['±20.0 V', '±10']),
    ('input_range_v', -10.0, ['±-10.0 V', '±10']),
    ('channel', 'Dev1/ao0', ["'Dev1/ao0'", '<device>/ai<K>']),
    ('channel', 'Dev1', ["'Dev1'", '<device>/ai<K>']),
    ('channel', 'Dev1/ai0:3', ["'Dev1/ai0:3'", '<device>/ai<K>']),
    ('channel', '/Dev1/ai0', ["'/Dev1/ai0'", '<device>/ai<K>']),
    ('channel', 'Dev1/ai32', ["'Dev1/ai32'", 'ai0..ai31']),
    ('block_size', 0, ['block size 0', '≥ 1']),
    ('block_size', -10, ['block size -10', '≥ 1']),
    ('block_size', 10.5, ['block size 10.5', 'integer']),
    ('newtons_per_volt', 0.0, ['newtons_per_volt 0.0', '> 0']),
    ('newtons_per_volt', -11.12, ['newtons_per_volt -11.12', '> 0']),
    ('offset_v', 10.5, ['offset 10.5 V', '±10 V']),
]


@pytest.mark.parametrize('field, value, fragments', BAD_CONFIGS)
def test_bad_configuration_is_refused_naming_value_and_limit(system, clock, field, value,
                                                             fragments):
    daq = open_daq(clock)
    with pytest.raises(ConfigurationError) as info:
        daq.configure(replace(CONFIG, **{field: value}))
    for fragment in fragments:
        assert fragment in str(info.value)
    assert daq.config == CONFIG
    with pytest.raises(ConfigurationError):
        NidaqForceDaq(replace(CONFIG, **{field: value}))


@pytest.mark.parametrize('channel', ['Dev1/ai0', 'Dev1/ai31', 'PXI1Slot2/ai0', 'Load_DAQ/ai7'])
def test_channel_names_that_parse(channel):
    assert NidaqForceDaq(replace(CONFIG, channel=channel)).config.channel == channel


@pytest.mark.parametrize('rate_hz', [2_000_000.0, 1.0])
@pytest.mark.parametrize('range_v', [0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0])
def test_limits_themselves_are_accepted(rate_hz, range_v):
    config = replace(CONFIG, sample_rate_hz=rate_hz, input_range_v=range_v, offset_v=0.0)
    assert NidaqForceDaq(config).config == config


def test_bad_terminal_configuration_is_refused():
    with pytest.raises(ConfigurationError, match="'BOGUS'"):
        NidaqForceDaq(CONFIG, terminal_config='BOGUS')


# --- camera trigger ----------------------------------------------------------------------------

def test_trigger_on_a_digital_line(system):
    sleeps = []
    clock = ManualClock(now_s=10.0, step_s=0.002)
    trigger = NidaqCameraTrigger('Dev1/port0/line3', pulse_width_s=5e-4, clock_s=clock,
                                 sleep_s=sleeps.append)
    with trigger:
        (task,) = system.open_tasks()
        assert task.added_channels[0]['name'] == 'Dev1/port0/line3'
        assert system.line_levels == {'Dev1/port0/line3': False}          # idle low
        assert trigger.status().armed is False
        with pytest.raises(DeviceError, match='arm'):
            trigger.trigger()

        trigger.arm(CameraConfig(frame_rate_hz=19_000.0, pre_trigger_s=0.05,
                                 post_trigger_s=0.02))
        assert trigger.status().armed is True
        time_s = trigger.trigger()

        assert time_s == pytest.approx(10.001)            # midway through the rising write
        writes = [detail for _, action, detail in system.events if action == 'write']
        assert writes == [False, True, False]
        assert sleeps == [5e-4]
        status = trigger.status()
        assert (status.armed, status.triggered, status.trigger_time_s) == (False, True, time_s)
        with pytest.raises(DeviceError, match='arm\\(\\) again'):
            trigger.trigger()
        trigger.arm(CameraConfig())
        assert trigger.status().triggered is False
    assert task.closed and task.close_calls == 1


def test_active_low_trigger_idles_high(system):
    with NidaqCameraTrigger('Dev1/port1/line7', active_high=False, sleep_s=lambda s: None) as t:
        t.arm(CameraConfig())
        t.trigger()
    writes = [detail for _, action, detail in system.events if action == 'write']
    assert writes == [True, False, True]


def test_trigger_on_a_counter(system):
    clock = ManualClock(now_s=5.0, step_s=0.001)
    with NidaqCameraTrigger('Dev1/ctr0', pulse_width_s=2e-4, clock_s=clock) as trigger:
        assert trigger.mode == 'counter'
        (task,) = system.open_tasks()
        assert task.committed
        trigger.arm(CameraConfig())
        time_s = trigger.trigger()
    constants = sys.modules['nidaqmx.constants']
    (pulse,) = system.pulses
    assert pulse['name'] == 'Dev1/ctr0'
    assert pulse['high_time'] == 2e-4 and pulse['idle_state'] is constants.Level.LOW
    assert pulse['units'] is constants.TimeUnits.SECONDS
    actions = [action for _, action, _ in system.events if action != 'control']
    assert actions == ['start', 'wait_until_done', 'stop', 'close']
    assert time_s == pytest.approx(5.0005)


def test_trigger_fails_clearly_when_the_device_is_gone(system):
    trigger = NidaqCameraTrigger('Dev1/ctr1')
    trigger.open()
    trigger.arm(CameraConfig())
    system.remove_device()
    with pytest.raises(DeviceError, match='disconnected'):
        trigger.trigger()
    assert system.open_tasks() == []
    trigger.close()
    assert trigger.status().triggered is False


@pytest.mark.parametrize('config, fragments', [
    (CameraConfig(frame_rate_hz=0.0), ['frame rate 0.0', '> 0']),
    (CameraConfig(frame_rate_hz=-100.0), ['frame rate -100.0', '> 0']),
    (CameraConfig(frame_rate_hz=40_000.0), ['40000', '37000']),
    (CameraConfig(pre_trigger_s=-0.01), ['pre_trigger_s -0.01', '≥ 0']),
    (CameraConfig(post_trigger_s=float('nan')), ['post_trigger_s nan', '≥ 0']),
])
def test_bad_arm_is_refused(system, config, fragments):
    with NidaqCameraTrigger() as trigger:
        with pytest.raises(ConfigurationError) as info:
            trigger.arm(config)
        for fragment in fragments:
            assert fragment in str(info.value)
        assert trigger.status().armed is False


def test_frame_rate_ceiling_is_a_parameter(system):
    with NidaqCameraTrigger(max_frame_rate_hz=50_000.0) as trigger:
        trigger.arm(CameraConfig(frame_rate_hz=40_000.0))
        assert trigger.status().armed
    assert NidaqCameraTrigger().max_frame_rate_hz == 37_000.0


@pytest.mark.parametrize('output', ['Dev1/port0/line32', 'Dev1/port1/line8', 'Dev1/port3/line0',
                                    'Dev1/ctr4', 'Dev1/ai0', 'Dev1/port0', ''])
def test_bad_trigger_output_is_refused(output):
    with pytest.raises(ConfigurationError, match=repr(output).replace('/', '.')):
        NidaqCameraTrigger(output)


@pytest.mark.parametrize('width_s', [0.0, -1e-3, 2.0, float('nan')])
def test_bad_pulse_width_is_refused(width_s):
    with pytest.raises(ConfigurationError, match='pulse width'):
        NidaqCameraTrigger(pulse_width_s=width_s)


# --- nidaqmx or its driver missing -------------------------------------------------------------

@pytest.mark.parametrize('make', [lambda: NidaqForceDaq(CONFIG), lambda: NidaqCameraTrigger()])
def test_missing_nidaqmx_is_a_clear_error(monkeypatch, make):
    monkeypatch.setitem(sys.modules, 'nidaqmx', None)
    device = make()
    with pytest.raises(DeviceError) as info:
        device.open()
    message = str(info.value)
    assert 'pip install mantis_rig[nidaq]' in message and 'pip install nidaqmx' in message
    assert 'NI-DAQmx' in message
    device.close()


def test_missing_driver_is_a_clear_error(monkeypatch):
    system = FakeDaqSystem().install(monkeypatch)
    system.driver_installed = False
    with pytest.raises(DeviceError, match='Install NI-DAQmx'):
        NidaqForceDaq(CONFIG).open()


# --- the fake against the real nidaqmx 1.7.0 (skipped where it is not installed) ---------------

def real_nidaqmx():
    if importlib.util.find_spec('nidaqmx') is None:
        pytest.skip('nidaqmx is not installed (pip install nidaqmx==1.7.0 to run this check)')
    return importlib.import_module('nidaqmx')


def normalized_signature(function):
    def default(value):
        if value is inspect.Parameter.empty or isinstance(value, (int, float, str, type(None))):
            return value
        if isinstance(value, Enum):
            return type(value).__name__, value.name
        return type(value).__name__
    return [(p.name, p.kind, default(p.default))
            for p in inspect.signature(function).parameters.values()]


def test_fake_matches_the_real_nidaqmx_api():
    real_nidaqmx()
    from nidaqmx import errors, stream_readers
    from nidaqmx.task import InStream, Task, Timing
    from nidaqmx.task.collections import (
        AIChannelCollection,
        COChannelCollection,
        DOChannelCollection,
    )
    fake = fakes_nidaq
    methods = [
        (fake.Task, Task, ['__init__', '__enter__', '__exit__', 'start', 'stop', 'close',
                           'write', 'wait_until_done', 'control']),
        (fake.AIChannelCollection, AIChannelCollection, ['add_ai_voltage_chan']),
        (fake.DOChannelCollection, DOChannelCollection, ['add_do_chan']),
        (fake.COChannelCollection, COChannelCollection, ['add_co_pulse_chan_time']),
        (fake.Timing, Timing, ['cfg_samp_clk_timing']),
        (fake.AnalogSingleChannelReader, stream_readers.AnalogSingleChannelReader,
         ['__init__', 'read_many_sample']),
        (fake.DaqError, errors.DaqError, ['__init__']),
        (fake.DaqReadError, errors.DaqReadError, ['__init__']),
    ]
    for fake_cls, real_cls, names in methods:
        for name in names:
            assert normalized_signature(getattr(fake_cls, name)) == \
                normalized_signature(getattr(real_cls, name)), f'{real_cls.__name__}.{name}'
    properties = [
        (fake.Task, Task, ['ai_channels', 'do_channels', 'co_channels', 'timing', 'in_stream']),
        (fake.Timing, Timing, ['samp_clk_rate']),
        (fake.InStream, InStream, ['overwrite']),
        (fake.DaqError, errors.DaqError, ['error_code']),
        (fake.DaqReadError, errors.DaqReadError, ['samps_per_chan_read']),
    ]
    for fake_cls, real_cls, names in properties:
        for name in names:
            assert isinstance(inspect.getattr_static(real_cls, name), property), name
            assert isinstance(inspect.getattr_static(fake_cls, name), property), name
    for name in ('Error', 'DaqNotFoundError', 'DaqNotSupportedError', 'DaqError',
                 'DaqReadError', 'DaqResourceWarning'):
        fake_bases = [b.__name__ for b in getattr(fake, name).__mro__]
        real_bases = [b.__name__ for b in getattr(errors, name).__mro__]
        assert fake_bases == real_bases, name


def test_fake_system_api_matches_the_real_nidaqmx():
    """The device listing mantis doctor reads: nidaqmx.system's System, Device and their
    collections."""
    real_nidaqmx()
    from nidaqmx.system import Device, System
    from nidaqmx.system._collections.device_collection import DeviceCollection
    from nidaqmx.system._collections.physical_channel_collection import (
        PhysicalChannelCollection,
    )
    fake = fakes_nidaq
    assert isinstance(inspect.getattr_static(System, 'local'), staticmethod)
    assert isinstance(inspect.getattr_static(fake.System, 'local'), staticmethod)
    methods = [
        (fake.Device, Device, ['__init__', 'self_test_device']),
        (fake.DeviceCollection, DeviceCollection, ['__iter__', '__len__', '__getitem__']),
        (fake.PhysicalChannelCollection, PhysicalChannelCollection,
         ['__iter__', '__len__', '__getitem__', '__contains__']),
    ]
    for fake_cls, real_cls, names in methods:
        for name in names:
            if name == '__init__' and fake_cls is not fake.Device:
                continue
            assert normalized_signature(getattr(fake_cls, name)) == \
                normalized_signature(getattr(real_cls, name)), f'{real_cls.__name__}.{name}'
    properties = [
        (fake.System, System, ['devices', 'driver_version']),
        (fake.Device, Device, ['name', 'product_type', 'dev_serial_num', 'dev_is_simulated',
                               'ai_physical_chans', 'do_lines', 'co_physical_chans']),
        (fake.DeviceCollection, DeviceCollection, ['device_names']),
        (fake.PhysicalChannelCollection, PhysicalChannelCollection, ['channel_names']),
    ]
    for fake_cls, real_cls, names in properties:
        for name in names:
            assert isinstance(inspect.getattr_static(real_cls, name), property), name
            assert isinstance(inspect.getattr_static(fake_cls, name), property), name


def test_fake_constants_and_error_codes_match_the_real_ones():
    real_nidaqmx()
    from nidaqmx import constants
    from nidaqmx.error_codes import DAQmxErrors
    for fake_enum in fakes_nidaq.CONSTANT_ENUMS:
        real_enum = getattr(constants, fake_enum.__name__)
        for member in fake_enum:
            assert real_enum[member.name].value == member.value, f'{fake_enum.__name__}.{member}'
    assert constants.READ_ALL_AVAILABLE == fakes_nidaq.READ_ALL_AVAILABLE
    used = {**OVERRUN_ERRORS, **TIMEOUT_ERRORS, **REMOVED_ERRORS}
    used.update({code: name for name, code in fakes_nidaq.FAKE_ERROR_CODES.items()})
    for code, name in used.items():
        assert DAQmxErrors[name].value == code, name
