"""`mantis doctor`: find the rig's devices and check them before the first trial.

Checks, in this order, each OK / WARN / FAIL with what it found and, unless OK, the fix in one
line: the ROS environment (domain, discovery range, middleware) and the free disk space where
trials are written; the NI DAQ devices (hardware); the load cell (the channel exists on the
device, 1 s at rest at the trial's rate: offset, noise, overruns, saturation); the camera
trigger (the line or counter exists and a test pulse is written: nothing is wired back to see
it arrive); the stage (which port and why, identity and firmware and how its status arrives:
streamed, or polled because the controller does not stream; the stage type and travel, the
limits the software enforces); with --move only, the stage homes, moves to 0.1 mm inside the
lower soft limit, jogs 1 mm at 0.5 mm/s and comes back there, guarded by the force ceiling fed
from the load cell (without a working load cell it does not move).

`--backend sim` runs the same checks against the simulated rig's devices (a world of the
params' scene in this process). Exit 0 when nothing FAILs, 1 otherwise; `--json` prints the
report as JSON. Nothing moves without --move; every device is closed, every DAQ task, thread
and the simulated world ended, before the command returns, whatever failed.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
import errno
import json
import math
import os
from pathlib import Path
import shutil
import threading
from typing import Optional

OK, WARN, FAIL = 'OK', 'WARN', 'FAIL'
EXPECTED_STAGE = 'MTS25-Z8'
JOG_M = 1.0e-3
JOG_SPEED_M_PER_S = 0.5e-3
ARRIVED_M = 0.01e-3
JOG_BASE_INSIDE_M = 0.1e-3         # the jog starts and ends this far inside the lower soft limit
REST_S = 1.0
SATURATION_FRACTION = 0.999        # a sample this close to the input range is clipped
NOISE_FAIL_FACTOR = 10.0           # noise this many times the expectation: FAIL, not WARN
CEILING_SIGMAS = 5.0               # at rest, offset + this many sigma must stay under the ceiling
DISK_FAIL_BYTES = 1 << 30
DISK_WARN_BYTES = 10 << 30
COUNTS_WARN_REL = 1e-3
COUNTS_FAIL_REL = 0.05


@dataclass
class Check:
    name: str
    status: str
    found: str
    fix: str = ''

    def line(self) -> str:
        text = f'{self.name}: {self.found}'
        if self.fix and self.status != OK:
            text += f' -- fix: {self.fix}'
        return f'{self.status:<4}  ' + ' '.join(text.split())


@dataclass
class Options:
    backend: str = 'hardware'
    params: object = None               # doctor_params.RigParams
    move: bool = False
    jog_m: float = JOG_M
    jog_speed_m_per_s: float = JOG_SPEED_M_PER_S
    rest_s: float = REST_S
    real_time_factor: float = 1.0       # sim backend
    home_timeout_s: float = 60.0


class Report:
    def __init__(self):
        self.checks: list[Check] = []
        self.moved = False
        self.stage_status: Optional[str] = None     # the KDC101's status_mode, once open

    def add(self, name, status, found, fix='') -> Check:
        check = Check(name, status, found, fix)
        self.checks.append(check)
        return check

    @property
    def failed(self) -> bool:
        return any(c.status == FAIL for c in self.checks)

    def counts(self) -> dict:
        return {s: sum(c.status == s for c in self.checks) for s in (OK, WARN, FAIL)}


def add_commands(commands) -> None:
    from ..contract import BACKENDS
    doctor = commands.add_parser(
        'doctor', help='find the rig\'s devices and check them before a trial',
        description=__doc__.split('\n\n')[0])
    doctor.add_argument('--backend', choices=BACKENDS, default='hardware',
                        help='hardware (default): the KDC101 and the NI DAQ; sim: the '
                             'simulated rig')
    doctor.add_argument('--params', type=Path, metavar='FILE',
                        help='the stack\'s ROS 2 parameters file (a section per node; '
                             'docs/commissioning.md)')
    doctor.add_argument('--move', action='store_true',
                        help='also home the stage and jog it 1 mm at 0.5 mm/s and back '
                             '(nothing moves without it)')
    doctor.add_argument('--json', action='store_true', help='print the report as JSON')
    doctor.set_defaults(run=run)


def run(args) -> int:
    from .doctor_params import load_params
    options = Options(backend=args.backend, params=load_params(args.params), move=args.move)
    report = run_checks(options)
    if args.json:
        print(json.dumps({'backend': options.backend, 'params': options.params.source,
                          'moved': report.moved, 'stage_status': report.stage_status,
                          'counts': report.counts(),
                          'ok': not report.failed,
                          'checks': [asdict(c) for c in report.checks]}, indent=2))
    else:
        print(f'mantis doctor: backend {options.backend}, parameters {options.params.source}')
        for check in report.checks:
            print(check.line())
        counts = report.counts()
        moved = '' if options.move else '; the stage was not moved (--move to home and jog it)'
        print(f'{counts[OK]} OK, {counts[WARN]} WARN, {counts[FAIL]} FAIL{moved}')
    return 1 if report.failed else 0


def run_checks(options: Options) -> Report:
    if options.params is None:
        from .doctor_params import RigParams
        options.params = RigParams()
    report = Report()
    check_ros_environment(report)
    check_disk(report, Path(options.params.out))
    if options.backend == 'sim':
        with SimRig(options) as rig:
            check_devices(report, options, rig)
    else:
        check_devices(report, options, HardwareRig(options))
    return report


# --- ROS environment and disk ---------------------------------------------------------------

def check_ros_environment(report: Report, env=None) -> None:
    env = os.environ if env is None else env
    domain = env.get('ROS_DOMAIN_ID', '')
    if not domain:
        report.add('ros: domain', WARN, 'ROS_DOMAIN_ID is unset: domain 0, shared with every '
                   'ROS 2 program on the network', 'export ROS_DOMAIN_ID=N, a number of this '
                   'rig\'s own in 1..101 (`. scripts/ros_env.sh` picks a free one)')
    elif not domain.isdigit() or not 0 <= int(domain) <= 232:
        report.add('ros: domain', FAIL, f'ROS_DOMAIN_ID={domain!r} is not a domain id '
                   f'(0..232)', 'export ROS_DOMAIN_ID=N with N in 1..101')
    else:
        report.add('ros: domain', OK, f'ROS_DOMAIN_ID={domain}')
    scope = env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '')
    if scope.upper() == 'LOCALHOST':
        report.add('ros: discovery range', OK, 'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: DDS '
                   'stays on this machine')
    else:
        shown = f'={scope}' if scope else ' is unset (SUBNET)'
        report.add('ros: discovery range', WARN, f'ROS_AUTOMATIC_DISCOVERY_RANGE{shown}: DDS '
                   f'discovery may leave this machine and other hosts may command the rig',
                   'export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (`. scripts/ros_env.sh`), '
                   'unless another machine must see the rig')
    rmw = env.get('RMW_IMPLEMENTATION', '')
    try:
        from rclpy.utilities import get_rmw_implementation_identifier
        loaded = get_rmw_implementation_identifier()
    except Exception as exc:  # noqa: BLE001 - a diagnosis: whatever loading rclpy's middleware raises is the finding, reported FAIL
        report.add('ros: middleware', FAIL, f'rclpy cannot load the middleware '
                   f'{rmw or "(default)"}: {" ".join(str(exc).split())}',
                   'reinstall with ./scripts/bootstrap.sh, or export '
                   'RMW_IMPLEMENTATION=rmw_fastrtps_cpp')
        return
    report.add('ros: middleware', OK, f'{loaded}' + ('' if rmw else ' (RMW_IMPLEMENTATION '
                                                     'unset: the default)'))


def _existing_parent(path: Path) -> Path:
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_disk(report: Report, out: Path) -> None:
    where = _existing_parent(out)
    try:
        usage = shutil.disk_usage(where)
    except OSError as exc:
        report.add('disk', FAIL, f'cannot read the free space at {where}: {exc.strerror}',
                   'set the supervisor\'s out parameter to a writable directory')
        return
    free_gib = usage.free / (1 << 30)
    found = f'{free_gib:.1f} GiB free where trials are written ({out})'
    if not os.access(where, os.W_OK):
        report.add('disk', FAIL, f'{found}, but {where} is not writable by this user',
                   f'make {where} writable or set the supervisor\'s out parameter elsewhere')
    elif usage.free < DISK_FAIL_BYTES:
        report.add('disk', FAIL, found, 'free space on that disk (a trial\'s bag takes tens '
                   'of MB) or set out to another disk')
    elif usage.free < DISK_WARN_BYTES:
        report.add('disk', WARN, found, 'free space soon: under 10 GiB left')
    else:
        report.add('disk', OK, found)


# --- the devices ----------------------------------------------------------------------------

class HardwareRig:
    """The real devices, built from the parameters by hardware.backends (none opened here)."""

    sim = False

    def __init__(self, options: Options):
        self.options = options
        self.params = options.params

    def make_stage(self, choice):
        """choice: the port choose_stage_port chose (discovery.StageChoice)."""
        from mantis_rig.backends import make_stage
        return make_stage('hardware', choice=choice, counts_per_mm=self.params.counts_per_mm)

    def make_daq(self):
        from mantis_rig.backends import make_force_daq
        return make_force_daq('hardware', config=self.params.daq_config())

    def make_trigger(self):
        from mantis_rig.backends import make_camera_trigger
        return make_camera_trigger('hardware', output=self.params.trigger_output)


class SimRig:
    """The simulated rig's devices, built by hardware.backends, on a world of the params'
    scene run in this process."""

    sim = True

    def __init__(self, options: Options):
        self.options = options
        self.params = options.params
        self.runner = None

    def __enter__(self):
        from mantis_rig.simulated.local_world import LocalWorldPort, WorldRunner
        from mantis_sim.scene import load_scene
        from mantis_sim.world import World
        self.scene = load_scene(self.params.scene, list(self.params.scene_overrides))
        self.runner = WorldRunner(World(self.scene),
                                  real_time_factor=self.options.real_time_factor).start()
        self.port = LocalWorldPort(self.runner)
        return self

    def __exit__(self, *exc):
        if self.runner is not None:
            self.runner.stop()
        return False

    def rest_force_n(self) -> float:
        """The simulated tendon's true force now (the stage at rest)."""
        return float(self.port.tendon_force(self.port.now_s(), 1.0, 1, 10.0)[0])

    def make_stage(self, choice=None):
        from mantis_rig.backends import make_stage
        return make_stage('sim', self.port)

    def make_daq(self):
        from mantis_rig.backends import make_force_daq
        return make_force_daq('sim', self.port, scene=self.scene, seed=self.params.seed,
                              config=self.params.daq_config())

    def make_trigger(self):
        from mantis_rig.backends import make_camera_trigger
        return make_camera_trigger('sim', self.port, scene=self.scene)


