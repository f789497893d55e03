"""sim_module as an rclpy node: what ``sim_module --ros-args ...`` runs.

``ros2 run`` and ``launch_ros`` start executables with ``--ros-args`` followed by
``-r __node:=NAME``, ``-r __ns:=/NS``, ``--params-file FILE`` and ``-p name:=value``.
Reading those by hand misses params files (every simulated module then binds the
default port), so here rclpy reads them: every option of
:data:`softsnap_driver.sim_module.OPTIONS` is a declared parameter with a descriptor and
a range. Plain options before ``--ros-args`` (``--port 8101``) give the defaults.

The node owns no simulation state: it starts :class:`~softsnap_driver.sim_module.SimServer`
threads from the parameter values and stops them when it is destroyed. The fault
probabilities and ``delay_s`` can be changed while running (``ros2 param set
/ns/sim_yellow drop_probability 0.2``); everything else is fixed at start-up.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.parameter import Parameter

from softsnap_ros.node import SoftSnapNode, table_descriptor
from softsnap_driver.sim_module import (MAX_COUNT, OPTIONS, STOP_JOIN_S, build_parser,
                                        start_servers)
from softsnap_ros.spinning import run_simulator_main

_NEVER_TO = 1e6  # largest "after" time of a fault, s (-1: never)
#: Ranges of the options (inclusive); an option missing here is declared without one.
RANGES = {
    'port': (0, 65535),   # 0: a free port
    'count': (1, MAX_COUNT),
    'seed': (-1, 2**31 - 1),
    'drop_probability': (0.0, 1.0),
    'delay_probability': (0.0, 1.0),
    'delay_s': (0.0, 60.0),
    'garbage_probability': (0.0, 1.0),
    'reboot_after_s': (-1.0, _NEVER_TO),
    'reboot_downtime_s': (0.0, 3600.0),
    'stall_after_s': (-1.0, _NEVER_TO),
    'stall_duration_s': (-1.0, _NEVER_TO),
    'outage_after_s': (-1.0, _NEVER_TO),
    'drop_first_reach': (0, 1000),
    'outage_duration_s': (0.0, _NEVER_TO),
    'no_load_rpm': (0.001, 100000.0),
    'counts_per_rev': (1.0, 1e6),
    'load_fraction': (0.0, 0.999),
    'battery_full_v': (0.1, 50.0),
    'battery_capacity_mah': (1.0, 1e6),
    'power_sample_period_s': (0.001, 10.0),
}
#: Options that change a running module (its Faults); the others are read-only.
RUNTIME_FAULTS = ('drop_probability', 'delay_probability', 'delay_s', 'garbage_probability')


def _descriptor(name: str, kind: type, text: str) -> ParameterDescriptor:
    return table_descriptor(kind, text, RANGES.get(name), runtime=name in RUNTIME_FAULTS)


class SimModuleNode(SoftSnapNode):
    """Parameters in, :class:`SimServer` threads out; nothing else touches ROS."""

    def __init__(self, defaults: argparse.Namespace):
        super().__init__('sim_module')
        for name, (kind, _default, text) in OPTIONS.items():
            self.declare_parameter(name, kind(getattr(defaults, name)), _descriptor(name, kind, text))
        opts = argparse.Namespace(**{name: self.get_parameter(name).value for name in OPTIONS})
        self.servers = start_servers(opts)  # ValueError/OSError: main reports and exits 2
        self.add_on_set_parameters_callback(self.parameters_callback)
        for server in self.servers:
            self.get_logger().info(
                f'serving the firmware protocol on {server.host}:{server.port}')

    def parameters_callback(self, parameters: list[Parameter]) -> SetParametersResult:
        """Apply new fault settings to every module, or refuse them with the reason."""
        changes = {p.name: p.value for p in parameters if p.name in RUNTIME_FAULTS}
        if not changes:
            return SetParametersResult(successful=True)
        if not all(isinstance(v, float) and math.isfinite(v) for v in changes.values()):
            return SetParametersResult(successful=False, reason=f'expected finite numbers, got {changes}')
        try:
            # Built for every server before any is changed: all or nothing.
            faults = [dataclasses.replace(s.module.faults, **changes) for s in self.servers]
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        for server, new in zip(self.servers, faults):
            with server.lock:
                server.module.faults = new
        self.get_logger().info(f'faults changed: {changes}')
        return SetParametersResult(successful=True)

    def destroy_node(self) -> None:
        for server in getattr(self, 'servers', []):
            server.stop(STOP_JOIN_S)
        super().destroy_node()


def _stop(node: SimModuleNode) -> int:
    servers = node.servers
    node.destroy_node()
    print(f'[sim_module] stopped after {sum(s.connections for s in servers)} connections',
          flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    # Plain options (before --ros-args) give the parameters' defaults; the servers run on
    # their own threads, the executor only serves the parameter services.
    return run_simulator_main(argv, 'sim_module', build_parser, SimModuleNode, _stop,
                              served=lambda node: sum(s.connections for s in node.servers))


if __name__ == '__main__':
    sys.exit(main())
