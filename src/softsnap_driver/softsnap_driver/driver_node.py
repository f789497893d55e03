"""driver_node: bridge one Wi-Fi SoftSnap module to cable-length topics.

For a module named M (parameter ``module``), relative to the node's namespace:

- subscribes ``M/cable_length/command`` (softsnap_interfaces/CableLength, metres);
- publishes ``M/cable_length/measured`` (CableLength, metres) while the module is
  calibrated and ``M/state`` (softsnap_interfaces/ModuleState) at the poll rate, from the
  freshest reply (online or not), and the state at once when an event field changes
  (:meth:`DriverNode.report_callback`, docs/driver.md "Publishing rate");
- publishes ``M/battery`` (sensor_msgs/BatteryState) and, on the absolute
  ``/diagnostics``, a diagnostic_msgs/DiagnosticArray with the module's status, every
  ``diagnostics_period_s`` (levels: :mod:`softsnap_driver.diagnostics`,
  docs/diagnostics.md);
- serves ``M/calibrate``, ``M/pause``, ``M/resume`` and ``M/stop`` (std_srvs/Trigger).

Time: stamps are the node's ROS clock. With ``use_sim_time:=true`` (a simulated robot,
``sim_robot`` publishing ``/clock``) that is the simulation's time, and so is the clock the
link measures the module's motion by (stall timeout, reboot speed check); the link's own
timeouts (requests, backoff, offline, stale commands, stop deadlines) and the
``/diagnostics`` period stay on the wall clock, so a stopped ``/clock`` freezes none of
them (docs/safety.md, "Simulated time"). ``use_sim_time`` is read once, at start-up.

The node is thin: it adapts parameters, messages and services to
:class:`softsnap_driver.link.ModuleLink`, which owns all module I/O in a worker thread,
and :class:`softsnap_driver.core.CableCalibration`, which converts lengths to encoder
counts (count 0 = straight; positive counts shorten the cable when ``count_sign`` = +1).
"""
from __future__ import annotations

import math
import re
import sys
import threading
import time

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import BatteryState
from softsnap_interfaces.msg import CableLength, ModuleState
from std_srvs.srv import Trigger

from softsnap_ros.cdr import check_wire, read_cable_length
from softsnap_driver.core import DEFAULT_CLAMP_MARGIN_M, STOP_UNCONFIRMED_EXIT, CableCalibration
from softsnap_driver.diagnostics import DriverHealth, battery_state, diagnostic_name
from softsnap_driver.link import ModuleLink
from softsnap_driver.link_config import LinkConfig
from softsnap_driver.link_report import LinkReport
from softsnap_driver.protocol import FIRMWARE_DEADBAND_COUNTS
from softsnap_ros.node import SoftSnapNode, float_range, integer_range
from softsnap_ros.service_queues import create_queued_service
from softsnap_ros.spinning import inbox_node, run_nodes_main
from softsnap_ros.units import sec_nanosec
from softsnap_ros.wait_loop import SubscriptionWaiter
from softsnap_ros.cdr import (CableLengthWire, ModuleStateFields, ModuleStateWire,
                              fill_module_state)

#: Default winch: 2800 counts per output revolution (N20 encoder, 7 PPR x4, 1:100) on a
#: 10 mm diameter spool. Calibrate it per module (docs/driver.md).
DEFAULT_COUNTS_PER_MM = 2800.0 / (math.pi * 10.0)

_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


