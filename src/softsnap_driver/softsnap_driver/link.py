"""The driver's link to one module: a worker thread that owns all module I/O (no ROS).

Why a worker thread: a real module answers over Wi-Fi, sometimes slowly or not at all,
and a request may take up to ``request_timeout_s``. If HTTP ran in ROS callbacks, one
slow reply would stall the executor (subscriptions, services, parameter updates). So the
ROS side only *posts* work here and returns at once; this thread is the only one that
talks to the module, which also guarantees one request at a time (the firmware serves one
client).

What the thread does, in priority order, each time it wakes:

1. service actions (calibrate, pause, resume, stop), in arrival order;
2. a stale command stream: no valid command for ``command_timeout_s`` -> ``reach``
   (stop where it is), once per stream;
3. the newest commanded target (latest wins: commands that arrive while a request is in
   flight coalesce, only the newest matters; an unchanged target is not re-sent);
4. a status poll every ``poll_period_s``.

Every firmware reply is a full status, so each successful request is reported.

Offline: after ``offline_after_failures`` consecutive failed requests the module is
reported offline and only polled, with exponential backoff from the poll period up to
``max_backoff_s``; the first answer brings it back online (after the reboot check).

Stall: a module that is outside the firmware's deadband, not paused, and has not moved
by ``STALL_PROGRESS_COUNTS`` for ``stall_timeout_s`` is stalled (jammed winch, dead
motor, PWM too low): the driver warns, reports it in ``last_error`` and sends ``reach``
so the motor stops drawing stall current; the next new target drives it again.

Reboot: see :func:`softsnap_driver.core.reboot_suspected`. On a detected reboot the
driver counts it, reports it (``last_error`` and a warning), drops the pending target,
holds the module with ``reach`` and marks it *uncalibrated*: the encoder count no longer
refers to the straight module, so a new target could drive the cable beyond the allowed
contraction. Until ``calibrate`` succeeds (call it with the module straight), commands are
refused and no measured length is reported. Nothing is re-sent as if nothing happened.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace

from softsnap_driver.core import CableCalibration, TargetCommand, reboot_suspected
from softsnap_driver.protocol import (FIRMWARE_DEADBAND_COUNTS, ModuleClient, ModuleError,
                                      ModuleStatus)

#: Movement smaller than this (counts) over ``stall_timeout_s`` is no progress.
STALL_PROGRESS_COUNTS = 10


class NeedsCalibration(ValueError):
    """A command was refused because the module rebooted and must be recalibrated."""


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


@dataclass(frozen=True)
class Counters:
    request_failures: int = 0
    commands_clamped: int = 0
    commands_refused: int = 0
    reboots_detected: int = 0
    stale_stops: int = 0
    stalls_detected: int = 0


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
    last_error: str


@dataclass
class _Action:
    kind: str
    done: threading.Event = field(default_factory=threading.Event)
    ok: bool = False
    message: str = ''


class ModuleLink:
    """Worker thread bridging commands and service actions to one module.

    Parameters
    ----------
    config : LinkConfig
    report : callable
        Called from the worker thread with a :class:`LinkReport` after every request.
    logger : object with ``info``, ``warning``, ``error`` methods (an rclpy logger works).
    clock : callable returning seconds (monotonic).
    """

    def __init__(self, config: LinkConfig, report, logger, clock=time.monotonic):
        self._config = config
        self._report = report
        self._log = logger
        self._clock = clock
        self._cond = threading.Condition()
        self._stop = False
        self._actions: deque[_Action] = deque()
        self._pending: TargetCommand | None = None
        self._last_command_time: float | None = None
        self._stale_handled = True
        self._counters = Counters()
        self._last_error = ''
        self._calibrated = True
        self._warned_at: dict[str, float] = {}
        # Worker-only state.
        self._client: ModuleClient | None = None
        self._online = True
        self._failures = 0
        self._backoff_s = 0.0
        self._next_poll = 0.0
        self._last_report = -math.inf
        self._status: ModuleStatus | None = None
        self._status_time = 0.0
        self._module_target: int | None = None   # what the module steers to, if known
        self._sent: tuple[int, int] | None = None  # (count, power) last acknowledged set
        self._progress: tuple[int, float] | None = None  # (count, time) of last progress
        self._thread = threading.Thread(target=self._run, name=f'module_link:{config.host}:{config.port}',
                                         daemon=True)

    # -- API for the ROS side (any thread, never blocks on I/O except request()) -------
    @property
    def config(self) -> LinkConfig:
        return self._config

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float | None = None) -> None:
        """Stop the worker (sending ``reach`` first if configured and a target was sent)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout if timeout is not None
                              else 2 * self._config.request_timeout_s + 1.0)

    def update_config(self, config: LinkConfig) -> None:
        with self._cond:
            self._config = config
            self._cond.notify_all()

    def command(self, length_m: float) -> TargetCommand:
        """Accept a commanded cable length (m): clamp it and queue it (latest wins).

        Raises ValueError (NaN, infinite) or :class:`NeedsCalibration`; both are counted
        as refused commands.
        """
        with self._cond:
            try:
                cmd = self._config.calibration.command(length_m)
                if not self._calibrated:
                    raise NeedsCalibration('module rebooted and must be recalibrated: '
                                           'command refused until calibrate succeeds')
            except ValueError as exc:
                self._count(commands_refused=1)
                self._last_error = f'command refused: {exc}'
                self._warn_throttled('refused', self._last_error)
                raise
            if cmd.clamped:
                self._count(commands_clamped=1)
                low, high = self._config.calibration.length_range_m
                self._last_error = (f'command {cmd.requested_length_m!r} m clamped to {cmd.length_m:.6f} m '
                                    f'(allowed [{low:.6f}, {high:.6f}] m)')
                self._warn_throttled('clamped', self._last_error)
            self._pending = cmd
            self._last_command_time = self._clock()
            self._stale_handled = False
            self._cond.notify_all()
        return cmd

    def request(self, kind: str, timeout: float | None = None) -> tuple[bool, str]:
        """Run a service action (calibrate, pause, resume, stop) and wait for its result."""
        if kind not in ('calibrate', 'pause', 'resume', 'stop'):
            raise ValueError(f'unknown action {kind!r}')
        action = _Action(kind)
        with self._cond:
            if self._stop:
                return False, 'driver is shutting down'
            self._actions.append(action)
            self._cond.notify_all()
        if timeout is None:
            timeout = 2 * self._config.request_timeout_s + 1.0
        if not action.done.wait(timeout):
            return False, f'{kind}: no result within {timeout:.3g} s'
        return action.ok, action.message

    # -- helpers -----------------------------------------------------------------------
    def _count(self, **deltas: int) -> None:
        values = {name: getattr(self._counters, name) + delta for name, delta in deltas.items()}
        self._counters = replace(self._counters, **values)

    def _warn_throttled(self, key: str, message: str, period_s: float = 1.0) -> None:
        now = self._clock()
        if now - self._warned_at.get(key, -math.inf) >= period_s:
            self._warned_at[key] = now
            self._log.warning(message)

    def _client_for(self, config: LinkConfig) -> ModuleClient:
        if (self._client is None or self._client.host != config.host or self._client.port != config.port
                or self._client.timeout_s != config.request_timeout_s):
            self._client = ModuleClient(config.host, config.port, config.request_timeout_s)
        return self._client

    # -- worker ------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001 - report, never die silently
            self._log.error(f'module link stopped by an unexpected error: {exc!r}')
            raise
        finally:
            with self._cond:
                actions, self._actions = list(self._actions), deque()
            for action in actions:
                action.message = 'driver is shutting down'
                action.done.set()

    def _next_job(self):
        """Under the lock: the next job, or the time (s) to wait for one."""
        config = self._config
        now = self._clock()
        if self._stop:
            return 'exit', None
        if self._actions:
            return 'action', self._actions.popleft()
        stale_at = math.inf
        if (config.command_timeout_s > 0 and not self._stale_handled
                and self._last_command_time is not None):
            stale_at = self._last_command_time + config.command_timeout_s
            if now >= stale_at and self._online:
                self._stale_handled = True
                self._pending = None
                return 'stale', None
        if self._pending is not None and self._online and self._calibrated:
            pending, self._pending = self._pending, None
            return 'set', pending
        if now >= self._next_poll:
            return 'poll', None
        if now >= self._last_report + config.poll_period_s:
            return 'heartbeat', None
        wake = min(self._next_poll, self._last_report + config.poll_period_s,
                   stale_at if self._online else math.inf)
        return 'wait', max(wake - now, 0.0)

    def _loop(self) -> None:
        while True:
            with self._cond:
                job, arg = self._next_job()
                while job == 'wait':
                    self._cond.wait(arg)
                    job, arg = self._next_job()
                config = self._config
            if job == 'exit':
                self._shutdown(config)
                return
            if job == 'action':
                self._do_action(config, arg)
            elif job == 'stale':
                self._do_stale(config)
            elif job == 'set':
                self._do_set(config, arg)
            elif job == 'poll':
                self._exchange(config, 'status', lambda c: c.status())
            else:
                self._emit(config, fresh=False)

    def _exchange(self, config: LinkConfig, what: str, call,
                  check_reboot: bool = True, check_stall: bool = True) -> ModuleStatus | None:
        """One request; updates online state, backoff, reboot check; reports."""
        client = self._client_for(config)
        try:
            status = call(client)
        except ModuleError as exc:
            self._on_failure(config, what, exc)
            self._emit(config, fresh=False)
            return None
        now = self._clock()
        if not self._online:
            self._log.info(f'module {config.host}:{config.port} answers again after '
                           f'{self._failures} failed requests')
        self._online = True
        self._failures = 0
        self._backoff_s = 0.0
        self._next_poll = now + config.poll_period_s
        previous, previous_time = self._status, self._status_time
        self._status, self._status_time = status, now
        if previous is not None and self._calibrated and check_reboot:
            evidence = reboot_suspected(
                previous.encoder_count, previous.encoder_errors, status.encoder_count,
                status.encoder_errors, now - previous_time, self._module_target,
                config.reboot_zero_band_counts, config.reboot_min_jump_counts,
                config.max_speed_counts_per_s)
            if evidence is not None:
                self._on_reboot(config, evidence)
                return status
        if check_stall and self._stalled(config, status, now):
            with self._cond:
                self._last_error = (
                    f'motor stalled: count {status.encoder_count}, target {self._module_target}, '
                    f'no progress for {config.stall_timeout_s:g} s at {status.power_w:.2f} W; '
                    'stopped it (reach)')
            self._log.warning(self._last_error)
            self._count(stalls_detected=1)
            self._hold(config, 'reach')       # reports the stopped module
            return status
        self._emit(config, fresh=True)
        return status

    def _stalled(self, config: LinkConfig, status: ModuleStatus, now: float) -> bool:
        """Track progress toward the target; True once when it stopped for too long."""
        count = status.encoder_count
        if (config.stall_timeout_s <= 0 or status.paused or self._module_target is None
                or abs(self._module_target - count) <= FIRMWARE_DEADBAND_COUNTS
                or self._progress is None
                or abs(count - self._progress[0]) > STALL_PROGRESS_COUNTS):
            self._progress = (count, now)
            return False
        return now - self._progress[1] >= config.stall_timeout_s

    def _on_failure(self, config: LinkConfig, what: str, exc: ModuleError) -> None:
        now = self._clock()
        self._failures += 1
        with self._cond:
            self._count(request_failures=1)
            self._last_error = f'{what} failed: {type(exc).__name__}: {exc}'
        if self._online and self._failures >= config.offline_after_failures:
            self._online = False
            self._log.warning(f'module {config.host}:{config.port} offline after {self._failures} '
                              f'failed requests ({self._last_error}); retrying with backoff')
        if self._online:
            self._next_poll = now + config.poll_period_s
        else:
            self._backoff_s = min(max(2 * self._backoff_s, config.poll_period_s), config.max_backoff_s)
            self._next_poll = now + self._backoff_s

    def _on_reboot(self, config: LinkConfig, evidence: str) -> None:
        with self._cond:
            self._count(reboots_detected=1)
            self._calibrated = False
            self._pending = None
            self._last_error = (f'module reboot detected ({evidence}): position reference lost; '
                                'holding with reach; commands refused until calibrate')
        self._sent = None
        self._log.warning(self._last_error)
        status = self._exchange(config, 'reach', lambda c: c.reach())
        if status is not None:
            self._module_target = status.encoder_count

    def _do_set(self, config: LinkConfig, cmd: TargetCommand) -> None:
        # Re-derive the count with the current calibration (parameters may have changed
        # since the command was accepted); clamping was counted when it arrived.
        try:
            cmd = config.calibration.command(cmd.requested_length_m)
        except ValueError:
            return  # cannot happen: the length was finite when accepted
        low, high = config.calibration.count_range
        if not low <= cmd.count <= high:
            # Unreachable by construction (CableCalibration clamps); a last guard.
            self._log.error(f'target {cmd.count} outside [{low}, {high}] counts: not sent')
            return
        key = (cmd.count, config.pwm_power)
        if key == self._sent:
            return
        status = self._exchange(config, 'set', lambda c: c.set_target(cmd.count, config.pwm_power))
        if status is None:
            with self._cond:
                # Retry when back: keep it unless a newer command arrived meanwhile.
                if self._pending is None and not self._stale_handled:
                    self._pending = cmd
            return
        self._sent = key
        self._module_target = cmd.count
        self._progress = (status.encoder_count, self._clock())   # a new target: re-arm

    def _do_stale(self, config: LinkConfig) -> None:
        with self._cond:
            self._count(stale_stops=1)
            self._last_error = (f'no command for {config.command_timeout_s:g} s: '
                                'stopped the module where it is (reach)')
        self._log.warning(self._last_error)
        self._hold(config, 'reach')

    def _hold(self, config: LinkConfig, what: str) -> ModuleStatus | None:
        status = self._exchange(config, what, lambda c: c.reach(), check_stall=False)
        if status is not None:
            self._progress = None
            self._sent = None
            self._module_target = status.encoder_count
        return status

    def _do_action(self, config: LinkConfig, action: _Action) -> None:
        try:
            if action.kind == 'calibrate':
                status = self._exchange(config, 'calibrate', lambda c: c.calibrate(),
                                        check_reboot=False)
                if status is not None:
                    with self._cond:
                        self._calibrated = True
                        self._pending = None
                        self._last_command_time = None
                    self._sent = None
                    self._module_target = 0
                    self._emit(config, fresh=True)
                    action.message = (f'calibrated: count 0 is now the straight length '
                                      f'{config.calibration.straight_length_m:g} m')
            elif action.kind == 'stop':
                with self._cond:
                    self._pending = None
                    self._stale_handled = True
                status = self._hold(config, 'stop')
                if status is not None:
                    action.message = f'stopped at count {status.encoder_count}'
            else:
                status = self._exchange(config, action.kind,
                                        lambda c: c.pause() if action.kind == 'pause' else c.resume())
                if status is not None:
                    action.message = f'{action.kind}d: module paused={status.paused}'
            action.ok = status is not None
            if not action.ok:
                action.message = self._last_error
        finally:
            action.done.set()

    def _shutdown(self, config: LinkConfig) -> None:
        if config.stop_on_shutdown and self._sent is not None and self._online:
            try:
                self._client_for(config).reach()
            except ModuleError as exc:
                self._log.warning(f'could not stop the module on shutdown: {exc}')

    def _emit(self, config: LinkConfig, fresh: bool) -> None:
        now = self._clock()
        self._last_report = now
        calibration = config.calibration
        status = self._status
        with self._cond:
            calibrated, counters, last_error = self._calibrated, self._counters, self._last_error
        measured = (calibration.length_m(status.encoder_count)
                    if status is not None and calibrated else math.nan)
        target = self._module_target
        report = LinkReport(
            stamp=now, fresh=fresh and status is not None, online=self._online, calibrated=calibrated,
            status=status, measured_length_m=measured,
            target_length_m=calibration.length_m(target) if target is not None and calibrated else math.nan,
            encoder_target=target if target is not None else 0, pwm_power=config.pwm_power,
            counters=counters, last_error=last_error)
        try:
            self._report(report)
        except Exception as exc:  # noqa: BLE001 - a broken consumer must not stop the link
            self._warn_throttled('report', f'publishing the module state failed: {exc!r}')
