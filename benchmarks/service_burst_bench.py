#!/usr/bin/env python3
"""Service bursts: how many of N simultaneous calls are answered, ROS's default service
queue (depth 10) against the stack's (softsnap_ros.service_queues, depth 1000), side
by side in the same run, and model_node's ``forward_shape`` itself.

The servers run as their own processes: a plain rclpy node whose Trigger callback takes
5 ms (created with the default QoS, then with ``create_queued_service``), and model_node
(brittle star). N clients in this process each send one call at the same moment; a call
not answered within 60 s counts as unanswered.

Usage: .venv/bin/python benchmarks/service_burst_bench.py [--clients 30 100] [--runs 3]
"""
from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import time

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from benchlib import fmt_spread, load_line, start_node  # noqa: E402

SERVER = r'''
import sys, time
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger
from softsnap_ros.service_queues import create_queued_service
rclpy.init()
node = rclpy.create_node('burst_server')
def work(request, response):
    time.sleep(0.005)
    response.success = True
    return response
if sys.argv[1] == 'default':
    node.create_service(Trigger, 'burst_default', work)
else:
    create_queued_service(node, Trigger, 'burst_queued', work)
executor = SingleThreadedExecutor()
executor.add_node(node)
try:
    executor.spin()
except BaseException:
    pass
'''


def burst(node, executor, srv_type, name, n, request) -> tuple[int, float]:
    """(answered, seconds until the last answer) of n clients calling at once."""
    from softsnap_ros.service_queues import service_qos
    clients = [node.create_client(srv_type, name, qos_profile=service_qos()) for _ in range(n)]
    deadline = time.monotonic() + 120
    while not all(c.service_is_ready() for c in clients) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    start = time.monotonic()
    futures = [c.call_async(request()) for c in clients]
    last, answered = start, 0
    while time.monotonic() - start < 60.0 and answered < n:
        executor.spin_once(timeout_sec=0.05)
        done = sum(f.done() for f in futures)
        if done > answered:
            last, answered = time.monotonic(), done
    for c in clients:
        node.destroy_client(c)
    return answered, last - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--clients', type=int, nargs='+', default=[30, 100])
    parser.add_argument('--runs', type=int, default=3)
    args = parser.parse_args()
    from softsnap_interfaces.srv import ForwardShape
    from std_srvs.srv import Trigger
    rclpy.init()
    node = rclpy.create_node('burst_bench')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    print(load_line('before'))

    def forward():
        r = ForwardShape.Request()
        r.holes = ['R3'] * 12
        r.cable_length = 0.19
        return r

    servers = {}
    for queue in ('default', 'queued'):
        servers[queue] = subprocess.Popen([sys.executable, '-c', SERVER, queue],
                                          start_new_session=True)
    model = start_node('softsnap_model', 'model_node', ['-r', '__ns:=/burst_bench',
                                                        '-p', 'scene:=brittle_star'], os.devnull)
    try:
        print(f'{"server":34s} {"clients":>7s} {"answered, median (min-max)":>28s} '
              f'{"s to the last answer":>22s}')
        for n in args.clients:
            for label, srv, name, request in (
                    ('Trigger, ROS default queue (10)', Trigger, '/burst_default', Trigger.Request),
                    ('Trigger, create_queued_service', Trigger, '/burst_queued', Trigger.Request),
                    ('model_node forward_shape', ForwardShape,
                     '/burst_bench/model_node/forward_shape', forward)):
                runs = [burst(node, executor, srv, name, n, request) for _ in range(args.runs)]
                print(f'{label:34s} {n:7d} {fmt_spread([r[0] for r in runs], digits=0):>28s} '
                      f'{fmt_spread([r[1] for r in runs], digits=2):>22s}', flush=True)
    finally:
        for proc in servers.values():
            if proc.poll() is None:
                proc.kill()
        model.send_signal(2)
        model.wait(30)
    print(load_line('after'))


if __name__ == '__main__':
    main()
