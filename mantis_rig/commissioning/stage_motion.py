"""`mantis doctor --move`: the stage homes, moves to 0.1 mm inside the lower soft limit, jogs
1 mm at 0.5 mm/s and comes back there, guarded by the force ceiling fed from the load cell in a
thread; a failure stops the stage and says where it stopped."""
from __future__ import annotations

import threading
from typing import Optional

from .check_report import FAIL, OK, Options, Report, one_line

ARRIVED_M = 0.01e-3
JOG_BASE_INSIDE_M = 0.1e-3         # the jog starts and ends this far inside the lower soft limit


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
            self.error = one_line(exc)
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


def check_motion(report: Report, options: Options, rig, stage, loadcell_ok: bool) -> None:
    from mantis_rig.hardware.device_interfaces import ConfigurationError, DeviceError
    from mantis_rig.trial.stage_guard import StageGuard
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
            one_line(exc)
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
        return (f'the stage could not be told to stop ({one_line(exc)}): the controller ends '
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


__all__ = ['check_motion']
