"""NidaqForceDaq: the load-cell amplifier's voltage on a USB-6363 analog input, in newtons."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import logging
import math
import time
from typing import Optional

import numpy as np

from mantis_rig.hardware.device_interfaces import (
    ConfigurationError,
    DaqConfig,
    DeviceError,
    ForceBlock,
    ForceDaq,
)
from mantis_rig.hardware.nidaq import (
    OVERRUN_ERRORS,
    TIMEOUT_ERRORS,
    USB6363_AI_RANGES_V,
    USB6363_MAX_AI_RATE_HZ,
    close_quietly,
    error_code,
    load_nidaqmx,
    parse_ai_channel,
    to_device_error,
)

log = logging.getLogger(__name__)

TERMINAL_CONFIGS = ('DEFAULT', 'DIFF', 'RSE', 'NRSE', 'PSEUDO_DIFF')
TARE_TIMEOUT_MARGIN_S = 2.0


def validate_config(config: DaqConfig) -> None:
    """Raise ConfigurationError naming the offending value and the USB-6363 limit."""
    parse_ai_channel(config.channel)
    rate_hz = config.sample_rate_hz
    if not rate_hz > 0:
        raise ConfigurationError(f'sample rate {rate_hz} Hz must be > 0 Hz')
    if rate_hz > USB6363_MAX_AI_RATE_HZ:
        raise ConfigurationError(f'sample rate {rate_hz} Hz exceeds the USB-6363 single-channel '
                                 f'limit {USB6363_MAX_AI_RATE_HZ:.0f} Hz')
    range_v = config.input_range_v
    if not any(math.isclose(range_v, r, rel_tol=1e-9) for r in USB6363_AI_RANGES_V):
        allowed = ', '.join(f'±{r:g}' for r in USB6363_AI_RANGES_V)
        raise ConfigurationError(
            f'input range ±{range_v} V is not one of the USB-6363 ranges {allowed} V')
    block = config.block_size
    if isinstance(block, bool) or not isinstance(block, (int, np.integer)) or block <= 0:
        raise ConfigurationError(f'block size {block!r} samples must be an integer ≥ 1')
    if not (config.newtons_per_volt > 0 and math.isfinite(config.newtons_per_volt)):
        raise ConfigurationError(
            f'newtons_per_volt {config.newtons_per_volt} N/V must be finite and > 0 N/V')
    if not abs(config.offset_v) <= range_v:
        raise ConfigurationError(
            f'offset {config.offset_v} V is outside the input range ±{range_v:g} V')


class NidaqForceDaq(ForceDaq):
    """Continuous, sample-clocked acquisition of one analog input, read in blocks.

    Time: the samples are paced by the DAQ's sample clock (its 100 MHz timebase; the rate
    actually used is read back from DAQmx, which rounds it to 100 MHz / integer). `t0_s` is on
    the host clock `clock_s` (default `time.monotonic`, the clock NidaqCameraTrigger uses):
    the host time read just after DAQmx Start returned, plus first_index × period. The start
    latency (sample 0 happens slightly before or after that reading) and the drift between the
    DAQ and host clocks are not measured here.

    Overrun: the buffer never overwrites unread samples. If the host falls behind (DAQmx error
    -200279) or the device FIFO overflows (-200010), read_block restarts the acquisition and
    returns the first block after the gap with `overrun=True`; the gap (lost samples, and the
    unfinished block before it) shows as a jump in `first_index`, estimated from the host clock
    at the restart, and `overrun_count` counts the events. A second overrun straight after a
    restart raises DeviceError.

    Read timeout: DeviceError; the task keeps running and the samples that did arrive are kept,
    so the next read_block continues without a gap. Any other DAQmx error (device unplugged,
    ...) closes the task and raises DeviceError: open() again to continue.
    """

    max_sample_rate_hz = USB6363_MAX_AI_RATE_HZ

    def __init__(self, config: Optional[DaqConfig] = None, *, terminal_config: str = 'DEFAULT',
                 buffer_duration_s: float = 1.0,
                 clock_s: Callable[[], float] = time.monotonic):
        if terminal_config not in TERMINAL_CONFIGS:
            raise ConfigurationError(f'terminal configuration {terminal_config!r} is not one of '
                                     f'{", ".join(TERMINAL_CONFIGS)}')
        if not buffer_duration_s > 0:
            raise ConfigurationError(f'buffer duration {buffer_duration_s} s must be > 0 s')
        self._terminal_config = terminal_config
        self._buffer_duration_s = buffer_duration_s
        self._clock_s = clock_s
        self._daqmx = None
        self._task = None
        self._reader = None
        self._running = False
        self.overrun_count = 0
        self._config = DaqConfig()
        self.configure(config or DaqConfig())

    @property
    def config(self) -> DaqConfig:
        return self._config

    @property
    def period_s(self) -> float:
        """Sample period; once opened, the one DAQmx actually uses."""
        return self._period_s

    # --- life cycle ----------------------------------------------------------------------------

    def open(self) -> None:
        if self._task is not None:
            return
        self._daqmx = load_nidaqmx()
        self._create_task()

    def close(self) -> None:
        self._running = False
        task, self._task, self._reader = self._task, None, None
        close_quietly(task)

    def configure(self, config: DaqConfig) -> None:
        validate_config(config)
        if self._running:
            raise DeviceError('configure() while acquiring: stop() first')
        self._config = config
        self._period_s = 1.0 / config.sample_rate_hz
        self._buffer_v = np.zeros(config.block_size)
        self._filled = 0
        if self._task is not None:
            self._create_task()

    def _create_task(self) -> None:
        close_quietly(self._task)
        self._task = self._reader = None
        daqmx, config = self._daqmx, self._config
        constants = daqmx.constants
        try:
            task = daqmx.Task()
        except daqmx.errors.Error as exc:
            raise to_device_error('creating the DAQmx task', exc) from exc
        try:
            task.ai_channels.add_ai_voltage_chan(
                physical_channel=config.channel,
                terminal_config=constants.TerminalConfiguration[self._terminal_config],
                min_val=-config.input_range_v, max_val=config.input_range_v,
                units=constants.VoltageUnits.VOLTS)
            task.in_stream.overwrite = constants.OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES
            self._apply_timing(task, constants.AcquisitionType.CONTINUOUS)
            task.control(constants.TaskMode.TASK_VERIFY)
            reader = daqmx.stream_readers.AnalogSingleChannelReader(task.in_stream)
        except daqmx.errors.Error as exc:
            close_quietly(task)
            raise to_device_error(f'setting up {config.channel}', exc) from exc
        self._task, self._reader = task, reader

    def _apply_timing(self, task, sample_mode, samples: Optional[int] = None) -> None:
        config = self._config
        if samples is None:   # continuous: the host buffer size
            samples = max(10 * config.block_size,
                          math.ceil(config.sample_rate_hz * self._buffer_duration_s))
        task.timing.cfg_samp_clk_timing(config.sample_rate_hz, sample_mode=sample_mode,
                                        samps_per_chan=samples)
        self._period_s = 1.0 / task.timing.samp_clk_rate

    def _require_task(self):
        if self._task is None:
            raise DeviceError(f'the DAQ task for {self._config.channel} is not open: open() first')
        return self._task

    def _fail(self, context: str, exc: BaseException) -> DeviceError:
        """Close the task after an unrecoverable DAQmx error; return the error to raise."""
        error = to_device_error(f'{self._config.channel}: {context}', exc)
        self.close()
        return error

    # --- acquisition ---------------------------------------------------------------------------

    def start(self) -> None:
        task = self._require_task()
        if self._running:
            return
        try:
            self._apply_timing(task, self._daqmx.constants.AcquisitionType.CONTINUOUS)
            task.start()
        except self._daqmx.errors.Error as exc:
            raise self._fail('starting the acquisition', exc) from exc
        self._anchor_time_s = self._clock_s()
        self._anchor_index = self._next_index = self._filled = 0
        self._running = True

    def stop(self) -> None:
        if not self._running:
            return
        self._running = False
        try:
            self._task.stop()
        except self._daqmx.errors.Error as exc:
            raise self._fail('stopping the acquisition', exc) from exc

    def read_block(self, timeout_s: float = 1.0) -> ForceBlock:
        if not self._running:
            raise DeviceError(f'{self._config.channel}: read_block() before start()')
        daq_error = self._daqmx.errors.DaqError
        overrun = False
        try:
            self._fill_buffer(timeout_s)
        except daq_error as exc:
            if error_code(exc) not in OVERRUN_ERRORS:
                raise self._read_failure(exc, timeout_s) from exc
            self._restart_after_overrun(exc)
            overrun = True
            try:
                self._fill_buffer(timeout_s)
            except daq_error as again:
                raise self._read_failure(again, timeout_s) from again
        return self._take_block(overrun)

    def _fill_buffer(self, timeout_s: float) -> None:
        wanted = self._config.block_size - self._filled
        try:
            got = self._reader.read_many_sample(
                self._buffer_v[self._filled:], number_of_samples_per_channel=wanted,
                timeout=timeout_s)
        except self._daqmx.errors.DaqError as exc:
            # A timed-out read still delivers what had arrived; keep it so no sample is skipped.
            partial = getattr(exc, 'samps_per_chan_read', 0) or 0
            self._filled += max(0, min(wanted, int(partial)))
            raise
        if got != wanted:
            raise DeviceError(f'{self._config.channel}: DAQmx returned {got} samples, '
                              f'asked for {wanted}')
        self._filled += got

    def _read_failure(self, exc: BaseException, timeout_s: float) -> DeviceError:
        code = error_code(exc)
        config = self._config
        if code in TIMEOUT_ERRORS:
            return DeviceError(
                f'{config.channel}: no block of {config.block_size} samples within the '
                f'{timeout_s:g} s timeout (a block takes {config.block_size * self._period_s:g} s '
                f'at {1.0 / self._period_s:g} Hz); {self._filled} samples that did arrive are '
                f'kept for the next read_block (DAQmx error {code} {TIMEOUT_ERRORS[code]})')
        if code in OVERRUN_ERRORS:
            return self._fail('overrun again right after restarting from an overrun', exc)
        return self._fail('reading samples', exc)

    def _restart_after_overrun(self, exc: BaseException) -> None:
        self.overrun_count += 1
        log.warning('%s: %s, restarting the acquisition; samples were lost',
                    self._config.channel, OVERRUN_ERRORS[error_code(exc)])
        errors = self._daqmx.errors
        try:
            self._task.stop()
        except errors.DaqError as stop_exc:
            if error_code(stop_exc) not in OVERRUN_ERRORS:   # stop may report the overrun again
                raise self._fail('stopping after an overrun', stop_exc) from stop_exc
        try:
            self._task.start()
        except errors.Error as start_exc:
            raise self._fail('restarting after an overrun', start_exc) from start_exc
        now_s = self._clock_s()
        elapsed = round((now_s - self._anchor_time_s) / self._period_s)
        self._anchor_index = max(self._next_index, self._anchor_index + elapsed)
        self._anchor_time_s = now_s
        self._next_index = self._anchor_index
        self._filled = 0

    def _take_block(self, overrun: bool) -> ForceBlock:
        config = self._config
        first_index = self._next_index
        t0_s = self._anchor_time_s + (first_index - self._anchor_index) * self._period_s
        force_n = (self._buffer_v - config.offset_v) * config.newtons_per_volt
        self._next_index += config.block_size
        self._filled = 0
        return ForceBlock(t0_s=t0_s, period_s=self._period_s, force_n=force_n,
                          first_index=first_index, overrun=overrun)

    # --- tare ----------------------------------------------------------------------------------

    def tare(self, duration_s: float = 0.2) -> float:
        """Average `duration_s` of input (a finite acquisition; not while acquiring) as zero."""
        if not (duration_s > 0 and math.isfinite(duration_s)):
            raise ConfigurationError(f'tare duration {duration_s} s must be finite and > 0 s')
        task = self._require_task()
        if self._running:
            raise DeviceError('tare() while acquiring: stop() first (tare with the tendon slack)')
        daqmx = self._daqmx
        samples = max(1, round(duration_s * self._config.sample_rate_hz))
        volts = np.zeros(samples)
        try:
            self._apply_timing(task, daqmx.constants.AcquisitionType.FINITE, samples)
            task.start()
            got = self._reader.read_many_sample(
                volts, number_of_samples_per_channel=samples,
                timeout=samples * self._period_s + TARE_TIMEOUT_MARGIN_S)
            task.stop()
        except daqmx.errors.Error as exc:
            raise self._fail('tare', exc) from exc
        if got != samples:
            raise DeviceError(f'{self._config.channel}: tare read {got} of {samples} samples')
        offset_v = float(np.mean(volts))
        self._config = replace(self._config, offset_v=offset_v)
        return offset_v
