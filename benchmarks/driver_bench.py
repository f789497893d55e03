#!/usr/bin/env python3
"""Driver benchmark: protocol rate, command-to-motion latency, command rate, CPU and memory.

Everything runs over loopback. The simulated module runs in this process (so the time a
target reaches it is read on this process's monotonic clock); driver_node runs as its own
process, started like `ros2 run`.

1. Protocol: back-to-back status requests of one ModuleClient against the sim
   (requests/s, round-trip median and p99).
2. Command -> module: a CableLength published here until the sim applies the new target
   (the motor starts moving at that instant), and until the measured topic shows the
   motion (this one also waits for the next status poll).
3. Achievable command rate: commands published at increasing rates with a new length each
   time; the rate of targets the module receives (the driver coalesces, newest wins).
4. driver_node CPU and memory: idle (polling at 10 Hz), and under 50 Hz commands.

Usage: .venv/bin/python benchmarks/driver_bench.py [--samples 50] [--seconds 5]
"""
from __future__ import annotations

import argparse
import os
import random
import statistics
import time

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import psutil  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from softsnap_driver.firmware import DEADBAND_COUNTS  # noqa: E402
from softsnap_driver.protocol import ModuleClient  # noqa: E402
from softsnap_driver.sim_module import SimServer  # noqa: E402
from softsnap_interfaces.msg import CableLength, ModuleState  # noqa: E402

from benchlib import start_node  # noqa: E402
from softsnap_ros.processes import stop_process_group  # noqa: E402

NS = '/bench'
MODULE = 'm1'
COUNTS_PER_MM = 89.13
STRAIGHT_M = 0.198


def percentile(values, q):
    ordered = sorted(values)
    return ordered[min(int(q * len(ordered)), len(ordered) - 1)]


def ms(values):
    return (f'{1e3 * statistics.median(values):.2f}', f'{1e3 * percentile(values, 0.95):.2f}',
            f'{1e3 * percentile(values, 0.99):.2f}')


def start_driver(port: int, poll_rate_hz: float):
    return start_node('softsnap_driver', 'driver_node', [
        '-r', f'__ns:={NS}', '-p', f'module:={MODULE}', '-p', f'port:={port}',
        '-p', f'counts_per_mm:={COUNTS_PER_MM}', '-p', f'straight_length_m:={STRAIGHT_M}',
        '-p', 'pwm_power:=255', '-p', f'poll_rate_hz:={poll_rate_hz}', '-p', 'command_timeout_s:=0.0'])


def bench_protocol(seconds: float) -> list[tuple[str, ...]]:
    rows = []
    with SimServer() as server:
        client = ModuleClient('127.0.0.1', server.port, timeout_s=1.0)
        times = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            start = time.perf_counter()
            client.status()
            times.append(time.perf_counter() - start)
        rows.append(('protocol: status round trip', 'ms', *ms(times)))
        rows.append(('protocol: back-to-back requests', 'req/s', f'{len(times) / seconds:.0f}', '', ''))
    return rows


