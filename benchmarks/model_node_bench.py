#!/usr/bin/env python3
"""Model node benchmark: forward-service latency and CPU while predicting a robot.

Starts model_node as its own process (brittle star, 5 modules) and, from this process:
1. calls ~/forward_shape N times (cold solves, a different length each call) and prints
   the round-trip latency median and p99;
2. publishes commanded and measured cable lengths for all 5 modules at 100 Hz (both
   sources change every message, like a moving gait), lets the node predict at 100 Hz,
   and measures the node's CPU time over the window, with skipping on and off; a third
   run holds the lengths still (a robot at rest), where skipping saves the most.

Usage: .venv/bin/python benchmarks/model_node_bench.py [--calls 500] [--seconds 10]
"""
from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import time

import psutil
import rclpy
from rclpy.executors import SingleThreadedExecutor

from softsnap_interfaces.msg import CableLength, ModelDiagnostics, RobotShape
from softsnap_interfaces.srv import ForwardShape
from softsnap_model.scene import load_scene

from benchlib import start_node  # noqa: E402
from softsnap_ros.processes import stop_process_group  # noqa: E402

NS = '/bench'


def start_model_node(skip: bool, rate: float):
    return start_node('softsnap_model', 'model_node', [
        '-r', f'__ns:={NS}', '-p', 'scene:=brittle_star', '-p', f'rate:={rate}',
        '-p', f'skip_work:={"true" if skip else "false"}', '-p', 'diagnostics_period:=0.5'],
        log_path=os.environ.get('MODEL_BENCH_LOG'))


def spin_until(executor, predicate, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not predicate():
        executor.spin_once(timeout_sec=0.01)
    return predicate()


def service_latency(node, executor, scene, calls: int) -> list[float]:
    client = node.create_client(ForwardShape, f'{NS}/model_node/forward_shape')
    if not spin_until(executor, client.service_is_ready, 30.0):
        raise RuntimeError('forward_shape service not available')
    module = scene.modules[0]
    rng = random.Random(1)
    times = []
    for i in range(calls + 20):
        length = (module.straight_length_mm - rng.uniform(1.0, 60.0)) / 1000.0
        start = time.perf_counter()
        future = client.call_async(ForwardShape.Request(holes=list(module.holes), cable_length=length))
        spin_until(executor, future.done, 10.0)
        elapsed = time.perf_counter() - start
        assert future.result().success, future.result().message
        if i >= 20:  # the first calls warm up discovery and caches
            times.append(elapsed)
    return times


def prediction_cpu(node, executor, scene, proc, seconds: float, moving: bool) -> dict:
    pubs = {(m.name, topic): node.create_publisher(CableLength, f'{NS}/{m.name}/cable_length/{topic}', 10)
            for m in scene.modules for topic in ('command', 'measured')}
    diagnostics, robots = [], []
    node.create_subscription(ModelDiagnostics, f'{NS}/model/diagnostics', diagnostics.append, 10)
    node.create_subscription(RobotShape, f'{NS}/model/shape/predicted', robots.append, 10)
    spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs.values()), 30.0)
    ps = psutil.Process(proc.pid)
    period = 0.01
    start = time.monotonic()
    cpu_start = None
    sent = 0
    tick = 0
    while True:
        now = time.monotonic()
        if now - start > seconds + 1.0:
            break
        if cpu_start is None and now - start > 1.0:  # 1 s warm-up, then measure
            cpu_start, wall_start, sent0 = ps.cpu_times(), now, sent
            diag0 = diagnostics[-1] if diagnostics else None
        for i, m in enumerate(scene.modules):
            contraction = 30.0 + 20.0 * ((tick * 0.013 + 0.2 * i) % 1.0) if moving else 30.0
            for topic, offset in (('command', 0.0), ('measured', 0.7)):
                msg = CableLength(cable_length=(m.straight_length_mm - contraction - offset) / 1000.0)
                pubs[(m.name, topic)].publish(msg)
                sent += 1
        tick += 1
        deadline = start + tick * period
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=max(0.0, deadline - time.monotonic()))
    cpu_end, wall_end = ps.cpu_times(), time.monotonic()
    last = diagnostics[-1]  # the last report inside the measured window
    cpu = (cpu_end.user + cpu_end.system - cpu_start.user - cpu_start.system) / (wall_end - wall_start)
    solves = last.solves - (diag0.solves if diag0 else 0)
    return {'cpu_percent': 100.0 * cpu, 'messages_in_per_s': (sent - sent0) / (wall_end - wall_start),
            'solves_per_s': solves / (wall_end - wall_start),
            'mean_solve_us': (last.mean_solve_time * 1e6) if solves else 0.0,
            'skipped_unchanged': last.skipped_unchanged, 'skipped_duplicate': last.skipped_duplicate,
            'skipped_rib_points': last.skipped_rib_points,
            'rss_mib': ps.memory_info().rss / 2**20}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--calls', type=int, default=500)
    parser.add_argument('--seconds', type=float, default=10.0)
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(120, 200) % 101))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    scene = load_scene('brittle_star')
    rows = []
    rclpy.init()
    try:
        for label, skip, moving in (('moving gait, skipping on', True, True),
                                    ('moving gait, skipping off', False, True),
                                    ('robot at rest, skipping on', True, False),
                                    ('robot at rest, skipping off', False, False)):
            proc = start_model_node(skip, 100.0)
            node = rclpy.create_node('model_bench_client')
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            try:
                if not rows:
                    times = sorted(service_latency(node, executor, scene, args.calls))
                    median = statistics.median(times) * 1e3
                    p99 = times[int(0.99 * (len(times) - 1))] * 1e3
                    print(f'forward_shape round trip over {len(times)} calls: '
                          f'median {median:.3f} ms, p99 {p99:.3f} ms, max {times[-1] * 1e3:.3f} ms')
                rows.append((label, prediction_cpu(node, executor, scene, proc, args.seconds, moving)))
            finally:
                executor.shutdown()
                node.destroy_node()
                stop_process_group(proc)
    finally:
        rclpy.try_shutdown()
    print()
    print('5-module brittle star, 10 length topics at 100 Hz in, prediction at 100 Hz:')
    print(f'{"case":30s} {"CPU % of 1 core":>16s} {"msgs in/s":>10s} {"solves/s":>9s} '
          f'{"solve µs":>9s} {"RSS MiB":>8s}')
    for label, r in rows:
        print(f'{label:30s} {r["cpu_percent"]:16.1f} {r["messages_in_per_s"]:10.0f} '
              f'{r["solves_per_s"]:9.0f} {r["mean_solve_us"]:9.0f} {r["rss_mib"]:8.1f}')
    print(f'(machine: {os.cpu_count()} cores; python {sys.version.split()[0]})')


if __name__ == '__main__':
    main()