# name: (default, descriptor). One declarative table: the README's table mirrors it.
PARAMETERS = {
    'module': ('m1', ParameterDescriptor(
        description='Module name; topics and services live under <module>/', read_only=True)),
    'host': ('127.0.0.1', ParameterDescriptor(
        description='Module IP address (or host name without the words status/set/...)', read_only=True)),
    'port': (80, integer_range('Module TCP port (80 on the firmware)', 1, 65535, read_only=True)),
    'counts_per_mm': (DEFAULT_COUNTS_PER_MM, float_range(
        'Encoder counts per millimetre of cable (calibrated per winch), counts/mm', 0.01, 100000.0)),
    'straight_length_m': (0.198, float_range('Cable length of the straight module, m', 0.001, 10.0)),
    'min_contraction_m': (0.0, float_range('Smallest allowed contraction (straight minus cable length), m', 0.0, 10.0)),
    'max_contraction_m': (0.080, float_range('Largest allowed contraction, m', 0.0, 10.0)),
    'count_sign': (1, integer_range('+1 if positive encoder counts shorten the cable, -1 otherwise', -1, 1, 2)),
    'pwm_power': (200, integer_range('Motor PWM power sent with every target, 0-255', 0, 255)),
    'poll_rate_hz': (10.0, float_range('Status polls per second, Hz', 0.1, 200.0)),
    'command_timeout_s': (1.0, float_range(
        'Stop the module where it is when no command came for this long, s (0: never)', 0.0, 3600.0)),
    'request_timeout_s': (0.5, float_range('Deadline of one HTTP request to the module, s', 0.01, 30.0)),
    'offline_after_failures': (3, integer_range('Consecutive failed requests before the module is offline', 1, 1000)),
    'max_backoff_s': (5.0, float_range('Longest wait between retries of an offline module, s', 0.01, 600.0)),
    'reboot_zero_band_counts': (60, integer_range('A count this close to 0 may mean a reboot, counts', 0, 1_000_000)),
    'reboot_min_jump_counts': (300, integer_range('Only a fall from at least this far is a reboot, counts', 1, 1_000_000_000)),
    'max_speed_counts_per_s': (20000.0, float_range(
        'Fastest the winch can move; faster falls to 0 are reboots, counts/s', 1.0, 1e9)),
    'stall_timeout_s': (1.0, float_range(
        'Outside the deadband with no progress for this long: stalled, stop it, s (0: never)', 0.0, 3600.0)),
    'stop_on_shutdown': (True, ParameterDescriptor(
        description='Stop the module (confirmed reach, within the shutdown budget) when the driver exits')),
    'clamp_margin_m': (DEFAULT_CLAMP_MARGIN_M, float_range(
        'Commands at most this far outside the allowed length range are clamped; further out refused, m',
        0.0, 1.0)),
    'stop_deadline_s': (1.0, float_range(
        'Retry reach until the stop is confirmed, for at most this long, then report and keep trying, s',
        0.05, 60.0)),
    'target_deadband_counts': (FIRMWARE_DEADBAND_COUNTS, integer_range(
        'A new target this close to the module\'s target waits for the next poll slot '
        '(at most one poll period) instead of a request of its own, counts (0: send every change)',
        0, 100_000)),
    'diagnostics_period_s': (1.0, float_range(
        'Period of /diagnostics and <module>/battery messages, s', 0.1, 60.0, read_only=True)),
}


#: How long a stop waits for the command thread to end (s); a stop wakes it at once.
COMMAND_WAIT_S = 0.05
#: Longest the command thread blocks in one wait with no command arriving (s): a safety
#: net only, since a stop, a new or closed route and the context's shutdown each wake it
#: through its guard condition (it woke 20 times a second, idle, before).
COMMAND_IDLE_WAIT_S = 1.0


class _Route:
    """One command topic of a :class:`CommandInbox`: its subscription (and the rclpy
    handle of it, read once: ``Subscription.handle`` is a Python property), its
    module's handler and logger. ``open`` is read and cleared under the inbox's lock."""

    __slots__ = ('subscription', 'rcl', 'handle', 'logger', 'open')

    def __init__(self, subscription, handle, logger):
        self.subscription, self.rcl = subscription, subscription.handle
        self.handle, self.logger = handle, logger
        self.open = True


