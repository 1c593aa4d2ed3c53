"""camera_node: the high-speed camera's trigger as a managed node (docs/ros_interfaces.md).

Active: /camera/arm arms with `frame_rate_hz`, `pre_trigger_s`, `post_trigger_s`;
/camera/trigger fires and publishes /camera/trigger_time (time_ref: the device's time of the
trigger; header.stamp: the same instant in ROS time, on the clock of the force and marker
blocks: the world's time in simulation, device time + (ROS - monotonic) offset on hardware).
In simulation a worker thread then waits until the world has run past the recorded window and
publishes its marker frames on /camera/markers (marker blocks, metres, frame times on the
world's clock), so the executor never blocks on it.

Filming (simulation; docs/simulated_rig.md, "Filming"): with `film_dir` set when the camera is
armed, the worker also takes the recorded window's poses from the world, and once the marker
frames are published a film thread renders that window into `film_dir` (written whole or not
at all; one film after another), so that neither the trial nor the next arm waits for it. A
film that fails leaves `<film_dir>.failed` holding why, and an ERROR line. The hardware camera
records itself (the Phantom's own .cine): there `film_dir` is refused.
"""
from __future__ import annotations

from pathlib import Path
import queue
import sys
import threading
import time

from sensor_msgs.msg import TimeReference
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from mantis_rig import backends, contract
from mantis_rig.hardware.device_interfaces import (
    CameraConfig,
    ConfigurationError,
    DeviceError,
    FilmError,
)
from mantis_rig.nodes.device_node import DeviceNode, time_msg
from mantis_rig.recording.marker_block import MarkerFrames, marker_blocks_to_msgs
from mantis_rig.runtime.executors import run_node

FRAMES_TIMEOUT_S = 60.0
FILM_DIR = 'film_dir'


def film_failed_path(film_dir) -> Path:
    """Where the camera says why it could not film into ``film_dir``."""
    film_dir = Path(film_dir)
    return film_dir.with_name(film_dir.name + contract.FILM_FAILED_SUFFIX)


