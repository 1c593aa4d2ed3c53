"""A fake of the part of nidaqmx 1.7.0 that mantis_rig's NI backends use, with fault injection.

`FakeDaqSystem` is the hardware behind the fake: a scripted input signal (volts as a function
of the physical sample index), faults to inject, and a record of what the tasks did.
`system.install(monkeypatch)` puts fake `nidaqmx`, `nidaqmx.constants`, `nidaqmx.errors`,
`nidaqmx.stream_readers` and `nidaqmx.system` modules into sys.modules, so the backends (and
the device discovery of `mantis doctor`) import them unchanged. `devices` names NI MAX's
devices: a name is a USB-6363, a `FakeDevice` sets the product type, serial number, simulated
flag and the channels it has (a task on a channel the device lacks fails as DAQmx does).
Names, signatures and defaults follow the real package (checked by test_nidaq.py when the real
package is importable). Misuse the real driver would not catch as clearly (reading a stopped
task, using a closed one) raises FakeMisuse so that a test fails.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum
import sys
import types
import warnings

import numpy as np

# --- nidaqmx.constants -------------------------------------------------------------------------

READ_ALL_AVAILABLE = -1
WAIT_INFINITELY = -1.0


class AcquisitionType(Enum):
    FINITE = 10178
    CONTINUOUS = 10123
    HW_TIMED_SINGLE_POINT = 12522


class Edge(Enum):
    RISING = 10280
    FALLING = 10171


class Level(Enum):
    HIGH = 10192
    LOW = 10214
    TRISTATE = 10310
    NO_CHANGE = 10160


class LineGrouping(Enum):
    CHAN_PER_LINE = 0
    CHAN_FOR_ALL_LINES = 1


class OverwriteMode(Enum):
    OVERWRITE_UNREAD_SAMPLES = 10252
    DO_NOT_OVERWRITE_UNREAD_SAMPLES = 10159


class TaskMode(Enum):
    TASK_START = 0
    TASK_STOP = 1
    TASK_VERIFY = 2
    TASK_COMMIT = 3
    TASK_RESERVE = 4
    TASK_UNRESERVE = 5
    TASK_ABORT = 6


class TerminalConfiguration(Enum):
    RSE = 10083
    NRSE = 10078
    DIFF = 10106
    PSEUDO_DIFF = 12529
    DEFAULT = -1


class TimeUnits(Enum):
    SECONDS = 10364
    FROM_CUSTOM_SCALE = 10065
    TICKS = 10304


class VoltageUnits(Enum):
    VOLTS = 10348
    FROM_CUSTOM_SCALE = 10065
    FROM_TEDS = 12516


CONSTANT_ENUMS = (AcquisitionType, Edge, Level, LineGrouping, OverwriteMode, TaskMode,
                  TerminalConfiguration, TimeUnits, VoltageUnits)

# --- nidaqmx.errors ----------------------------------------------------------------------------

# DAQmxErrors member names of the codes the fake raises (checked against the real enum).
SAMPLES_NOT_YET_AVAILABLE = -200284
SAMPLES_NO_LONGER_AVAILABLE = -200279
INPUT_FIFO_OVERFLOW = -200010
INVALID_DEVICE_ID = -200220
DEV_CANNOT_BE_ACCESSED = -201003
PAL_TRANSFER_ABORTED = -50405
CAN_NOT_PERFORM_OP_WHILE_TASK_RUNNING = -200479
PHYSICAL_CHAN_DOES_NOT_EXIST = -200170
UNKNOWN = -1
FAKE_ERROR_CODES = {
    'SAMPLES_NOT_YET_AVAILABLE': SAMPLES_NOT_YET_AVAILABLE,
    'SAMPLES_NO_LONGER_AVAILABLE': SAMPLES_NO_LONGER_AVAILABLE,
    'INPUT_FIFO_OVERFLOW': INPUT_FIFO_OVERFLOW,
    'INVALID_DEVICE_ID': INVALID_DEVICE_ID,
    'DEV_CANNOT_BE_ACCESSED': DEV_CANNOT_BE_ACCESSED,
    'PAL_TRANSFER_ABORTED': PAL_TRANSFER_ABORTED,
    'CAN_NOT_PERFORM_OP_WHILE_TASK_RUNNING': CAN_NOT_PERFORM_OP_WHILE_TASK_RUNNING,
    'PHYSICAL_CHAN_DOES_NOT_EXIST': PHYSICAL_CHAN_DOES_NOT_EXIST,
    'UNKNOWN': UNKNOWN,
}


class Error(Exception):
    pass


class DaqNotFoundError(Error):
    pass


class DaqNotSupportedError(Error):
    pass


class DaqError(Error):
    def __init__(self, message, error_code, task_name=""):
        self._error_code = int(error_code)
        if task_name:
            message = f'{message}\n\nTask Name: {task_name}'
        if str(self._error_code) not in message:
            message = f'{message}\n\nStatus Code: {self._error_code}'
        super().__init__(message)

    @property
    def error_code(self):
        return self._error_code


class DaqReadError(DaqError):
    def __init__(self, message, error_code, samps_per_chan_read, task_name=""):
        super().__init__(message, error_code, task_name)
        self._samps_per_chan_read = samps_per_chan_read

    @property
    def samps_per_chan_read(self):
        return self._samps_per_chan_read


class DaqResourceWarning(ResourceWarning):
    pass


class FakeMisuse(AssertionError):
    """The backend used the API in a way the fake does not model or the rig would not accept."""


# --- nidaqmx.Task and its parts ----------------------------------------------------------------

class UnsetAutoStartSentinel:
    pass


AUTO_START_UNSET = UnsetAutoStartSentinel()
USB6363_TIMEBASE_HZ = 100e6


class _ChannelCollection:
    def __init__(self, task):
        self._task = task
        self.channels = []

    def _add(self, kind, name, **settings):
        self._task._check_usable()
        self._task.system._check_device(name, self._task.name)
        channel = dict(kind=kind, name=name, **settings)
        self.channels.append(channel)
        self._task.added_channels.append(channel)
        return channel


class AIChannelCollection(_ChannelCollection):
    def add_ai_voltage_chan(
            self, physical_channel, name_to_assign_to_channel="",
            terminal_config=TerminalConfiguration.DEFAULT, min_val=-5.0,
            max_val=5.0, units=VoltageUnits.VOLTS, custom_scale_name=""):
        return self._add('ai', physical_channel, terminal_config=terminal_config,
                         min_val=min_val, max_val=max_val, units=units)


class DOChannelCollection(_ChannelCollection):
    def add_do_chan(
            self, lines, name_to_assign_to_lines="",
            line_grouping=LineGrouping.CHAN_FOR_ALL_LINES):
        return self._add('do', lines, line_grouping=line_grouping)


class COChannelCollection(_ChannelCollection):
    def add_co_pulse_chan_time(
            self, counter, name_to_assign_to_channel="",
            units=TimeUnits.SECONDS, idle_state=Level.LOW, initial_delay=0.0,
            low_time=0.01, high_time=0.01):
        return self._add('co', counter, units=units, idle_state=idle_state,
                         initial_delay=initial_delay, low_time=low_time, high_time=high_time)


class Timing:
    def __init__(self, task):
        self._task = task
        self.sample_mode = None
        self.samps_per_chan = None
        self._rate = None

    def cfg_samp_clk_timing(
            self, rate, source="", active_edge=Edge.RISING,
            sample_mode=AcquisitionType.FINITE, samps_per_chan=1000):
        self._task._check_usable()
        if self._task.running:
            raise DaqError('Timing cannot be changed while the task is running.',
                           CAN_NOT_PERFORM_OP_WHILE_TASK_RUNNING)
        self._rate, self.sample_mode, self.samps_per_chan = rate, sample_mode, samps_per_chan

    @property
    def samp_clk_rate(self):
        """Like DAQmx: the rate the 100 MHz timebase can divide down to."""
        return USB6363_TIMEBASE_HZ / round(USB6363_TIMEBASE_HZ / self._rate)


class InStream:
    def __init__(self, task):
        self._task = task
        self._overwrite = OverwriteMode.OVERWRITE_UNREAD_SAMPLES   # not the DAQmx default:
        # a backend that relies on the default instead of setting it shows up in the tests.

    @property
    def overwrite(self):
        return self._overwrite

    @overwrite.setter
    def overwrite(self, val):
        self._overwrite = val

    @property
    def num_chans(self):
        return len(self._task.added_channels)


class Task:
    system: FakeDaqSystem   # set on the per-system subclass made by FakeDaqSystem

    def __init__(self, new_task_name="", *, grpc_options=None):
        system = self.system
        if not system.driver_installed:
            raise DaqNotFoundError('Could not find an installation of NI-DAQmx.')
        system.tasks.append(self)
        self.name = new_task_name or f'_unnamedTask<{len(system.tasks) - 1}>'
        self.added_channels = []
        self._ai = AIChannelCollection(self)
        self._do = DOChannelCollection(self)
        self._co = COChannelCollection(self)
        self._timing = Timing(self)
        self._in_stream = InStream(self)
        self.running = False
        self.closed = False
        self.close_calls = 0
        self.committed = False
        self.error_code = None        # a latched acquisition error (overrun) until restarted
        self.finite_remaining = None

    def __enter__(self):
        return self

    def __exit__(self, type, value, traceback):
        self.close()

    @property
    def ai_channels(self):
        return self._ai

    @property
    def do_channels(self):
        return self._do

    @property
    def co_channels(self):
        return self._co

    @property
    def timing(self):
        return self._timing

    @property
    def in_stream(self):
        return self._in_stream

    def _check_usable(self):
        if self.closed:
            raise FakeMisuse(f'task {self.name} used after close()')
        if self.system.removed:
            raise DaqError('Device cannot be accessed.', DEV_CANNOT_BE_ACCESSED, self.name)

    def _kind(self):
        kinds = {channel['kind'] for channel in self.added_channels}
        if len(kinds) != 1:
            raise FakeMisuse(f'task {self.name} has channels of kinds {sorted(kinds)}')
        return kinds.pop()

    def control(self, action):
        self._check_usable()
        self._kind()
        self.system.events.append((self.name, 'control', action))
        if action in (TaskMode.TASK_VERIFY, TaskMode.TASK_COMMIT) and self._kind() == 'ai':
            if self._timing.sample_mode is None:
                raise FakeMisuse('verify without timing: the rig would use on-demand timing')
        if action is TaskMode.TASK_COMMIT:
            self.committed = True

    def start(self):
        self._check_usable()
        kind = self._kind()
        if self.running:
            raise DaqError('The specified operation cannot be performed while the task is '
                           'running.', CAN_NOT_PERFORM_OP_WHILE_TASK_RUNNING, self.name)
        self.running = True
        self.error_code = None
        self.system.events.append((self.name, 'start', None))
        if kind == 'ai':
            timing = self._timing
            if timing.sample_mode is None:
                raise FakeMisuse('AI task started without sample clock timing')
            finite = timing.sample_mode is AcquisitionType.FINITE
            self.finite_remaining = timing.samps_per_chan if finite else None
        elif kind == 'co':
            self.system.pulses.append(dict(self.added_channels[0], task=self.name))

    def stop(self):
        self._check_usable()
        self.running = False
        self.system.events.append((self.name, 'stop', None))

    def close(self):
        self.close_calls += 1
        if self.closed:
            warnings.warn(f'Attempted to close NI-DAQmx task of name "{self.name}" but task '
                          'was already closed.', DaqResourceWarning, stacklevel=2)
            return
        self.closed = True
        self.running = False
        self.system.events.append((self.name, 'close', None))
        if self.system.removed:
            raise DaqError('Device cannot be accessed.', DEV_CANNOT_BE_ACCESSED, self.name)

    def write(self, data, auto_start=AUTO_START_UNSET, timeout=10.0):
        self._check_usable()
        if self._kind() != 'do':
            raise FakeMisuse(f'write() on a {self._kind()} task')
        if not isinstance(data, (bool, np.bool_)):
            raise FakeMisuse(f'the fake models single-line boolean writes, got {data!r}')
        self.system.events.append((self.name, 'write', bool(data)))
        self.system.line_levels[self.added_channels[0]['name']] = bool(data)
        return 1

    def wait_until_done(self, timeout=10.0):
        self._check_usable()
        if not self.running:
            raise FakeMisuse('wait_until_done() on a task that was not started')
        self.system.events.append((self.name, 'wait_until_done', timeout))


# --- nidaqmx.stream_readers --------------------------------------------------------------------

class AnalogSingleChannelReader:
    def __init__(self, task_in_stream):
        self._in_stream = task_in_stream
        self._task = task_in_stream._task

    def read_many_sample(
            self, data, number_of_samples_per_channel=READ_ALL_AVAILABLE, timeout=10.0):
        task, system = self._task, self._task.system
        if task.closed:
            raise FakeMisuse(f'read from closed task {task.name}')
        if system.removed:
            raise DaqReadError('No transfer is in progress because the transfer was aborted '
                               'by the client.', PAL_TRANSFER_ABORTED, 0, task.name)
        if not task.running:
            raise FakeMisuse('read from a task that is not started (DAQmx would auto-start it)')
        samples = number_of_samples_per_channel
        if samples == READ_ALL_AVAILABLE or not isinstance(samples, (int, np.integer)):
            raise FakeMisuse(f'the fake reads a fixed sample count, got {samples!r}')
        if data.shape != (samples,):
            raise DaqError('Read cannot be performed because the NumPy array passed into this '
                           f'function is not shaped correctly: {data.shape} != {(samples,)}',
                           UNKNOWN)
        if data.dtype != np.float64 or not data.flags.c_contiguous or not data.flags.writeable:
            raise FakeMisuse('read_many_sample needs a writeable C-contiguous float64 array')
        system.reads.append((task.name, samples, timeout))
        if task.error_code is not None:
            raise DaqReadError('The acquisition stopped earlier with an error.',
                               task.error_code, 0, task.name)
        fault = system.read_faults.popleft() if system.read_faults else None
        if fault is not None and fault[0] == 'overrun':
            _, lost_samples, code = fault
            system.position += lost_samples
            task.error_code = code
            raise DaqReadError('The application is not able to keep up with the hardware '
                               'acquisition.', code, 0, task.name)
        delivered = samples
        if fault is not None and fault[0] == 'timeout':
            delivered = min(samples, fault[1])
        if task.finite_remaining is not None:
            delivered = min(delivered, task.finite_remaining)
            task.finite_remaining -= delivered
        data[:delivered] = system.volts(task, delivered)
        if delivered < samples:
            raise DaqReadError('Wait Until Done did not indicate all samples were acquired '
                               'in the allotted time.', SAMPLES_NOT_YET_AVAILABLE, delivered,
                               task.name)
        return samples



# --- nidaqmx.system ----------------------------------------------------------------------------

@dataclass(frozen=True)
class FakeDevice:
    """One device as NI MAX lists it: a USB-6363 unless told otherwise."""

    name: str
    product_type: str = 'USB-6363'
    serial_num: int = 0x1F2E3D4
    simulated: bool = False
    ai_channels: int = 32
    do_lines_per_port: tuple = ((0, 32), (1, 8), (2, 8))
    counters: int = 4

    def channel_names(self, kind):
        if kind == 'ai':
            return [f'{self.name}/ai{i}' for i in range(self.ai_channels)]
        if kind == 'do':
            return [f'{self.name}/port{port}/line{line}'
                    for port, lines in self.do_lines_per_port for line in range(lines)]
        return [f'{self.name}/ctr{i}' for i in range(self.counters)]


class PhysicalChannelCollection:
    def __init__(self, names):
        self._names = list(names)

    def __contains__(self, item):
        return item in self._names

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)

    def __getitem__(self, index):
        return self._names[index]

    @property
    def channel_names(self):
        return list(self._names)


class Device:
    system: FakeDaqSystem   # set on the per-system subclass

    def __init__(self, name, *, grpc_options=None):
        self._name = name

    def _spec(self):
        if self.system.removed:
            raise DaqError('Device cannot be accessed.', DEV_CANNOT_BE_ACCESSED)
        return self.system.device_specs[self._name]

    @property
    def name(self):
        return self._name

    @property
    def product_type(self):
        return self._spec().product_type

    @property
    def dev_serial_num(self):
        return self._spec().serial_num

    @property
    def dev_is_simulated(self):
        return self._spec().simulated

    @property
    def ai_physical_chans(self):
        return PhysicalChannelCollection(self._spec().channel_names('ai'))

    @property
    def do_lines(self):
        return PhysicalChannelCollection(self._spec().channel_names('do'))

    @property
    def co_physical_chans(self):
        return PhysicalChannelCollection(self._spec().channel_names('co'))

    def self_test_device(self):
        self._spec()
        self.system.events.append((self._name, 'self_test_device', None))


class DeviceCollection:
    def __init__(self, system):
        self._system = system

    @property
    def device_names(self):
        return sorted(self._system.device_specs)

    def __len__(self):
        return len(self._system.device_specs)

    def __iter__(self):
        return (self._system.Device(name) for name in self.device_names)

    def __getitem__(self, index):
        names = self.device_names
        if isinstance(index, str):
            if index not in names:
                raise DaqError(f'Device identifier is invalid. Device Specified: {index}',
                               INVALID_DEVICE_ID)
            return self._system.Device(index)
        return self._system.Device(names[index])


class System:
    system: FakeDaqSystem   # set on the per-system subclass

    @staticmethod
    def local():
        raise FakeMisuse('System.local() of the unbound fake: use FakeDaqSystem.modules()')

    @property
    def devices(self):
        if not self.system.driver_installed:
            raise DaqNotFoundError('Could not find an installation of NI-DAQmx.')
        return DeviceCollection(self.system)

    @property
    def driver_version(self):
        if not self.system.driver_installed:
            raise DaqNotFoundError('Could not find an installation of NI-DAQmx.')
        return (2025, 1, 0)

# --- the fake hardware -------------------------------------------------------------------------

class FakeDaqSystem:
    """A USB-6363 named `devices`, whose AI sees `signal_v(index)` at physical sample `index`."""

    def __init__(self, signal_v=None, devices=('Dev1',)):
        self.signal_v = signal_v or (lambda index: np.zeros(index.shape))
        specs = [d if isinstance(d, FakeDevice) else FakeDevice(d) for d in devices]
        self.device_specs = {spec.name: spec for spec in specs}
        self.devices = set(self.device_specs)
        self.driver_installed = True
        self.removed = False
        self.position = 0             # physical index of the next sample the AI will deliver
        self.tasks = []
        self.events = []              # (task name, action, detail)
        self.reads = []               # (task name, samples asked, timeout)
        self.pulses = []              # counter pulses generated
        self.line_levels = {}         # DO line -> last level written
        self.read_faults = deque()
        self.Task = type('Task', (Task,), {'system': self})
        self.Device = type('Device', (Device,), {'system': self})
        bound = self

        class BoundSystem(System):
            system = bound

            @staticmethod
            def local():
                return BoundSystem()

        self.System = BoundSystem

    # fault injection
    def inject_overrun(self, lost_samples, code=SAMPLES_NO_LONGER_AVAILABLE):
        """The next read fails with an overrun; `lost_samples` samples are never delivered."""
        self.read_faults.append(('overrun', lost_samples, code))

    def inject_timeout(self, delivered=0):
        """The next read times out after delivering `delivered` samples."""
        self.read_faults.append(('timeout', delivered))

    def remove_device(self):
        """The USB cable is pulled: every later call on the device fails."""
        self.removed = True

    # helpers for the tasks
    def _check_device(self, name, task_name):
        if self.removed:
            raise DaqError('Device cannot be accessed.', DEV_CANNOT_BE_ACCESSED, task_name)
        device = name.split('/')[0]
        if device not in self.devices:
            raise DaqError(f'Device identifier is invalid. Device Specified: {device}',
                           INVALID_DEVICE_ID, task_name)
        spec = self.device_specs[device]
        if not any(name in spec.channel_names(kind) for kind in ('ai', 'do', 'co')):
            raise DaqError(f'Physical channel specified does not exist on this device. '
                           f'Physical Channel Name: {name}', PHYSICAL_CHAN_DOES_NOT_EXIST,
                           task_name)

    def volts(self, task, samples):
        index = np.arange(self.position, self.position + samples)
        self.position += samples
        channel = task.added_channels[0]
        return np.clip(self.signal_v(index), channel['min_val'], channel['max_val'])

    def open_tasks(self):
        return [task for task in self.tasks if not task.closed]

    # the fake package
    def modules(self):
        constants = types.ModuleType('nidaqmx.constants')
        for enum in CONSTANT_ENUMS:
            setattr(constants, enum.__name__, enum)
        constants.READ_ALL_AVAILABLE = READ_ALL_AVAILABLE
        constants.WAIT_INFINITELY = WAIT_INFINITELY
        errors = types.ModuleType('nidaqmx.errors')
        for cls in (Error, DaqNotFoundError, DaqNotSupportedError, DaqError, DaqReadError,
                    DaqResourceWarning):
            setattr(errors, cls.__name__, cls)
        stream_readers = types.ModuleType('nidaqmx.stream_readers')
        stream_readers.AnalogSingleChannelReader = AnalogSingleChannelReader
        system = types.ModuleType('nidaqmx.system')
        system.System, system.Device = self.System, self.Device
        package = types.ModuleType('nidaqmx')
        package.__path__ = []
        package.system = system
        package.Task = self.Task
        package.DaqError, package.DaqReadError = DaqError, DaqReadError
        package.constants, package.errors = constants, errors
        package.stream_readers = stream_readers
        return {'nidaqmx': package, 'nidaqmx.constants': constants, 'nidaqmx.errors': errors,
                'nidaqmx.stream_readers': stream_readers, 'nidaqmx.system': system}

    def install(self, monkeypatch):
        for name, module in self.modules().items():
            monkeypatch.setitem(sys.modules, name, module)
        return self


__all__ = ['FakeDaqSystem', 'FakeDevice', 'FakeMisuse', 'CONSTANT_ENUMS', 'FAKE_ERROR_CODES']
