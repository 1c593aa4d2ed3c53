"""RigClient: the supervisor's side of the device nodes' ROS interfaces, as a RigPort.

Every request returns a Pending at once, completed from the executor when the answer comes;
the trial sequence waits on it (and can abort meanwhile). Stopping the stage never waits: it
publishes velocity 0 and fires /stage/stop.
"""
from __future__ import annotations

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from mantis_rig.trial.sequence import DEVICE_NODES, Pending

from .recorder import RELIABLE

TRIGGER_SERVICES = ('stage/home', 'stage/stop', 'loadcell/tare', 'camera/arm', 'camera/trigger')
TRANSITIONS = {'configure': Transition.TRANSITION_CONFIGURE,
               'activate': Transition.TRANSITION_ACTIVATE}
SERVICE_WAIT_S = 10.0


class RigClient:
    def __init__(self, node, callback_group=None, publish_state=None):
        self.node = node
        self._publish_state = publish_state or (lambda state, reason: None)
        group = {'callback_group': callback_group}
        self._triggers = {name: node.create_client(Trigger, '/' + name, **group)
                          for name in TRIGGER_SERVICES}
        self._get_state = {n: node.create_client(GetState, f'/{n}/get_state', **group)
                           for n in DEVICE_NODES}
        self._change_state = {n: node.create_client(ChangeState, f'/{n}/change_state', **group)
                              for n in DEVICE_NODES}
        self._set_parameters = {n: node.create_client(SetParameters, f'/{n}/set_parameters',
                                                      **group) for n in DEVICE_NODES}
        self._velocity = node.create_publisher(Float64, '/stage/velocity_command', RELIABLE)
        self._position = node.create_publisher(Float64, '/stage/position_command', RELIABLE)

    # ------------------------------------------------------------------ RigPort
    def now_s(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def publish_state(self, state: str, reason: str) -> None:
        self._publish_state(state, reason)

    def get_state(self, node_name: str) -> Pending:
        return self._request(self._get_state[node_name], GetState.Request(),
                             lambda r: (True, r.current_state.label))

    def change_state(self, node_name: str, transition: str) -> Pending:
        request = ChangeState.Request()
        request.transition.id = TRANSITIONS[transition]
        return self._request(self._change_state[node_name], request,
                             lambda r: (r.success, '' if r.success else 'transition refused'))

    def call(self, service: str, wait: bool = True) -> Pending:
        return self._request(self._triggers[service], Trigger.Request(),
                             lambda r: (r.success, r.message), wait)

    def set_camera(self, frame_rate_hz, pre_trigger_s, post_trigger_s) -> Pending:
        return self.set_parameters('camera_node', {'frame_rate_hz': frame_rate_hz,
                                                   'pre_trigger_s': pre_trigger_s,
                                                   'post_trigger_s': post_trigger_s})

    def set_parameters(self, node_name: str, values: dict) -> Pending:
        """Set float parameters of a device node; (all set, the refusals' reasons)."""
        request = SetParameters.Request()
        for name, value in values.items():
            request.parameters.append(ParameterMsg(name=name, value=ParameterValue(
                type=ParameterType.PARAMETER_DOUBLE, double_value=float(value))))

        def answer(response):
            refused = [f'{node_name} {p.name}: {r.reason}'
                       for p, r in zip(request.parameters, response.results) if not r.successful]
            return (not refused, '; '.join(refused))
        return self._request(self._set_parameters[node_name], request, answer)

    def move_at(self, velocity_m_per_s: float) -> None:
        self._velocity.publish(Float64(data=float(velocity_m_per_s)))

    def move_to(self, position_m: float) -> None:
        self._position.publish(Float64(data=float(position_m)))

    def stop_stage(self) -> None:
        self.move_at(0.0)
        self.call('stage/stop', wait=False)

    # ------------------------------------------------------------------ plumbing
    def _request(self, client, request, answer, wait: bool = True) -> Pending:
        if not client.service_is_ready() and not (
                wait and client.wait_for_service(timeout_sec=SERVICE_WAIT_S)):
            return Pending((False, f'service {client.srv_name} is not available'), done=True)
        pending = Pending()

        def done(future):
            try:
                pending.set(answer(future.result()))
            except Exception as exc:   # the call failed in the client library
                pending.set((False, f'{client.srv_name}: {exc}'))
        client.call_async(request).add_done_callback(done)
        return pending
