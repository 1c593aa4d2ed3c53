"""Real translation-stage backend: a Thorlabs KDC101 K-Cube DC servo controller over APT.

One background I/O thread owns the reading side of the port: it decodes every message,
keeps the latest status, sends MOT_ACK_USTATUSUPDATE about once a second (without it the
controller stops sending status updates), and enforces the travel limits during motion by
stopping the stage. A controller that does not stream status after HW_START_UPDATEMSGS (some
KDC101s do not) is polled instead: the I/O thread sends MOT_REQ_DCSTATUSUPDATE at
`poll_rate_hz` (`status_mode` says which). Either way a status older than `status_timeout_s`
ends the link. Commands are written from the caller's thread and wait, with a timeout,
for the reply the I/O thread records. Any broken link (timeout, garbled or truncated bytes,
vanished port) ends in a DeviceError, a closed port and a stopped I/O thread.

A bounded velocity move (move_at(v, bound_m): a pull) is sent as MOT_MOVE_ABSOLUTE to the
bound at |v| (MOT_SET_VELPARAMS' maximum velocity): the controller itself ends it at rest there,
whatever becomes of this process (docs/hardware_kdc101.md).
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
import io
import logging
import math
import struct
import threading
import time
from typing import Optional

import serial
import thorlabs_apt_protocol as apt
from thorlabs_apt_protocol.parsing import id_to_func

from mantis_rig.hardware.device_interfaces import (
    ConfigurationError,
    DeviceError,
    SafetyLimitError,
    Stage,
    StageInfo,
    StageLimits,
    StageState,
)

from .apt_units import Z8_COUNTS_PER_MM, AptScale

log = logging.getLogger(__name__)

HOST = 0x01
CONTROLLER = 0x50          # a single-channel K-Cube answers as the generic USB unit
CHANNEL = 1
FORWARD, REVERSE = 1, 2
STOP_IMMEDIATE = 1
HEADER_BYTES = 6
MAX_DATA_BYTES = 255       # APT spec: no data packet exceeds 255 bytes
READ_POLL_S = 0.05
DEFAULT_HOMING_SPEED_M_PER_S = 2.0e-3   # (capped by the limits) set before every homing
DEFAULT_POLL_RATE_HZ = 10.0             # the rate a streaming controller sends status at
DEFAULT_STREAM_WAIT_S = 0.5             # (at most a third of status_timeout_s) see open()
STREAMING, POLLING = 'streaming', 'polling'

# thorlabs_apt_protocol calls the DC servo status messages MOT_*_DCSTATUSUPDATE (0x0490-0x0492);
# newer editions of the APT document name the same ids MOT_*_USTATUSUPDATE.
STATUS = 'mot_get_dcstatusupdate'
MOVING_FLAGS = ('moving_forward', 'moving_reverse', 'jogging_forward', 'jogging_reverse', 'homing')
FAULT_FLAGS = ('motion_error', 'instrument_error', 'overtemp', 'voltage_fault',
               'commutation_error', 'encoder_fault', 'overcurrent', 'current_fault', 'error')


@dataclass(frozen=True)
class StageAxis:
    """The stage the controller reports (MOT_GET_STAGEAXISPARAMS), in its own units."""

    part_number: str
    serial_number: str
    counts_per_unit: int
    min_position_counts: int
    max_position_counts: int


@dataclass(frozen=True)
class _Motion:
    kind: str          # 'home', 'absolute', 'velocity' or 'bounded' (a velocity move that
    #                    the controller ends at its bound: MOT_MOVE_ABSOLUTE, not waited for)
    direction: int     # +1 forward (position increases), -1 reverse, 0 none
    description: str


def message_name(msgid: int) -> str:
    func = id_to_func.get(msgid)
    return func.__name__.upper() if func else f'unknown message 0x{msgid:04x}'


def is_moving(status) -> bool:
    return any(getattr(status, flag) for flag in MOVING_FLAGS)


class Kdc101Stage(Stage):
    """A KDC101 driving a Z8 actuator (MTS25/M-Z8). Positions are in the controller's frame
    (0 at home), in metres; the soft travel limits and the speed ceiling of `limits` hold
    whatever the caller asks, homing included (its velocity is set to `homing_speed_m_per_s`
    before every MOT_MOVE_HOME). The force ceiling needs the force: wrap the stage in
    mantis_rig.trial.stage_guard.StageGuard and feed it the load-cell readings."""

    def __init__(self, port: str, counts_per_mm: float = Z8_COUNTS_PER_MM,
                 velocity_per_mm_s: Optional[float] = None,
                 acceleration_per_mm_s2: Optional[float] = None,
                 limits: Optional[StageLimits] = None, *,
                 status_velocity_per_mm_s: Optional[float] = None,
                 reply_timeout_s: float = 1.0, stop_timeout_s: float = 2.0,
                 status_timeout_s: float = 1.5, frame_timeout_s: float = 0.5,
                 keepalive_period_s: float = 1.0, expected_model: Optional[str] = 'KDC101',
                 homing_speed_m_per_s: Optional[float] = None,
                 poll_rate_hz: float = DEFAULT_POLL_RATE_HZ,
                 stream_wait_s: Optional[float] = None):
        """stream_wait_s: how long open() waits, after the first status, for a second one the
        controller sends by itself before it polls instead (default the smaller of 0.5 s and a
        third of status_timeout_s); poll_rate_hz: the rate of MOT_REQ_DCSTATUSUPDATE then."""
        self.port_path = port
        self.scale = AptScale(counts_per_mm, velocity_per_mm_s, acceleration_per_mm_s2,
                              status_velocity_per_mm_s)
        self.limits = limits if limits is not None else StageLimits()
        for name, value in (('reply_timeout_s', reply_timeout_s),
                            ('stop_timeout_s', stop_timeout_s),
                            ('status_timeout_s', status_timeout_s),
                            ('frame_timeout_s', frame_timeout_s),
                            ('keepalive_period_s', keepalive_period_s)):
            if not (value > 0 and math.isfinite(value)):
                raise ConfigurationError(f'{name} {value!r} s must be finite and > 0 s')
        if not (poll_rate_hz > 0 and math.isfinite(poll_rate_hz)):
            raise ConfigurationError(f'poll_rate_hz {poll_rate_hz!r} Hz must be finite and '
                                     f'> 0 Hz')
        if 1.0 / poll_rate_hz > status_timeout_s / 2:
            raise ConfigurationError(
                f'poll_rate_hz {poll_rate_hz:g} Hz is too slow for status_timeout_s '
                f'{status_timeout_s:g} s: polls must come at least twice within it')
        if stream_wait_s is None:
            stream_wait_s = min(DEFAULT_STREAM_WAIT_S, status_timeout_s / 3)
        if not (stream_wait_s > 0 and stream_wait_s <= status_timeout_s / 2):
            raise ConfigurationError(
                f'stream_wait_s {stream_wait_s!r} s must be > 0 s and at most half of '
                f'status_timeout_s {status_timeout_s:g} s')
        if homing_speed_m_per_s is None:
            homing_speed_m_per_s = min(DEFAULT_HOMING_SPEED_M_PER_S, self.limits.max_speed_m_per_s)
        self.limits.check_speed(homing_speed_m_per_s)
        if not homing_speed_m_per_s > 0:
            raise ConfigurationError(f'homing speed {homing_speed_m_per_s * 1e3:g} mm/s must be '
                                     f'> 0 mm/s')
        self.homing_speed_m_per_s = homing_speed_m_per_s
        self.reply_timeout_s = reply_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.status_timeout_s = status_timeout_s
        self.frame_timeout_s = frame_timeout_s
        self.keepalive_period_s = keepalive_period_s
        self.poll_rate_hz = poll_rate_hz
        self.stream_wait_s = stream_wait_s
        self.expected_model = expected_model
        self._port: Optional[serial.Serial] = None
        self._thread: Optional[threading.Thread] = None
        self._stop_event = threading.Event()
        self._write_lock = threading.Lock()
        self._cond = threading.Condition()
        self._reset_link_state()

    def _reset_link_state(self) -> None:
        self._events: deque = deque(maxlen=256)   # (sequence number, decoded message)
        self._seq = 0
        self._status = None
        self._status_seq = 0
        self._status_time = 0.0
        self._stop_pending = False      # a MOT_MOVE_STOP whose MOT_MOVE_STOPPED is still due
        self._last_ack = 0.0
        self._last_poll = 0.0
        self._updates_on = False
        self._status_mode: Optional[str] = None
        self._motion: Optional[_Motion] = None
        self._trip: Optional[SafetyLimitError] = None
        self._fault_text: Optional[str] = None
        self._failure: Optional[DeviceError] = None
        self._info: Optional[StageInfo] = None

    # --- life cycle -------------------------------------------------------------------------

    def open(self) -> None:
        if self._port is not None:
            return
        self._shutdown()                  # join an I/O thread left by an earlier failure
        self._reset_link_state()
        self._stop_event.clear()
        try:
            self._port = serial.Serial(
                self.port_path, baudrate=115200, bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE, rtscts=True,
                timeout=READ_POLL_S, write_timeout=self.reply_timeout_s, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._port = None
            raise DeviceError(f'cannot open KDC101 port {self.port_path}: {exc}') from exc
        try:
            self._port.reset_input_buffer()
            self._thread = threading.Thread(target=self._io_loop, daemon=True,
                                            name=f'kdc101-io {self.port_path}')
            self._thread.start()
            info = self.identify()
            if self.expected_model and self.expected_model not in info.model:
                raise DeviceError(f'{self.port_path} is a {info.model!r}, not a '
                                  f'{self.expected_model}')
            self._send(apt.mod_set_chanenablestate(CONTROLLER, HOST, CHANNEL, 1))
            seq = self._seq_now()
            with self._cond:
                self._status_time = self._last_ack = time.monotonic()
                self._updates_on = True
            self._send(apt.hw_start_updatemsgs(CONTROLLER, HOST))
            self._send(apt.mot_req_dcstatusupdate(CONTROLLER, HOST, CHANNEL))
            self._wait_for(lambda m: m.msg == STATUS, seq, self.reply_timeout_s,
                           'status update (neither streamed after HW_START_UPDATEMSGS nor '
                           'in reply to MOT_REQ_DCSTATUSUPDATE)')
            self._choose_status_mode(seq)
        except BaseException:
            self.close()
            raise

    @property
    def status_mode(self) -> Optional[str]:
        """'streaming': the controller sends status updates by itself (HW_START_UPDATEMSGS);
        'polling': it does not, and the I/O thread requests one (MOT_REQ_DCSTATUSUPDATE) at
        `poll_rate_hz`. None until open() has found out."""
        return self._status_mode

    def _choose_status_mode(self, since_seq: int) -> None:
        """One status came (the reply to open()'s request, or a streamed one). A streaming
        controller sends another by itself within `stream_wait_s`; otherwise poll."""
        deadline = time.monotonic() + self.stream_wait_s
        with self._cond:
            while self._failure is None:
                statuses = sum(1 for seq, msg in self._events
                               if seq > since_seq and msg.msg == STATUS)
                if statuses >= 2:
                    self._status_mode = STREAMING
                    return
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    self._status_mode, self._last_poll = POLLING, 0.0
                    break
                self._cond.wait(min(remaining, 0.1))
            failure = self._failure
        if failure is not None:
            self._shutdown()
            raise type(failure)(str(failure))
        log.info('KDC101 on %s sent no status update by itself within %g s of '
                 'HW_START_UPDATEMSGS: polling it with MOT_REQ_DCSTATUSUPDATE at %g Hz',
                 self.port_path, self.stream_wait_s, self.poll_rate_hz)

    def close(self) -> None:
        if self._port is None and self._thread is None:
            return
        if self._failure is None and self._port is not None:
            try:
                if self._motion is not None or (self._status and is_moving(self._status)):
                    self._write_stop()
                self._write(apt.hw_stop_updatemsgs(CONTROLLER, HOST))
            except DeviceError as exc:
                log.warning('KDC101 close: %s', exc)
        self._shutdown()

    def _shutdown(self) -> None:
        """Stop the I/O thread (unless called from it) and close the port."""
        self._stop_event.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
            if thread.is_alive():
                log.error('KDC101 I/O thread did not stop')
            self._thread = None
        self._close_port()

    def _close_port(self) -> None:
        with self._write_lock:
            port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass

    # --- commands ---------------------------------------------------------------------------

    def identify(self) -> StageInfo:
        seq = self._seq_now()
        self._send(apt.hw_req_info(CONTROLLER, HOST))
        msg = self._wait_for(lambda m: m.msg == 'hw_get_info', seq, self.reply_timeout_s,
                             'HW_GET_INFO reply to HW_REQ_INFO')
        self._info = StageInfo(
            model=msg.model_number.split(b'\x00')[0].decode('ascii', 'replace').strip(),
            serial_number=str(msg.serial_number),
            firmware='.'.join(str(v) for v in msg.firmware_version))
        return self._info

    def stage_axis(self, timeout_s: Optional[float] = None) -> Optional[StageAxis]:
        """The stage the controller says it drives (MOT_REQ_STAGEAXISPARAMS), or None when it
        does not answer within `timeout_s` (default reply_timeout_s): not every APT
        controller's firmware answers this request."""
        seq = self._seq_now()
        self._send(apt.mot_req_stageaxisparams(CONTROLLER, HOST, CHANNEL))
        msg = self._wait_for(lambda m: m.msg == 'mot_get_stageaxisparams', seq,
                             self.reply_timeout_s if timeout_s is None else timeout_s,
                             'MOT_GET_STAGEAXISPARAMS', fail_on_timeout=False)
        if msg is None:
            return None
        return StageAxis(
            part_number=msg.part_no_axis.split(b'\x00')[0].decode('ascii', 'replace').strip(),
            serial_number=str(msg.serial_num), counts_per_unit=int(msg.counts_per_unit),
            min_position_counts=int(msg.min_pos), max_position_counts=int(msg.max_pos))

    def home(self, timeout_s: float = 60.0) -> None:
        self._settle_pending_stop()
        self._set_homing_velocity()
        seq = self._begin_motion(_Motion('home', -1, 'homing'))
        self._send(apt.mot_move_home(CONTROLLER, HOST, CHANNEL))
        msg = self._wait_for(lambda m: m.msg in ('mot_move_homed', 'mot_move_stopped'), seq,
                             timeout_s, 'MOT_MOVE_HOMED', motion=True)
        self._end_motion()
        if msg.msg == 'mot_move_stopped':
            raise DeviceError('homing was interrupted: the KDC101 reported MOT_MOVE_STOPPED')
        seq = self._seq_now()
        self._send(apt.mot_req_dcstatusupdate(CONTROLLER, HOST, CHANNEL))
        self._wait_for(lambda m: m.msg == STATUS and m.homed, seq, self.reply_timeout_s,
                       'status update showing the stage homed after MOT_MOVE_HOMED')

    def move_to(self, position_m: float, speed_m_per_s: float, timeout_s: float = 60.0) -> None:
        self.limits.check_position(position_m)
        self.limits.check_speed(speed_m_per_s)
        if speed_m_per_s <= 0.0:
            raise ConfigurationError(f'stage speed {speed_m_per_s * 1e3:.4f} mm/s must be '
                                     f'positive for a move to {position_m * 1e3:.4f} mm')
        self._settle_pending_stop()
        status = self._require_homed('move_to')
        self._set_velocity(speed_m_per_s)
        target_counts = self.scale.position_to_counts(position_m)
        direction = (target_counts > status.position) - (target_counts < status.position)
        what = f'move to {position_m * 1e3:.4f} mm'
        seq = self._begin_motion(_Motion('absolute', direction, what))
        self._send(apt.mot_move_absolute(CONTROLLER, HOST, CHANNEL, target_counts))
        msg = self._wait_for(lambda m: m.msg in ('mot_move_completed', 'mot_move_stopped'),
                             seq, timeout_s, f'MOT_MOVE_COMPLETED for the {what}', motion=True)
        self._end_motion()
        if msg.msg == 'mot_move_stopped':
            raise DeviceError(f'{what} ended early: the stage stopped at '
                              f'{self.scale.counts_to_position_m(msg.position) * 1e3:.4f} mm')

    def move_at(self, velocity_m_per_s: float, bound_m: Optional[float] = None) -> None:
        """A velocity move (MOT_MOVE_VELOCITY), or with ``bound_m`` a bounded one: the
        controller is sent the speed as its maximum velocity (MOT_SET_VELPARAMS, with the
        limits' acceleration) and MOT_MOVE_ABSOLUTE to the bound, so that it stops there by
        itself, at rest, whatever becomes of this process. Returns at once either way; the
        bounded move's MOT_MOVE_COMPLETED is not waited for."""
        self.limits.check_speed(velocity_m_per_s)
        if velocity_m_per_s == 0.0:
            self.stop()
            return
        self._settle_pending_stop()
        status = self._require_homed('move_at')
        position_m = self.scale.counts_to_position_m(status.position)
        direction = 1 if velocity_m_per_s > 0 else -1
        limit_m = self.limits.max_position_m if direction > 0 else self.limits.min_position_m
        if (position_m - limit_m) * direction >= 0:
            raise ConfigurationError(
                f'cannot move {"forward" if direction > 0 else "in reverse"}: the stage is at '
                f'{position_m * 1e3:.4f} mm, at or beyond the soft travel limit '
                f'{limit_m * 1e3:.3f} mm')
        if bound_m is not None:
            self.limits.check_bound(velocity_m_per_s, position_m, bound_m)
        self._set_velocity(abs(velocity_m_per_s))
        what = f'velocity move at {velocity_m_per_s * 1e3:+.4f} mm/s'
        if bound_m is None:
            self._begin_motion(_Motion('velocity', direction, what))
            self._send(apt.mot_move_velocity(CONTROLLER, HOST, CHANNEL,
                                             FORWARD if direction > 0 else REVERSE))
            return
        self._begin_motion(_Motion('bounded', direction,
                                   f'{what} bounded at {bound_m * 1e3:.4f} mm'))
        self._send(apt.mot_move_absolute(CONTROLLER, HOST, CHANNEL,
                                         self.scale.position_to_counts(bound_m)))

    def stop(self) -> None:
        with self._cond:
            self._motion = None
            failure = self._failure
        if failure is not None or self._port is None:
            self._shutdown()
            raise DeviceError(f'cannot stop the stage: KDC101 port {self.port_path} is not open'
                              + (f' ({failure})' if failure else ''))
        seq = self._seq_now()
        try:
            self._write_stop()
        except DeviceError as exc:
            raise self._fail(exc) from exc
        if self._wait_for(lambda m: m.msg == 'mot_move_stopped', seq, self.stop_timeout_s,
                          'MOT_MOVE_STOPPED', fail_on_timeout=False) is not None:
            return
        # An already stopped controller may not confirm: a fresh status at rest is as good.
        with self._cond:
            at_rest = self._status_seq > seq and not is_moving(self._status)
            self._stop_pending = self._stop_pending and not at_rest
        if not at_rest:
            raise self._fail(DeviceError(
                f'no MOT_MOVE_STOPPED from the KDC101 on {self.port_path} within '
                f'{self.stop_timeout_s:g} s of MOT_MOVE_STOP, and it reports motion; port closed'))

    def state(self) -> StageState:
        with self._cond:
            failure, status, fault_text = self._failure, self._status, self._fault_text
        if failure is not None:
            self._shutdown()
            raise type(failure)(str(failure))
        if status is None or self._port is None:
            raise DeviceError(f'KDC101 on {self.port_path} is not open')
        faults = [flag for flag in FAULT_FLAGS if getattr(status, flag)]
        if faults:
            fault_text = '; '.join(filter(None, [
                fault_text, 'controller reports ' + ', '.join(faults)]))
        return StageState(
            position_m=self.scale.counts_to_position_m(status.position),
            velocity_m_per_s=self.scale.status_velocity_m_per_s(status.velocity),
            moving=is_moving(status), homed=status.homed,
            forward_limit=status.forward_limit_switch,
            reverse_limit=status.reverse_limit_switch, fault=fault_text)

    # --- command helpers --------------------------------------------------------------------

    def _require_homed(self, command: str):
        with self._cond:
            status, failure = self._status, self._failure
        if failure is not None:
            self._shutdown()
            raise type(failure)(str(failure))
        if status is None or self._port is None:
            raise DeviceError(f'{command}: KDC101 on {self.port_path} is not open')
        if not status.homed:
            raise DeviceError(f'{command} refused: the stage is not homed; call home() first '
                              f'(the soft travel limits need a homed position)')
        return status

    def _set_velocity(self, speed_m_per_s: float) -> None:
        speed_units = self.scale.velocity_to_units(speed_m_per_s)
        accel_units = self.scale.acceleration_to_units(self.limits.max_acceleration_m_per_s2)
        self._send(apt.mot_set_velparams(CONTROLLER, HOST, CHANNEL, 0, accel_units, speed_units))
        seq = self._seq_now()
        self._send(apt.mot_req_velparams(CONTROLLER, HOST, CHANNEL))
        got = self._wait_for(lambda m: m.msg == 'mot_get_velparams', seq, self.reply_timeout_s,
                             'MOT_GET_VELPARAMS reply to MOT_REQ_VELPARAMS')
        if (got.max_velocity, got.acceleration) != (speed_units, accel_units):
            raise DeviceError(
                f'KDC101 did not take the velocity parameters: sent max velocity {speed_units}, '
                f'acceleration {accel_units}; it reports {got.max_velocity}, {got.acceleration}')

    def _set_homing_velocity(self) -> None:
        """Homing runs at the controller's stored home velocity, which may be anything: set it
        to `homing_speed_m_per_s` (under the ceiling), keeping the stored direction, limit
        switch and offset, and read it back."""
        wanted = self.scale.velocity_to_units(self.homing_speed_m_per_s)
        got = self._request_home_params()
        if got.home_velocity == wanted:
            return
        self._send(apt.mot_set_homeparams(CONTROLLER, HOST, CHANNEL, got.home_dir,
                                          got.limit_switch, wanted, got.offset_distance))
        again = self._request_home_params()
        if again.home_velocity != wanted:
            raise DeviceError(
                f'KDC101 did not take the homing velocity: sent {wanted} '
                f'({self.homing_speed_m_per_s * 1e3:g} mm/s), it reports {again.home_velocity}')

    def _request_home_params(self):
        seq = self._seq_now()
        self._send(apt.mot_req_homeparams(CONTROLLER, HOST, CHANNEL))
        return self._wait_for(lambda m: m.msg == 'mot_get_homeparams', seq, self.reply_timeout_s,
                              'MOT_GET_HOMEPARAMS reply to MOT_REQ_HOMEPARAMS')

    def _settle_pending_stop(self) -> None:
        """Let the confirmation of an earlier stop arrive, so that it cannot be taken for the
        end of the next move."""
        deadline = time.monotonic() + self.stop_timeout_s
        with self._cond:
            while self._stop_pending and self._failure is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(remaining, 0.1))
            self._stop_pending = False

    def _begin_motion(self, motion: _Motion) -> int:
        with self._cond:
            self._motion = motion
            self._trip = None
            self._fault_text = None
            return self._seq

    def _end_motion(self) -> None:
        with self._cond:
            self._motion = None

    def _seq_now(self) -> int:
        with self._cond:
            return self._seq

    def _send(self, data: bytes) -> None:
        """Write from a caller's thread; a broken port fails the whole link."""
        try:
            self._write(data)
        except DeviceError as exc:
            raise self._fail(exc) from exc

    def _write(self, data: bytes) -> None:
        name = message_name(struct.unpack_from('<H', data)[0])
        with self._write_lock:
            if self._port is None:
                cause = f' ({self._failure})' if self._failure else ''
                raise DeviceError(f'cannot send {name}: KDC101 port {self.port_path} is not '
                                  f'open{cause}')
            try:
                self._port.write(data)
            except (serial.SerialException, OSError) as exc:
                if isinstance(exc, serial.SerialTimeoutException) \
                        and self._bytes_still_queued() == 0:
                    # pyserial checks its write timeout after the bytes are handed over: a
                    # process stalled for longer (a long GC pause) is not a stuck line.
                    return
                raise DeviceError(f'KDC101 port {self.port_path} failed while sending '
                                  f'{name}: {exc}') from exc

    def _bytes_still_queued(self) -> int:
        try:
            return self._port.out_waiting
        except (serial.SerialException, OSError, AttributeError):
            return -1

    def _wait_for(self, accept: Callable, since_seq: int, timeout_s: float, what: str,
                  motion: bool = False, fail_on_timeout: bool = True):
        """The first message after `since_seq` that `accept`s. Raise if the link fails, on
        timeout (or return None if not `fail_on_timeout`), and for a `motion` wait if a travel
        limit tripped."""
        deadline = time.monotonic() + timeout_s
        failure = trip = None
        with self._cond:
            while True:
                failure, trip = self._failure, (self._trip if motion else None)
                if failure or trip:
                    break
                for seq, msg in self._events:
                    if seq > since_seq and accept(msg):
                        return msg
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(remaining, 0.1))
        if failure is not None:
            self._shutdown()
            raise type(failure)(str(failure))
        if trip is not None:
            raise SafetyLimitError(str(trip))
        if not fail_on_timeout:
            return None
        if motion:
            self._stop_quietly()
        raise self._fail(DeviceError(f'no {what} from the KDC101 on {self.port_path} '
                                     f'within {timeout_s:g} s; port closed'))

    def _stop_quietly(self) -> None:
        try:
            self._write_stop()
        except DeviceError:
            pass

    def _write_stop(self) -> None:
        with self._cond:
            self._stop_pending = True
        self._write(apt.mot_move_stop(CONTROLLER, HOST, CHANNEL, STOP_IMMEDIATE))

    def _fail(self, error: DeviceError) -> DeviceError:
        """Record the first failure of the link, shut it down and return the error to raise."""
        with self._cond:
            if self._failure is None:
                self._failure = error
            self._cond.notify_all()
        self._shutdown()
        return error

    # --- background I/O ---------------------------------------------------------------------

    def _io_loop(self) -> None:
        try:
            while not self._stop_event.is_set():
                self._housekeeping()
                first = self._port.read(1)
                if first:
                    self._dispatch(self._read_message(first))
        except DeviceError as exc:
            if not self._stop_event.is_set():
                self._fail_from_io(exc)
        except (serial.SerialException, OSError, AttributeError) as exc:
            if not self._stop_event.is_set():
                self._fail_from_io(DeviceError(
                    f'KDC101 port {self.port_path} vanished: {exc}'))

    def _fail_from_io(self, error: DeviceError) -> None:
        log.error('KDC101: %s', error)
        if self._motion is not None:
            self._stop_quietly()
        with self._cond:
            if self._failure is None:
                self._failure = error
            self._cond.notify_all()
        self._close_port()

    def _housekeeping(self) -> None:
        with self._cond:
            updates_on, last_ack, status_time, mode, last_poll = (
                self._updates_on, self._last_ack, self._status_time, self._status_mode,
                self._last_poll)
        if not updates_on:
            return
        now = time.monotonic()
        if now - last_ack >= self.keepalive_period_s:
            self._write(apt.mot_ack_dcstatusupdate(CONTROLLER, HOST))
            with self._cond:
                self._last_ack = now
        if mode == POLLING and now - last_poll >= 1.0 / self.poll_rate_hz:
            self._write(apt.mot_req_dcstatusupdate(CONTROLLER, HOST, CHANNEL))
            with self._cond:
                self._last_poll = now
        if now - status_time > self.status_timeout_s:
            polled = (f', although polled with MOT_REQ_DCSTATUSUPDATE at '
                      f'{self.poll_rate_hz:g} Hz' if mode == POLLING else '')
            raise DeviceError(f'no status update from the KDC101 on {self.port_path} for '
                              f'{now - status_time:.1f} s (limit {self.status_timeout_s:g} s)'
                              f'{polled}; port closed')

    def _read_message(self, first: bytes):
        deadline = time.monotonic() + self.frame_timeout_s
        header = first + self._read_exact(
            HEADER_BYTES - 1, deadline,
            lambda got: f'truncated message header from the KDC101: got {got + 1} of '
                        f'{HEADER_BYTES} bytes ({(first).hex(" ")}...)')
        msgid, length = struct.unpack_from('<HH', header)
        long_form, dest, source = header[4] & 0x80, header[4] & 0x7F, header[5]
        name = message_name(msgid)
        if msgid not in id_to_func:
            raise DeviceError(f'garbled reply from the KDC101: {name} '
                              f'(header bytes {header.hex(" ")})')
        if dest not in (0x00, HOST) or source != CONTROLLER:
            raise DeviceError(f'garbled reply from the KDC101: {name} from 0x{source:02x} to '
                              f'0x{dest:02x}, expected from 0x{CONTROLLER:02x} to the host '
                              f'(header bytes {header.hex(" ")})')
        data = b''
        if long_form:
            if length > MAX_DATA_BYTES:
                raise DeviceError(f'garbled reply from the KDC101: {name} claims {length} data '
                                  f'bytes (at most {MAX_DATA_BYTES})')
            data = self._read_exact(
                length, deadline,
                lambda got: f'truncated {name} message from the KDC101: got {got} of {length} '
                            f'data bytes within {self.frame_timeout_s:g} s')
        frame = header + data
        try:
            return next(apt.Unpacker(io.BytesIO(frame), on_error='raise'))
        except (RuntimeError, StopIteration, struct.error, AssertionError, ValueError,
                IndexError) as exc:
            raise DeviceError(f'malformed {name} message from the KDC101 ({len(data)} data '
                              f'bytes: {frame.hex(" ")}): {exc}') from exc

    def _read_exact(self, count: int, deadline: float, describe: Callable[[int], str]) -> bytes:
        data = b''
        while len(data) < count:
            chunk = self._port.read(count - len(data))
            if chunk:
                data += chunk
            elif time.monotonic() > deadline or self._stop_event.is_set():
                raise DeviceError(describe(len(data)))
        return data

    def _dispatch(self, msg) -> None:
        tripped = None
        with self._cond:
            self._seq += 1
            if msg.msg == 'mot_move_stopped':
                self._stop_pending = False
            if hasattr(msg, 'moving_forward'):   # status updates and long-form end-of-move
                self._status, self._status_time = msg, time.monotonic()
                self._status_seq = self._seq
                tripped = self._check_travel(msg)
            if msg.msg in ('hw_response', 'hw_richresponse'):
                self._fault_text = f'controller error event: {msg}'
            self._events.append((self._seq, msg))
            self._cond.notify_all()
        if tripped:
            log.warning('KDC101: %s', tripped)
            self._write_stop()
        if msg.msg == 'hw_disconnect':
            raise DeviceError(f'the KDC101 on {self.port_path} announced HW_DISCONNECT')

    def _check_travel(self, status) -> Optional[str]:
        """Called with the lock held: trip (and return why) if motion passes a limit."""
        motion = self._motion
        if motion is None or motion.kind == 'home' or motion.direction == 0:
            return None
        position_m = self.scale.counts_to_position_m(status.position)
        where = f'{position_m * 1e3:.4f} mm'
        forward = motion.direction > 0
        if forward and status.forward_limit_switch:
            reason = f'forward hardware limit switch hit at {where}'
        elif not forward and status.reverse_limit_switch:
            reason = f'reverse hardware limit switch hit at {where}'
        elif forward and position_m > self.limits.max_position_m:
            reason = (f'position {where} passed the soft travel limit '
                      f'{self.limits.max_position_m * 1e3:.3f} mm')
        elif not forward and position_m < self.limits.min_position_m:
            reason = (f'position {where} passed the soft travel limit '
                      f'{self.limits.min_position_m * 1e3:.3f} mm')
        else:
            return None
        message = f'{reason} during the {motion.description}; stage stopped'
        self._motion = None
        self._stop_pending = True     # set now: the waiter may start a new move before we write
        self._trip = SafetyLimitError(message)
        self._fault_text = message
        return message