class CommandInbox:
    """Takes the command topics' messages on one thread, blocked in ``rcl_wait``.

    Why not an executor subscription: every executor wake rebuilds its wait set over all
    of the node's entities (parameter and trigger services...) in Python, about 0.5 ms a
    message on the loaded development machine, so 50 Hz commands alone cost 2-3% of a
    core. Here one wait set holds the command subscriptions only, on an inbox node no
    executor spins.

    Why one thread for several modules (``driver_container``): a gait publishes every
    module's command at nearly the same instant. One wait set over all the modules'
    subscriptions, taking from every ready one per wake, wakes once or a few times per
    burst instead of once per command (five modules at 50 Hz: ~85 wakes a second
    instead of 250). A ``driver_node`` has one route.

    Each message is taken serialised, decoded (:func:`softsnap_ros.cdr.decode_cable_length`,
    rclpy's deserialisation for another encoding) and goes straight to its own route's
    ``handle(cable_length_m, stamp_ns)``, in the order the topic delivered them. A
    message that cannot be read is logged (throttled, on the route's logger) and
    skipped; the other routes are not disturbed. The thread never dies silently: an
    unexpected error is logged (throttled) and the loop goes on; it ends on :meth:`stop`
    or when the context shuts down.

    Between commands the thread sleeps in ``rcl_wait``; a guard condition in the same
    wait set wakes it for a stop, a route added or closed, and the context's shutdown.
    """

    def __init__(self, node: Node):
        self._node = node
        self._lock = threading.Lock()       # guards _routes and every route's ``open``
        self._routes: tuple[_Route, ...] = ()
        self._stop = threading.Event()
        self._waiter = SubscriptionWaiter(node.context)
        # Kept as a weak reference by rclpy. It sets the stop: a wake that also brings a
        # command would otherwise skip the context check below and sleep again.
        node.context.on_shutdown(self._on_context_shutdown)
        self._thread = threading.Thread(target=self._run, name='commands', daemon=True)
        self._thread.start()

    def subscribe(self, topic: str, depth: int, handle, logger) -> _Route:
        """Deliver the CableLength messages of ``topic`` to ``handle`` (which must not
        raise); the thread waits on it from its next wake (queued messages are kept)."""
        route = _Route(self._node.create_subscription(CableLength, topic, lambda msg: None,
                                                      depth), handle, logger)
        with self._lock:
            self._routes = (*self._routes, route)
        self._wake()
        return route

    def close(self, route: _Route) -> None:
        """No call of ``route``'s handler once this returns (a call in progress ends
        first). Its subscription lives on with the inbox node, untaken."""
        with self._lock:
            route.open = False
            self._routes = tuple(r for r in self._routes if r is not route)
        self._wake()

    def _on_context_shutdown(self) -> None:
        self._stop.set()
        self._wake()

    def _wake(self) -> None:
        """End the thread's current wait (it then looks at its routes and the stop)."""
        self._waiter.wake()

    def _run(self) -> None:
        context = self._node.context
        routes: tuple[_Route, ...] = ()
        waiter = self._waiter
        try:
            while not self._stop.is_set():
                try:
                    if self._routes is not routes:
                        routes = self._routes
                        waiter.set_subscriptions([r.subscription for r in routes], wake=False)
                    ready = waiter.wait(COMMAND_IDLE_WAIT_S if routes else COMMAND_WAIT_S)
                    # The context is asked only after a wake without a message (rclpy
                    # takes a lock for it): a shut-down context ends the thread within
                    # one wait.
                    if not ready and not context.ok():
                        return
                    for index in ready:
                        # One message per ready route and wake: at 50 Hz there is one,
                        # and a take that finds none costs half a wait; if more are
                        # queued the next wait returns at once.
                        route = routes[index]
                        try:
                            raw = waiter.take(index, CableLength)
                        except Exception as exc:  # noqa: BLE001 - this module only
                            # The other ready modules still get their commands this wake.
                            if self._stop.is_set() or not context.ok():
                                return
                            route.logger.error(f'{route.subscription.topic_name}: take '
                                               f'failed: {exc!r}', throttle_duration_sec=1.0)
                            continue
                        if raw is not None:
                            self._deliver(route, raw)
                except Exception as exc:  # noqa: BLE001 - report and go on; never die silently
                    if self._stop.is_set() or not context.ok():
                        return  # shutting down: the context or a handle is gone
                    self._node.get_logger().error(f'command thread: {exc!r}',
                                                  throttle_duration_sec=1.0)
                    time.sleep(COMMAND_WAIT_S)
        finally:
            waiter.close()

    def _deliver(self, route: _Route, raw: bytes) -> None:
        try:
            stamp_ns, length_m = read_cable_length(raw)
        except Exception as exc:  # noqa: BLE001 - one unreadable message is skipped
            route.logger.warning(
                f'{route.subscription.topic_name}: unreadable command skipped '
                f'({len(raw)} bytes): {exc!r}', throttle_duration_sec=1.0)
            return
        with self._lock:
            if route.open:
                route.handle(length_m, stamp_ns)

    def stop(self, timeout: float) -> None:
        self._stop.set()
        self._wake()
        self._thread.join(timeout)


