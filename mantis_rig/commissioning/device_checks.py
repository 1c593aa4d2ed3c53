"""The NI DAQ's devices, the load cell (its channel, then 1 s at rest) and the camera trigger
(its line or counter, and a test pulse), as `mantis doctor` checks them."""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

from .check_report import FAIL, OK, WARN, Options, Report, one_line

SATURATION_FRACTION = 0.999        # a sample this close to the input range is clipped
NOISE_FAIL_FACTOR = 10.0           # noise this many times the expectation: FAIL, not WARN
CEILING_SIGMAS = 5.0               # at rest, offset + this many sigma must stay under the ceiling


# --- NI DAQ -------------------------------------------------------------------------------------

@dataclass
class DaqDeviceView:
    """The NI MAX device of the channel: its listing and nidaqmx's Device object."""

    listing: object
    device: object


def check_daq_devices(report: Report, params) -> Optional[DaqDeviceView]:
    from ..hardware.discovery import daq_device, list_daq_devices
    from ..hardware.nidaq import parse_ai_channel
    listing = list_daq_devices()
    if listing.problem is not None:
        report.add('daq: devices', FAIL, f'cannot list NI DAQ devices: {listing.problem}',
                   (listing.fix or 'reinstall the NI-DAQmx driver') + ', then check the '
                   'USB-6363 in NI MAX')
        return None
    if not listing.devices:
        report.add('daq: devices', FAIL, f'NI-DAQmx {listing.driver_version} lists no device',
                   'connect the USB-6363 (USB and its power) and check that NI MAX lists it')
        return None
    found = ', '.join(str(d) for d in listing.devices)
    report.add('daq: devices', OK, f'NI-DAQmx {listing.driver_version}: {found}')
    try:
        name = parse_ai_channel(params.channel)[0]
    except ValueError:
        return None                     # the load-cell check names the malformed channel
    entry = next((d for d in listing.devices if d.name == name), None)
    if entry is None:
        return DaqDeviceView(listing=listing, device=None)
    return DaqDeviceView(listing=listing, device=daq_device(name))


def _device_problem(view: Optional[DaqDeviceView], channel: str, kind: str):
    """(status, found, fix) when the channel's device or the channel is missing, else None."""
    if view is None:
        return None
    device_name = channel.split('/')[0]
    found = ', '.join(str(d) for d in view.listing.devices)
    if view.device is None:
        return (FAIL, f'no device {device_name} in NI-DAQmx (found {found})',
                f'rename the DAQ to {device_name} in NI MAX, or set the {kind} to a channel '
                f'of a listed device')
    collection = {'ai': 'ai_physical_chans', 'do': 'do_lines', 'co': 'co_physical_chans'}
    names = list(getattr(view.device, collection[kind_code(channel)]).channel_names)
    if channel not in names:
        have = f'{names[0]}..{names[-1].split("/")[-1]}' if names else 'none'
        return (FAIL, f'{device_name} ({view.device.product_type}) has no {channel} '
                      f'(its channels: {have})',
                f'set the {kind} to the channel the wiring uses, as NI MAX names it')
    return None


def kind_code(channel: str) -> str:
    last = channel.split('/')[-1]
    return 'ai' if last.startswith('ai') else 'co' if last.startswith('ctr') else 'do'


# --- load cell ----------------------------------------------------------------------------------

def check_loadcell(report: Report, options: Options, rig, view) -> bool:
    """The channel, then 1 s at rest. True when the load cell can feed the force ceiling."""
    from mantis_rig.hardware.device_interfaces import ConfigurationError, DeviceError

    from ..hardware.nidaq_force import validate_config
    params = options.params
    name = 'load cell'
    try:
        validate_config(params.daq_config())
    except ConfigurationError as exc:
        report.add(f'{name}: channel', FAIL, one_line(exc),
                   'correct loadcell_node\'s parameters in the params file')
        return False
    if not rig.sim:
        if view is None:
            report.add(f'{name}: channel', FAIL, f'{params.channel}: no NI DAQ to check it on',
                       'fix the daq check above first')
            return False
        problem = _device_problem(view, params.channel, 'loadcell_node channel')
        if problem is not None:
            report.add(f'{name}: channel', *problem)
            return False
        entry = next(d for d in view.listing.devices if d.name == params.channel.split('/')[0])
        try:
            view.device.self_test_device()
        except Exception as exc:  # noqa: BLE001 - a diagnosis: any error of the self-test is the finding, reported FAIL
            report.add(f'{name}: channel', FAIL, f'{entry} failed its self-test: '
                       f'{one_line(exc)}', 'reset the device in NI MAX, reconnect it and '
                       'run its self-test there')
            return False
        if entry.simulated:
            report.add(f'{name}: channel', WARN, f'{params.channel} on {entry}: the readings '
                       f'are synthetic', 'replace the simulated device in NI MAX by the real '
                       'USB-6363 (same name)')
        else:
            report.add(f'{name}: channel', OK, f'{params.channel} on {entry}, self-test passed')
    else:
        report.add(f'{name}: channel', OK, f'{params.channel} (simulated DAQ, scene '
                   f'{params.scene})')
    daq = rig.make_daq()
    try:
        daq.open()
        daq.start()
        blocks = []
        needed = max(1, math.ceil(options.rest_s * params.sample_rate_hz / params.block_size))
        for _ in range(needed):
            blocks.append(daq.read_block(timeout_s=2.0 + params.block_size
                                         / params.sample_rate_hz))
        daq.stop()
    except DeviceError as exc:
        report.add(f'{name}: at rest', FAIL, f'{options.rest_s:g} s at '
                   f'{params.sample_rate_hz:g} S/s on {params.channel} failed: {one_line(exc)}',
                   'check the USB-6363\'s cable and power and that no other program (NI MAX '
                   'test panel, a running stack) uses it')
        return False
    finally:
        daq.close()
    return _judge_rest(report, name, params, blocks, getattr(daq, 'overrun_count', 0),
                       rig.rest_force_n() if rig.sim else 0.0)


