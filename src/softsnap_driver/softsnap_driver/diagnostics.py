"""Standard health messages of one driven module: DiagnosticStatus and BatteryState.

No rclpy: the driver node calls these from its diagnostics timer with the link's latest
:class:`~softsnap_driver.link_report.LinkReport`. Levels follow the thresholds below, documented
in docs/diagnostics.md (keep both in step).

Examples
--------
>>> health = DriverHealth('softsnap/robot/m1/driver', '127.0.0.1:80')
>>> health.status(None, now_s=0.0).message
'no report from the module link yet'
"""
from __future__ import annotations

import math
from dataclasses import fields
from typing import TYPE_CHECKING

from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import BatteryState

from softsnap_ros.diagnostics import key_values

if TYPE_CHECKING:  # annotations only: rerun_logger uses RECENT_S without loading the
    # link and the HTTP protocol client (~30 ms at start)
    from .link_report import Counters, LinkReport

__all__ = ['BATTERY_WARN_V', 'BATTERY_ERROR_V', 'RECENT_S', 'STALE_AFTER_S',
           'BATTERY_DESIGN_CAPACITY_AH', 'DriverHealth', 'battery_state', 'diagnostic_name']

#: Battery voltage (mean of the module's last 8 samples) below which the status is WARN
#: (V): a single Li-ion cell (FACTS.md: 80130 Li-ion, 3.7 V nominal) is nearly empty.
BATTERY_WARN_V = 3.5
#: Below this the cell is empty (V): ERROR, the motor's boost converter browns out soon.
BATTERY_ERROR_V = 3.3
#: A counted event (failure, reboot, stall, ...) keeps its WARN or ERROR this long after
#: it happened (s), so that a one-off event is seen in a 1 Hz monitor and then clears.
RECENT_S = 10.0
#: No report from the link for this long (s): the status is STALE (the link's worker is
#: stuck; it reports at least at the poll rate, also while the module is offline).
STALE_AFTER_S = 5.0
#: Nominal capacity of the module's battery (Ah): FACTS.md, 80130 Li-ion 200 mAh.
BATTERY_DESIGN_CAPACITY_AH = 0.2

#: Counters whose increase is an ERROR (safety: a stop the module did not confirm; a bug).
_ERROR_EVENTS = {'stops_unconfirmed': 'stop(s) not confirmed',
                 'internal_errors': 'internal error(s) in the driver loop (a bug: see the log)'}
#: Counters whose increase is a WARN.
_WARN_EVENTS = {'request_failures': 'failed request(s)',
                'reboots_detected': 'module reboot(s)',
                'stalls_detected': 'motor stall(s)',
                'stale_stops': 'stop(s) on a stale command stream',
                'commands_refused': 'command(s) refused'}


def diagnostic_name(namespace: str, module: str) -> str:
    """``softsnap/<robot>/<module>/driver``: the robot is the node's namespace (may be empty)."""
    robot = namespace.strip('/')
    return '/'.join(part for part in ('softsnap', robot, module, 'driver') if part)


