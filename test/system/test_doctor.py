"""`mantis doctor` and device discovery against the APT emulator and the nidaqmx fake.

Each fault of issue 23 is a case: it is reported as FAIL with its fix on the same line, and
nothing is left running (no driver, guard, feed or world thread, no open DAQ task, no port fd).
No assertion is on wall-clock time.
"""
import fcntl
import json
import os
import sys
import threading

from fakes_nidaq import FakeDaqSystem, FakeDevice
import numpy as np
import pytest
import serial
import serial.tools.list_ports
from serial.tools.list_ports_common import ListPortInfo

from mantis_rig.backends import make_stage
from mantis_rig.cli.main import main
from mantis_rig.commissioning.check_report import FAIL, OK, WARN, Options, Report
from mantis_rig.commissioning.checks import run_checks
from mantis_rig.commissioning.environment_checks import check_ros_environment
from mantis_rig.commissioning.rig_params import RigParams, load_params
from mantis_rig.hardware import discovery
from mantis_rig.hardware.discovery import DiscoveryError, choose_kdc101

pytestmark = pytest.mark.timeout(60)

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
NEWTONS_PER_VOLT = 11.12
OUR_THREADS = ('kdc101', 'stage-guard', 'doctor-force-feed', 'world-runner', 'sim-stage')


def our_threads():
    return [t.name for t in threading.enumerate() if t.name.startswith(OUR_THREADS)]


def usb_port(device, serial_number, vid=0x0403, pid=0xFAF0):
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number = vid, pid, serial_number
    info.description = 'Kinesis K-Cube  DC Servo'
    return info


@pytest.fixture(autouse=True)
def nothing_left_running():
    yield
    assert our_threads() == [], 'a thread outlived mantis doctor'


@pytest.fixture
def ports(monkeypatch):
    """The serial ports the machine lists: set `listed[:]` in a test."""
    listed = []
    monkeypatch.setattr(serial.tools.list_ports, 'comports', lambda: list(listed))
    return listed


def quiet_cell(noise_v=0.002, offset_v=0.01, seed=1):
    rng = np.random.default_rng(seed)
    return lambda index: offset_v + rng.normal(0.0, noise_v, index.shape)


@pytest.fixture
def make_daq(monkeypatch):
    systems = []

    def make(signal_v=None, devices=('Dev1',)):
        systems.append(FakeDaqSystem(signal_v=signal_v or quiet_cell(), devices=devices)
                       .install(monkeypatch))
        return systems[-1]

    yield make
    for system in systems:
        assert system.open_tasks() == [], 'a DAQmx task was left open'


def rig_params(tmp_path, port='/dev/ttyUSB0', serial_number='', channel='Dev1/ai0',
               lines='Dev1/port0/line0', doctor_section=None):
    text = (f"stage_node:\n  ros__parameters:\n    serial_port: '{port}'\n"
            f"    stage_serial_number: '{serial_number}'\n"
            f"loadcell_node:\n  ros__parameters:\n    channel: {channel}\n"
            f"    newtons_per_volt: {NEWTONS_PER_VOLT}\n"
            f"camera_node:\n  ros__parameters:\n    lines: {lines}\n"
            f"supervisor_node:\n  ros__parameters:\n    out: '{tmp_path / 'trials'}'\n"
            f"    force_ceiling_n: 30.0\n")
    if doctor_section:
        text += 'doctor:\n' + ''.join(f'  {k}: {v}\n' for k, v in doctor_section.items())
    path = tmp_path / 'rig.yaml'
    path.write_text(text)
    return path


def run_doctor(params_path, **options):
    report = run_checks(Options(params=load_params(params_path), **options))
    return report, {c.name: c for c in report.checks}


def assert_fail(check, *words):
    assert check.status == FAIL, check.line()
    line = check.line()
    assert '\n' not in line and ' -- fix: ' in line, line
    for word in words:
        assert word.lower() in line.lower(), line


# --- discovery --------------------------------------------------------------------------------

