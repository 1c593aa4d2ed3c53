"""Executors: a single-threaded one where callbacks never block, threads where they do.

rclpy's MultiThreadedExecutor costs about 2 ms of CPU per callback, the SingleThreadedExecutor
well under half of that (bench/bench_throughput.py --executor). Nodes whose callbacks only
record, publish or hand work to their own threads (supervisor, sim world, recorder, clients)
run on a SingleThreadedExecutor; the device nodes, whose services block (homing, tare,
simulated backends waiting for the world), need the MultiThreadedExecutor. (rclpy's
experimental EventsExecutor is cheaper still, but in rclpy 7.1 a publish from another thread
deadlocks against its spin(): the supervisor publishes from its trial thread.)
"""
from __future__ import annotations

from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor


def light_executor(context=None):
    """An executor for nodes whose callbacks never block."""
    return SingleThreadedExecutor(context=context)


def threaded_executor(num_threads: int = 8, context=None):
    return MultiThreadedExecutor(num_threads=num_threads, context=context)
