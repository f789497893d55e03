#!/usr/bin/env python3
"""CPU per published driver report: ModuleState + measured CableLength as CDR bytes
(state_wire) against message objects filled in place and serialised by rclpy.

Both paths publish to real rclpy publishers of one node (a subscriber process is not
needed: what is measured is the publishing thread's own CPU, ``time.thread_time``),
interleaved in blocks so both see the same load; median (min-max) of ``--repeats``
blocks of ``--count`` reports each. Prints the load average at start and end.

Usage: .venv/bin/python benchmarks/state_publish_bench.py [--count 2000] [--repeats 7]
"""
from __future__ import annotations

import argparse
import sys
import time

from benchlib import fmt_spread, load_line, spread


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--count', type=int, default=2000, help='reports per block')
    parser.add_argument('--repeats', type=int, default=7, help='blocks per path')
    args = parser.parse_args()
    print(load_line('start'), flush=True)

    import rclpy
    from softsnap_interfaces.msg import CableLength, ModuleState
    from softsnap_ros.cdr import (CableLengthWire, ModuleStateFields, ModuleStateWire,
                                  fill_module_state)

    rclpy.init()
    node = rclpy.create_node('state_publish_bench')
    states = node.create_publisher(ModuleState, 'bench/m1/state', 10)
    lengths = node.create_publisher(CableLength, 'bench/m1/cable_length/measured', 50)
    state_wire, length_wire = ModuleStateWire('m1', 'm1'), CableLengthWire('m1')
    state_msg = ModuleState(module='m1')
    state_msg.header.frame_id = 'm1'
    length_msg = CableLength()
    length_msg.header.frame_id = 'm1'

    def fields(i: int) -> ModuleStateFields:   # a report as the driver makes one
        return ModuleStateFields(True, False, 0.19 - i * 1e-6, 0.19, 700 + i, 712, 255, 3.9,
                                 0.5, 0, 0, 5 * i, 2 * i, (i, 17), 0, 0, 0, 0, 0, 0, 0, '',
                                 (0, 0))

    def as_bytes(i: int) -> None:
        stamp = divmod(1_800_000_000_000_000_000 + i, 1_000_000_000)
        lengths.publish(length_wire.serialize(stamp, 0.19 - i * 1e-6))
        states.publish(state_wire.serialize(stamp, fields(i)))

    def as_objects(i: int) -> None:
        stamp = divmod(1_800_000_000_000_000_000 + i, 1_000_000_000)
        length_msg.header.stamp.sec, length_msg.header.stamp.nanosec = stamp
        length_msg.cable_length = 0.19 - i * 1e-6
        lengths.publish(length_msg)
        state_msg.header.stamp.sec, state_msg.header.stamp.nanosec = stamp
        states.publish(fill_module_state(state_msg, fields(i)))

    per = {'bytes': [], 'objects': []}
    for _ in range(args.repeats):
        for name, publish in (('objects', as_objects), ('bytes', as_bytes)):
            t0 = time.thread_time()
            for i in range(args.count):
                publish(i)
            per[name].append((time.thread_time() - t0) / args.count)
    node.destroy_node()
    rclpy.shutdown()
    for name in ('objects', 'bytes'):
        print(f'{name:8s}: {fmt_spread(per[name], 1e6)} µs of CPU per report '
              '(one ModuleState + one CableLength published)')
    ratio = spread(per['bytes'])[0] / spread(per['objects'])[0]
    print(f'bytes/objects: {ratio:.2f}; at 10 Hz a module saves '
          f'{(spread(per["objects"])[0] - spread(per["bytes"])[0]) * 10 * 100:.3f} % of a core')
    print(load_line('end'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