def test_discovery_lists_kdc101_by_usb_id_and_serial(ports):
    ports[:] = [usb_port('/dev/ttyUSB1', '27000456'), usb_port('/dev/ttyUSB0', '27000123'),
                usb_port('/dev/ttyUSB2', '83000001'),                  # another Thorlabs cube
                usb_port('/dev/ttyACM0', '27999999', vid=0x2341, pid=0x0043)]   # not Thorlabs
    assert [c.port for c in discovery.list_thorlabs_controllers()] == [
        '/dev/ttyUSB0', '/dev/ttyUSB1', '/dev/ttyUSB2']
    assert [c.serial_number for c in discovery.list_kdc101()] == ['27000123', '27000456']
    choice = choose_kdc101('/dev/ttyUSB9', '27000456')
    assert choice.port == '/dev/ttyUSB1'
    assert 'serial number 27000456' in choice.reason
    assert choose_kdc101('/dev/ttyUSB9', '').port == '/dev/ttyUSB9'   # the port as given
    with pytest.raises(DiscoveryError, match='matches 2 controllers.*27000123.*27000456'):
        choose_kdc101('/dev/ttyUSB9', 'auto')
    with pytest.raises(DiscoveryError, match='#27000789 .* is not connected: found .*27000123'):
        choose_kdc101('/dev/ttyUSB9', '27000789')


def test_discovery_without_nidaqmx_says_so(monkeypatch):
    monkeypatch.setitem(sys.modules, 'nidaqmx', None)
    monkeypatch.setitem(sys.modules, 'nidaqmx.system', None)
    listing = discovery.list_daq_devices()
    assert listing.devices == () and 'nidaqmx is not installed' in listing.problem
    assert 'pip install mantis_rig[nidaq]' in listing.fix


def test_discovery_without_the_driver_says_so(make_daq):
    make_daq().driver_installed = False
    listing = discovery.list_daq_devices()
    assert 'the NI-DAQmx driver is not' in listing.problem and 'installdriver' in listing.fix


def test_discovery_lists_daq_devices(make_daq):
    make_daq(devices=(FakeDevice('Dev1', serial_num=0x1A2B3C), FakeDevice(
        'SimDev', product_type='USB-6001', simulated=True)))
    listing = discovery.list_daq_devices()
    assert [str(d) for d in listing.devices] == [
        'Dev1 (USB-6363 #1A2B3C)', 'SimDev (USB-6001 #1F2E3D4, simulated in NI MAX)']


def test_the_stage_is_found_by_serial_number(ports, make_emulator):
    emu = make_emulator()
    ports[:] = [usb_port(emu.port, '27000123')]
    stage = make_stage('hardware', serial_port='/dev/nonexistent', stage_serial_number='auto')
    assert stage.port_path == emu.port and 'the only KDC101' in stage.choice.reason
    with stage:
        assert stage.identify().serial_number == '27000123'


def test_stage_node_declares_stage_serial_number():
    from mantis_rig.nodes.stage_node import StageNode
    assert 'stage_serial_number' in [p.name for p in StageNode.PARAMETERS]


# --- the whole command on a healthy rig ---------------------------------------------------------

def test_a_healthy_rig_passes(tmp_path, ports, make_emulator, make_daq, capsys):
    emu = make_emulator()
    ports[:] = [usb_port(emu.port, '27000123')]
    system = make_daq()
    status = main(['doctor', '--params', str(rig_params(tmp_path, serial_number='27000123')),
                   '--json'])
    out = json.loads(capsys.readouterr().out)
    assert status == 0, out
    statuses = {c['name']: c['status'] for c in out['checks']}
    assert set(statuses.values()) == {'OK'}, out
    assert list(statuses) == ['ros: domain', 'ros: discovery range', 'ros: middleware', 'disk',
                              'daq: devices', 'load cell: channel', 'load cell: at rest',
                              'camera trigger', 'stage: port', 'stage: identity',
                              'stage: type', 'stage: limits']
    found = {c['name']: c['found'] for c in out['checks']}
    assert 'the one controller with serial number 27000123' in found['stage: port']
    assert 'KDC101 #27000123, firmware 3.0.10' in found['stage: identity']
    assert found['stage: identity'].endswith('; status: streaming')
    assert out['stage_status'] == 'streaming'
    assert 'MTS25-Z8' in found['stage: type']
    assert 'force ceiling 30 N' in found['stage: limits']
    assert 'nothing is wired back' in found['camera trigger']
    assert system.line_levels == {'Dev1/port0/line0': False}       # pulsed, back to idle
    assert not emu.moving and out['moved'] is False                # nothing moved without --move
    assert MOVE_COMMANDS.isdisjoint(emu.received)


