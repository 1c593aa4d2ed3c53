"""loadcell_node: the load-cell DAQ as a managed node (docs/ros_interfaces.md).

Active: a reader thread calls read_block in a loop and publishes every block on
/loadcell/force_block (force-block convention: first-sample time on the ROS clock and period;
consecutive blocks join without a gap unless the DAQ reports an overrun), and the 1/k-window
means on /loadcell/wrench at about `wrench_rate_hz` (k = sample rate / wrench rate, stamped at
the window's centre). A force above `force_ceiling_n` stops the stage (0 on
/stage/velocity_command and a /stage/stop call) and is an ERROR on /diagnostics until the next
activate; the driver layer has its own limits too. /loadcell/tare zeroes the reading; the
hardware DAQ cannot tare while acquiring, so there the stream pauses for the tare.
"""
from __future__ import annotations

import sys
import threading

from geometry_msgs.msg import WrenchStamped
import numpy as np
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from mantis_rig import backends, contract
from mantis_rig.contract import FORCE_CEILING_NAME
from mantis_rig.hardware.device_interfaces import DaqConfig, DeviceError
from mantis_rig.nodes.device_node import ERROR, WARN, DeviceNode
from mantis_rig.recording.force_block import force_block_to_msg
from mantis_rig.runtime.executors import run_node


