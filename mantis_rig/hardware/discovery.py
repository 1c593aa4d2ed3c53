"""Find the rig's devices: KDC101 controllers on the serial ports, NI DAQ devices in NI-DAQmx.

KDC101: a Thorlabs K-Cube enumerates as an FTDI USB serial port with Thorlabs' own product id
(USB 0403:faf0); the USB serial number is the controller's (printed on its label, shown by
Kinesis), and a KDC101's starts with 27. `serial.tools.list_ports` lists them; nothing is opened.

NI DAQ: nidaqmx's system API (`nidaqmx.system.System.local().devices`): NI MAX's device name,
product type, serial number, and whether NI MAX simulates the device. nidaqmx is an optional
dependency (the `nidaq` extra): without it, or without the NI-DAQmx driver, the listing says so.

A rig's parameters may name the stage by its serial number instead of its port
(`stage_serial_number`, stage_node): `choose_kdc101` picks the one controller that matches and
says which and why, or raises DiscoveryError naming what was found.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
import importlib
from typing import Optional

from mantis_rig.hardware.device_interfaces import DeviceError

THORLABS_FTDI_VID = 0x0403          # FTDI
THORLABS_APT_PID = 0xFAF0           # the product id Thorlabs' APT controllers enumerate with
KDC101_SERIAL_PREFIX = '27'          # KDC101 serial numbers: 27xxxxxx
ANY_KDC101 = 'auto'                  # stage_serial_number: the only KDC101 on the machine


PACKAGE_FIX = ('pip install mantis_rig[nidaq] (nidaqmx 1.7.0) and the NI-DAQmx driver from '
               'ni.com (Linux: python -m nidaqmx installdriver)')
DRIVER_FIX = 'install the NI-DAQmx driver from ni.com (Linux: python -m nidaqmx installdriver)'


class DiscoveryError(DeviceError):
    """No device, or more than one, matches what the parameters ask for; the message lists
    what was found."""


@dataclass(frozen=True)
class SerialController:
    """A Thorlabs APT controller on a serial port (nothing opened)."""

    port: str
    serial_number: str
    description: str = ''

    @property
    def is_kdc101(self) -> bool:
        return self.serial_number.startswith(KDC101_SERIAL_PREFIX)

    def __str__(self) -> str:
        kind = 'KDC101' if self.is_kdc101 else 'Thorlabs controller (not a KDC101)'
        return f'{kind} #{self.serial_number} on {self.port}'


@dataclass(frozen=True)
class DaqDevice:
    name: str
    product_type: str
    serial_number: str
    simulated: bool

    def __str__(self) -> str:
        simulated = ', simulated in NI MAX' if self.simulated else ''
        return f'{self.name} ({self.product_type} #{self.serial_number}{simulated})'


@dataclass(frozen=True)
class DaqListing:
    """NI DAQ devices, or why none could be listed (`problem`: nidaqmx or the driver missing)."""

    devices: tuple = ()
    problem: Optional[str] = None
    driver_version: Optional[str] = None
    fix: Optional[str] = None           # what to install, when `problem` is a missing piece


@dataclass(frozen=True)
class StageChoice:
    port: str
    reason: str
    controller: Optional[SerialController] = None
    found: tuple = field(default=())


def _serial_text(value) -> str:
    return (value or '').strip()


def list_thorlabs_controllers(comports: Optional[Callable[[], Iterable]] = None
                              ) -> list[SerialController]:
    """Thorlabs APT controllers (USB 0403:faf0) among the serial ports, sorted by port."""
    if comports is None:
        from serial.tools.list_ports import comports
    found = []
    for info in comports():
        if info.vid != THORLABS_FTDI_VID or info.pid != THORLABS_APT_PID:
            continue
        found.append(SerialController(port=info.device,
                                      serial_number=_serial_text(info.serial_number),
                                      description=_serial_text(info.description)))
    return sorted(found, key=lambda c: c.port)


def list_kdc101(comports: Optional[Callable[[], Iterable]] = None) -> list[SerialController]:
    """The KDC101 controllers (serial number 27...) among the serial ports."""
    return [c for c in list_thorlabs_controllers(comports) if c.is_kdc101]


def describe_found(controllers: Iterable[SerialController]) -> str:
    controllers = list(controllers)
    if not controllers:
        return 'no Thorlabs controller (USB 0403:faf0) on any serial port'
    return 'found ' + ', '.join(str(c) for c in controllers)


def choose_kdc101(serial_port: str, stage_serial_number: str = '',
                  comports: Optional[Callable[[], Iterable]] = None) -> StageChoice:
    """The port to open for the stage, and why.

    `stage_serial_number` empty: `serial_port` as given. A serial number (e.g. '27000123'):
    the controller with it. 'auto': the only KDC101 on the machine. Anything but exactly one
    match raises DiscoveryError naming every Thorlabs controller found."""
    wanted = _serial_text(str(stage_serial_number))
    if not wanted:
        return StageChoice(port=serial_port, reason=f'parameter serial_port {serial_port}')
    controllers = list_thorlabs_controllers(comports)
    if wanted.lower() == ANY_KDC101:
        matches = [c for c in controllers if c.is_kdc101]
        asked = 'any KDC101 (stage_serial_number auto)'
    else:
        matches = [c for c in controllers if c.serial_number == wanted]
        asked = f'the KDC101 #{wanted} (stage_serial_number)'
    if len(matches) == 1:
        chosen = matches[0]
        why = ('the only KDC101 on this machine' if wanted.lower() == ANY_KDC101
               else f'the one controller with serial number {wanted}')
        return StageChoice(port=chosen.port, controller=chosen, found=tuple(controllers),
                           reason=f'{chosen.port}: {why} (stage_serial_number {wanted})')
    if not matches:
        raise DiscoveryError(f'{asked} is not connected: {describe_found(controllers)}')
    raise DiscoveryError(f'{asked} matches {len(matches)} controllers, '
                         f'{describe_found(matches)}: name one by its serial number')


def list_daq_devices() -> DaqListing:
    """The NI DAQ devices NI-DAQmx knows (NI MAX's list); a `problem` when it cannot tell."""
    try:
        system_module = importlib.import_module('nidaqmx.system')
        errors = importlib.import_module('nidaqmx.errors')
    except ImportError:
        return DaqListing(problem='the Python package nidaqmx is not installed (the nidaq '
                                  'extra)', fix=PACKAGE_FIX)
    try:
        system = system_module.System.local()
        version = system.driver_version
        devices = tuple(
            DaqDevice(name=device.name, product_type=device.product_type,
                      serial_number=f'{device.dev_serial_num:X}' if isinstance(
                          device.dev_serial_num, int) else str(device.dev_serial_num),
                      simulated=bool(device.dev_is_simulated))
            for device in system.devices)
    except errors.Error as exc:
        message = ' '.join(str(exc).split())
        if getattr(exc, 'error_code', None) is None:      # DaqNotFoundError: no driver
            return DaqListing(problem=f'nidaqmx is installed, the NI-DAQmx driver is not: '
                                      f'{message}', fix=DRIVER_FIX)
        return DaqListing(problem=f'NI-DAQmx could not list the devices: {message}')
    version_text = '.'.join(str(part) for part in version) if version is not None else None
    return DaqListing(devices=devices, driver_version=version_text)


def daq_device(name: str):
    """nidaqmx's Device object for an NI MAX device name (nidaqmx must be importable)."""
    system_module = importlib.import_module('nidaqmx.system')
    return system_module.System.local().devices[name]


__all__ = ['ANY_KDC101', 'DaqDevice', 'DaqListing', 'DiscoveryError', 'KDC101_SERIAL_PREFIX',
           'SerialController', 'StageChoice', 'THORLABS_APT_PID', 'THORLABS_FTDI_VID',
           'choose_kdc101', 'daq_device', 'describe_found', 'list_daq_devices', 'list_kdc101',
           'list_thorlabs_controllers']
