"""A command's ROS session: a domain of this machine's own, our stop signals, rclpy around
the work, and a prompt exit once an interrupted run has stopped everything.

`mantis trial`, `mantis bringup` and `mantis study` run their work inside one
(`ros_session`); `mantis start|abort|state` reach a running rig through `rig_client`.
"""
from __future__ import annotations

from collections.abc import Callable
import contextlib
import os

from mantis_rig.contract import START_TRIAL, resolve
from mantis_rig.faults import StackError
from mantis_rig.runtime.ros_env import claim_local_domain
from mantis_rig.runtime.stopping import StopSignals, end_process


def ros_session(command: str, run: Callable[[StopSignals], int]) -> int:
    """``run(signals)`` with rclpy initialised in a domain of its own (unless ROS_DOMAIN_ID is
    set), SIGINT and SIGTERM handled by the rig's StopSignals (named ``mantis <command>``);
    its exit status."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    claim_local_domain()
    # our handlers, not rclpy's: its handler shuts the context down before the stage's stop and
    # the trial's end could be published
    signals = StopSignals(f'mantis {command}').install()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        status = run(signals)
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    if signals.first is not None:
        # Everything is stopped and closed; the interpreter's own teardown (DDS participants)
        # takes seconds more, which an interrupted operator should not wait for.
        end_process(status)
    return status


@contextlib.contextmanager
def rig_client(command: str, namespace: str, reach_timeout_s: float):
    """A TrialClient in the rig's ``namespace``, spun in a context of its own, once the
    supervisor has answered (StackError, one line, if it does not within
    ``reach_timeout_s``)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from mantis_rig.nodes.trial_client import TrialClient
    from mantis_rig.runtime.executors import Spinner

    own_domain = not os.environ.get('ROS_DOMAIN_ID')
    claim_local_domain()
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    client = spinner = None
    try:
        client = TrialClient(namespace=namespace, context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(client)
        spinner = Spinner(executor, f'mantis {command}')
        if not client.wait_for_supervisor(reach_timeout_s):
            raise StackError(unreachable_line(namespace, reach_timeout_s, own_domain))
        yield client
    finally:
        if spinner is not None:
            spinner.stop()
        if client is not None:
            client.destroy_node()
        rclpy.try_shutdown(context=context)


def unreachable_line(namespace: str, reach_timeout_s: float, own_domain: bool) -> str:
    """The one line when no supervisor answers: where it was asked for, in which domain, and
    what to check."""
    where = resolve(START_TRIAL.name, namespace or '/')
    domain = os.environ.get('ROS_DOMAIN_ID')
    line = f'no supervisor answered at {where} within {reach_timeout_s:g} s (ROS domain ' \
           f'{domain}'
    if own_domain:
        return line + ': ROS_DOMAIN_ID was not set, so this command took a domain of its own, ' \
                      'where no rig runs; set it to the rig\'s)'
    return line + '; is the rig up, in this namespace and domain?)'


__all__ = ['rig_client', 'ros_session', 'unreachable_line']
