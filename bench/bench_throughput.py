"""Throughput of the force stream into the log: loss and CPU share (prints figures; not a test).

    .venv/bin/python bench/bench_throughput.py [--duration 60] [--rate 20000] [--block-size N]
                                               [--source sim|synthetic]

Three processes on one local ROS domain, each measured on its own from /proc/<pid>/stat:

* the source: ``ni`` (default) = loadcell_node, the DAQ node as it runs on the rig (backend
  ``hardware``, the NI-DAQmx code path), over the test suite's fake of nidaqmx
  (test/fakes_nidaq) paced to deliver samples no faster than the wall clock, as the USB-6363
  does; ``sim`` = the simulated rig (mantis_rig.simulated.sim_rig: the world and loadcell_node
  with the simulated backend, in one process); ``synthetic`` = a
  bare publisher of force blocks standing in for the DAQ node. The DAQ node is configured and
  activated here through its lifecycle services.
  With ``sim`` the DAQ's share includes the world's, and the stream runs on simulated time (it
  slips when the world falls behind);
  ``synthetic`` paces 20 kS/s on the wall clock.
* the recorder: a node with mantis_rig.nodes.recorder.Recorder writing every
  /loadcell/force_block (and /loadcell/wrench, /diagnostics) into a BagWriter bag.

After ``--duration`` seconds of recording the bag is read back: the force stream must have no
gap and hold rate x duration samples. CPU share = (user + system CPU time) / wall time of the
window, 1.0 = one core. Goal: DAQ node + recorder < 0.5.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def cpu_seconds(pid: int) -> float:
    from mantis_rig.runtime.process_state import read
    state = read(pid)
    if state is None:
        raise ProcessLookupError(f'process {pid} is gone')
    return state.cpu_s      # utime + stime


# ------------------------------------------------------------------------------- roles
def role_recorder(args) -> int:
    import rclpy
    from rclpy.node import Node

    from mantis_rig import contract
    from mantis_rig.nodes.recorder import Recorder
    from mantis_rig.recording import BagWriter

    rclpy.init()
    node = Node('bench_recorder')
    topics = [contract.FORCE_BLOCK, contract.WRENCH, contract.DIAGNOSTICS]
    recorder = Recorder(node, topics)
    bag = BagWriter(args.bag)
    recorder.start(bag)
    executor = make_executor(args.executor)
    executor.add_node(node)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        executor.spin_once(timeout_sec=0.1)
    recorder.stop()
    bag.close(trial_outcome={'result': 'bench'})
    print(json.dumps(recorder.counts), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


def make_executor(name: str):
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
    if name == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor()
    if name == 'single':
        return SingleThreadedExecutor()
    return MultiThreadedExecutor(num_threads=2)


def role_ni_daq(args) -> int:
    """loadcell_node with the hardware backend over a fake USB-6363 that keeps real time."""
    sys.path.insert(0, str(REPO / 'test'))
    from fakes_nidaq import FakeDaqSystem
    import numpy as np

    class PacedDaq(FakeDaqSystem):
        """Samples exist only once the wall clock has reached them (the real DAQ's pace)."""

        started = None

        def volts(self, task, samples):
            rate = task.timing.samp_clk_rate
            if self.started is None:
                self.started = time.monotonic() - self.position / rate
            delay = self.started + (self.position + samples) / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            return super().volts(task, samples)

    system = PacedDaq(signal_v=lambda index: 0.9 + 0.001 * np.sin(index * 1e-3))
    sys.modules.update(system.modules())
    from mantis_rig.nodes.loadcell_node import LoadcellNode
    from mantis_rig.runtime.executors import run_node
    return run_node(LoadcellNode, args=[sys.argv[0], '--ros-args', '-p', 'backend:=hardware',
                                 '-p', f'sample_rate_hz:={args.rate}',
                                 *(['-p', f'block_size:={args.block_size}']
                                   if args.block_size else [])])


def role_synthetic(args) -> int:
    import numpy as np
    import rclpy
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray

    from mantis_rig import contract
    from mantis_rig.recording.force_block import force_block_to_msg

    rclpy.init()
    node = Node(contract.LOADCELL_NODE)
    publisher = node.create_publisher(Float64MultiArray, contract.FORCE_BLOCK.name,
                                      contract.FORCE_BLOCK.qos.publisher())
    period_ns = round(1e9 / args.rate)
    n = args.block_size
    rng = np.random.default_rng(0)
    start = time.monotonic()
    index = 0
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        due = start + (index + n) / args.rate
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        publisher.publish(force_block_to_msg(index * period_ns / 1e9, period_ns / 1e9,
                                             10.0 + 0.01 * rng.standard_normal(n)))
        index += n
    node.destroy_node()
    rclpy.shutdown()
    return 0


# ------------------------------------------------------------------------------- driver
def spawn(argv, log):
    return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy())


def lifecycle(node_name: str, transitions, timeout_s=30.0) -> None:
    from lifecycle_msgs.srv import ChangeState
    import rclpy
    from rclpy.node import Node

    from mantis_rig import contract

    rclpy.init()
    node = Node('bench_lifecycle')
    client = node.create_client(ChangeState, contract.node_interface(node_name,
                                                                     contract.CHANGE_STATE))
    if not client.wait_for_service(timeout_sec=timeout_s):
        raise SystemExit(f'{node_name} did not come up')
    for transition in transitions:
        request = ChangeState.Request()
        request.transition.id = transition
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=timeout_s)
        if not future.done() or not future.result().success:
            raise SystemExit(f'{node_name}: transition {transition} failed')
    node.destroy_node()
    rclpy.shutdown()


