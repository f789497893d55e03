"""What a :class:`~softsnap_driver.link.ModuleLink` reports: its state after each request,
its event counters, the outcome of a stop, and the refusal of an uncalibrated command."""
from __future__ import annotations

import math
from dataclasses import dataclass

from softsnap_driver.protocol import ModuleStatus


class NeedsCalibration(ValueError):
    """A command was refused because the module rebooted and must be recalibrated."""


@dataclass(frozen=True)
class Counters:
    """Event counts since the link started."""

    request_failures: int = 0
    commands_received: int = 0       # every command() call, refused or not
    targets_sent: int = 0            # set requests the module acknowledged
    commands_clamped: int = 0
    commands_refused: int = 0
    reboots_detected: int = 0
    stale_stops: int = 0
    stalls_detected: int = 0
    internal_errors: int = 0         # unexpected exceptions caught in the worker loop
    stops_unconfirmed: int = 0       # stops not confirmed within stop_deadline_s


@dataclass(frozen=True)
class LinkReport:
    """What the link knows after a request (or a heartbeat while offline)."""

    stamp: float                     # clock time of the report (s)
    fresh: bool                      # True if `status` is a reply received just now
    online: bool
    calibrated: bool
    status: ModuleStatus | None      # last good reply, None before the first
    measured_length_m: float         # NaN when unknown or uncalibrated
    target_length_m: float           # NaN before any target was sent
    encoder_target: int
    pwm_power: int
    counters: Counters
    last_error: str                  # active problems, '' when none
    last_error_stamp: float = math.nan   # clock time (s) of the most recent error; NaN: none
    last_command_stamp_ns: int = 0   # the sender's stamp of the latest command (ns); 0: none


@dataclass(frozen=True)
class StopOutcome:
    """Result of one bounded attempt to stop the module (see "Confirmed stops")."""

    confirmed: bool
    count: int | None                # count the module holds at, when confirmed
    attempts: int                    # reach requests sent
    elapsed_s: float
    message: str