def check_devices(report: Report, options: Options, rig) -> None:
    daq_device = None
    if not rig.sim:
        daq_device = check_daq_devices(report, options.params)
    loadcell_ok = check_loadcell(report, options, rig, daq_device)
    check_camera(report, options, rig, daq_device)
    check_stage(report, options, rig, loadcell_ok)


def _one_line(exc: BaseException) -> str:
    return ' '.join(str(exc).split())


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
        report.add(f'{name}: channel', FAIL, _one_line(exc),
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
                       f'{_one_line(exc)}', 'reset the device in NI MAX, reconnect it and '
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
                   f'{params.sample_rate_hz:g} S/s on {params.channel} failed: {_one_line(exc)}',
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
        report.add(name, FAIL, _one_line(exc), 'correct camera_node\'s lines parameter')
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
        report.add(name, FAIL, f'a test pulse on {output} failed: {_one_line(exc)}',
                   'check that no other task (NI MAX test panel, a running stack) holds the '
                   'line or counter')
        return
    finally:
        trigger.close()
    where = 'the simulated camera' if rig.sim else output
    report.add(name, OK, f'test pulse written on {where}; nothing is wired back to check that '
               f'it reached the camera: watch the Phantom\'s trigger indicator')


# --- stage ----------------------------------------------------------------------------------------

def _port_fix(message: str, port: str) -> str:
    lowered = message.lower()
    if 'permission denied' in lowered or f'errno {errno.EACCES}' in lowered:
        return (f'give this user the port: sudo usermod -aG dialout $USER, log out and in '
                f'(or a udev rule for {port})')
    if ('busy' in lowered or 'exclusively lock' in lowered
            or f'errno {errno.EBUSY}' in lowered or f'errno {errno.EAGAIN}' in lowered):
        return (f'close the program that holds {port} (Kinesis, a running mantis stack, another '
                f'doctor): `fuser {port}` names it')
    if 'no such file' in lowered or f'errno {errno.ENOENT}' in lowered:
        return ('connect the KDC101 (USB and its power supply), or set stage_serial_number to '
                'its serial number (27...) instead of serial_port')
    if 'not a kdc101' in lowered:
        return ('this port holds another device: set stage_serial_number to the KDC101\'s '
                'serial number (27...) instead of serial_port')
    return ('power the KDC101 (its display lit), check its USB cable, and power-cycle it if '
            'it still does not answer')


def choose_stage_port(report: Report, params):
    """The stage's port (a discovery.StageChoice), reported; None when there is none."""
    from ..hardware.discovery import DiscoveryError, choose_kdc101, describe_found, list_kdc101
    name = 'stage: port'
    try:
        choice = choose_kdc101(params.serial_port, params.stage_serial_number)
    except DiscoveryError as exc:
        report.add(name, FAIL, _one_line(exc),
                   'connect and power the KDC101, or set stage_node stage_serial_number to '
                   'the serial number of one of those listed')
        return None
    if params.stage_serial_number:
        report.add(name, OK, f'chose {choice.reason}')
        return choice
    found = list_kdc101()
    listed = describe_found(found)
    if not found:
        report.add(name, WARN, f'serial_port {choice.port} (parameter); {listed}',
                   'connect the KDC101 (USB and its power supply); on a USB hub or a virtual '
                   'machine check that the port reaches this system')
    elif choice.port not in [c.port for c in found]:
        report.add(name, WARN, f'serial_port {choice.port} (parameter) is none of the KDC101s '
                   f'listed: {listed}', f'set stage_node stage_serial_number to '
                   f'{found[0].serial_number} (or serial_port to {found[0].port})')
    else:
        report.add(name, OK, f'serial_port {choice.port} (parameter); {listed}')
    return choice


def check_stage(report: Report, options: Options, rig, loadcell_ok: bool) -> None:
    from mantis_rig.hardware.device_interfaces import DeviceError
    params = options.params
    if rig.sim:
        choice, port = None, 'simulated'
    else:
        choice = choose_stage_port(report, params)
        if choice is None:
            return
        port = choice.port
    stage = rig.make_stage(choice)
    try:
        try:
            stage.open()
            info = stage.identify()
        except DeviceError as exc:
            message = _one_line(exc)
            report.add('stage: identity', FAIL, message, _port_fix(message, port))
            return
        report.stage_status = getattr(stage, 'status_mode', None)
        report.add('stage: identity', OK, f'{info.model} #{info.serial_number}, firmware '
                   f'{info.firmware}' + ('' if rig.sim else f', on {port}')
                   + _status_text(stage))
        if not _check_stage_type(report, stage, params, rig):
            return
        if not _check_stage_limits(report, stage, params):
            return
        if options.move:
            _check_motion(report, options, rig, stage, loadcell_ok)
    finally:
        try:
            stage.close()
        except DeviceError as exc:
            report.add('stage: close', WARN, f'closing the stage: {_one_line(exc)}',
                       'power-cycle the KDC101 before the trial')


def _status_text(stage) -> str:
    """How the stage's status arrives ('' for a stage without status modes: the simulated)."""
    mode = getattr(stage, 'status_mode', None)
    if mode == 'streaming':
        return '; status: streaming'
    if mode == 'polling':
        return (f'; status: polled at {stage.poll_rate_hz:g} Hz (the controller does not '
                f'stream)')
    return ''


def _normalized(part: str) -> str:
    return ''.join(ch for ch in part.upper() if ch.isalnum())


def _check_stage_type(report: Report, stage, params, rig) -> bool:
    from mantis_rig.hardware.device_interfaces import STAGE_TRAVEL_M, DeviceError

    from ..hardware.apt_units import Z8_COUNTS_PER_MM
    name = 'stage: type'
    counts_per_mm = params.counts_per_mm or Z8_COUNTS_PER_MM
    soft_max_mm = stage.limits.max_position_m * 1e3
    if rig.sim:
        report.add(name, OK, f'simulated {EXPECTED_STAGE}, travel {STAGE_TRAVEL_M * 1e3:g} mm')
        return True
    try:
        axis = stage.stage_axis()
    except DeviceError as exc:
        report.add(name, FAIL, f'asking the KDC101 for its stage: {_one_line(exc)}',
                   _port_fix(str(exc), stage.port_path))
        return False
    if axis is None:
        report.add(name, WARN, f'the KDC101 did not report its stage (no answer to '
                   f'MOT_REQ_STAGEAXISPARAMS); the parameters expect an {EXPECTED_STAGE}, '
                   f'{counts_per_mm:g} counts/mm, {STAGE_TRAVEL_M * 1e3:g} mm travel',
                   f'check in Kinesis (Settings, stage) that this KDC101 is set to '
                   f'{EXPECTED_STAGE}, and confirm the travel by hand before --move')
        return True
    travel_mm = (axis.max_position_counts - axis.min_position_counts) / max(
        axis.counts_per_unit, 1)
    found = (f'{axis.part_number or "(no part number)"}, {axis.counts_per_unit} counts/mm, '
             f'travel {travel_mm:.1f} mm')
    if _normalized(EXPECTED_STAGE) not in _normalized(axis.part_number):
        report.add(name, FAIL, f'the KDC101 drives a {found}, not an {EXPECTED_STAGE}',
                   f'connect the {EXPECTED_STAGE}, or select {EXPECTED_STAGE} in Kinesis\' '
                   f'stage settings for this KDC101 and save them to the controller')
        return False
    if travel_mm + 1e-6 < soft_max_mm:
        report.add(name, FAIL, f'{found}: shorter than the soft travel limit '
                   f'{soft_max_mm:g} mm', f'set the stage\'s travel to '
                   f'{STAGE_TRAVEL_M * 1e3:g} mm in Kinesis, or check the stage')
        return False
    rel = abs(axis.counts_per_unit - counts_per_mm) / counts_per_mm
    if rel > COUNTS_FAIL_REL:
        report.add(name, FAIL, f'{found}; the parameters say {counts_per_mm:g} counts/mm '
                   f'({rel:.0%} apart: another actuator)', 'set stage_node counts_per_mm to '
                   'the actuator\'s, or connect the Z8 actuator')
        return False
    if rel > COUNTS_WARN_REL:
        report.add(name, WARN, f'{found}; the parameters say {counts_per_mm:g} counts/mm '
                   f'({rel:.2%} apart)', 'measure a 10 mm move with a dial gauge and set '
                   'stage_node counts_per_mm to what it shows')
        return True
    report.add(name, OK, found)
    return True


def _check_stage_limits(report: Report, stage, params) -> bool:
    from mantis_rig.hardware.device_interfaces import DeviceError

    from ..trial.safety_limits import FORCE_CEILING_RANGE_N
    limits = stage.limits
    enforced = (f'soft travel [{limits.min_position_m * 1e3:g}, '
                f'{limits.max_position_m * 1e3:g}] mm, speed ceiling '
                f'{limits.max_speed_m_per_s * 1e3:g} mm/s, acceleration '
                f'{limits.max_acceleration_m_per_s2 * 1e3:g} mm/s², force ceiling '
                f'{params.force_ceiling_n:g} N (allowed {FORCE_CEILING_RANGE_N[0]:g}-'
                f'{FORCE_CEILING_RANGE_N[1]:g} N)')
    try:
        state = stage.state()
    except DeviceError as exc:
        report.add('stage: limits', FAIL, f'{enforced}; reading its state: {_one_line(exc)}',
                   _port_fix(str(exc), getattr(stage, 'port_path', 'the port')))
        return False
    where = (f'at {state.position_m * 1e3:.3f} mm, {"homed" if state.homed else "not homed"}'
             + (', forward limit switch on' if state.forward_limit else '')
             + (', reverse limit switch on' if state.reverse_limit else ''))
    if state.fault:
        report.add('stage: limits', FAIL, f'{enforced}; {where}; fault: {state.fault}',
                   'clear the controller\'s fault (power-cycle the KDC101) and check the '
                   'stage cable')
        return False
    if state.moving:
        report.add('stage: limits', FAIL, f'{enforced}; {where}, and moving although nothing '
                   f'asked it to', 'stop it on the KDC101 (its stop button) and close the '
                   'program that moves it')
        return False
    report.add('stage: limits', OK, f'{enforced}; {where}')
    return True


class _ForceFeed:
    """Reads the load cell in a thread and feeds every block to the stage's force guard; a DAQ
    failure stops the stage at once."""

    def __init__(self, daq, guard, params):
        self.daq, self.guard, self.params = daq, guard, params
        self.error: Optional[str] = None
        self.blocks = 0
        self.first = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='doctor-force-feed', daemon=True)

    def start(self):
        self.daq.open()
        try:
            self.daq.start()
        except BaseException:
            self.daq.close()
            raise
        self._thread.start()
        return self

    def _run(self):
        from mantis_rig.hardware.device_interfaces import DeviceError
        timeout_s = 2.0 + self.params.block_size / self.params.sample_rate_hz
        try:
            while not self._stop.is_set():
                block = self.daq.read_block(timeout_s=timeout_s)
                self.guard.observe_force(block)
                self.blocks += 1
                self.first.set()
        except Exception as exc:  # noqa: BLE001 - the feed thread's boundary: on any failure the stage must stop, not pull blind
            self.error = _one_line(exc)
            try:
                self.guard.stop()
            except DeviceError:
                pass
        finally:
            self.first.set()

    def close(self):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)
        try:
            self.daq.stop()
        except Exception:  # noqa: BLE001 - a cleanup path: the DAQ may be gone, closing below is what matters
            pass
        self.daq.close()


