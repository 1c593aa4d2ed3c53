"""An emulated Thorlabs KDC101 on a pseudo-terminal, speaking the APT protocol.

The driver opens `emulator.port` (the pty's slave) like a real USB serial port. One thread
reads host messages from the master side, moves the stage at constant velocity in encoder
counts (real time), and sends replies and periodic MOT_GET_USTATUSUPDATE messages; like the
real controller, it stops sending status updates when the host has not sent
MOT_ACK_USTATUSUPDATE for `ack_timeout_s`. Replies are built with struct per the APT spec;
thorlabs_apt_protocol only decodes controller-to-host messages, so host messages are
decoded here with struct as well.

Moves as the APT document describes them: MOT_MOVE_ABSOLUTE moves to its absolute position at
the maximum velocity of the last MOT_SET_VELPARAMS (a constant speed here: the acceleration is
not modelled) and ends at rest on it with MOT_MOVE_COMPLETED, whatever the host does meanwhile
(it need not be there: a bounded pull ends at its bound with the driver's process dead);
MOT_MOVE_VELOCITY moves until MOT_MOVE_STOP or a limit switch; MOT_MOVE_STOP stops at once.

Some KDC101s do not stream status after HW_START_UPDATEMSGS and only answer
MOT_REQ_USTATUSUPDATE: `streams_status=False` emulates them (`answers_status_requests=False`
as well: a controller that gives status neither way).

Fault injection: mute(), garble_next(), truncate_next(), shorten_next(), limit_switch_at(),
vanish().
"""
from __future__ import annotations

import math
import os
import select
import struct
import threading
import time
import tty
from typing import Optional

HOST, CONTROLLER, CHANNEL = 0x01, 0x50, 1
SAMPLE_PERIOD_S = 2048 / 6e6
VELOCITY_UNITS_PER_COUNT_S = SAMPLE_PERIOD_S * 2 ** 16   # APT velocity unit, per count/s

HW_REQ_INFO, HW_GET_INFO = 0x0005, 0x0006
HW_START_UPDATEMSGS, HW_STOP_UPDATEMSGS = 0x0011, 0x0012
MOD_SET_CHANENABLESTATE = 0x0210
MOT_SET_HOMEPARAMS, MOT_REQ_HOMEPARAMS, MOT_GET_HOMEPARAMS = 0x0440, 0x0441, 0x0442
MOT_SET_VELPARAMS, MOT_REQ_VELPARAMS, MOT_GET_VELPARAMS = 0x0413, 0x0414, 0x0415
MOT_MOVE_HOME, MOT_MOVE_HOMED = 0x0443, 0x0444
MOT_MOVE_ABSOLUTE, MOT_MOVE_VELOCITY = 0x0453, 0x0457
MOT_MOVE_COMPLETED, MOT_MOVE_STOP, MOT_MOVE_STOPPED = 0x0464, 0x0465, 0x0466
MOT_REQ_USTATUSUPDATE, MOT_GET_USTATUSUPDATE, MOT_ACK_USTATUSUPDATE = 0x0490, 0x0491, 0x0492
MOT_REQ_STAGEAXISPARAMS, MOT_GET_STAGEAXISPARAMS = 0x04F1, 0x04F2

# status bits (APT spec, DC servo)
FWD_LIMIT, REV_LIMIT, MOVING_FWD, MOVING_REV = 0x1, 0x2, 0x10, 0x20
MOTOR_CONNECTED, HOMING, HOMED, CHANNEL_ENABLED = 0x100, 0x200, 0x400, 0x80000000


NOISE = bytes.fromhex('a5 5a de ad be ef 13 37')


def short_message(msgid: int, param1: int = 0, param2: int = 0) -> bytes:
    return struct.pack('<HBBBB', msgid, param1, param2, HOST, CONTROLLER)


def long_message(msgid: int, data: bytes) -> bytes:
    return struct.pack('<HHBB', msgid, len(data), HOST | 0x80, CONTROLLER) + data


