"""Stress: does a process destroy rclpy's signal guard conditions while rclpy's signal
thread may still be triggering them? (the SIGSEGV on SIGINT behind spin_until_shutdown)

On SIGINT rclpy's signal thread triggers every registered signal guard condition, then
shuts the contexts down; Python raises KeyboardInterrupt in the main thread meanwhile.
A main that lets its executor go as soon as KeyboardInterrupt arrives destroys the
executor's guard condition under the signal thread. With one guard condition the window
is microseconds (one CI failure in many runs); here each child registers
``--guards`` extra ones, so the signal thread's loop lasts milliseconds, and the child
destroys them all when spinning ends:

- ``plain``: ``executor.spin()``, destroyed right after KeyboardInterrupt (the old code);
- ``fixed``: :func:`softsnap_ros.spinning.spin_until_shutdown`, which returns once the
  signal thread has shut the context down.

Each run starts a child, sends SIGINT while it spins and records its exit status
(-11 = SIGSEGV). Both kinds alternate in the same run; the load average is printed.

    .venv/bin/python benchmarks/sigint_race_stress.py --runs 40 --guards 3000
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import time
from collections import Counter


def child(kind: str, guards: int) -> None:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerGuardCondition

    from softsnap_ros.spinning import spin_until_shutdown

    rclpy.init()
    node = rclpy.create_node('sigint_race_stress', start_parameter_services=False)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    extra = [SignalHandlerGuardCondition() for _ in range(guards)]
    print('ready', flush=True)
    if kind == 'fixed':
        spin_until_shutdown(executor)
    else:
        try:
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
    for guard in extra:
        guard.destroy()
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()


def run_once(kind: str, guards: int, env: dict) -> int | str:
    proc = subprocess.Popen([sys.executable, __file__, '--child', kind, '--guards', str(guards)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        if proc.stdout.readline().strip() != 'ready':
            proc.kill()
            proc.wait()
            return 'no start'
        time.sleep(random.uniform(0.0, 0.1))
        proc.send_signal(signal.SIGINT)
        return proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return 'timeout'
    finally:
        proc.stdout.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=40, help='runs of each kind')
    parser.add_argument('--guards', type=int, default=3000,
                        help='extra signal guard conditions per child (widens the race)')
    parser.add_argument('--child', choices=('plain', 'fixed'), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.guards)
        return
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(150, 230)))
    results = {'plain': Counter(), 'fixed': Counter()}
    for _ in range(args.runs):
        for kind in results:
            results[kind][run_once(kind, args.guards, env)] += 1
    print(f'load average {os.getloadavg()[0]:.2f}; {args.runs} runs of each, '
          f'{args.guards} extra guard conditions')
    for kind, counts in results.items():
        print(f'{kind:6s} exit statuses {dict(counts)}; SIGSEGV {counts[-11]}/{args.runs}')


if __name__ == '__main__':
    main()