class LoadcellNode(DeviceNode):
    DEVICE = 'load cell'
    PARAMETERS = contract.LOADCELL_PARAMETERS

    def __init__(self, node_name: str = contract.LOADCELL_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        c = contract
        self._block_pub = self.create_publisher(Float64MultiArray, c.FORCE_BLOCK.name,
                                                c.FORCE_BLOCK.qos.publisher())
        self._wrench_pub = self.create_publisher(WrenchStamped, c.WRENCH.name,
                                                 c.WRENCH.qos.publisher())
        self._wrench_msg = WrenchStamped()       # filled in for each window (reader thread)
        self._wrench_msg.header.frame_id = 'loadcell'
        self._stage_velocity_pub = self.create_publisher(Float64, c.VELOCITY_COMMAND.name,
                                                         c.VELOCITY_COMMAND.qos.publisher())
        self._stage_stop = self.create_client(Trigger, c.STAGE_STOP.name,
                                              callback_group=self.services_group)
        self.create_service(Trigger, c.TARE.name, self._on_tare,
                            callback_group=self.services_group)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._offset_ns = 0
        self._read_timeout_s = 2.0
        # called with each published block's end (rig time, s) by the reader thread: the
        # simulated world of this process, which paces itself by the stream (sim_rig), instead
        # of a subscription of its own
        self.on_block_published = None
        self._reset_counters()

    # --- lifecycle hooks --------------------------------------------------------------------
    def open_device(self, port):
        config = DaqConfig(channel=self.param('channel'),
                           sample_rate_hz=self.param('sample_rate_hz'),
                           newtons_per_volt=self.param('newtons_per_volt'),
                           block_size=self.param('block_size'))
        daq = backends.make_force_daq(self.backend_name, port, scene=self.param('scene'),
                                      overrides=[s for s in self.param('set') if s],
                                      seed=self.param('seed'), config=config)
        daq.open()
        try:
            daq.configure(config)
        except Exception:
            daq.close()
            raise
        return daq

    def start_streaming(self) -> None:
        self._reset_counters()
        self._offset_ns = round(self.device_time_offset_s() * 1e9)
        block_s = self.param('block_size') / self.param('sample_rate_hz')
        self._read_timeout_s = (10.0 if self.sim() else 2.0) + 2 * block_s
        self.device.start()
        self._stop.clear()
        self._thread = threading.Thread(target=self._read_loop, args=(self.device,),
                                        name='loadcell-reader', daemon=True)
        self._thread.start()

    def stop_streaming(self) -> None:
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._stop.set()
        daq = self.device
        if daq is not None:
            try:
                daq.stop()
            except DeviceError as exc:
                self.get_logger().warning(f'stopping the acquisition: {exc}')
        if thread is not threading.current_thread():
            thread.join(timeout=self._read_timeout_s + 1.0)

    def diagnostic_values(self) -> dict:
        values = dict(blocks=self._blocks, samples=self._samples, overruns=self._overruns,
                      ceiling_trips=self._ceiling_trips)
        if self._last_n is not None:
            values.update(force_n=f'{self._last_n:.4f}', peak_force_n=f'{self._peak_n:.4f}')
        return values

    # --- the stream -------------------------------------------------------------------------
    def _reset_counters(self) -> None:
        self._blocks = self._samples = self._overruns = self._ceiling_trips = 0
        self._last_n = None
        self._peak_n = -np.inf
        self._over_ceiling = False
        self._carry = np.empty(0)
        self._carry_t0_s = 0.0
        self._decimation = None

    def _read_loop(self, daq) -> None:
        while not self._stop.is_set():
            try:
                block = daq.read_block(timeout_s=self._read_timeout_s)
            except DeviceError as exc:
                if not self._stop.is_set():
                    self.fault(f'reading the load cell: {exc}')
                return
            try:
                self._publish(block)
            except Exception as exc:  # noqa: BLE001 - a publishing bug must show, not hang
                self.fault(f'publishing a force block: {exc!r}')
                return

    def _publish(self, block) -> None:
        # The block moves from the device's clock to ROS time, which counts whole nanoseconds
        # (the offset is a count of them): the message carries that instant in seconds.
        t0_ns = self._offset_ns + round(block.t0_s * 1e9)
        t0_s = t0_ns * 1e-9
        forces = np.asarray(block.force_n, dtype=np.float64)
        period_s = round(block.period_s * 1e9) / 1e9
        self._block_pub.publish(force_block_to_msg(t0_ns / 1e9, period_s, forces))
        published = self.on_block_published
        if published is not None:
            published(t0_ns / 1e9 + forces.size * period_s)
        self._blocks += 1
        self._samples += forces.size
        self._last_n = float(forces[-1])
        self._peak_n = max(self._peak_n, float(forces.max()))
        if block.overrun:
            self._overruns += 1
            self.report(WARN, f'DAQ overrun before the block at {t0_s:.6f} s: samples lost')
        self._publish_wrenches(t0_s, block.period_s, forces, reset=block.overrun)
        self._check_ceiling(t0_s, block.period_s, forces)

    def _publish_wrenches(self, t0_s, period_s, forces, reset) -> None:
        k = max(1, round(1.0 / (period_s * self.param('wrench_rate_hz'))))
        if reset or k != self._decimation or self._carry.size == 0:
            self._carry, self._carry_t0_s, self._decimation = np.empty(0), t0_s, k
        samples = np.concatenate([self._carry, forces])
        windows = samples.size // k
        means = samples[:windows * k].reshape(windows, k).mean(axis=1)
        centres = self._carry_t0_s + (np.arange(windows) * k + (k - 1) / 2) * period_s
        self._carry = samples[windows * k:]
        self._carry_t0_s += windows * k * period_s
        # one message, filled in and published for each window (publish serializes it at once);
        # only the reader thread publishes wrenches
        msg = self._wrench_msg
        stamp = msg.header.stamp
        for t_s, force in zip(centres.tolist(), means.tolist()):
            stamp.sec, stamp.nanosec = divmod(round(t_s * 1e9), 1_000_000_000)
            msg.wrench.force.x = force
            self._wrench_pub.publish(msg)

    def _check_ceiling(self, t0_s, period_s, forces) -> None:
        ceiling = self.param(FORCE_CEILING_NAME)
        i = int(np.argmax(forces))
        if forces[i] <= ceiling:
            self._over_ceiling = False
            return
        if self._over_ceiling:
            return
        self._over_ceiling = True
        self._ceiling_trips += 1
        self._stage_velocity_pub.publish(Float64(data=0.0))
        if self._stage_stop.service_is_ready():
            self._stage_stop.call_async(Trigger.Request())
        reason = (f'force {forces[i]:.3f} N above the ceiling {ceiling:.3f} N at '
                  f'{t0_s + i * period_s:.4f} s: stage stop requested')
        self.get_logger().error(reason)
        self.report(ERROR, reason)

    # --- tare -------------------------------------------------------------------------------
    def _on_tare(self, request, response):
        daq = self.device
        if daq is None or self.state_label not in ('inactive', 'active'):
            response.success = False
            response.message = f'tare refused: loadcell_node is {self.state_label}'
            return response
        pause = self._thread is not None and not self.sim()
        try:
            if pause:
                self.stop_streaming()
            offset_v = daq.tare()
            if pause:
                self.start_streaming()
        except DeviceError as exc:
            self.fault(f'tare: {exc}')
            response.success, response.message = False, f'tare failed: {exc}'
            return response
        response.success = True
        response.message = f'tared: offset {offset_v:.6f} V' + (
            ' (acquisition restarted)' if pause else '')
        return response


def main(args=None) -> int:
    return run_node(LoadcellNode, args)


if __name__ == '__main__':
    sys.exit(main())
