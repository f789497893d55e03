#!/usr/bin/env python3
"""Driver shutdown benchmark: time from SIGINT to process exit of a driving driver_node.

The simulated module runs in this process; driver_node runs as its own process, started
like `ros2 run`, drives the module toward full contraction at low PWM, and gets SIGINT
while the motor runs. Its stop on shutdown must be confirmed (or given up and logged)
within the link's 1.2 s budget, and the process must exit within 2 s of SIGINT.

Cases: the module answers every request; the first 1 or 2 `reach` requests are lost
(`drop_first_reach`); the module stops answering just before SIGINT (outage: the stop
cannot be confirmed and is given up).

Usage: .venv/bin/python benchmarks/driver_shutdown_bench.py [--runs 5]
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import tempfile
import time

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402

from softsnap_driver.firmware import Faults, SimModule  # noqa: E402
from softsnap_driver.protocol import ModuleClient  # noqa: E402
from softsnap_driver.sim_module import SimServer  # noqa: E402
from softsnap_interfaces.msg import CableLength  # noqa: E402

from benchlib import start_node  # noqa: E402


def one_run(case: str) -> tuple[float, str, bool]:
    """Seconds from SIGINT to exit, the shutdown outcome in the log, module stopped."""
    faults = Faults(drop_first_reach={'lost 1 reach': 1, 'lost 2 reach': 2}.get(case, 0))
    server = SimServer(SimModule(faults=faults, start_time=time.monotonic()))
    server.start()
    with tempfile.NamedTemporaryFile(suffix='.log', delete=False) as handle:
        log = handle.name
    proc = start_node('softsnap_driver', 'driver_node', [
        '-p', f'port:={server.port}', '-p', 'pwm_power:=40', '-p', 'command_timeout_s:=0.0',
        '-p', 'counts_per_mm:=89.13', '-p', 'straight_length_m:=0.198'], log)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('shutdown_bench', context=context)
    try:
        client = ModuleClient('127.0.0.1', server.port, timeout_s=1.0)
        publisher = node.create_publisher(CableLength, 'm1/cable_length/command', 10)
        deadline = time.monotonic() + 30
        while publisher.get_subscription_count() == 0 or server.connections < 3:
            assert time.monotonic() < deadline and proc.poll() is None, open(log).read()
            time.sleep(0.05)
        publisher.publish(CableLength(cable_length=0.118))      # full contraction, slowly
        while client.status().encoder_count < 300:
            assert time.monotonic() < deadline, open(log).read()
            time.sleep(0.02)
        if case == 'outage':
            with server.lock:
                server.module.faults.outage_after_s = server.module.since_start(server.clock())
                server.module.faults.outage_duration_s = 60.0
        started = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(10)
        elapsed = time.monotonic() - started
        text = open(log).read()
        outcome = ('confirmed' if 'stop confirmed' in text and '(shutdown)' in text
                   else 'NOT confirmed' if 'stop NOT confirmed' in text else 'none logged')
        with server.lock:
            stopped = server.module.target == server.module.encoder_count
        return elapsed, outcome, stopped
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        server.stop()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--runs', type=int, default=5, help='runs per case')
    args = parser.parse_args()
    print('| case | SIGINT -> exit median (s) | max (s) | stop on shutdown | module stopped |')
    print('|---|---|---|---|---|')
    for case in ('answers', 'lost 1 reach', 'lost 2 reach', 'outage'):
        results = [one_run(case) for _ in range(args.runs)]
        times = [r[0] for r in results]
        outcomes = sorted({r[1] for r in results})
        stopped = sum(r[2] for r in results)
        print(f'| {case} | {statistics.median(times):.3f} | {max(times):.3f} | '
              f'{", ".join(outcomes)} | {stopped}/{len(results)} |', flush=True)


if __name__ == '__main__':
    main()