MOVE_COMMANDS = {0x0443, 0x0453, 0x0457}     # MOT_MOVE_HOME, _ABSOLUTE, _VELOCITY
POLLED = 'status: polled at 10 Hz (the controller does not stream)'


def test_a_controller_that_does_not_stream_is_polled_and_said_so(tmp_path, ports,
                                                                 make_emulator, make_daq,
                                                                 capsys):
    emu = make_emulator(streams_status=False)
    ports[:] = [usb_port(emu.port, '27000123')]
    make_daq()
    params = str(rig_params(tmp_path, serial_number='27000123'))
    assert main(['doctor', '--params', params]) == 0
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if 'stage: identity' in ln]
    assert line.startswith('OK') and line.endswith(POLLED), line
    assert main(['doctor', '--params', params, '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['stage_status'] == 'polling'
    identity = next(c for c in out['checks'] if c['name'] == 'stage: identity')
    assert identity['status'] == 'OK' and identity['found'].endswith(POLLED)
    assert not emu.sending_status and emu.status_requests_answered > 2


@pytest.mark.slow
@pytest.mark.parametrize('streams_status', [True, False], ids=['streaming', 'polled'])
def test_move_homes_jogs_and_returns(tmp_path, ports, make_emulator, make_daq, streams_status):
    emu = make_emulator(position_mm=0.2, streams_status=streams_status)
    ports[:] = [usb_port(emu.port, '27000123')]
    make_daq()
    report, checks = run_doctor(rig_params(tmp_path, serial_number='auto'), move=True,
                                jog_m=0.3e-3)
    assert not report.failed, [c.line() for c in report.checks]
    motion = checks['stage: motion']
    assert motion.status == OK and 'homed at 0.000 mm -> 0.900 mm -> 0.600 mm' in \
        motion.found, motion.line()
    assert report.stage_status == ('streaming' if streams_status else 'polling')
    assert emu.position_mm == pytest.approx(0.6, abs=1e-4) and not emu.moving


# --- faults: each a FAIL with its fix, nothing left running -------------------------------------

def test_no_device(tmp_path, ports, monkeypatch):
    monkeypatch.setitem(sys.modules, 'nidaqmx', None)
    monkeypatch.setitem(sys.modules, 'nidaqmx.system', None)
    report, checks = run_doctor(rig_params(tmp_path, serial_number='auto'))
    assert report.failed
    assert_fail(checks['stage: port'], 'not connected', 'no Thorlabs controller', 'connect')
    assert_fail(checks['daq: devices'], 'nidaqmx is not installed', 'pip install')
    assert_fail(checks['load cell: channel'], 'no NI DAQ')


def test_no_daq_device_listed(tmp_path, ports, make_daq):
    make_daq(devices=())
    _, checks = run_doctor(rig_params(tmp_path))
    assert_fail(checks['daq: devices'], 'lists no device', 'connect the USB-6363')


def test_two_controllers(tmp_path, ports, make_daq):
    make_daq()
    ports[:] = [usb_port('/dev/ttyUSB0', '27000123'), usb_port('/dev/ttyUSB1', '27000456')]
    _, checks = run_doctor(rig_params(tmp_path, serial_number='auto'))
    assert_fail(checks['stage: port'], '2 controllers', '27000123 on /dev/ttyUSB0',
                '27000456 on /dev/ttyUSB1', 'stage_serial_number')
    assert 'stage: identity' not in checks                     # nothing was opened


def test_port_busy(tmp_path, ports, make_emulator, make_daq):
    make_daq()
    emu = make_emulator()
    holder = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)     # another program holds the port
    try:
        fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        _, checks = run_doctor(rig_params(tmp_path, port=emu.port))
    finally:
        os.close(holder)
    assert_fail(checks['stage: identity'], emu.port, 'close the program that holds', 'fuser')


def test_port_not_permitted(tmp_path, ports, make_daq, monkeypatch):
    make_daq()

    class Refused(serial.Serial):
        def open(self):
            raise serial.SerialException(13, f'could not open port {self.port}: [Errno 13] '
                                              f'Permission denied: {self.port!r}')

    monkeypatch.setattr('mantis_rig.hardware.kdc101.serial.Serial', Refused)
    _, checks = run_doctor(rig_params(tmp_path, port='/dev/ttyUSB0'))
    assert_fail(checks['stage: identity'], 'permission denied', 'dialout')


def test_wrong_stage_type(tmp_path, ports, make_emulator, make_daq):
    make_daq()
    emu = make_emulator(stage_part=b'PRM1-Z8')
    _, checks = run_doctor(rig_params(tmp_path, port=emu.port))
    assert_fail(checks['stage: type'], 'PRM1-Z8', 'not an MTS25-Z8', 'Kinesis')
    assert 'stage: limits' not in checks


def test_wrong_controller(tmp_path, ports, make_emulator, make_daq):
    make_daq()
    emu = make_emulator(model=b'KST101')
    _, checks = run_doctor(rig_params(tmp_path, port=emu.port))
    assert_fail(checks['stage: identity'], 'KST101', 'not a KDC101', 'stage_serial_number')


def test_a_controller_that_does_not_report_its_stage_is_a_warning(tmp_path, ports,
                                                                  make_emulator, make_daq):
    make_daq()
    emu = make_emulator(stage_part=None)
    report, checks = run_doctor(rig_params(tmp_path, port=emu.port))
    assert checks['stage: type'].status == WARN and not report.failed
    assert 'Kinesis' in checks['stage: type'].fix


@pytest.mark.parametrize('channel, device, words', [
    ('Dev1/ai12', FakeDevice('Dev1', product_type='USB-6001', ai_channels=8),
     ('USB-6001', 'has no Dev1/ai12', 'ai0..ai7')),
    ('Dev2/ai0', FakeDevice('Dev1'), ('no device Dev2', 'Dev1 (USB-6363', 'NI MAX')),
])
def test_a_channel_the_device_lacks(tmp_path, ports, make_daq, channel, device, words):
    make_daq(devices=(device,))
    _, checks = run_doctor(rig_params(tmp_path, channel=channel))
    assert_fail(checks['load cell: channel'], *words)
    assert 'load cell: at rest' not in checks


def test_a_trigger_line_the_device_lacks(tmp_path, ports, make_daq):
    make_daq(devices=(FakeDevice('Dev1', do_lines_per_port=((0, 8),)),))
    _, checks = run_doctor(rig_params(tmp_path, lines='Dev1/port1/line0'))
    assert_fail(checks['camera trigger'], 'has no Dev1/port1/line0')


def test_a_noisy_load_cell(tmp_path, ports, make_daq):
    make_daq(signal_v=quiet_cell(noise_v=1.0 / NEWTONS_PER_VOLT))      # 1 N rms
    _, checks = run_doctor(rig_params(tmp_path))
    assert_fail(checks['load cell: at rest'], 'far noisier', 'shield')


def test_a_slightly_noisy_load_cell_is_a_warning(tmp_path, ports, make_daq):
    make_daq(signal_v=quiet_cell(noise_v=0.1 / NEWTONS_PER_VOLT))      # 0.1 N rms
    _, checks = run_doctor(rig_params(tmp_path))
    assert checks['load cell: at rest'].status == WARN
    assert 'noise above the calibration' in checks['load cell: at rest'].found


def test_a_saturated_load_cell(tmp_path, ports, make_daq):
    make_daq(signal_v=lambda index: np.full(index.shape, 12.0))      # clipped at +10 V
    _, checks = run_doctor(rig_params(tmp_path))
    assert_fail(checks['load cell: at rest'], 'saturated', '±10 V', 'amplifier')


def test_the_load_cell_unplugged_during_move_stops_the_stage(tmp_path, ports, make_emulator,
                                                             make_daq):
    emu = make_emulator(position_mm=0.2)
    ports[:] = [usb_port(emu.port, '27000123')]
    holder = {}

    def signal_v(index):          # the USB-6363's cable is pulled once the jog is under way
        if emu.moving and emu.position_mm > 0.7:
            holder['system'].remove_device()
        return np.zeros(index.shape)

    holder['system'] = make_daq(signal_v=signal_v)
    report, checks = run_doctor(rig_params(tmp_path, serial_number='auto'), move=True,
                                jog_m=0.3e-3)
    assert_fail(checks['stage: motion'], 'homed at 0.000 mm', 'the load cell failed',
                'disconnected', 'the stage stopped at', 'reconnect the USB-6363')
    assert not emu.moving
    assert 0.7 < emu.position_mm < 0.9                  # stopped on the way to 0.9 mm


def test_the_controller_unplugged_during_move(tmp_path, ports, make_emulator, make_daq):
    emu = make_emulator(position_mm=0.2)
    ports[:] = [usb_port(emu.port, '27000123')]
    # the KDC101's USB cable is pulled once the jog is under way: by the emulator's own motion,
    # not from the load cell's feed, which a busy machine delays past the guard's limit
    emu.vanish_at(0.7)
    make_daq(signal_v=lambda index: np.zeros(index.shape))
    report, checks = run_doctor(rig_params(tmp_path, serial_number='auto'), move=True,
                                jog_m=0.3e-3)
    assert_fail(checks['stage: motion'], 'vanished', 'could not be told to stop',
                'reconnect the KDC101')


def test_move_refused_when_the_load_cell_fails(tmp_path, ports, make_emulator, make_daq):
    emu = make_emulator()
    make_daq(signal_v=lambda index: np.full(index.shape, 12.0))
    _, checks = run_doctor(rig_params(tmp_path, port=emu.port), move=True)
    assert_fail(checks['stage: motion'], 'not moved', 'force ceiling')
    assert MOVE_COMMANDS.isdisjoint(emu.received)


# --- parameters, environment -------------------------------------------------------------------

def test_bad_parameters_exit_2(tmp_path, capsys):
    path = tmp_path / 'rig.yaml'
    path.write_text('loadcell_node:\n  ros__parameters:\n    sample_rate_hz: fast\n')
    assert main(['doctor', '--params', str(path)]) == 2
    assert 'loadcell_node.sample_rate_hz' in capsys.readouterr().err
    path.write_text('doctor:\n  expected_noise: 0.1\n')
    assert main(['doctor', '--params', str(path)]) == 2
    assert 'doctor.expected_noise is not a doctor setting' in capsys.readouterr().err


def test_parameters_file_is_the_stacks_own(tmp_path):
    path = tmp_path / 'rig.yaml'
    path.write_text("/**:\n  ros__parameters:\n    force_ceiling_n: 12.0\n"
                    "stage_node:\n  ros__parameters:\n    stage_serial_number: 27000123\n"
                    "doctor:\n  expected_noise_n: 0.02\n")
    params = load_params(path)
    assert (params.force_ceiling_n, params.stage_serial_number, params.expected_noise_n) == (
        12.0, '27000123', 0.02)
    assert params.channel == RigParams().channel


def test_ros_environment_warns_off_localhost():
    report = Report()
    check_ros_environment(report, {'ROS_DOMAIN_ID': '7',
                                   'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'})
    checks = {c.name: c for c in report.checks}
    assert checks['ros: domain'].status == OK
    assert checks['ros: discovery range'].status == WARN
    assert 'LOCALHOST' in checks['ros: discovery range'].fix
    report = Report()
    check_ros_environment(report, {'ROS_DOMAIN_ID': 'seven'})
    assert report.checks[0].status == FAIL


# --- the simulated rig, as CI runs it ------------------------------------------------------------

@pytest.mark.slow
def test_sim_backend_with_move(tmp_path):
    params = RigParams(out=str(tmp_path))
    report = run_checks(Options(backend='sim', params=params, move=True, jog_m=0.3e-3))
    statuses = {c.name: c.status for c in report.checks}
    assert not report.failed, [c.line() for c in report.checks]
    assert statuses['stage: motion'] == OK and statuses['load cell: at rest'] == OK
