#!/usr/bin/env python3
"""Graph benchmark: the 5-module brittle star as separate processes at 50 and 100 Hz.

Runs the demo graph (simulated modules, drivers, model node, gait node, rerun logger)
for each gait command rate and prints: end-to-end latency from a gait command to the
commanded shape published by the model node, and from a driver's measured length to the
predicted shape (median and p99, observed in a separate process); command rates achieved
against the configured rate; commands lost between the gait node and the drivers (by
their own counters); CPU (% of one core) and memory (RSS) per node.

Usage: .venv/bin/python benchmarks/graph_bench.py [--seconds 20] [--rates 50 100]
[--drivers container separate] (the demo's drivers in one driver_container, its default,
and/or one driver_node process per module)
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

from softsnap_ros.processes import stop_process_tree, tagged_env


def run_demo(rate_hz: float, seconds: float, scene: str, drivers: str = 'container') -> dict:
    # The runner starts every node in a session of its own: on a timeout or Ctrl-C,
    # stopping the runner alone would leave them running (and loading the next run).
    env, tag = tagged_env(dict(os.environ))
    with tempfile.TemporaryDirectory() as run_dir:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'softsnap_gaits.demo', '--scene', scene, '--seconds', str(seconds),
             '--gait-rate', str(rate_hz), '--model-rate', str(max(100.0, rate_hz)),
             '--drivers', drivers, '--run-dir', run_dir, '--json'],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
            env=env, start_new_session=True)
        try:
            stdout, stderr = proc.communicate(timeout=seconds + 180)
        finally:
            stop_process_tree(proc, tag)
    if proc.returncode != 0:
        raise RuntimeError(f'demo failed ({proc.returncode}):\n{stdout[-2000:]}\n{stderr[-2000:]}')
    return json.loads(stdout[stdout.index('{'):])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--rates', type=float, nargs='+', default=[50.0, 100.0])
    parser.add_argument('--scene', default='brittle_star')
    parser.add_argument('--drivers', nargs='+', choices=('container', 'separate'),
                        default=['container'],
                        help="the demo's driver processes; both modes run one after the other")
    args = parser.parse_args()
    for rate, drivers in itertools.product(args.rates, args.drivers):
        summary = run_demo(rate, args.seconds, args.scene, drivers)
        modules = summary['modules'].values()
        cmd_med = np.median([m['command_to_shape_ms']['median'] for m in modules])
        cmd_p99 = np.max([m['command_to_shape_ms']['p99'] for m in modules])
        meas_med = np.median([m['measured_to_shape_ms']['median'] for m in modules])
        meas_p99 = np.max([m['measured_to_shape_ms']['p99'] for m in modules])
        achieved = np.mean([m['command_rate_hz'] for m in modules])
        lost = sum(m['commands_lost'] or 0 for m in modules)  # gait sent - drivers received
        print(f"\n{summary['scene']}: gait at {rate:g} Hz for {summary['seconds']:g} s, "
              f"drivers: {drivers}")
        print(f'  command -> commanded shape: median {cmd_med:.2f} ms, p99 {cmd_p99:.2f} ms')
        print(f'  measured -> predicted shape: median {meas_med:.2f} ms, p99 {meas_p99:.2f} ms')
        print(f'  command rate achieved: {achieved:.1f} Hz of {rate:g} Hz per module; '
              f'commands lost: {lost}')
        print(f"  {'node':16s} {'CPU % of 1 core':>16s} {'RSS MiB':>8s}")
        for name, usage in summary['processes'].items():
            print(f"  {name:16s} {usage['cpu_percent']:16.1f} {usage['rss_mib']:8.1f}")
    print(f'\n(machine: {os.cpu_count()} cores)')


if __name__ == '__main__':
    main()
