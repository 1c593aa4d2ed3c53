"""A study's ROS session: the rig brought up by the command (as `mantis trial` brings it up) or
a rig already running (``--connect``), the study's client and its continue service, and the
orderly stop: Ctrl-C or SIGTERM records the trial in progress as interrupted (its bag closed by
the supervisor, the stage stopped first), a rig fault ends the study with the row still owed.
Either way the same command resumes it."""
from __future__ import annotations

import os
from pathlib import Path
import sys
import threading

from mantis_rig.contract import START_TRIAL, STUDY_CONTINUE, STUDY_NODE, resolve
from mantis_rig.faults import StackError
from mantis_rig.study_session.record import RECORD_NAME
from mantis_rig.study_session.rig import ClientRig, PersonOperator, SimulatedOperator
from mantis_rig.study_session.runner import StudyRunner, StudySetup
from mantis_sim.studies.rig_study.plan import StudyPlan

FINAL_STATES = ('done', 'aborted')


def _say(line: str) -> None:
    from mantis_rig.runtime.stopping import say
    say(line)


class Progress:
    """A trial's state as one line: rewritten on a terminal, its end only elsewhere."""

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = stream.isatty()

    def __call__(self, line: str) -> None:
        if self.tty:
            self.stream.write('\r\033[K' + line)
            if line.endswith(FINAL_STATES):
                self.stream.write('\n')
            self.stream.flush()
        elif line.endswith(FINAL_STATES):
            _say(line)


def _continue_node(namespace: str):
    """The study's node: ``<ns>/study/continue`` (std_srvs/Trigger) lets a GUI go on."""
    from rclpy.node import Node
    from std_srvs.srv import Trigger
    proceed = threading.Event()
    node = Node(STUDY_NODE, namespace=namespace or None)

    def on_continue(request, response):
        proceed.set()
        response.success, response.message = True, 'going on with the next trial'
        return response

    node.create_service(Trigger, STUDY_CONTINUE.name, on_continue)
    return node, proceed


def _operator(ask: bool, namespace: str, proceed):
    if not ask:
        return SimulatedOperator()
    return PersonOperator(_say, resolve(STUDY_CONTINUE, namespace), proceed=proceed)


def _setup(plan: StudyPlan, args, overrides: list) -> StudySetup:
    return StudySetup(plan=plan, directory=Path(args.out).resolve(),
                      scene_overrides=tuple(overrides))


def run_with_stack(plan: StudyPlan, config, directory: Path, *, log_dir=None,
                   ask: bool = False) -> int:
    """Bring the rig up (``config``: a StackConfig, as `mantis trial` builds it, its bags under
    ``directory``/bags) and run the plan on it; the study's record in ``directory``."""
    from mantis_rig.stack.command_session import ros_session
    return ros_session('study', lambda signals: _with_stack(plan, config, directory, log_dir,
                                                            ask, signals))


def _with_stack(plan: StudyPlan, config, directory: Path, log_dir, ask: bool, signals) -> int:
    from mantis_rig.nodes.trial_client import TrialClient
    from mantis_rig.stack.bringup import Stack
    from mantis_rig.study_session.analyst import Analyst

    stack = Stack(config, log_dir=log_dir)
    signals.emergency_stop = stack.emergency_stop
    client = TrialClient(namespace=config.namespace)
    stack.add_node(client)
    node, proceed = _continue_node(config.namespace)
    stack.add_node(node)
    setup = StudySetup(plan=plan, directory=directory,
                       scene_overrides=tuple(config.scene_overrides if config.sim else []))
    analyst = Analyst()
    runner = StudyRunner(setup, None, _operator(ask or not config.sim, config.namespace,
                                                proceed), analyst, say=_say, progress=Progress())
    report = None
    try:
        stack.start()
        if not client.wait_for_supervisor(60.0, stack.check_processes):
            raise StackError('the supervisor did not come up within 60 s')
        runner.rig = ClientRig(client, alive=stack.check_processes)
        status, report = _run(runner, signals, analyst)
        return status
    finally:
        signals.shield()
        stack.stop(reason=signals.first.reason if signals.first else 'study ended',
                   signum=_signum(signals))
        client.destroy_node()
        node.destroy_node()
        _say_report(report)
        analyst.close(wait=signals.first is None)


def run_connected(plan: StudyPlan, args) -> int:
    """Run the plan on a rig already up in this ROS domain (and namespace)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from mantis_rig.nodes.trial_client import TrialClient
    from mantis_rig.runtime.executors import Spinner, light_executor
    from mantis_rig.runtime.ros_env import claim_local_domain
    from mantis_rig.runtime.stopping import StopSignals
    from mantis_rig.study_session.analyst import Analyst

    claim_local_domain()
    signals = StopSignals('mantis study').install()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    client = TrialClient(namespace=args.namespace or None)
    node, proceed = _continue_node(args.namespace)
    executor = light_executor()
    executor.add_node(client)
    executor.add_node(node)
    spinner = Spinner(executor, 'study-client')
    analyst = Analyst()
    try:
        if not client.wait_for_supervisor(30.0):
            raise StackError(f'no supervisor answers at '
                             f'{resolve(START_TRIAL, args.namespace)} in ROS domain '
                             f'{os.environ.get("ROS_DOMAIN_ID")} within 30 s: is the rig up in '
                             f'this domain?')
        backend = client.get_parameters(['backend']).get('backend')
        setup = _setup(plan, args, [])
        runner = StudyRunner(setup, ClientRig(client),
                             _operator(args.ask or backend != 'sim', args.namespace, proceed),
                             analyst, say=_say, progress=Progress())
        status, report = _run(runner, signals, analyst)
        if signals.first is not None:
            client.call('abort', timeout_s=5.0)
        _say_report(report)
        return status
    finally:
        signals.shield()
        spinner.stop()
        analyst.close(wait=signals.first is None)
        client.destroy_node()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


def _run(runner: StudyRunner, signals, analyst) -> tuple:
    """(exit status, the report's future): the report is written by the analyst while the
    rig's stack shuts down."""
    from mantis_rig.runtime.stopping import StopRequested
    try:
        runner.open()
        runner.run()
    except StopRequested as stop:
        signals.shield()
        runner.interrupted(stop.reason)
        _say(f'mantis study: {stop.reason}: the trial in progress is recorded as interrupted; '
             f'run the same command again to resume ({runner.directory / RECORD_NAME})')
        return stop.exit_status, None
    except StackError as exc:
        runner.interrupted(f'rig fault: {exc}')
        raise
    return 0, analyst.report(runner.directory)


def _say_report(report) -> None:
    if report is None:
        return
    folder, said = report.result()
    for line in said:
        _say(line)
    _say(f'report: {folder}')


def _signum(signals) -> int:
    import signal
    return signals.first.signum if signals.first is not None else signal.SIGINT


__all__ = ['run_connected', 'run_with_stack']
