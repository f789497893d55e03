"""driver_container: several modules' drivers in one process (one per module, as separate
processes would run them).

Each module gets the same :class:`~softsnap_driver.driver_node.DriverNode` as a
``driver_node`` process: node ``<module>_driver``, the same parameters, topics,
services, link worker thread and safety behaviour (docs/safety.md). What they share is
what an rclpy process costs whatever it does: the DDS participant and its threads, one
executor for the services and parameters, one diagnostics timer per distinct
``diagnostics_period_s`` (each executor wake costs milliseconds here: it rebuilds a wait
set over every node's services), and one command thread
(:class:`~softsnap_driver.driver_node.CommandInbox`, on node ``driver_container_inbox``)
that waits on every module's command topic at once and hands each command to its own
module's driver. With several modules on one machine (the simulated robot, or one
computer driving a robot's modules over Wi-Fi) that fixed cost is paid once
(docs/driver.md, "Several modules in one process").

Parameters of the container node ``driver_container`` (read-only):

- ``modules`` (string array, required): the module names, e.g. ``[yellow, blue]``;
- ``ports`` (integer array, optional): module i's TCP port is ``ports[i]``;
- ``hosts`` (string array, optional): module i's address is ``hosts[i]``.

Every other parameter is a driver's own: a global ``-p name:=value`` applies to every
driver, and a parameters file addresses one driver by its fully qualified node name
(``/robot/yellow_driver: ros__parameters: {port: 8101}``; a bare ``yellow_driver`` key
matches only outside a namespace). ``ports``/``hosts`` entries win over both.

A module that fails (its link offline, a reboot, an unconfirmed stop) affects no other:
each has its own link thread and state. On Ctrl-C or SIGTERM every link stops in
parallel (each with its confirmed stop, ``stop_on_shutdown``), within the same 2 s budget
as one driver.
"""
from __future__ import annotations

import sys
import threading

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter

from softsnap_driver.driver_node import (_NAME, COMMAND_WAIT_S, STOP_UNCONFIRMED_EXIT,
                                         CommandInbox, DriverNode, steady_timer)
from softsnap_driver.link_config import SHUTDOWN_BUDGET_S
from softsnap_ros.spinning import inbox_node, run_nodes_main


def _read_only_array(kind: int, description: str) -> ParameterDescriptor:
    return ParameterDescriptor(type=kind, description=description, read_only=True)


