"""The stage as `mantis doctor` checks it: which port and why, identity, firmware and how its
status arrives, the stage type and travel, the limits the software enforces; with --move, the
guarded jog (stage_motion)."""
from __future__ import annotations

import errno

from .check_report import FAIL, OK, WARN, Options, Report, one_line
from .stage_motion import check_motion

EXPECTED_STAGE = 'MTS25-Z8'
COUNTS_WARN_REL = 1e-3
COUNTS_FAIL_REL = 0.05


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
        report.add(name, FAIL, one_line(exc),
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
            message = one_line(exc)
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
            check_motion(report, options, rig, stage, loadcell_ok)
    finally:
        try:
            stage.close()
        except DeviceError as exc:
            report.add('stage: close', WARN, f'closing the stage: {one_line(exc)}',
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
        report.add(name, FAIL, f'asking the KDC101 for its stage: {one_line(exc)}',
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
        report.add('stage: limits', FAIL, f'{enforced}; reading its state: {one_line(exc)}',
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


__all__ = ['EXPECTED_STAGE', 'check_stage', 'choose_stage_port']
