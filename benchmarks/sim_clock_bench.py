#!/usr/bin/env python3
"""What ``use_sim_time`` costs a node: CPU per ``/clock`` message, side by side.

With ``--physics`` every node but ``sim_robot`` runs with ``use_sim_time:=true``, and
rclpy's time source subscribes each one to ``/clock`` through its executor: every message
wakes the executor. This benchmark publishes ``/clock`` at ``--rate`` Hz (wall) from this
process, with the QoS ``sim_robot`` uses, and runs an idle rclpy node in a child process
for ``--seconds``, alternately without and with ``use_sim_time`` (``--repeat`` rounds,
same load for both). It prints the child's CPU seconds and the difference per ``/clock``
message (µs) and per node at that rate (% of a core): multiply by the nodes of a graph
(the demo: 4-5 drivers, model, gait, rerun logger, its observer) for the graph's cost.

Usage: nice .venv/bin/python benchmarks/sim_clock_bench.py [--rate 100] [--seconds 15] [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time


def _child(sim_time: bool, seconds: float) -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    rclpy.init()
    node = rclpy.create_node('clock_listener', parameter_overrides=[
        Parameter('use_sim_time', Parameter.Type.BOOL, sim_time)])
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    start, cpu = time.monotonic(), time.process_time()
    while time.monotonic() - start < seconds:
        executor.spin_once(timeout_sec=0.1)
    print(time.process_time() - cpu, flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rate', type=float, default=100.0, help='/clock messages per wall second')
    parser.add_argument('--seconds', type=float, default=15.0, help='per run, s')
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--child', choices=('0', '1'), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        _child(args.child == '1', args.seconds)
        return 0
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock
    from softsnap_driver.sim_robot_node import CLOCK_QOS
    rclpy.init()
    node = rclpy.create_node('clock_source')
    publisher = node.create_publisher(Clock, '/clock', CLOCK_QOS)
    print(f'load average at start: {os.getloadavg()[0]:.1f}', flush=True)
    cpu = {False: [], True: []}
    sim_ns = 0
    for _ in range(args.repeat):
        for sim_time in (False, True):
            child = subprocess.Popen([sys.executable, __file__, '--child', '1' if sim_time else '0',
                                      '--seconds', str(args.seconds)],
                                     stdout=subprocess.PIPE, text=True)
            next_at = time.monotonic()
            while child.poll() is None:
                sim_ns += round(1e9 / args.rate)
                publisher.publish(Clock(clock=Time(sec=sim_ns // 10**9, nanosec=sim_ns % 10**9)))
                next_at += 1.0 / args.rate
                time.sleep(max(next_at - time.monotonic(), 0.0))
            cpu[sim_time].append(float(child.stdout.read()))
    wall, sim = statistics.median(cpu[False]), statistics.median(cpu[True])
    print(f'load average at end: {os.getloadavg()[0]:.1f}')
    print(f'child CPU s per {args.seconds:g} s run: wall clock {cpu[False]}, use_sim_time {cpu[True]}')
    print(f'use_sim_time at {args.rate:g} Hz of /clock: {(sim - wall) / (args.rate * args.seconds) * 1e6:.0f} µs '
          f'CPU per message, {100 * (sim - wall) / args.seconds:.1f} % of a core per node')
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
