"""A probe for test_two_hosts: run on one "host", prints what it sees of the robot.

``python two_host_probe.py NAMESPACE MODULE,MODULE,...`` prints one JSON line every 0.25 s
until stdin closes or SIGINT: per module the predicted and commanded shapes taken so far
and the latest driver state's ``online`` and ``commands_received`` (None before any).
"""
from __future__ import annotations

import json
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from softsnap_interfaces.msg import ModuleShape, ModuleState


def main() -> int:
    ns, modules = sys.argv[1], sys.argv[2].split(',')
    rclpy.init()
    node = rclpy.create_node('two_host_probe', namespace=ns)
    seen = {m: {'predicted': 0, 'commanded': 0, 'online': None, 'commands_received': None}
            for m in modules}

    def count(module, source):
        def take(_msg):
            seen[module][source] += 1
        return take

    def state(module):
        def take(msg):
            seen[module]['online'] = bool(msg.online)
            seen[module]['commands_received'] = int(msg.commands_received)
        return take

    for m in modules:
        node.create_subscription(ModuleShape, f'{m}/shape/predicted', count(m, 'predicted'), 50)
        node.create_subscription(ModuleShape, f'{m}/shape/commanded', count(m, 'commanded'), 50)
        node.create_subscription(ModuleState, f'{m}/state', state(m), 50)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    next_print = time.monotonic()
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
            if time.monotonic() >= next_print:
                print(json.dumps({'t': time.monotonic(), 'modules': seen}), flush=True)
                next_print += 0.25
    except KeyboardInterrupt:
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
