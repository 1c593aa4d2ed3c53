"""What the three device nodes share: lifecycle, checked parameters, diagnostics and faults.

configure builds the device for parameter `backend` (mantis_rig.backends) and opens it;
activate starts streaming; deactivate stops; cleanup and shutdown release the device. Any
failure to configure is a FAILURE return, its reason logged and on /diagnostics.

A device error while the device is in use is a fault: ERROR on /diagnostics at once, then the
node goes through the lifecycle's ErrorProcessing state (on_error releases the device) to
'unconfigured', from where it can be configured again. rcl's state machine enters
ErrorProcessing only from a transition, so a fault triggers deactivate (or cleanup) from the
executor and that transition returns ERROR.

Parameters carry descriptions and ranges (rclpy refuses out-of-range values); the node's own
check refuses bad values that a range cannot express, and changes to a parameter that is applied
at configure while the device is configured, each with the reason.

Services that block (homing, tare) and the simulated backends (which wait for the simulated
world) need a MultiThreadedExecutor: `executors.run_node` spins one. The simulated backends
exist only inside the simulated rig (mantis_rig.simulated.sim_rig), which gives each device node the
world and its clock.
"""
from __future__ import annotations

import threading
import time
from typing import Optional

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterUninitializedException
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter

from mantis_rig import contract
from mantis_rig.contract import DEVICE_COMMON_PARAMETERS, ParamSpec, check_backend
from mantis_rig.faults import ConfigurationError
from mantis_rig.hardware.device_interfaces import DeviceError
from mantis_rig.runtime.lean_node import WithoutDefaultEventHandlers
from mantis_sim.errors import InputError

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR
SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE


def declare(node, spec: ParamSpec):
    descriptor = ParameterDescriptor(description=spec.description)
    if spec.range is not None:
        low, high = spec.range
        if isinstance(spec.default, float):
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
        else:
            descriptor.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
    value = Parameter.Type.STRING_ARRAY if spec.default == [] else spec.default
    return node.declare_parameter(spec.name, value, descriptor)


def param_value(node, name: str):
    """The parameter's value; [] for a string array declared without one."""
    try:
        value = node.get_parameter(name).value
    except ParameterUninitializedException:
        return []
    return [] if value is None else value


#: the parameters every device node has (mantis_rig.contract)
COMMON_PARAMETERS = DEVICE_COMMON_PARAMETERS