def check_bag(path, rate):
    from mantis_rig import contract
    from mantis_rig.recording import BagReader
    from mantis_rig.recording.force_block import force_block_from_msg
    from mantis_rig.trial.force_monitor import ForceMonitor

    monitor = ForceMonitor(ceiling_n=float('inf'))
    blocks = [force_block_from_msg(m.message)
              for m in BagReader(path).messages([contract.resolve(contract.FORCE_BLOCK)])]
    for block in sorted(blocks, key=lambda b: b.t0_s):
        monitor.feed(block.t0_s, block.period_s, block.force_n)
    return monitor, len(blocks)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--duration', type=float, default=60.0, help='recording window, s')
    parser.add_argument('--rate', type=float, default=20_000.0, help='samples/s')
    parser.add_argument('--block-size', type=int, default=None,
                        help='samples per force block (default: the DAQ node\'s; synthetic 1000)')
    parser.add_argument('--source', choices=('ni', 'sim', 'synthetic'), default='ni')
    parser.add_argument('--scene', default='air_23mm_rig',
                        help='sim source: the world\'s scene (default air_23mm_rig, the cheapest)')
    parser.add_argument('--executor', choices=('multi', 'single', 'events'), default='single',
                        help='the recorder process\'s executor (default single, as in the '
                        'supervisor)')
    parser.add_argument('--role', choices=('driver', 'recorder', 'synthetic', 'ni_daq'),
                        default='driver',
                        help=argparse.SUPPRESS)
    parser.add_argument('--bag', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    from mantis_rig.runtime.ros_env import claim_local_domain
    claim_local_domain()
    if args.role == 'recorder':
        return role_recorder(args)
    if args.role == 'ni_daq':
        return role_ni_daq(args)
    if args.role == 'synthetic':
        args.block_size = args.block_size or 1000
        return role_synthetic(args)

    work = Path(tempfile.mkdtemp(prefix='bench_throughput_'))
    bag = work / 'bag'
    me = [sys.executable, str(Path(__file__).resolve())]
    logs = {name: open(work / f'{name}.log', 'wb') for name in ('daq', 'recorder')}
    processes = {}
    try:
        recorder = subprocess.Popen(me + ['--role', 'recorder', '--bag', str(bag),
                                          '--executor', args.executor],
                                    stdout=subprocess.PIPE, stderr=logs['recorder'],
                                    env=os.environ.copy())
        processes['recorder'] = recorder
        if args.source == 'sim':
            ros = ['--ros-args', '-p', f'scene:={args.scene}',
                   '-p', f'sample_rate_hz:={args.rate}']
            if args.block_size:
                ros += ['-p', f'block_size:={args.block_size}']
            processes['daq'] = spawn([sys.executable, '-m', 'mantis_rig.simulated.sim_rig', *ros],
                                     logs['daq'])
            lifecycle('loadcell_node', (1, 3))           # configure, activate
        elif args.source == 'ni':
            block = ['--block-size', str(args.block_size)] if args.block_size else []
            processes['daq'] = spawn(me + ['--role', 'ni_daq', '--rate', str(args.rate),
                                           *block], logs['daq'])
            lifecycle('loadcell_node', (1, 3))
        else:
            block = ['--block-size', str(args.block_size)] if args.block_size else []
            processes['daq'] = spawn(me + ['--role', 'synthetic', '--rate', str(args.rate),
                                           *block], logs['daq'])
        time.sleep(2.0)                                      # discovery, warm-up
        before = {name: cpu_seconds(p.pid) for name, p in processes.items()}
        wall0 = time.monotonic()
        time.sleep(args.duration)
        wall = time.monotonic() - wall0
        after = {name: cpu_seconds(p.pid) for name, p in processes.items()}
        processes['daq'].send_signal(signal.SIGINT)
        time.sleep(1.0)                                      # the last blocks in flight
        recorder.send_signal(signal.SIGTERM)
        counts, _ = recorder.communicate(timeout=60)
        monitor, blocks = check_bag(bag, args.rate)
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()
    share = {name: (after[name] - before[name]) / wall for name in processes}
    expected = monitor.duration_s * args.rate
    print(f'source: {args.source}; window {wall:.1f} s; logs and bag in {work}')
    print(f'recorded force stream: {monitor.samples} samples in {blocks} blocks over '
          f'{monitor.duration_s:.3f} s (rate x duration = {expected:.0f}); '
          f'gaps: {len(monitor.gaps)}; lost: {sum(n for _, n in monitor.gaps)} samples')
    print(f'recorder counts: {counts.decode().strip()}')
    print(f'stream produced at {monitor.samples / (wall + 1.0):.0f} samples per wall second '
          f'(the simulated world slips behind real time when it cannot keep up)')
    for name, value in share.items():
        print(f'CPU share {name:9s} {value:6.3f} core')
    total = share['daq'] + share['recorder']
    print(f'DAQ node + recorder: {total:.3f} core (goal < 0.5: '
          f'{"met" if total < 0.5 else "NOT met"})')
    # the stream must also have lasted the whole window: a source that died early loses
    # everything after it, gap-free or not
    loss_free = (not monitor.gaps and abs(monitor.samples - expected) < 1.5
                 and monitor.duration_s >= wall)
    print(f'zero loss: {"yes" if loss_free else "NO"}')
    return 0 if loss_free else 1


if __name__ == '__main__':
    sys.exit(main())