def _check_motion(report: Report, options: Options, rig, stage, loadcell_ok: bool) -> None:
    from mantis_rig.hardware.device_interfaces import ConfigurationError, DeviceError, StageGuard
    name = 'stage: motion'
    params = options.params
    if not loadcell_ok:
        report.add(name, FAIL, 'not moved: the load cell failed, and a jog needs the force '
                   'ceiling fed from it', 'fix the load cell first, then run --move again')
        return
    guard = StageGuard(stage, params.force_ceiling_n, max_force_age_s=0.5)
    feed = _ForceFeed(rig.make_daq(), guard, params)
    report.moved = True
    steps = []
    try:
        guard.open()          # the stage is open already: this starts the guard's watchdog
        feed.start()
        feed.first.wait(timeout=5.0)
        if feed.error:
            raise DeviceError(f'the load cell failed before the jog: {feed.error}')
        if rig.sim:
            # The simulated stage starts homed, at the scene's start pose, with the robot's
            # latch loaded: a homing run there would strain it. Jog from where it stands.
            low = guard.state().position_m
            steps.append(f'starts homed at {low * 1e3:.3f} mm (simulated: no homing run)')
        else:
            guard.home(timeout_s=options.home_timeout_s)
            steps.append(f'homed at {guard.state().position_m * 1e3:.3f} mm')
            low = stage.limits.min_position_m + JOG_BASE_INSIDE_M   # back here, inside the limit
        target = low + options.jog_m
        for goal in (target, low):
            guard.move_to(goal, options.jog_speed_m_per_s,
                          timeout_s=options.jog_m / options.jog_speed_m_per_s + 30.0)
            at = guard.state().position_m
            if abs(at - goal) > ARRIVED_M:
                raise DeviceError(f'asked for {goal * 1e3:.3f} mm, the stage rests at '
                                  f'{at * 1e3:.4f} mm')
            steps.append(f'{at * 1e3:.3f} mm')
    except (DeviceError, ConfigurationError, ValueError) as exc:
        cause = f'the load cell failed during the move ({feed.error})' if feed.error else \
            _one_line(exc)
        report.add(name, FAIL, f'{", ".join(steps) or "nothing done"}; then {cause}; '
                   f'{_stop_and_say(guard, stage)}', _motion_fix(feed.error, str(exc), stage))
        return
    finally:
        feed.close()
        guard.close()         # ends the guard's watchdog and closes the stage (stopping it)
    report.add(name, OK, f'{" -> ".join(steps)} at {options.jog_speed_m_per_s * 1e3:g} mm/s, '
               f'force ceiling {params.force_ceiling_n:g} N fed by {feed.blocks} load-cell '
               f'blocks')


def _stop_and_say(guard, stage) -> str:
    """Stop the stage (a failed check never leaves it moving) and say how that went."""
    from mantis_rig.hardware.device_interfaces import DeviceError
    try:
        guard.stop()
        state = stage.state()
    except DeviceError as exc:
        return (f'the stage could not be told to stop ({_one_line(exc)}): the controller ends '
                f'the move it was given by itself, at its target inside the soft limits (or '
                f'at home); check the stage')
    if state.moving:
        return f'the stage still reports motion at {state.position_m * 1e3:.3f} mm: stop it'
    return f'the stage stopped at {state.position_m * 1e3:.3f} mm'


def _motion_fix(feed_error, message: str, stage) -> str:
    if feed_error:
        return ('reconnect the USB-6363 (USB and power), check it in NI MAX, then run '
                'mantis doctor --move again')
    if 'vanished' in message or 'not open' in message:
        return ('reconnect the KDC101\'s USB cable, check the stage by eye, then run '
                'mantis doctor --move again')
    return ('check the stage and its cable, that nothing blocks it, and the limit switches; '
            'then run mantis doctor --move again')


__all__ = ['Check', 'FAIL', 'OK', 'Options', 'Report', 'WARN', 'add_commands', 'run',
           'run_checks']