class Bench:
    def __init__(self, server: SimServer):
        self.server = server
        self.node = rclpy.create_node('driver_bench')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.states = []
        self.measured = []
        base = f'{NS}/{MODULE}'
        self.node.create_subscription(ModuleState, f'{base}/state', self.states.append, 100)
        self.node.create_subscription(CableLength, f'{base}/cable_length/measured',
                                      lambda m: self.measured.append((time.monotonic(), m)), 100)
        self.publisher = self.node.create_publisher(CableLength, f'{base}/cable_length/command', 100)

    def spin_until(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not predicate():
            self.executor.spin_once(timeout_sec=0.001)
        return predicate()

    def command(self, length_m):
        msg = CableLength()
        msg.cable_length = length_m
        self.publisher.publish(msg)

    def received(self):
        with self.server.lock:
            return list(self.server.module.received_targets)

    def latency(self, samples: int):
        to_module, to_measured = [], []
        lengths = [0.19, 0.15]
        for i in range(samples):
            length = lengths[i % 2] - 0.0001 * i        # a new target every time
            count = round((STRAIGHT_M - length) * 1000 * COUNTS_PER_MM)
            before = len(self.received())
            start_count = self.states[-1].encoder_count if self.states else 0
            sent = time.monotonic()
            self.command(length)
            assert self.spin_until(lambda: len(self.received()) > before, 5.0), 'target never arrived'
            target = self.received()[-1]
            assert target.target == count
            to_module.append(target.time_s - sent)
            moved = lambda: any(t > sent and abs(round((STRAIGHT_M - m.cable_length) * 1000 * COUNTS_PER_MM)
                                                 - start_count) > DEADBAND_COUNTS
                                for t, m in self.measured[-5:])
            if self.spin_until(moved, 5.0):
                first = next(t for t, m in self.measured if t > sent and abs(round(
                    (STRAIGHT_M - m.cable_length) * 1000 * COUNTS_PER_MM) - start_count) > DEADBAND_COUNTS)
                to_measured.append(first - sent)
            self.spin_until(lambda: False, 0.4)            # let it arrive (and be polled)
        return to_module, to_measured

    def command_rate(self, rate_hz: float, seconds: float):
        before = len(self.received())
        period = 1.0 / rate_hz
        start = time.monotonic()
        n = 0
        while time.monotonic() - start < seconds:
            self.command(0.19 - 0.06 * ((n % 200) / 200.0))
            n += 1
            next_at = start + n * period
            while time.monotonic() < next_at:
                self.executor.spin_once(timeout_sec=max(next_at - time.monotonic(), 0.0))
        elapsed = time.monotonic() - start
        self.spin_until(lambda: False, 0.3)
        return n / elapsed, (len(self.received()) - before) / elapsed


def cpu_window(proc: psutil.Process, seconds: float, work=None):
    proc.cpu_percent(None)
    start = time.monotonic()
    if work is not None:
        work(seconds)
    else:
        time.sleep(seconds)
    cpu = proc.cpu_percent(None)
    return cpu, proc.memory_info().rss / 2 ** 20, time.monotonic() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--samples', type=int, default=50, help='latency samples')
    parser.add_argument('--seconds', type=float, default=5.0, help='length of each rate/CPU window (s)')
    opts = parser.parse_args()

    rows = bench_protocol(min(opts.seconds, 3.0))
    rclpy.init()
    server = SimServer()
    server.start()
    driver = start_driver(server.port, 10.0)
    try:
        bench = Bench(server)
        assert bench.spin_until(lambda: bench.states and bench.publisher.get_subscription_count() > 0, 30), \
            'driver_node did not come up'
        to_module, to_measured = bench.latency(opts.samples)
        rows.append(('command -> module applies target', 'ms', *ms(to_module)))
        rows.append(('command -> measured shows motion (10 Hz poll)', 'ms', *ms(to_measured)))
        for rate in (20, 50, 100, 200, 500):
            sent, received = bench.command_rate(rate, opts.seconds)
            rows.append((f'commands at {rate} Hz: sent / reached module', '1/s',
                         f'{sent:.0f} / {received:.0f}', '', ''))
        proc = psutil.Process(driver.pid)
        cpu, rss, _ = cpu_window(proc, opts.seconds,
                                 lambda s: bench.spin_until(lambda: False, s))
        rows.append(('driver_node idle (10 Hz poll): CPU / RSS', '% / MiB', f'{cpu:.1f} / {rss:.0f}', '', ''))
        cpu, rss, _ = cpu_window(proc, opts.seconds, lambda s: bench.command_rate(50, s))
        rows.append(('driver_node at 50 Hz commands: CPU / RSS', '% / MiB', f'{cpu:.1f} / {rss:.0f}', '', ''))
    finally:
        stop_process_group(driver)
        server.stop()
        rclpy.try_shutdown()

    header = ('measurement', 'unit', 'median', 'p95', 'p99')
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(5)]
    line = lambda r: '| ' + ' | '.join(str(c).ljust(w) for c, w in zip(r, widths)) + ' |'
    print(line(header))
    print('|' + '|'.join('-' * (w + 2) for w in widths) + '|')
    for row in rows:
        print(line(row))


if __name__ == '__main__':
    main()