def time_msg(t_s: float) -> Time:
    ns = round(t_s * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class DeviceNode(WithoutDefaultEventHandlers, LifecycleNode):
    DEVICE = 'device'
    PARAMETERS: tuple = ()
    def __init__(self, node_name: str, *, world_port=None, sim_clock=None, **kwargs):
        """world_port: the WorldPort of the sim backend (a LocalWorldPort), without which the
        sim backend cannot be configured; sim_clock: the SharedSimClock that sets this node's
        time. Both come from the simulated rig (mantis_rig.simulated.sim_rig)."""
        super().__init__(node_name, **kwargs)
        if sim_clock is not None:
            sim_clock.attach(self)
        self._specs = {p.name: p for p in COMMON_PARAMETERS + self.PARAMETERS}
        for spec in self._specs.values():
            declare(self, spec)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.services_group = ReentrantCallbackGroup()
        self.device = None
        self.backend_name: Optional[str] = None
        self.port = None
        self._given_port = world_port
        self._fault: Optional[str] = None
        self._fault_lock = threading.Lock()
        self._fault_signal = self.create_guard_condition(self._on_fault_signal)
        self._diag_lock = threading.Lock()
        self._level, self._message = OK, 'unconfigured'
        self._diag_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                                contract.DIAGNOSTICS.qos.publisher())
        self.create_timer(1.0, self.publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    # --- for the subclasses -------------------------------------------------------------------
    def open_device(self, port):
        """Build the device for self.backend_name via backends.py, open and set it up."""
        raise NotImplementedError

    def start_streaming(self) -> None:
        """activate"""

    def stop_streaming(self) -> None:
        """deactivate, error, shutdown; must be idempotent and never raise."""

    def diagnostic_values(self) -> dict:
        return {}

    def param(self, name: str):
        return param_value(self, name)

    @property
    def state_label(self) -> str:
        return self._state_machine.current_state[1]

    @property
    def is_active(self) -> bool:
        return self.state_label == 'active'

    def sim(self) -> bool:
        return self.backend_name == 'sim'

    def device_time_offset_s(self) -> float:
        """ROS time minus device time: 0 in simulation (the world's clock is /clock), the
        ROS clock minus time.monotonic (the hardware drivers' clock) otherwise."""
        if self.sim():
            return 0.0
        return self.get_clock().now().nanoseconds * 1e-9 - time.monotonic()

    def report(self, level, message: str) -> None:
        """Set the status shown on /diagnostics and publish it now."""
        with self._diag_lock:
            self._level, self._message = level, message
        self.publish_diagnostics()

    def fault(self, message: str) -> None:
        """A device error while the device is in use (any thread)."""
        with self._fault_lock:
            if self._fault is not None:
                return
            self._fault = message
        self.get_logger().error(f'device error: {message}')
        self.report(ERROR, f'device error: {message}')
        self._fault_signal.trigger()

    def publish_diagnostics(self) -> None:
        with self._diag_lock:
            level, message = self._level, self._message
        values = {'state': self.state_label, 'backend': str(self.backend_name or
                                                            self.param('backend'))}
        try:
            values.update(self.diagnostic_values())
        except Exception as exc:      # noqa: BLE001 - diagnostics must not take the node down
            values['diagnostics_error'] = str(exc)
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: {self.DEVICE}',
                                  message=message, hardware_id=self._hardware_id(),
                                  values=[KeyValue(key=k, value=str(v))
                                          for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(array)

    def _hardware_id(self) -> str:
        return f'{self.backend_name or self.param("backend")} {self.DEVICE}'

    # --- lifecycle ------------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        with self._fault_lock:
            self._fault = None
        try:
            self.backend_name = check_backend(self.param('backend'))
            if self.sim():
                self.port = self._world_port()
            self.device = self.open_device(self.port)
        except Exception as exc:      # noqa: BLE001 - every reason goes back to the caller
            self._release()
            reason = f'configure failed: {exc}'
            self.get_logger().error(reason)
            self.report(ERROR, reason)
            return FAILURE
        self.report(OK, f'configured ({self.backend_name}), inactive')
        return SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        try:
            self.start_streaming()
        except DeviceError as exc:
            self.stop_streaming()
            with self._fault_lock:
                self._fault = f'activate: {exc}'
            return TransitionCallbackReturn.ERROR
        except Exception as exc:      # noqa: BLE001 - a transition's boundary: any failure is ERROR with its reason
            self.stop_streaming()
            reason = f'activate failed: {exc}'
            self.get_logger().error(reason)
            self.report(ERROR, reason)
            return FAILURE
        self.report(OK, f'active ({self.backend_name})')
        return SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.stop_streaming()
        if self._fault is not None:
            return TransitionCallbackReturn.ERROR
        self.report(OK, f'inactive ({self.backend_name})')
        return SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        if self._fault is not None:
            return TransitionCallbackReturn.ERROR
        self._release()
        self.report(OK, 'unconfigured (device released)')
        return SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.stop_streaming()
        self._release()
        self.report(OK, 'finalized (device released)')
        return SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        self.stop_streaming()
        self._release()
        with self._fault_lock:
            reason, self._fault = self._fault or 'a transition failed', None
        self.report(ERROR, f'device error: {reason}; device released, node unconfigured '
                           f'(configure to retry)')
        return SUCCESS

    def destroy_node(self):
        try:
            self.stop_streaming()
            self._release()
        except Exception as exc:      # noqa: BLE001 - e.g. the context is already shut down
            self.get_logger().warning(f'releasing the {self.DEVICE}: {exc}')
        super().destroy_node()

    # --- internals ------------------------------------------------------------------------------
    def _on_fault_signal(self) -> None:
        if self._fault is None:
            return
        if self.state_label == 'active':
            self.trigger_deactivate()
        elif self.state_label == 'inactive':
            self.trigger_cleanup()

    def _world_port(self):
        if self._given_port is None:
            raise DeviceError(
                f'the simulated {self.DEVICE} runs inside the simulated rig, which gives it the '
                f'world: `ros2 run mantis_rig sim_rig` (or `mantis bringup`), not '
                f'`{self.get_name()}` alone with backend sim')
        return self._given_port

    def _release(self) -> None:
        device, self.device = self.device, None
        if device is not None:
            try:
                device.close()
            except Exception as exc:  # noqa: BLE001 - releasing must go on
                self.get_logger().warning(f'closing the {self.DEVICE}: {exc}')
        self.port = None

    def _on_set_parameters(self, params) -> SetParametersResult:
        for param in params:
            spec = self._specs.get(param.name)
            if spec is None:
                continue
            if spec.at_configure and self.state_label != 'unconfigured':
                return SetParametersResult(
                    successful=False,
                    reason=f'{param.name} is applied at configure and the node is '
                           f'{self.state_label}: deactivate and clean up first')
            if spec.check is not None:
                try:
                    spec.check(param.value)
                except (InputError, ConfigurationError) as exc:
                    return SetParametersResult(successful=False, reason=f'{param.name}: {exc}')
        return SetParametersResult(successful=True)
