#!/usr/bin/env python3
"""How late a process joining a running graph gets its first messages, with and without
the nodes' Fast DDS profile (``softsnap_ros/fastdds_profile.xml``), side by side.

Five publisher processes (rclpy, 100 Hz each on one topic) run for a while; then a
late joiner, a plain rclpy process without any profile (as ``ros2 bag record`` or a
viewer would be), subscribes and notes, per publisher, the time from its subscription's
creation to that publisher's first message. ``--trials`` late joiners one after another,
for publishers with the profile (participants announced every second) and without it
(Fast DDS's 3 s), the two settings alternating in separate ROS domains. Also the CPU
that the faster announcements cost: ``--idle`` idle rclpy processes per setting, CPU
over ``--seconds`` from the kernel, per process.

ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, as the demo and the tests run.

Usage: .venv/bin/python benchmarks/discovery_bench.py [--rounds 2] [--trials 8]
       [--idle 8] [--seconds 15]
Prints median, 90th percentile and maximum of the delays per setting (over publishers
and trials), how many late joiners waited more than 1.5 s for some publisher, and the
idle CPU per process; the load average at start and end.
"""
from __future__ import annotations

import argparse
import os
import random
import statistics
import subprocess
import sys
import time
from pathlib import Path

import psutil

from benchlib import load_line

HERE = Path(__file__).resolve()
PUBLISHERS = 5
TOPIC = '/discovery_bench'


def env_for(domain: int, profile: bool) -> dict:
    """A child's environment: ``domain``, loopback only, the nodes' profile or none."""
    from softsnap_ros.dds_profile import PROFILES_FILE_VARIABLES, use_node_profile

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    for name in PROFILES_FILE_VARIABLES:
        env.pop(name, None)
    if profile:
        use_node_profile(env)
    return env


def child(kind: str, index: int) -> None:
    """(child process) ``publish``: UInt32 ``index`` at 100 Hz; ``idle``: a node that
    only spins; ``join``: the late joiner, prints one delay (s) per publisher."""
    import rclpy
    from std_msgs.msg import UInt32

    rclpy.init()
    if kind == 'join':
        node = rclpy.create_node('late_joiner')
        first: dict[int, float] = {}
        start = time.monotonic()
        node.create_subscription(UInt32, TOPIC,
                                 lambda m: first.setdefault(m.data, time.monotonic() - start),
                                 100)
        while len(first) < index and time.monotonic() < start + 15.0:
            rclpy.spin_once(node, timeout_sec=0.05)
        print(' '.join(f'{first.get(i, float("nan")):.3f}' for i in range(index)), flush=True)
        return
    node = rclpy.create_node(f'{kind}_{index}')
    if kind == 'publish':
        publisher = node.create_publisher(UInt32, TOPIC, 100)
        msg = UInt32(data=index)
        node.create_timer(0.01, lambda: publisher.publish(msg))
    try:
        rclpy.spin(node)
    except BaseException:   # noqa: BLE001 - SIGINT ends the child
        pass


def spawn(kind: str, index: int, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(HERE), '--child', kind, str(index)], env=env,
                            stdout=subprocess.PIPE if kind == 'join' else subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, text=True)


def stop(procs) -> None:
    for proc in procs:
        proc.send_signal(2)
    for proc in procs:
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def late_joins(domain: int, profile: bool, trials: int) -> list[list[float]]:
    """Per trial, the delay (s) of each publisher's first message to a late joiner."""
    publishers = [spawn('publish', i, env_for(domain, profile)) for i in range(PUBLISHERS)]
    try:
        time.sleep(4.0)   # running and discovered among themselves
        out = []
        for _ in range(trials):
            joiner = spawn('join', PUBLISHERS, env_for(domain, False))
            text, _ = joiner.communicate(timeout=60)
            out.append([float(v) for v in text.split()])
            time.sleep(0.3)
        return out
    finally:
        stop(publishers)


def idle_cpu(domain: int, profile: bool, count: int, seconds: float) -> float:
    """% of a core per idle rclpy process, ``count`` of them in one domain."""
    procs = [spawn('idle', i, env_for(domain, profile)) for i in range(count)]
    try:
        time.sleep(6.0)
        ps = [psutil.Process(p.pid) for p in procs]
        c0, t0 = sum(sum(p.cpu_times()[:2]) for p in ps), time.monotonic()
        time.sleep(seconds)
        c1, t1 = sum(sum(p.cpu_times()[:2]) for p in ps), time.monotonic()
        return 100.0 * (c1 - c0) / (t1 - t0) / count
    finally:
        stop(procs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=2)
    parser.add_argument('--trials', type=int, default=8, help='late joiners per round')
    parser.add_argument('--idle', type=int, default=8, help='idle processes for the CPU')
    parser.add_argument('--seconds', type=float, default=15.0, help='CPU window (s)')
    parser.add_argument('--child', nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]))
        return 0
    print(load_line('start'), flush=True)
    base = random.randint(150, 200)
    settings = {'nodes\' profile (1 s)': True, 'Fast DDS default (3 s)': False}
    delays = {name: [] for name in settings}
    cpu = {name: [] for name in settings}
    for round_ in range(args.rounds):
        for k, (name, profile) in enumerate(settings.items()):
            domain = base + 2 * round_ + k
            trials = late_joins(domain, profile, args.trials)
            delays[name].extend(trials)
            worst = [max(t) for t in trials]
            print(f'  round {round_ + 1}, {name}: the slowest publisher per late joiner '
                  f'{" ".join(f"{w:.2f}" for w in worst)} s', flush=True)
            cpu[name].append(idle_cpu(domain, profile, args.idle, args.seconds))
            print(f'  round {round_ + 1}, {name}: idle process {cpu[name][-1]:.3f} % of a '
                  'core', flush=True)
    print(f'\nlate joiner (no profile), first message from each of {PUBLISHERS} running '
          f'publishers, {args.rounds * args.trials} joins per setting; idle rclpy process, '
          f'{args.idle} running, median [range] of {args.rounds} windows of {args.seconds:g} s:')
    for name in settings:
        flat = sorted(v for trial in delays[name] for v in trial)
        p90 = flat[int(0.9 * (len(flat) - 1))]
        slow = sum(max(trial) > 1.5 for trial in delays[name])
        print(f'  {name:24s} delay median {statistics.median(flat):.2f} s, p90 {p90:.2f} s, '
              f'max {flat[-1]:.2f} s; joins waiting > 1.5 s for some publisher: {slow} of '
              f'{len(delays[name])}; idle CPU {statistics.median(cpu[name]):.3f} % '
              f'[{min(cpu[name]):.3f}-{max(cpu[name]):.3f}] of a core per process')
    print(load_line('end'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