class DriverNode(SoftSnapNode):
    """One module: parameters and ROS interfaces around a :class:`ModuleLink`.

    Shared with other drivers of the process (``driver_container``): ``inbox``, a
    :class:`CommandInbox` whose owner runs its thread (by default the node makes its
    own), and with ``diagnostics_timer=False`` the owner calls
    :meth:`diagnostics_callback` every ``diagnostics_period_s`` instead of a timer of
    this node.
    """

    def __init__(self, node_name: str = 'driver_node', inbox: CommandInbox | None = None,
                 diagnostics_timer: bool = True, **kwargs):
        super().__init__(node_name, **kwargs)
        for name, (default, descriptor) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor)
        self.module = self.get_parameter('module').value
        if not _NAME.match(self.module):
            raise ValueError(f'parameter module must be a name like "yellow" '
                             f'([A-Za-z][A-Za-z0-9_]*), got {self.module!r}')
        config = self._config_from({name: self.get_parameter(name).value for name in PARAMETERS})
        self.add_on_set_parameters_callback(self.parameters_callback)
        self.add_post_set_parameters_callback(self.parameters_applied_callback)

        m = self.module
        # Depth 50: a briefly starved subscriber (model node, logger) loses no measurement.
        self.measured_publisher = self.create_publisher(CableLength, f'{m}/cable_length/measured', 50)
        self.state_publisher = self.create_publisher(ModuleState, f'{m}/state', 10)
        # Depth 100 (2 s of 50 Hz commands): a driver starved by a busy machine takes the
        # queued commands late instead of having them overwritten (commands_received
        # tells the sender what arrived). Commands arrive on their own thread
        # (CommandInbox says why), through a node of their own that no executor spins.
        self._inbox = None
        if inbox is None:
            self._inbox = inbox_node(f'{self.get_name()}_inbox', self.get_namespace(),
                                     self.context)
        self.trigger_services = [
            create_queued_service(self, Trigger, f'{m}/{kind}', self._trigger_callback(kind))
            for kind in ('calibrate', 'pause', 'resume', 'stop')]
        # (link clock, ROS time as (sec, nanosec)) of the latest error
        self._error_stamp = (math.nan, (0, 0))
        # Standard health outputs, from the link's latest report (set by its worker thread;
        # one reference assignment, read by the timer).
        self._latest_report: LinkReport | None = None
        self.health = DriverHealth(diagnostic_name(self.get_namespace(), m),
                                   f'{config.host}:{config.port}')
        self.battery_publisher = self.create_publisher(BatteryState, f'{m}/battery', 10)
        self.diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.diagnostics_period_s = self.get_parameter('diagnostics_period_s').value
        self.diagnostics_timer = (steady_timer(self, self.diagnostics_period_s,
                                               self.diagnostics_callback)
                                  if diagnostics_timer else None)
        # State and measured length go out as ready CDR bytes (softsnap_ros.cdr.state_writers
        # says why) if rclpy reads them back as the messages; else as message objects, filled
        # in place.
        self._state_wire = ModuleStateWire(m, m)
        self._measured_wire = CableLengthWire(m)
        self._measured_msg = CableLength()
        self._measured_msg.header.frame_id = m
        self._state_msg = ModuleState()
        self._state_msg.header.frame_id = m
        self._state_msg.module = m
        self.wire_format = self._wire_matches_rclpy()
        # Publishing throttle (report_callback): link-clock time the next report is due
        # anyway, and the event fields of the last state published.
        self._publish_due = -math.inf
        self._published_events = None
        # The module's motion is timed on the simulation's clock when there is one.
        self.sim_time = bool(self.get_parameter('use_sim_time').value)
        motion_clock = self._ros_time_s if self.sim_time else None
        self.link = ModuleLink(config, self.report_callback, ShutdownSafeLogger(self),
                               motion_clock=motion_clock)
        self.link.start()
        self.commands = inbox if inbox is not None else CommandInbox(self._inbox)
        self._command_route = self.commands.subscribe(
            f'{m}/cable_length/command', 100, self.command_callback, self.get_logger())
        low, high = config.calibration.length_range_m
        self.get_logger().info(
            f'driving module {m!r} at {config.host}:{config.port}; cable length range '
            f'[{low:.4f}, {high:.4f}] m, encoder targets {list(config.calibration.count_range)}'
            + ('; simulated time (stall timeout on /clock, link timeouts on the wall clock)'
               if self.sim_time else ''))

    def _ros_time_s(self) -> float:
        """The node's ROS time, s (the simulation's with use_sim_time; any thread)."""
        return self.get_clock().now().nanoseconds * 1e-9

    # -- parameters --------------------------------------------------------------------
    @staticmethod
    def _config_from(values: dict) -> LinkConfig:
        """Build a consistent configuration; raises ValueError naming the bad value."""
        calibration = CableCalibration(
            counts_per_mm=values['counts_per_mm'], straight_length_m=values['straight_length_m'],
            max_contraction_m=values['max_contraction_m'],
            min_contraction_m=values['min_contraction_m'], count_sign=values['count_sign'],
            clamp_margin_m=values['clamp_margin_m'])
        return LinkConfig(
            host=values['host'], port=values['port'], calibration=calibration,
            pwm_power=values['pwm_power'], poll_period_s=1.0 / values['poll_rate_hz'],
            command_timeout_s=values['command_timeout_s'],
            request_timeout_s=values['request_timeout_s'],
            offline_after_failures=values['offline_after_failures'],
            max_backoff_s=values['max_backoff_s'],
            reboot_zero_band_counts=values['reboot_zero_band_counts'],
            reboot_min_jump_counts=values['reboot_min_jump_counts'],
            max_speed_counts_per_s=values['max_speed_counts_per_s'],
            stop_on_shutdown=values['stop_on_shutdown'],
            stall_timeout_s=values['stall_timeout_s'], stop_deadline_s=values['stop_deadline_s'],
            target_deadband_counts=values['target_deadband_counts'])

    def _values_with(self, parameters: list[Parameter]) -> dict:
        values = {name: self.get_parameter(name).value for name in PARAMETERS}
        values.update({p.name: p.value for p in parameters if p.name in PARAMETERS})
        return values

    def parameters_callback(self, parameters: list[Parameter]) -> SetParametersResult:
        """Refuse values that do not make a consistent configuration, with the reason."""
        try:
            self._config_from(self._values_with(parameters))
        except (ValueError, TypeError, ZeroDivisionError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def parameters_applied_callback(self, parameters: list[Parameter]) -> None:
        self.link.update_config(self._config_from(self._values_with([])))

    # -- ROS inputs --------------------------------------------------------------------
    def command_callback(self, cable_length_m: float, stamp_ns: int) -> None:
        try:
            self.link.command(cable_length_m, stamp_ns)
        except ValueError:
            pass  # counted, logged (throttled) and reported in the state by the link
        except Exception as exc:  # noqa: BLE001 - no input may take the driver down
            self.get_logger().error(f'command {cable_length_m!r} not handled: {exc!r}')

    def _trigger_callback(self, kind: str):
        def callback(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            response.success, response.message = self.link.request(kind)
            return response
        callback.__name__ = f'{kind}_callback'
        return callback

    # -- ROS outputs (called from the link's worker thread) ----------------------------
    def report_callback(self, report: LinkReport) -> None:
        self._latest_report = report
        c = report.counters
        status = report.status
        # Published at the poll rate, however many commands the link sends (each reply
        # is a status): what a watcher must see at once (events) is published at once.
        # The latest report is never lost: the next poll comes a poll period after it.
        events = (report.online, report.calibrated, status is not None and status.paused,
                  c.request_failures, c.commands_clamped, c.commands_refused,
                  c.reboots_detected, c.stale_stops, c.stalls_detected, c.internal_errors,
                  c.stops_unconfirmed, report.last_error, report.last_error_stamp)
        if report.stamp < self._publish_due and events == self._published_events:
            return
        # Asked only before a publish (rclpy takes a lock for it): most reports publish
        # nothing, and a shut-down context publishes nothing and changes no state here.
        if not self.context.ok():
            return
        # Due again a little before the next poll's report: jitter must not skip a poll.
        self._publish_due = report.stamp + 0.9 * self.link.config.poll_period_s
        self._published_events = events
        stamp = sec_nanosec(self.get_clock().now().nanoseconds)
        if report.fresh and math.isfinite(report.measured_length_m):
            self.measured_publisher.publish(self._measured_out(stamp, report.measured_length_m))
        if math.isfinite(report.last_error_stamp) and report.last_error_stamp != self._error_stamp[0]:
            # The link stamps on its monotonic clock: shift to ROS time by the error's
            # age, once per error (so the field only changes when a new error happens).
            # Floored at 0: a simulated time (use_sim_time) can be younger than the
            # error's wall age, or 0 before the first /clock (a negative time raised
            # here and no state was ever published).
            age_ns = int(max(report.stamp - report.last_error_stamp, 0.0) * 1e9)
            error_ns = max(self.get_clock().now().nanoseconds - age_ns, 0)
            self._error_stamp = (report.last_error_stamp, sec_nanosec(error_ns))
        # Before the first reply (status None) the module's own fields are zero.
        self.state_publisher.publish(self._state_out(stamp, ModuleStateFields(
            online=report.online,
            paused=status is not None and status.paused,
            measured_cable_length=report.measured_length_m,
            target_cable_length=report.target_length_m,
            encoder_count=status.encoder_count if status is not None else 0,
            encoder_target=report.encoder_target,
            motor_power=status.motor_power if status is not None else report.pwm_power,
            battery_voltage=status.battery_voltage if status is not None else 0.0,
            power=status.power_w if status is not None else 0.0,
            encoder_errors=status.encoder_errors if status is not None else 0,
            request_failures=c.request_failures,
            commands_received=c.commands_received,
            targets_sent=c.targets_sent,
            last_command_stamp=sec_nanosec(report.last_command_stamp_ns),
            commands_clamped=c.commands_clamped,
            commands_refused=c.commands_refused,
            reboots_detected=c.reboots_detected,
            stale_stops=c.stale_stops,
            stalls_detected=c.stalls_detected,
            internal_errors=c.internal_errors,
            stops_unconfirmed=c.stops_unconfirmed,
            last_error=report.last_error,
            last_error_time=self._error_stamp[1])))

    # Only the link's worker thread calls these (report_callback), so one message object
    # per topic is filled in place: publish() serialises it before it returns.
    def _state_out(self, stamp: tuple[int, int], fields: ModuleStateFields):
        """The state to publish: CDR bytes, or the message object (the fallback)."""
        if self.wire_format:
            return self._state_wire.serialize(stamp, fields)
        state = self._state_msg
        state.header.stamp.sec, state.header.stamp.nanosec = stamp
        return fill_module_state(state, fields)

    def _measured_out(self, stamp: tuple[int, int], cable_length_m: float):
        if self.wire_format:
            return self._measured_wire.serialize(stamp, cable_length_m)
        measured = self._measured_msg
        measured.header.stamp.sec, measured.header.stamp.nanosec = stamp
        measured.cable_length = cable_length_m
        return measured

    def _wire_matches_rclpy(self) -> bool:
        """True if rclpy reads the bytes of a sample state and length back as the same
        messages built as objects; else False, with a warning. Run once at start: a
        middleware with another encoding then costs CPU, not correctness."""
        try:
            written = []
            for error in ('', 'command refused: \u00e9 -1.0 m'):
                fields = ModuleStateFields(
                    True, False, 0.1875, 0.15, -123456, 7890, 200, 3.875, 1.5, 1, 2, 3, 4,
                    (1_700_000_000, 123_456_789), 5, 6, 7, 8, 9, 10, 11, error, (12, 13))
                want = ModuleState(module=self.module)
                want.header.frame_id = self.module
                want.header.stamp.sec, want.header.stamp.nanosec = 1_800_000_000, 42
                written.append((self._state_wire.serialize((1_800_000_000, 42), fields),
                                fill_module_state(want, fields)))
            length = CableLength(cable_length=0.1234567)
            length.header.frame_id = self.module
            length.header.stamp.sec, length.header.stamp.nanosec = 17, 42
            written.append((self._measured_wire.serialize((17, 42), 0.1234567), length))
            check_wire(written)
        except Exception as error:  # noqa: BLE001 - fall back, never fail the start
            self.get_logger().warning(
                'publishing state and measured length as message objects (costs more CPU): '
                f'the wire format does not match this middleware\'s: {error!r}')
            return False
        return True

    def diagnostics_callback(self) -> None:
        # The link stamps reports on time.monotonic (its default clock).
        report = self._latest_report
        stamp = self.get_clock().now().to_msg()
        try:
            diagnostics = DiagnosticArray(status=[self.health.status(report, time.monotonic())])
            battery = battery_state(report, self.module)
        except Exception as exc:  # noqa: BLE001 - health reporting must not stop the driver
            self.get_logger().error(f'diagnostics failed: {exc!r}', throttle_duration_sec=5.0)
            return
        diagnostics.header.stamp = stamp
        self.diagnostics_publisher.publish(diagnostics)
        battery.header.stamp = stamp
        battery.header.frame_id = self.module
        self.battery_publisher.publish(battery)

    def stop_link(self) -> None:
        """No new command after this (its own command thread stopped within
        COMMAND_WAIT_S, or its route of a shared one closed at once); then the link's
        stop, bounded (link.SHUTDOWN_BUDGET_S) to fit the 2 s SIGINT budget. A second
        call returns at once."""
        if hasattr(self, '_command_route'):
            self.commands.close(self._command_route)
            if self._inbox is not None:
                self.commands.stop(2 * COMMAND_WAIT_S)
        self.link.stop()

    def last_stop_failed(self) -> bool:
        """Whether the link's shutdown stop, its last act, ran and was not confirmed."""
        outcome = self.link.shutdown_stop
        return outcome is not None and not outcome.confirmed

    def destroy_node(self) -> None:
        self.stop_link()
        if self._inbox is not None:
            self._inbox.destroy_node()
        super().destroy_node()


class ShutdownSafeLogger:
    """The node's logger while its ROS context runs; after that (SIGINT: rclpy shuts the
    context down before the link's last confirmed stop is logged) a logger of the same
    name plus ``.shutdown`` that is not tied to /rosout, so those lines still reach the
    console and the log file instead of each giving "Failed to publish log message to
    rosout: publisher's context is invalid" (44-51 such lines per Ctrl-C under ros2
    launch)."""

    def __init__(self, node: Node):
        import rclpy.logging
        self._node = node
        self._detached = rclpy.logging.get_logger(f'{node.get_logger().name}.shutdown')

    def _logger(self):
        return self._node.get_logger() if self._node.context.ok() else self._detached

    def info(self, message: str) -> None:
        self._logger().info(message)

    def warning(self, message: str) -> None:
        self._logger().warning(message)

    def error(self, message: str) -> None:
        self._logger().error(message)


def steady_timer(node: Node, period_s: float, callback):
    """A timer on the steady clock: health must be reported while a simulated time
    stands still."""
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


def _module_argument(args: list[str]) -> str | None:
    """The value of ``-p module:=X`` among the ROS arguments, if any (for the node name)."""
    for i, arg in enumerate(args[:-1]):
        if arg in ('-p', '--param') and args[i + 1].startswith('module:='):
            return args[i + 1].split(':=', 1)[1]
    return None


def main(args=None):
    argv = sys.argv if args is None else args
    # Name the node after its module so several drivers can share a namespace; a
    # `-r __node:=...` remap still wins.
    module = _module_argument(list(argv))
    node_name = f'{module}_driver' if module and _NAME.match(module) else 'driver_node'
    # One thread is enough: callbacks here never do I/O (the link's worker thread
    # does); a service waits for its own request only, bounded by request_timeout_s.

    def build(at_exit):
        node = DriverNode(node_name)

        def stop() -> int:
            node.destroy_node()
            return STOP_UNCONFIRMED_EXIT if node.last_stop_failed() else 0

        at_exit(stop)
        return [node]

    return run_nodes_main(args, 'driver_node', build)


if __name__ == '__main__':
    sys.exit(main())
