"""How a :class:`~softsnap_driver.link.ModuleLink` is configured: its settings, its fixed
thresholds and the timings derived from them (the link's behaviour is described in
:mod:`softsnap_driver.link`)."""
from __future__ import annotations

from dataclasses import dataclass

from softsnap_driver.core import CableCalibration
from softsnap_driver.protocol import FIRMWARE_DEADBAND_COUNTS

#: Movement smaller than this (counts) over ``stall_timeout_s`` is no progress.
STALL_PROGRESS_COUNTS = 10

#: A stop is confirmed when the status after an answered ``reach`` is within this many
#: counts of the count the ``reach`` reply showed (the firmware's deadband).
STOP_STILL_COUNTS = FIRMWARE_DEADBAND_COUNTS

#: Pause before the first repeated ``reach`` of a stop, doubling up to the maximum (s).
STOP_RETRY_FIRST_S = 0.02

STOP_RETRY_MAX_S = 0.2

#: Time :meth:`ModuleLink.stop` gives the worker (its last stop included), in seconds:
#: leaves room within the node's 2 s SIGINT budget for rclpy's own shutdown.
SHUTDOWN_BUDGET_S = 1.2

#: A traceback of an unexpected error is logged at most once per this period (s); every
#: error is counted.
INTERNAL_ERROR_LOG_PERIOD_S = 5.0


@dataclass(frozen=True)
class LinkConfig:
    """Everything the link needs; replaced as a whole (a consistent snapshot)."""

    host: str
    port: int
    calibration: CableCalibration
    pwm_power: int = 200
    poll_period_s: float = 0.1
    command_timeout_s: float = 1.0      # 0 disables the stale-stream stop
    request_timeout_s: float = 0.5
    offline_after_failures: int = 3
    max_backoff_s: float = 5.0
    reboot_zero_band_counts: int = 60
    reboot_min_jump_counts: int = 300
    max_speed_counts_per_s: float = 20000.0
    stop_on_shutdown: bool = True
    stall_timeout_s: float = 1.0        # 0 disables stall detection
    stop_deadline_s: float = 1.0        # confirm a stop within this (s), else report and retry
    target_deadband_counts: int = FIRMWARE_DEADBAND_COUNTS   # see "Target deadband"; 0: off


def failure_backoff_s(config: LinkConfig, failures: int) -> float:
    """Pause after the ``failures``-th consecutive failed request (s): doubles from the
    poll period, at most ``max_backoff_s``."""
    return min(config.poll_period_s * 2.0 ** min(max(failures - 1, 0), 30), config.max_backoff_s)


def action_timeout_s(config: LinkConfig) -> float:
    """How long a service caller waits for its action (s): a stop in progress, then its own."""
    return config.stop_deadline_s + 2 * config.request_timeout_s + 1.0
