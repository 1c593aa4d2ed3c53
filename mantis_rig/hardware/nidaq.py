"""What the NI USB-6363 backends share: the lazy `nidaqmx` import, DAQmx error handling, names.

The backends themselves are `nidaq_force.NidaqForceDaq` (load-cell voltage) and
`nidaq_trigger.NidaqCameraTrigger` (camera TTL trigger). `nidaqmx` is an optional dependency:
nothing here imports it until a backend is opened, so this module imports without it.

Accepted physical names (`<device>` is what NI MAX shows: a letter, then letters, digits or
underscores, e.g. 'Dev1', 'PXI1Slot2', 'LoadCellDAQ'):
  analog input     <device>/ai<K>                 K in 0..31   (e.g. 'Dev1/ai0')
  digital output   <device>/port<P>/line<L>       port0 line 0..31, port1/port2 line 0..7
  counter output   <device>/ctr<N>                N in 0..3
Ranges ('ai0:3'), lists and terminal names ('/Dev1/PFI0') are refused: one channel per device.
"""
from __future__ import annotations

import importlib
import logging
import re
from typing import NamedTuple

from mantis_rig.hardware.device_interfaces import ConfigurationError, DeviceError

log = logging.getLogger(__name__)

USB6363_MAX_AI_RATE_HZ = 2_000_000.0          # one channel; the aggregate limit is 1 MS/s
USB6363_AI_RANGES_V = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)   # bipolar: ±range
USB6363_AI_CHANNELS = 32
USB6363_DO_LINES_PER_PORT = {0: 32, 1: 8, 2: 8}
USB6363_COUNTERS = 4
USB6363_TIMEBASE_HZ = 100e6

INSTALL_HINT = ('the Python package nidaqmx is not installed: `pip install mantis_rig[nidaq]` '
                '(or `pip install nidaqmx`), and install the NI-DAQmx driver from ni.com '
                '(on Linux: `python -m nidaqmx installdriver`)')

# DAQmx error codes (nidaqmx.error_codes.DAQmxErrors member names) by what they mean for us.
OVERRUN_ERRORS = {
    -200279: 'SAMPLES_NO_LONGER_AVAILABLE',
    -200010: 'INPUT_FIFO_OVERFLOW',
    -200222: 'ACQ_STOPPED_TO_PREVENT_INPUT_BUFFER_OVERWRITE',
    -200613: 'ACQ_STOPPED_TO_PREVENT_INPUT_BUFFER_OVERWRITE_ONE_DATA_XFER_MECH',
}
TIMEOUT_ERRORS = {
    -200284: 'SAMPLES_NOT_YET_AVAILABLE',
    -200474: 'OPERATION_TIMED_OUT',
}
# What a USB device that was unplugged or powered off mid-task has been seen to report.
REMOVED_ERRORS = {
    -200045: 'DEVICE_REMOVED',
    -201003: 'DEV_CANNOT_BE_ACCESSED',
    -50405: 'PAL_TRANSFER_ABORTED',
}


class Nidaqmx(NamedTuple):
    """The parts of the nidaqmx package the backends use."""

    Task: type
    constants: object
    errors: object
    stream_readers: object


def load_nidaqmx() -> Nidaqmx:
    """Import nidaqmx now; DeviceError with the install instructions if it is missing."""
    try:
        package = importlib.import_module('nidaqmx')
        return Nidaqmx(
            Task=package.Task,
            constants=importlib.import_module('nidaqmx.constants'),
            errors=importlib.import_module('nidaqmx.errors'),
            stream_readers=importlib.import_module('nidaqmx.stream_readers'),
        )
    except ImportError as exc:
        raise DeviceError(f'NI-DAQ backend unavailable: {INSTALL_HINT} ({exc})') from exc


def error_code(exc: BaseException):
    return getattr(exc, 'error_code', None)


def to_device_error(context: str, exc: BaseException) -> DeviceError:
    """A DeviceError carrying the DAQmx code and message (on one line) of a nidaqmx error."""
    message = ' '.join(str(exc).split())
    code = error_code(exc)
    if code is None:   # DaqNotFoundError / DaqNotSupportedError: no driver on this machine
        return DeviceError(f'{context}: {message}. Install NI-DAQmx: {INSTALL_HINT}')
    if code in REMOVED_ERRORS:
        return DeviceError(f'{context}: the DAQ was disconnected or powered off '
                           f'(DAQmx error {code} {REMOVED_ERRORS[code]}): {message}')
    return DeviceError(f'{context}: DAQmx error {code}: {message}')


_DEVICE = r'(?P<device>[A-Za-z][A-Za-z0-9_]*)'
_AI = re.compile(_DEVICE + r'/ai(?P<index>\d+)')
_DO = re.compile(_DEVICE + r'/port(?P<port>\d+)/line(?P<line>\d+)')
_CTR = re.compile(_DEVICE + r'/ctr(?P<index>\d+)')


def parse_ai_channel(name: str) -> tuple[str, int]:
    """'Dev1/ai0' -> ('Dev1', 0); ConfigurationError naming the grammar or the limit."""
    match = _AI.fullmatch(name.strip()) if isinstance(name, str) else None
    if match is None:
        raise ConfigurationError(
            f'analog input channel {name!r} does not parse as <device>/ai<K> (e.g. Dev1/ai0)')
    index = int(match['index'])
    if index >= USB6363_AI_CHANNELS:
        raise ConfigurationError(f'analog input channel {name!r}: ai{index} is beyond the '
                                 f'USB-6363 inputs ai0..ai{USB6363_AI_CHANNELS - 1}')
    return match['device'], index


def parse_trigger_output(name: str) -> tuple[str, str]:
    """A DO line or a counter: ('do', name) or ('counter', name); ConfigurationError if neither."""
    text = name.strip() if isinstance(name, str) else ''
    match = _DO.fullmatch(text)
    if match is not None:
        port, line = int(match['port']), int(match['line'])
        lines = USB6363_DO_LINES_PER_PORT.get(port)
        if lines is None or line >= lines:
            raise ConfigurationError(
                f'digital output {name!r}: port{port}/line{line} does not exist on the '
                'USB-6363 (port0 line0..31, port1 line0..7, port2 line0..7)')
        return 'do', text
    match = _CTR.fullmatch(text)
    if match is not None:
        if int(match['index']) >= USB6363_COUNTERS:
            raise ConfigurationError(f'counter {name!r} is beyond the USB-6363 counters '
                                     f'ctr0..ctr{USB6363_COUNTERS - 1}')
        return 'counter', text
    raise ConfigurationError(f'trigger output {name!r} parses neither as <device>/port<P>/line<L> '
                             '(e.g. Dev1/port0/line0) nor as <device>/ctr<N> (e.g. Dev1/ctr0)')


def close_quietly(task) -> None:
    """Close a DAQmx task, ignoring errors: it may be on a device that is gone."""
    if task is None:
        return
    try:
        task.close()
    except Exception as exc:  # noqa: BLE001 - a cleanup path: the device may be gone; logged
        log.warning('closing DAQmx task failed: %s', ' '.join(str(exc).split()))