class CameraNode(DeviceNode):
    DEVICE = 'camera'
    PARAMETERS = contract.CAMERA_PARAMETERS

    def __init__(self, node_name: str = contract.CAMERA_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        c = contract
        self._time_pub = self.create_publisher(TimeReference, c.TRIGGER_TIME.name,
                                               c.TRIGGER_TIME.qos.publisher())
        self._markers_pub = self.create_publisher(Float64MultiArray, c.MARKERS.name,
                                                  c.MARKERS.qos.publisher())
        self.create_service(Trigger, c.CAMERA_ARM.name, self._on_arm,
                            callback_group=self.services_group)
        self.create_service(Trigger, c.CAMERA_TRIGGER.name, self._on_trigger,
                            callback_group=self.services_group)
        self._fetch: threading.Thread | None = None
        self._triggers = 0
        self._frames_published = 0
        self._last_trigger_s = None
        self._armed_film_dir = ''
        self._films: queue.Queue = queue.Queue()
        self._filmer: threading.Thread | None = None
        self._filmer_lock = threading.Lock()
        self._films_written = 0
        self._films_failed = 0

    def _on_set_parameters(self, params):
        result = super()._on_set_parameters(params)
        if not result.successful:
            return result
        values = {p.name: p.value for p in params}
        backend = values.get('backend', self.param('backend'))
        film_dir = values.get(FILM_DIR, '')
        if film_dir and backend != 'sim':
            result.successful = False
            result.reason = (f'{FILM_DIR}: the {backend} camera records the strike itself (the '
                             f'Phantom\'s own .cine); only the simulated camera films into '
                             f'{FILM_DIR}')
        elif film_dir and not Path(film_dir).is_absolute():
            result.successful = False
            result.reason = f'{FILM_DIR}: {film_dir!r} is not an absolute path'
        return result

    def open_device(self, port):
        camera = backends.make_camera_trigger(self.backend_name, port,
                                              scene=self.param('scene'),
                                              overrides=[s for s in self.param('set') if s],
                                              output=self.param('lines'))
        camera.open()
        return camera

    def diagnostic_values(self) -> dict:
        values = dict(triggers=self._triggers, frames_published=self._frames_published)
        if self._films_written or self._films_failed:
            values.update(films_written=self._films_written, films_failed=self._films_failed)
        camera = self.device
        if camera is not None:
            status = camera.status()
            values.update(armed=status.armed, triggered=status.triggered)
        if self._last_trigger_s is not None:
            values['last_trigger_device_time_s'] = f'{self._last_trigger_s:.6f}'
        return values

    # --- services ---------------------------------------------------------------------------
    def _on_arm(self, request, response):
        camera = self.device
        if not self.is_active:
            return _answer(response, False, f'arm refused: camera_node is {self.state_label}')
        if self._fetch is not None and self._fetch.is_alive():
            return _answer(response, False, 'arm refused: the marker frames of the last '
                                            'recording are still being collected')
        config = CameraConfig(frame_rate_hz=self.param('frame_rate_hz'),
                              pre_trigger_s=self.param('pre_trigger_s'),
                              post_trigger_s=self.param('post_trigger_s'))
        film_dir = self.param(FILM_DIR) if self.sim() else ''
        try:
            camera.arm(config)
        except ConfigurationError as exc:
            return _answer(response, False, f'arm refused: {exc}')
        except DeviceError as exc:
            self.fault(f'arming: {exc}')
            return _answer(response, False, f'arm failed: {exc}')
        self._armed_film_dir = film_dir
        return _answer(response, True, f'armed: {config.frame_rate_hz:g} frames/s, '
                                       f'{config.pre_trigger_s:g} s before and '
                                       f'{config.post_trigger_s:g} s after the trigger'
                                       + (f'; filming into {film_dir}' if film_dir else ''))

    def _on_trigger(self, request, response):
        camera = self.device
        if not self.is_active:
            return _answer(response, False,
                           f'trigger refused: camera_node is {self.state_label}')
        status = camera.status()
        if not status.armed:
            return _answer(response, False, 'trigger refused: the camera is not armed')
        if status.triggered:
            return _answer(response, False, f'trigger refused: already triggered at '
                                            f'{status.trigger_time_s:.6f} s; arm again')
        try:
            device_s = camera.trigger()
        except DeviceError as exc:
            self.fault(f'trigger: {exc}')
            return _answer(response, False, f'trigger failed: {exc}')
        msg = TimeReference(time_ref=time_msg(device_s), source='camera')
        msg.header.stamp = time_msg(device_s + self.device_time_offset_s())
        self._time_pub.publish(msg)
        self._triggers += 1
        self._last_trigger_s = device_s
        if self.sim():
            self._fetch = threading.Thread(target=self._publish_frames,
                                           args=(camera, self._armed_film_dir),
                                           name='camera-frames', daemon=True)
            self._fetch.start()
        self.publish_diagnostics()
        return _answer(response, True, f'triggered at {device_s:.6f} s (device time)')

    def _publish_frames(self, camera, film_dir: str = '') -> None:
        try:
            frames = camera.marker_frames(timeout_s=FRAMES_TIMEOUT_S)
        except DeviceError as exc:
            if self.device is camera:
                self.fault(f'collecting the marker frames: {exc}')
            if film_dir:
                self._film_failed(film_dir, f'no marker frames: {exc}')
            return
        take = None
        if film_dir:          # the world forgets and runs on: its poses are taken now
            try:
                take = camera.take(timeout_s=FRAMES_TIMEOUT_S)
                if take is None:
                    self._film_failed(film_dir, 'the camera recorded no frame')
            except DeviceError as exc:
                self._film_failed(film_dir, str(exc))
        if frames is None or len(frames.time_s) == 0:
            return
        offset_s = self.device_time_offset_s()
        window = MarkerFrames(frames.time_s + offset_s, frames.markers_m)    # on ROS time
        for msg in marker_blocks_to_msgs(window):
            self._markers_pub.publish(msg)
        self._frames_published += len(window)
        self.get_logger().info(f'published {len(window)} marker frames '
                               f'{window.time_s[0]:.4f}..{window.time_s[-1]:.4f} s')
        if take is not None:
            self._queue_film(camera, film_dir, take)

    # --- filming (simulation) ---------------------------------------------------------------
    def _queue_film(self, camera, film_dir: str, take) -> None:
        self._films.put((camera, film_dir, take, int(self.param('seed'))))
        with self._filmer_lock:
            if self._filmer is None:
                self._filmer = threading.Thread(target=self._film_worker, name='camera-film',
                                                daemon=True)
                self._filmer.start()

    def _film_worker(self) -> None:
        """Render the queued films one after another, for the node's life."""
        while True:
            camera, film_dir, take, seed = self._films.get()
            started = time.monotonic()
            try:
                result = camera.film(film_dir, take, seed=seed)
            except FilmError as exc:
                self._film_failed(film_dir, str(exc))
                continue
            except Exception as exc:  # noqa: BLE001 - the film thread's boundary: a bug is its film's failure, said where it is looked for
                self._film_failed(film_dir, f'{type(exc).__name__}: {exc}')
                continue
            self._films_written += 1
            self.get_logger().info(f'filmed {result.frame_count} frames at '
                                   f'{result.rate_hz:g} frames/s into {film_dir} in '
                                   f'{time.monotonic() - started:.1f} s')

    def _film_failed(self, film_dir: str, reason: str) -> None:
        self._films_failed += 1
        self.get_logger().error(f'no film in {film_dir}: {reason}')
        try:
            path = film_failed_path(film_dir)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(reason + '\n', encoding='utf-8')
        except OSError as exc:
            self.get_logger().error(f'cannot write why into {film_failed_path(film_dir)}: '
                                    f'{exc}')


def _answer(response, success: bool, message: str):
    response.success, response.message = success, message
    return response


def main(args=None) -> int:
    return run_node(CameraNode, args)


if __name__ == '__main__':
    sys.exit(main())
