"""camera_node: the high-speed camera's trigger as a managed node (docs/ros_interfaces.md).

Active: /camera/arm arms with `frame_rate_hz`, `pre_trigger_s`, `post_trigger_s`;
/camera/trigger fires and publishes /camera/trigger_time (time_ref: the device's time of the
trigger; header.stamp: the same instant in ROS time, on the clock of the force and marker
blocks: the world's time in simulation, device time + (ROS - monotonic) offset on hardware).
In simulation a worker thread then waits until the world has run past the recorded window and
publishes its marker frames on /camera/markers (marker blocks, metres, frame times on the
world's clock), so the executor never blocks on it.
"""
from __future__ import annotations

import sys
import threading

from sensor_msgs.msg import TimeReference
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from mantis_rig import contract
from mantis_rig.hardware import backends
from mantis_rig.hardware.interfaces import CameraConfig, ConfigurationError, DeviceError
from mantis_rig.nodes.device_node import DeviceNode, time_msg
from mantis_rig.nodes.executors import run_node
from mantis_rig.recording.marker_block import MarkerFrames, marker_blocks_to_msgs

FRAMES_TIMEOUT_S = 60.0


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

    def open_device(self, port):
        camera = backends.make_camera_trigger(self.backend_name, port,
                                              scene=self.param('scene'),
                                              overrides=[s for s in self.param('set') if s],
                                              output=self.param('lines'))
        camera.open()
        return camera

    def diagnostic_values(self) -> dict:
        values = dict(triggers=self._triggers, frames_published=self._frames_published)
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
        try:
            camera.arm(config)
        except ConfigurationError as exc:
            return _answer(response, False, f'arm refused: {exc}')
        except DeviceError as exc:
            self.fault(f'arming: {exc}')
            return _answer(response, False, f'arm failed: {exc}')
        return _answer(response, True, f'armed: {config.frame_rate_hz:g} frames/s, '
                                       f'{config.pre_trigger_s:g} s before and '
                                       f'{config.post_trigger_s:g} s after the trigger')

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
            self._fetch = threading.Thread(target=self._publish_frames, args=(camera,),
                                           name='camera-frames', daemon=True)
            self._fetch.start()
        self.publish_diagnostics()
        return _answer(response, True, f'triggered at {device_s:.6f} s (device time)')

    def _publish_frames(self, camera) -> None:
        try:
            frames = camera.marker_frames(timeout_s=FRAMES_TIMEOUT_S)
        except DeviceError as exc:
            if self.device is camera:
                self.fault(f'collecting the marker frames: {exc}')
            return
        if frames is None or len(frames.time_s) == 0:
            return
        offset_s = self.device_time_offset_s()
        window = MarkerFrames(frames.time_s + offset_s, frames.markers_m)    # on ROS time
        for msg in marker_blocks_to_msgs(window):
            self._markers_pub.publish(msg)
        self._frames_published += len(window)
        self.get_logger().info(f'published {len(window)} marker frames '
                               f'{window.time_s[0]:.4f}..{window.time_s[-1]:.4f} s')


def _answer(response, success: bool, message: str):
    response.success, response.message = success, message
    return response


def main(args=None) -> int:
    return run_node(CameraNode, args)


if __name__ == '__main__':
    sys.exit(main())