class Kdc101Emulator:
    def __init__(self, *, counts_per_mm: float = 34554.96, position_mm: float = 5.0,
                 homed: bool = False, travel_mm: float = 25.0, home_speed_mm_s: float = 20.0,
                 status_period_s: float = 0.1, ack_timeout_s: float = 3.0,
                 serial_number: int = 27000123, model: bytes = b'KDC101',
                 firmware: tuple = (3, 0, 10), stage_part: Optional[bytes] = b'MTS25-Z8',
                 streams_status: bool = True, answers_status_requests: bool = True):
        """stage_part: the stage the controller reports in MOT_GET_STAGEAXISPARAMS (with
        travel_mm and counts_per_mm); None: the request is not answered.
        streams_status: False ignores HW_START_UPDATEMSGS (no periodic status updates);
        answers_status_requests: False leaves MOT_REQ_USTATUSUPDATE unanswered. End-of-move
        messages (MOT_MOVE_COMPLETED, MOT_MOVE_STOPPED) carry their status either way."""
        self.counts_per_mm = counts_per_mm
        self.status_period_s = status_period_s
        self.ack_timeout_s = ack_timeout_s
        self.streams_status = streams_status
        self.answers_status_requests = answers_status_requests
        self._serial_number, self._model, self._firmware = serial_number, model, firmware
        self._stage_part, self._travel_mm = stage_part, travel_mm
        # the controller's stored homing parameters (reverse, reverse switch, 0.1 mm offset);
        # the default stored velocity is deliberately far above the rig's 2.4 mm/s ceiling
        self.homeparams = {'home_dir': 2, 'limit_switch': 1,
                           'home_velocity': round(home_speed_mm_s * counts_per_mm
                                                  * VELOCITY_UNITS_PER_COUNT_S),
                           'offset_distance': round(0.1 * counts_per_mm)}
        self._position = position_mm * counts_per_mm        # counts, float
        self._homed = homed
        self._fwd_switch = travel_mm * counts_per_mm
        self._rev_switch = -0.3 * counts_per_mm              # home (0) sits just off the switch
        self._mode: Optional[str] = None                     # 'home', 'absolute', 'velocity'
        self._direction = 0
        self._target = 0.0
        self._enabled = True
        self.velparams = {'min_velocity': 0, 'acceleration': 0, 'max_velocity': 0}
        self.received: list = []       # message ids from the host, in order
        self.acks_received = 0
        self.status_sent = 0              # periodic status updates
        self.status_requests_answered = 0
        self._updates_on = False
        self._last_ack = self._last_status = 0.0
        self._mute = False
        self._fault: Optional[tuple] = None                   # (kind, replies_only, keep)
        self._vanish = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._rx = b''
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._run, name='kdc101-emulator', daemon=True)

    # --- life cycle ---

    def start(self) -> Kdc101Emulator:
        self._last_tick = time.monotonic()
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()
        return False

    # --- observation ---

    @property
    def position_mm(self) -> float:
        with self._lock:
            return self._position / self.counts_per_mm

    @property
    def moving(self) -> bool:
        with self._lock:
            return self._mode is not None

    @property
    def mode(self) -> Optional[str]:
        """The move under way: 'home', 'absolute', 'velocity', or None at rest."""
        with self._lock:
            return self._mode

    @property
    def sending_status(self) -> bool:
        """Whether periodic status updates are currently being sent."""
        with self._lock:
            return self._updates_live(time.monotonic())

    @property
    def thread_alive(self) -> bool:
        return self._thread.is_alive()

    def set_position_mm(self, position_mm: float, homed: bool = True) -> None:
        with self._lock:
            self._position, self._homed = position_mm * self.counts_per_mm, homed

    # --- fault injection ---

    def mute(self, muted: bool = True) -> None:
        """Stop answering anything and stop sending status updates."""
        with self._lock:
            self._mute = muted

    def garble_next(self, replies_only: bool = True) -> None:
        """Replace the next reply (or the next message of any kind) with line noise."""
        with self._lock:
            self._fault = ('garble', replies_only, 0)

    def truncate_next(self, keep_bytes: int = 9, replies_only: bool = True) -> None:
        """Send only the first bytes of the next reply (or message), then fall silent."""
        with self._lock:
            self._fault = ('truncate', replies_only, keep_bytes)

    def shorten_next(self, data_bytes: int = 4, replies_only: bool = False) -> None:
        """Send the next long message as a complete frame that declares and carries only
        `data_bytes` of its data (too short for its type)."""
        with self._lock:
            self._fault = ('shorten', replies_only, data_bytes)

    def limit_switch_at(self, position_mm: float, forward: bool = True) -> None:
        """Put a hardware limit switch at this position (a stage hitting an obstacle)."""
        with self._lock:
            if forward:
                self._fwd_switch = position_mm * self.counts_per_mm
            else:
                self._rev_switch = position_mm * self.counts_per_mm

    def vanish(self) -> None:
        """Unplug the USB cable: the emulator thread closes the pty master."""
        with self._lock:
            self._vanish = True

    def vanish_at(self, position_mm: float) -> None:
        """Unplug the USB cable when a move first passes this position (mm), whatever else
        the host is doing then."""
        with self._lock:
            self._vanish_at = position_mm * self.counts_per_mm

    # --- emulator thread ---

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if self._vanish and self._master is not None:
                    os.close(self._master)
                    self._master = None
                master = self._master
            if master is None:
                time.sleep(0.01)
                continue
            readable, _, _ = select.select([master], [], [], 0.01)
            if readable:
                try:
                    self._rx += os.read(master, 4096)
                except OSError:
                    pass
            with self._lock:
                now = time.monotonic()
                self._handle_input(now)
                self._advance(now)
                if self._updates_live(now) and now - self._last_status >= self.status_period_s:
                    self._last_status = now
                    self.status_sent += 1
                    self._send(long_message(MOT_GET_USTATUSUPDATE, self._status_data()),
                               reply=False)

    def _updates_live(self, now: float) -> bool:
        return (self._updates_on and not self._mute
                and now - self._last_ack <= self.ack_timeout_s)

    def _send(self, message: bytes, reply: bool = True) -> None:
        if self._mute or self._master is None:
            return
        if self._fault is not None and (reply or not self._fault[1]):
            kind, _, keep = self._fault
            self._fault = None
            if kind == 'garble':
                message = NOISE
            elif kind == 'shorten':
                message = message[:2] + struct.pack('<H', keep) + message[4:6 + keep]
            else:
                message, self._mute = message[:keep], True
        try:
            os.write(self._master, message)
        except (BlockingIOError, OSError):
            pass    # nobody reads the port: the bytes are lost, as on a real line

    def _handle_input(self, now: float) -> None:
        while len(self._rx) >= 6:
            msgid, length = struct.unpack_from('<HH', self._rx)
            size = 6 + (length if self._rx[4] & 0x80 else 0)
            if len(self._rx) < size:
                return
            frame, self._rx = self._rx[:size], self._rx[size:]
            self.received.append(msgid)
            if not self._mute:
                self._handle(msgid, frame, now)

    def _handle(self, msgid: int, frame: bytes, now: float) -> None:
        param2 = frame[3]
        if msgid == HW_REQ_INFO:
            minor, interim, major = self._firmware[2], self._firmware[1], self._firmware[0]
            data = struct.pack('<l8sH4B60sHHH', self._serial_number, self._model.ljust(8, b'\0'),
                               16, minor, interim, major, 0, bytes(60), 1, 0, 1)
            self._send(long_message(HW_GET_INFO, data))
        elif msgid == HW_START_UPDATEMSGS:
            if self.streams_status:
                self._updates_on, self._last_ack = True, now
        elif msgid == HW_STOP_UPDATEMSGS:
            self._updates_on = False
        elif msgid == MOT_ACK_USTATUSUPDATE:
            self._last_ack = now
            self.acks_received += 1
        elif msgid == MOT_REQ_USTATUSUPDATE:
            if self.answers_status_requests:
                self.status_requests_answered += 1
                self._send(long_message(MOT_GET_USTATUSUPDATE, self._status_data()))
        elif msgid == MOD_SET_CHANENABLESTATE:
            self._enabled = param2 == 1
        elif msgid == MOT_SET_VELPARAMS:
            _, vmin, acc, vmax = struct.unpack_from('<H3l', frame, 6)
            self.velparams = {'min_velocity': vmin, 'acceleration': acc, 'max_velocity': vmax}
        elif msgid == MOT_SET_HOMEPARAMS:
            _, direction, switch, velocity, offset = struct.unpack_from('<3Hll', frame, 6)
            self.homeparams = {'home_dir': direction, 'limit_switch': switch,
                               'home_velocity': velocity, 'offset_distance': offset}
        elif msgid == MOT_REQ_HOMEPARAMS:
            p = self.homeparams
            self._send(long_message(MOT_GET_HOMEPARAMS, struct.pack(
                '<3Hll', CHANNEL, p['home_dir'], p['limit_switch'], p['home_velocity'],
                p['offset_distance'])))
        elif msgid == MOT_REQ_VELPARAMS:
            p = self.velparams
            self._send(long_message(MOT_GET_VELPARAMS, struct.pack(
                '<H3l', CHANNEL, p['min_velocity'], p['acceleration'], p['max_velocity'])))
        elif msgid == MOT_REQ_STAGEAXISPARAMS and self._stage_part is not None:
            counts = round(self.counts_per_mm)
            data = struct.pack('<HHH16sLL5l4H4L', CHANNEL, 1, 1, self._stage_part.ljust(16, b'\0'),
                               self._serial_number, counts, 0,
                               round(self._travel_mm * self.counts_per_mm), 0, 0, 0,
                               0, 0, 0, 0, 0, 0, 0, 0)
            self._send(long_message(MOT_GET_STAGEAXISPARAMS, data))
        elif msgid == MOT_MOVE_HOME:
            self._mode, self._target, self._homed = 'home', 0.0, False
            self._direction = -1 if self._position > 0 else 1
        elif msgid == MOT_MOVE_ABSOLUTE and len(frame) >= 12:
            self._target = float(struct.unpack_from('<Hl', frame, 6)[1])
            self._mode = 'absolute'
            self._direction = 1 if self._target >= self._position else -1
        elif msgid == MOT_MOVE_VELOCITY:
            self._mode, self._direction = 'velocity', 1 if param2 == 1 else -1
        elif msgid == MOT_MOVE_STOP:
            self._mode = None
            self._send(long_message(MOT_MOVE_STOPPED, self._status_data()))

    def _advance(self, now: float) -> None:
        dt, self._last_tick = now - self._last_tick, now
        if self._mode is None or not self._enabled:
            return
        speed = self._speed_counts_s()
        step = speed * dt * self._direction
        target = self._target if self._mode != 'velocity' else math.copysign(math.inf, step)
        new = self._position + step
        arrived = (new - target) * self._direction >= 0
        if arrived:
            new = target
        switch = None
        if self._mode != 'home':
            if self._direction > 0 and new >= self._fwd_switch:
                new, switch = self._fwd_switch, 'forward'
            elif self._direction < 0 and new <= self._rev_switch:
                new, switch = self._rev_switch, 'reverse'
        self._position = new
        unplug = getattr(self, '_vanish_at', None)
        if unplug is not None and min(new - step, new) <= unplug <= max(new - step, new):
            self._vanish, self._vanish_at = True, None
        if switch:
            self._mode = None
            self._send(long_message(MOT_MOVE_STOPPED, self._status_data()))
        elif arrived:
            mode, self._mode = self._mode, None
            if mode == 'home':
                self._homed = True
                self._send(short_message(MOT_MOVE_HOMED, CHANNEL))
            else:
                self._send(long_message(MOT_MOVE_COMPLETED, self._status_data()))

    def _speed_counts_s(self) -> float:
        """The speed of the current move, from the APT velocity units the host set (the
        protocol's definition, independent of the driver's apt_units)."""
        units = (self.homeparams['home_velocity'] if self._mode == 'home'
                 else self.velparams['max_velocity'])
        return units / VELOCITY_UNITS_PER_COUNT_S

    @property
    def speed_mm_s(self) -> float:
        """The speed of the current move (or of the last velocity setting), mm/s."""
        with self._lock:
            return self._speed_counts_s() / self.counts_per_mm

    def _status_data(self) -> bytes:
        bits = MOTOR_CONNECTED | (CHANNEL_ENABLED if self._enabled else 0)
        bits |= FWD_LIMIT if self._position >= self._fwd_switch - 0.5 else 0
        bits |= REV_LIMIT if self._position <= self._rev_switch + 0.5 else 0
        bits |= HOMED if self._homed else 0
        velocity_counts_s = 0.0
        if self._mode is not None:
            bits |= MOVING_FWD if self._direction > 0 else MOVING_REV
            bits |= HOMING if self._mode == 'home' else 0
            velocity_counts_s = self._speed_counts_s() * self._direction
        # velocity field: counts per servo sample period (see AptScale.status_velocity_per_mm_s)
        velocity_field = max(-32768, min(32767, round(velocity_counts_s * SAMPLE_PERIOD_S)))
        return struct.pack('<HlhHL', CHANNEL, round(self._position), velocity_field, 0, bits)


def fds_open_on(path: str) -> list[int]:
    """File descriptors of this process open on `path` (the pty's slave device; once the
    master is closed the link reads '<path> (deleted)')."""
    found = []
    for fd in os.listdir('/proc/self/fd'):
        try:
            if os.readlink(f'/proc/self/fd/{fd}') in (path, f'{path} (deleted)'):
                found.append(int(fd))
        except OSError:
            pass
    return found