class DriverHealth:
    """Turns the link's reports into one DiagnosticStatus per call, for one module.

    Keeps, per event counter, when it last increased (link clock, s), so that events
    stay visible for :data:`RECENT_S`. Call :meth:`status` from one thread only.

    Levels (the worst applies):

    - STALE: no report yet, or none for :data:`STALE_AFTER_S`.
    - ERROR: module offline; not calibrated (rebooted: commands are refused until
      ``calibrate``); battery below :data:`BATTERY_ERROR_V`; a stop not confirmed or an
      internal error within :data:`RECENT_S`.
    - WARN: battery below :data:`BATTERY_WARN_V`; failed requests, reboots, stalls, stops
      on a stale command stream or refused commands within :data:`RECENT_S`; an active
      problem in ``last_error``.
    - OK otherwise.
    """

    def __init__(self, name: str, hardware_id: str):
        self.name = name
        self.hardware_id = hardware_id
        self._counts: dict[str, int] = {}                          # last seen per counter
        self._history: dict[str, list[tuple[float, int]]] = {}    # (seen at s, increase)

    def _recent(self, counters: Counters, now_s: float) -> dict[str, int]:
        """Increase of each event counter within the last RECENT_S (counts).

        An increase is dated when first seen (at most one diagnostics period late)."""
        recent = {}
        for name in (*_ERROR_EVENTS, *_WARN_EVENTS):
            count = getattr(counters, name)
            if count > self._counts.get(name, 0):
                self._history.setdefault(name, []).append((now_s, count - self._counts.get(name, 0)))
            self._counts[name] = count
            history = [(at, n) for at, n in self._history.get(name, ()) if now_s - at <= RECENT_S]
            self._history[name] = history
            if history:
                recent[name] = sum(n for _, n in history)
        return recent

    def status(self, report: LinkReport | None, now_s: float) -> DiagnosticStatus:
        """Status of the module from the link's latest report at link clock time ``now_s``."""
        status = DiagnosticStatus(name=self.name, hardware_id=self.hardware_id)
        if report is None:
            status.level = DiagnosticStatus.STALE
            status.message = 'no report from the module link yet'
            return status
        errors, warnings = [], []
        age = now_s - report.stamp
        recent = self._recent(report.counters, now_s)
        if not report.online:
            errors.append('offline')
        if not report.calibrated:
            errors.append('not calibrated (module rebooted): call calibrate')
        voltage = report.status.battery_voltage if report.status is not None else math.nan
        if math.isfinite(voltage) and voltage < BATTERY_ERROR_V:
            errors.append(f'battery {voltage:.2f} V below {BATTERY_ERROR_V:g} V')
        elif math.isfinite(voltage) and voltage < BATTERY_WARN_V:
            warnings.append(f'battery {voltage:.2f} V below {BATTERY_WARN_V:g} V')
        for name, text in _ERROR_EVENTS.items():
            if recent.get(name):
                errors.append(f'{recent[name]} {text} in the last {RECENT_S:g} s')
        for name, text in _WARN_EVENTS.items():
            if recent.get(name):
                warnings.append(f'{recent[name]} {text} in the last {RECENT_S:g} s')
        if report.last_error and not errors and not warnings:
            warnings.append(report.last_error)
        if age > STALE_AFTER_S:
            status.level = DiagnosticStatus.STALE
            problems = [f'no report from the module link for {age:.1f} s']
        elif errors:
            status.level = DiagnosticStatus.ERROR
            problems = errors + warnings
        elif warnings:
            status.level = DiagnosticStatus.WARN
            problems = warnings
        else:
            status.level = DiagnosticStatus.OK
            problems = []
        status.message = '; '.join(problems) if problems else 'ok'
        c = report.counters
        values = {
            'online': report.online,
            'calibrated': report.calibrated,
            'paused': report.status.paused if report.status is not None else 'unknown',
            'battery voltage (V)': float(voltage),
            'measured cable length (m)': float(report.measured_length_m),
            'target cable length (m)': float(report.target_length_m),
            'encoder target (counts)': report.encoder_target,
            'encoder count (counts)': (report.status.encoder_count if report.status is not None
                                       else 'unknown'),
            'report age (s)': float(max(age, 0.0)),
        }
        values.update({f'{f.name.replace("_", " ")} (count)': getattr(c, f.name)
                       for f in fields(c)})
        values['last error'] = report.last_error
        values['last error age (s)'] = (float(now_s - report.last_error_stamp)
                                        if math.isfinite(report.last_error_stamp) else 'none')
        status.values = key_values(values)
        return status


def battery_state(report: LinkReport | None, module: str) -> BatteryState:
    """sensor_msgs/BatteryState of a module from the link's latest report.

    Only the voltage is measured (the firmware's mean of its last 8 samples, V); the
    unknown quantities are NaN as the message defines. ``present`` is true while the
    module answers (a battery that powers a replying module is there). The module's single
    Li-ion cell makes ``cell_voltage`` the voltage itself. ``header`` is left to the caller.
    """
    msg = BatteryState()
    voltage = math.nan
    if report is not None and report.status is not None:
        voltage = float(report.status.battery_voltage)
    msg.voltage = voltage
    msg.temperature = math.nan
    msg.current = math.nan
    msg.charge = math.nan
    msg.capacity = math.nan
    msg.design_capacity = BATTERY_DESIGN_CAPACITY_AH
    msg.percentage = math.nan
    msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_UNKNOWN
    msg.power_supply_health = BatteryState.POWER_SUPPLY_HEALTH_UNKNOWN
    msg.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_LION
    msg.present = bool(report is not None and report.online and report.status is not None)
    msg.cell_voltage = [voltage]
    msg.cell_temperature = [math.nan]
    msg.location = module
    msg.serial_number = report.status.mac if report is not None and report.status is not None else ''
    return msg
