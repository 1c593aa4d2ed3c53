"""RigClient: the supervisor's side of the device nodes' ROS interfaces, as a RigPort.

Every request returns a Pending at once, completed from the executor when the answer comes;
the trial sequence waits on it (and can abort meanwhile). Stopping the stage never waits: it
publishes velocity 0 and fires /stage/stop. Parameters can be set on the device nodes and, in
simulation, on the world (sim_world_node, the trial's conditions): the world takes its values
all or none (its set_parameters_atomically), so a refusal leaves its robot as it was.
"""
from __future__ import annotations

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from mantis_rig import contract
from mantis_rig.contract import DEVICE_NODES
from mantis_rig.trial.sequence import Pending

from .progress import ProgressReporter

TRIGGER_SERVICES = tuple(service.name for service in contract.DEVICE_SERVICES)
TRANSITIONS = {'configure': Transition.TRANSITION_CONFIGURE,
               'activate': Transition.TRANSITION_ACTIVATE,
               'deactivate': Transition.TRANSITION_DEACTIVATE}
SERVICE_WAIT_S = 10.0
#: the supervisor's part that reports progress (mantis_rig.nodes.progress)
TRIAL_CONSUMER = 'trial'
#: nodes whose parameters are set all or none
ATOMIC_NODES = (contract.SIM_WORLD_NODE,)


def _parameter_value(value) -> ParameterValue:
    if isinstance(value, str):
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    if isinstance(value, bool):
        return ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(value))


class RigClient:
    def __init__(self, node, callback_group=None, publish_state=None):
        self.node = node
        self._publish_state = publish_state or (lambda state, reason: None)
        group = {'callback_group': callback_group}
        c = contract
        self._triggers = {name: node.create_client(Trigger, name, **group)
                          for name in TRIGGER_SERVICES}
        self._get_state = {n: node.create_client(
            GetState, c.node_interface(n, c.GET_STATE), **group) for n in DEVICE_NODES}
        self._change_state = {n: node.create_client(
            ChangeState, c.node_interface(n, c.CHANGE_STATE), **group) for n in DEVICE_NODES}
        self._set_parameters = {n: node.create_client(
            SetParameters, c.node_interface(n, c.SET_PARAMETERS), **group)
            for n in DEVICE_NODES}
        # the world (simulation only: on hardware nothing serves it, and nothing calls it)
        self._set_parameters_atomically = {n: node.create_client(
            SetParametersAtomically, c.node_interface(n, c.SET_PARAMETERS_ATOMICALLY), **group)
            for n in ATOMIC_NODES}
        self._velocity = node.create_publisher(Float64, c.VELOCITY_COMMAND.name,
                                               c.VELOCITY_COMMAND.qos.publisher())
        self._position = node.create_publisher(Float64, c.POSITION_COMMAND.name,
                                               c.POSITION_COMMAND.qos.publisher())
        self._progress = ProgressReporter(node, TRIAL_CONSUMER)

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

    def set_camera(self, frame_rate_hz, pre_trigger_s, post_trigger_s,
                   film_dir: str = '') -> Pending:
        return self.set_parameters(contract.CAMERA_NODE, dict(zip(
            contract.CAMERA_WINDOW_PARAMETERS,
            (frame_rate_hz, pre_trigger_s, post_trigger_s, str(film_dir)))))

    def set_parameters(self, node_name: str, values: dict) -> Pending:
        """Set parameters of a device node or the world (strings as strings, booleans as
        booleans, numbers as doubles); (all set, the refusals' reasons). The world's are set
        all or none."""
        parameters = [ParameterMsg(name=name, value=_parameter_value(value))
                      for name, value in values.items()]
        if node_name in ATOMIC_NODES:
            def answer_all(response):
                result = response.result
                return (result.successful, '' if result.successful
                        else f'{node_name}: {result.reason}')
            return self._request(self._set_parameters_atomically[node_name],
                                 SetParametersAtomically.Request(parameters=parameters),
                                 answer_all)

        def answer(response):
            refused = [f'{node_name} {p.name}: {r.reason}'
                       for p, r in zip(parameters, response.results) if not r.successful]
            return (not refused, '; '.join(refused))
        return self._request(self._set_parameters[node_name],
                             SetParameters.Request(parameters=parameters), answer)

    def move_at(self, velocity_m_per_s: float) -> None:
        self._velocity.publish(Float64(data=float(velocity_m_per_s)))

    def move_to(self, position_m: float) -> None:
        self._position.publish(Float64(data=float(position_m)))

    def stop_stage(self) -> None:
        self.move_at(0.0)
        self.call(contract.STAGE_STOP.name, wait=False)

    def report_progress_to(self, direct) -> None:
        """The trial's progress goes to ``direct`` (the simulated world of this process), not
        to /progress (mantis_rig.nodes.progress.ProgressReporter.report_to)."""
        self._progress.report_to(direct)

    def report_progress(self, rig_time_s: float) -> None:
        self._progress.report(rig_time_s)

    # ------------------------------------------------------------------ plumbing
    def _full_name(self, client) -> str:
        """The service's name in the rig's namespace (its client holds the contract's)."""
        return self.node.resolve_service_name(client.srv_name)

    def _request(self, client, request, answer, wait: bool = True) -> Pending:
        if not client.service_is_ready() and not (
                wait and client.wait_for_service(timeout_sec=SERVICE_WAIT_S)):
            return Pending((False, f'service {self._full_name(client)} is not available'),
                           done=True)
        pending = Pending()

        def done(future):
            try:
                pending.set(answer(future.result()))
            except Exception as exc:  # noqa: BLE001 - a callback's boundary: any failure of the call is its (False, reason) answer
                pending.set((False, f'{self._full_name(client)}: {exc}'))
        client.call_async(request).add_done_callback(done)
        return pending
