"""Executors: a single-threaded one where callbacks never block, threads where they do; and
run_node, the main() of every node process.

rclpy's MultiThreadedExecutor costs about 2 ms of CPU per callback, the SingleThreadedExecutor
well under half of that (bench/bench_throughput.py --executor). Nodes whose callbacks only
record, publish or hand work to their own threads (supervisor, sim world, clients)
run on a SingleThreadedExecutor; the device nodes, whose services block (homing, tare,
simulated backends waiting for the world), need the MultiThreadedExecutor. (rclpy's
experimental EventsExecutor is cheaper still, but in rclpy 7.1 a publish from another thread
deadlocks against its spin(): the supervisor publishes from its trial thread. The side nodes,
which only subscribe, do take it: SideNode.)
"""
from __future__ import annotations

import os
import sys
import threading
import time

import rclpy
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import (
    ExternalShutdownException,
    MultiThreadedExecutor,
    ShutdownException,
    SingleThreadedExecutor,
)
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions

from mantis_rig.contract import side_node_name
from mantis_rig.faults import USAGE_ERROR, ConfigurationError
from mantis_rig.runtime.lean_node import LeanNode
from mantis_rig.runtime.memory import limit_malloc_arenas
from mantis_rig.runtime.ros_env import claim_local_domain
from mantis_rig.runtime.stopping import (
    PROCESS_STOPPING,
    StopRequested,
    StopSignals,
    stop_reason,
    watch_parent,
)
from mantis_sim.errors import InputError

NODE_THREADS = 4        # a device node process: its blocking services and backend waits


def light_executor(context=None):
    """An executor for nodes whose callbacks never block."""
    return SingleThreadedExecutor(context=context)


def threaded_executor(num_threads: int = 8, context=None):
    return MultiThreadedExecutor(num_threads=num_threads, context=context)


SPIN_CHECK_S = 0.1          # how often a Spinner looks at its stop flag
# ... when its executor is one of rclpy's Python executors, which stop() wakes: each idle
# wake-up makes a timer for the timeout and rebuilds the wait set in Python over all its nodes'
# entities (some 40 services on the device nodes' executor), and the stop flag ends the wait
# itself. (The EventsExecutor waits in C++, cheap when idle; its wake() does not end a
# spin_once, so it keeps SPIN_CHECK_S.)
PYTHON_SPIN_CHECK_S = 1.0


class Spinner:
    """An executor spun in a thread of its own, and stopped without racing rclpy.

    rclpy 7.1's Executor.shutdown() neither waits for callbacks in progress nor for spin() to
    leave its wait set, yet destroys the guard condition spin() waits on: the spinning thread
    then died with "'NoneType' object has no attribute 'handle'", and callbacks still queued
    ran against destroyed nodes ("The following exception was never retrieved: cannot use
    Destroyable because destruction was requested"). Here the thread stops first (it spins in
    slices of SPIN_CHECK_S, or PYTHON_SPIN_CHECK_S; stop() wakes it), then the callbacks a
    MultiThreadedExecutor handed to its pool finish, and only then is the executor shut down;
    its nodes can then be destroyed."""

    def __init__(self, executor, name: str):
        self.executor = executor
        self.name = name
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        # rclpy's Python executors: spin once, or until the stop flag is set and stop()'s
        # wake() has the wait look at it (as rclpy 7.1's spin_once_until_future_complete does
        # with a future's done(), without a callback added to it at every call)
        until_stopped = getattr(self.executor, '_spin_once_impl', None)
        while not self._stop.is_set():
            try:
                if until_stopped is not None:
                    until_stopped(PYTHON_SPIN_CHECK_S, self._stop.is_set)
                else:
                    self.executor.spin_once(timeout_sec=SPIN_CHECK_S)
            except (ExternalShutdownException, ShutdownException):
                return
            except Exception as exc:      # noqa: BLE001 - one callback's bug: report, go on
                print(f'{self.name}: a callback failed: {exc!r}', file=sys.stderr, flush=True)

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        try:
            self.executor.wake()            # out of its wait now, not at the slice's end
        except Exception:                   # noqa: BLE001 - shut down already: it returns anyway
            pass
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        deadline = time.monotonic() + timeout_s
        for future in list(getattr(self.executor, '_futures', ())):   # MultiThreadedExecutor
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.005)
        self.executor.shutdown(timeout_sec=0)