class DriverContainer(Node):
    """Reads which modules to drive and builds one :class:`DriverNode` for each."""

    def __init__(self, **kwargs):
        super().__init__('driver_container', **kwargs)
        self.declare_parameter('modules', Parameter.Type.STRING_ARRAY, _read_only_array(
            ParameterType.PARAMETER_STRING_ARRAY, 'Names of the modules driven by this process'))
        self.declare_parameter('ports', Parameter.Type.INTEGER_ARRAY, _read_only_array(
            ParameterType.PARAMETER_INTEGER_ARRAY,
            'TCP port of each module, in the order of modules (optional)'))
        self.declare_parameter('hosts', Parameter.Type.STRING_ARRAY, _read_only_array(
            ParameterType.PARAMETER_STRING_ARRAY,
            'Address of each module, in the order of modules (optional)'))
        self.drivers: list[DriverNode] = []
        self._inbox_node: Node | None = None
        self.commands: CommandInbox | None = None

    def _array(self, name: str) -> list:
        """An array parameter's value; [] when it was not given."""
        try:
            return list(self.get_parameter(name).value or [])
        except ParameterUninitializedException:
            return []

    def module_overrides(self) -> list[tuple[str, list[Parameter]]]:
        """(module, parameters set for its driver) for each module; ValueError when the
        lists do not make one driver per module."""
        modules = self._array('modules')
        if not modules:
            raise ValueError('parameter modules must name at least one module, '
                             'e.g. modules:=[yellow,blue]')
        for name in modules:
            if not _NAME.match(name):
                raise ValueError(f'module names must be like "yellow" ([A-Za-z][A-Za-z0-9_]*), '
                                 f'got {name!r} in modules')
        if len(set(modules)) != len(modules):
            raise ValueError(f'module names must differ, got {list(modules)}')
        overrides = [[Parameter('module', Parameter.Type.STRING, name)] for name in modules]
        for key, kind in (('ports', Parameter.Type.INTEGER), ('hosts', Parameter.Type.STRING)):
            values = self._array(key)
            if not values:
                continue
            if len(values) != len(modules):
                raise ValueError(f'{key} must give one value per module ({len(modules)}: '
                                 f'{list(modules)}), got {len(values)}: {list(values)}')
            for parameters, value in zip(overrides, values):
                parameters.append(Parameter(key[:-1], kind, value))
        return list(zip(modules, overrides))

    def start_drivers(self) -> None:
        """One driver per module; ValueError (the drivers built so far are stopped)."""
        modules = self.module_overrides()
        # One command thread for every module (CommandInbox says why).
        self._inbox_node = inbox_node(f'{self.get_name()}_inbox', self.get_namespace(),
                                      self.context)
        self.commands = CommandInbox(self._inbox_node)
        for module, parameters in modules:
            name = f'{module}_driver'
            # A node-local remap: a process-wide `-r __node:=X` must not rename them all.
            self.drivers.append(DriverNode(
                name, inbox=self.commands, diagnostics_timer=False,
                parameter_overrides=parameters, cli_args=['--ros-args', '-r', f'__node:={name}']))
        periods: dict[float, list[DriverNode]] = {}
        for driver in self.drivers:
            periods.setdefault(driver.diagnostics_period_s, []).append(driver)
        self.diagnostics_timers = [
            steady_timer(self, period, lambda group=group: self.diagnostics_callback(group))
            for period, group in periods.items()]

    @staticmethod
    def diagnostics_callback(drivers: list[DriverNode]) -> None:
        """Each driver's own diagnostics and battery messages; one driver's failure is
        logged on its own logger and does not skip the others (each had its own timer)."""
        for driver in drivers:
            try:
                driver.diagnostics_callback()
            except Exception as exc:  # noqa: BLE001 - report it and go on to the next module
                driver.get_logger().error(f'diagnostics failed: {exc!r}',
                                          throttle_duration_sec=1.0)

    def stop_drivers(self) -> int:
        """Stop every link at once (each within its own budget), then destroy the nodes.

        Each driver's stop_link closes its command route at once; the shared command
        thread is told to end now and joined before its node is destroyed. Returns the
        exit status: STOP_UNCONFIRMED_EXIT if a driver's last stop was not confirmed."""
        if self.commands is not None:
            self.commands.stop(0.0)
        threads = [threading.Thread(target=d.stop_link, name=f'stop:{d.module}')
                   for d in self.drivers]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(SHUTDOWN_BUDGET_S + 2 * COMMAND_WAIT_S + 0.1)
        failed = [d.module for d in self.drivers if d.last_stop_failed()]
        for driver in self.drivers:
            driver.destroy_node()   # links already stopped: returns at once
        self.drivers = []
        if self._inbox_node is not None:
            self.commands.stop(2 * COMMAND_WAIT_S)
            self._inbox_node.destroy_node()
            self._inbox_node = None
        if failed:
            print(f'[driver_container] last stop NOT confirmed for: {", ".join(failed)}',
                  file=sys.stderr, flush=True)
        return STOP_UNCONFIRMED_EXIT if failed else 0


def main(args=None):
    def build(at_exit):
        container = DriverContainer()
        at_exit(container.destroy_node)
        at_exit(container.stop_drivers)      # runs first: the links' stops, in parallel
        container.start_drivers()
        # One thread for all drivers' executor work (services, parameters, diagnostics):
        # their callbacks never do I/O (each link's worker thread does).
        return [container, *container.drivers]

    return run_nodes_main(args, 'driver_container', build)


if __name__ == '__main__':
    sys.exit(main())