def _judge_rest(report: Report, name, params, blocks, overrun_count, truth_n=0.0) -> bool:
    """truth_n: the force on the cell at rest (0 N: the tendon slack; the simulated world
    knows its own), from which the offset counts."""
    import numpy as np
    forces = np.concatenate([b.force_n for b in blocks]) - truth_n
    overruns = max(overrun_count, sum(b.overrun for b in blocks))
    volts = (forces + truth_n) / params.newtons_per_volt        # offset_v is 0: untared
    limit_v = params.input_range_v * SATURATION_FRACTION
    offset, noise = float(np.mean(forces)), float(np.std(forces))
    found = (f'{forces.size} samples at {params.sample_rate_hz:g} S/s: offset {offset:+.3f} N'
             + (f' (from the simulated tendon\'s {truth_n:.3f} N)' if truth_n else '')
             + f', noise {noise:.4f} N rms, {overruns} overruns')
    saturated = int(np.count_nonzero(np.abs(volts) >= limit_v))
    if saturated or not np.isfinite(forces).all():
        report.add(f'{name}: at rest', FAIL, f'{found}; {saturated} samples at the '
                   f'±{params.input_range_v:g} V input range: saturated, forces beyond it '
                   f'are not seen', 'check the amplifier\'s output (zero it with the tendon '
                   'slack) and its wiring to the DAQ input; a saturated cell blinds the force '
                   'ceiling')
        return False
    if noise > NOISE_FAIL_FACTOR * params.expected_noise_n or \
            abs(offset) + CEILING_SIGMAS * noise >= params.force_ceiling_n:
        report.add(f'{name}: at rest', FAIL, f'{found}: far noisier than the calibration\'s '
                   f'{params.expected_noise_n:g} N rms (the force ceiling '
                   f'{params.force_ceiling_n:g} N would trip at rest)',
                   'check the shield and ground of the amplifier cable and the terminal '
                   'configuration (DIFF/RSE) of the input; an open input floats')
        return False
    problems = []
    if noise > params.expected_noise_n:
        problems.append(f'noise above the calibration\'s {params.expected_noise_n:g} N rms')
    if abs(offset) > params.expected_offset_n:
        problems.append(f'offset beyond the calibration\'s ±{params.expected_offset_n:g} N')
    if overruns:
        problems.append('samples were lost')
    if problems:
        report.add(f'{name}: at rest', WARN, f'{found}: {"; ".join(problems)}',
                   'zero the amplifier with the tendon slack, check the cable\'s shield; '
                   'for overruns close other programs or raise block_size; or measure the '
                   'calibration again and set doctor: expected_noise_n / expected_offset_n')
        return True
    report.add(f'{name}: at rest', OK, found)
    return True


# --- camera trigger -----------------------------------------------------------------------------

def check_camera(report: Report, options: Options, rig, view) -> None:
    from mantis_rig.hardware.device_interfaces import CameraConfig, ConfigurationError, DeviceError

    from ..hardware.nidaq import parse_trigger_output
    output = options.params.trigger_output
    name = 'camera trigger'
    try:
        parse_trigger_output(output)
    except ConfigurationError as exc:
        report.add(name, FAIL, one_line(exc), 'correct camera_node\'s lines parameter')
        return
    if not rig.sim:
        if view is None:
            report.add(name, FAIL, f'{output}: no NI DAQ to check it on',
                       'fix the daq check above first')
            return
        problem = _device_problem(view, output, 'camera_node lines')
        if problem is not None:
            report.add(name, *problem)
            return
    trigger = rig.make_trigger()
    try:
        trigger.open()
        trigger.arm(CameraConfig())
        trigger.trigger()
    except (DeviceError, ConfigurationError) as exc:
        report.add(name, FAIL, f'a test pulse on {output} failed: {one_line(exc)}',
                   'check that no other task (NI MAX test panel, a running stack) holds the '
                   'line or counter')
        return
    finally:
        trigger.close()
    where = 'the simulated camera' if rig.sim else output
    report.add(name, OK, f'test pulse written on {where}; nothing is wired back to check that '
               f'it reached the camera: watch the Phantom\'s trigger indicator')


__all__ = ['DaqDeviceView', 'check_camera', 'check_daq_devices', 'check_loadcell', 'kind_code']