class SideNode:
    """A node of its own beside `owner`, spun by rclpy's EventsExecutor in its own thread.

    For high-rate topics a node with blocking services must not route through its
    MultiThreadedExecutor, which rebuilds its wait set in Python over all of the node's entities
    on every wake-up (100 force blocks a second cost a simulated DAQ node a whole core). A side
    node only subscribes: its callbacks run in its thread, and nothing publishes on it from
    another thread (the case in which rclpy 7.1's EventsExecutor deadlocks), so it takes the
    EventsExecutor, which waits and dispatches in C++: the recorder's thread, which writes every
    message of a trial, costs half the CPU it did on a SingleThreadedExecutor. close() stops it
    and destroys the node."""

    def __init__(self, owner, suffix: str):
        self.node = LeanNode(side_node_name(owner.get_name(), suffix),
                             namespace=owner.get_namespace(), context=owner.context,
                             start_parameter_services=False)
        executor = EventsExecutor(context=owner.context)
        executor.add_node(self.node)
        self._spinner = Spinner(executor, suffix)

    def close(self) -> None:
        self._spinner.stop()
        self.node.destroy_node()


STACK_PARENT_ENV = 'MANTIS_STACK_PARENT'    # set by a stack for its node processes
SIGNAL_CHECK_S = 0.05       # how soon a node process's main thread sees a stop signal


def spin_in_slices(executor, check_stop=lambda: None) -> None:
    """executor.spin() in slices of SIGNAL_CHECK_S, until its context shuts down; between
    slices ``check_stop()`` (StopSignals.raise_if_stopped) may raise the stop a signal asked for.

    A node process's stop signals are handled in Python (run_node), and Python runs a handler
    only when the main thread is between bytecodes; rclpy's wait blocks in C until one of the
    executor's entities is ready, which in a quiet node is its next timer: the simulated rig
    stopped its stage up to a second after SIGINT (the world's 1 Hz diagnostics)."""
    while executor.context.ok():
        check_stop()
        executor.spin_once(timeout_sec=SIGNAL_CHECK_S)


def run_node(node_class, args=None, make_executor=None) -> int:
    """main() of a node process: local DDS, init, spin, clean up; the exit status.

    `make_executor`: a factory called after init; default a MultiThreadedExecutor (the device
    nodes' services block). A node whose parameters are refused at construction exits 2 with
    the reason. SIGINT and SIGTERM end the spin here rather than in rclpy's handler, which would
    shut the context down first: the node still stops its device (a node's `emergency_stop`)
    and the supervisor aborts its trial and closes its log (`shutdown_trial`) before the
    context goes; the exit status is then 130 or 143. A node process of a stack also stops when
    the stack's process is gone or frozen; the supervisor then aborts its trial with the reason
    the stack stops for, when it gave one (stopping.stop_reason: the node process that died)."""
    claim_local_domain()
    limit_malloc_arenas()          # before the node's threads: a long bring-up stays flat
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    signals = StopSignals(node_class.__name__,
                          emergency_stop=lambda: _call(node, 'emergency_stop')
                          ).install(deferred=True)
    if os.environ.get(STACK_PARENT_ENV, '').isdigit():
        watch_parent(int(os.environ[STACK_PARENT_ENV]))
    status = 0
    try:
        try:
            node = node_class()
        except (InputError, ConfigurationError, InvalidParameterValueException) as exc:
            print(f'{node_class.__name__}: {exc}', file=sys.stderr)
            return USAGE_ERROR
        signals.raise_if_stopped()
        if hasattr(node, 'spin'):            # several nodes that spin themselves (sim_rig)
            node.spin(signals.raise_if_stopped)
        else:
            executor = make_executor() if make_executor else threaded_executor(NODE_THREADS)
            executor.add_node(node)
            spin_in_slices(executor, signals.raise_if_stopped)
    except StopRequested as stop:
        status = stop.exit_status
        _call(node, 'emergency_stop', f'{PROCESS_STOPPING}: {stop.reason}')
        # no return of the stage after this abort, nor after one under way (the stack is
        # shutting down: a return would wait for a stage that may be gone)
        _call(getattr(node, 'sequence', None), 'stop_where_it_is')
        # the stack's reason when it gave one (a node process that ended, froze or hung)
        _call(node, 'shutdown_trial', stop_reason(stop.reason))
    except ExternalShutdownException:
        pass
    finally:
        signals.shield()
        if node is not None:
            _call(node, 'destroy_node')     # a failure here is reported, not a new exit status
        rclpy.try_shutdown()
    return status


def _call(node, method: str, *args) -> None:
    function = getattr(node, method, None)
    if function is None:
        return
    try:
        function(*args)
    except Exception as exc:       # noqa: BLE001 - the rest of the shutdown must go on
        # the class, not get_name(): a node half destroyed has no name to give any more
        print(f'{type(node).__name__}: {method}: {exc}', file=sys.stderr, flush=True)
