"""NidaqCameraTrigger: the Phantom camera's TTL trigger from a USB-6363 DO line or counter."""
from __future__ import annotations

from collections.abc import Callable
import math
import time
from typing import Optional

from mantis_rig.hardware.device_interfaces import (
    CameraConfig,
    CameraStatus,
    CameraTrigger,
    ConfigurationError,
    DeviceError,
    check_camera_config,
)
from mantis_rig.hardware.nidaq import (
    close_quietly,
    load_nidaqmx,
    parse_trigger_output,
    to_device_error,
)

PHANTOM_V73_MAX_FRAME_RATE_HZ = 37_000.0    # the highest rate the lab used on its Phantom v7.3
MAX_PULSE_WIDTH_S = 1.0
COUNTER_DONE_MARGIN_S = 1.0


class NidaqCameraTrigger(CameraTrigger):
    """One TTL pulse on `output`: a DO line ('Dev1/port0/line0') or a counter ('Dev1/ctr0').

    DO line: software-timed; the line goes active, stays for at least `pulse_width_s`
    (host sleep, so possibly longer), and returns to idle. Counter: one hardware-timed pulse of
    `pulse_width_s` on the counter's default output terminal (PFI12 for ctr0 on a USB-6363),
    committed at open() so that trigger() only starts it.
    `active_high` selects the edge the camera sees first (idle low, pulse high by default);
    it must match the camera's trigger setting.

    trigger() returns the host-clock time (`clock_s`, default time.monotonic: the clock of
    NidaqForceDaq.t0_s) halfway through the call that drives the active edge (DO write or
    counter start); the edge itself comes somewhere within that call plus the USB latency.

    arm() validates and records the camera settings; the camera itself is set up in its own
    software. frame_timestamps() stays None: the DAQ sees no frames (the camera's saved file
    has their times).
    """

    def __init__(self, output: str = 'Dev1/port0/line0', *, pulse_width_s: float = 1e-3,
                 max_frame_rate_hz: float = PHANTOM_V73_MAX_FRAME_RATE_HZ,
                 active_high: bool = True,
                 clock_s: Callable[[], float] = time.monotonic,
                 sleep_s: Callable[[float], None] = time.sleep):
        self._kind, self._output = parse_trigger_output(output)
        if not 0 < pulse_width_s <= MAX_PULSE_WIDTH_S:
            raise ConfigurationError(
                f'pulse width {pulse_width_s} s must be > 0 s and ≤ {MAX_PULSE_WIDTH_S:g} s')
        if not (max_frame_rate_hz > 0 and math.isfinite(max_frame_rate_hz)):
            raise ConfigurationError(
                f'frame rate ceiling {max_frame_rate_hz} frames/s must be finite and > 0')
        self.max_frame_rate_hz = float(max_frame_rate_hz)
        self._pulse_width_s = pulse_width_s
        self._active_high = active_high
        self._clock_s = clock_s
        self._sleep_s = sleep_s
        self._daqmx = None
        self._task = None
        self._config: Optional[CameraConfig] = None
        self._armed = False
        self._trigger_time_s: Optional[float] = None

    @property
    def mode(self) -> str:
        """'do' or 'counter'."""
        return self._kind

    @property
    def config(self) -> Optional[CameraConfig]:
        return self._config

    def open(self) -> None:
        if self._task is not None:
            return
        self._daqmx = daqmx = load_nidaqmx()
        try:
            task = daqmx.Task()
        except daqmx.errors.Error as exc:
            raise to_device_error('creating the DAQmx task', exc) from exc
        try:
            if self._kind == 'do':
                task.do_channels.add_do_chan(
                    lines=self._output,
                    line_grouping=daqmx.constants.LineGrouping.CHAN_FOR_ALL_LINES)
                task.write(not self._active_high)
            else:
                self._add_counter_pulse(task)
        except daqmx.errors.Error as exc:
            close_quietly(task)
            raise to_device_error(f'setting up the camera trigger on {self._output}', exc) from exc
        self._task = task

    def _add_counter_pulse(self, task) -> None:
        constants = self._daqmx.constants
        idle = constants.Level.LOW if self._active_high else constants.Level.HIGH
        task.co_channels.add_co_pulse_chan_time(
            counter=self._output, units=constants.TimeUnits.SECONDS, idle_state=idle,
            initial_delay=0.0, low_time=self._pulse_width_s, high_time=self._pulse_width_s)
        task.control(constants.TaskMode.TASK_COMMIT)

    def close(self) -> None:
        self._armed = False
        task, self._task = self._task, None
        close_quietly(task)

    def arm(self, config: CameraConfig) -> None:
        check_camera_config(config, self.max_frame_rate_hz)
        if self._task is None:
            raise DeviceError(f'camera trigger on {self._output} is not open: open() first')
        self._config = config
        self._armed = True
        self._trigger_time_s = None

    def trigger(self) -> float:
        if self._task is None:
            raise DeviceError(f'camera trigger on {self._output} is not open: open() first')
        if not self._armed:
            raise DeviceError('trigger() without arm(): arm the camera first'
                              if self._trigger_time_s is None else
                              'trigger() twice: the camera was already triggered; arm() again')
        try:
            time_s = self._pulse_do() if self._kind == 'do' else self._pulse_counter()
        except self._daqmx.errors.Error as exc:
            error = to_device_error(f'camera trigger pulse on {self._output}', exc)
            self.close()
            raise error from exc
        self._armed = False
        self._trigger_time_s = time_s
        return time_s

    def _pulse_do(self) -> float:
        before_s = self._clock_s()
        self._task.write(self._active_high)
        after_s = self._clock_s()
        self._sleep_s(self._pulse_width_s)
        self._task.write(not self._active_high)
        return 0.5 * (before_s + after_s)

    def _pulse_counter(self) -> float:
        before_s = self._clock_s()
        self._task.start()
        after_s = self._clock_s()
        self._task.wait_until_done(timeout=2 * self._pulse_width_s + COUNTER_DONE_MARGIN_S)
        self._task.stop()
        return 0.5 * (before_s + after_s)

    def status(self) -> CameraStatus:
        return CameraStatus(armed=self._armed, triggered=self._trigger_time_s is not None,
                            trigger_time_s=self._trigger_time_s)
