"""The driver's link to one module: a worker thread that owns all module I/O (no ROS).

Why a worker thread: a real module answers over Wi-Fi, sometimes slowly or not at all,
and a request may take up to ``request_timeout_s``. If HTTP ran in ROS callbacks, one
slow reply would stall the executor (subscriptions, services, parameter updates). So the
ROS side only *posts* work here and returns at once; this thread is the only one that
talks to the module, which also guarantees one request at a time (the firmware serves one
client).

What the thread does, in priority order, each time it wakes:

1. service actions (calibrate, pause, resume, stop), in arrival order;
2. a stale command stream: no valid command for ``command_timeout_s`` -> a confirmed
   stop (below), decided once per stream;
3. a stop that is still wanted but not yet confirmed (watchdog, ``stop`` service, stall,
   reboot): retried after the failure backoff until confirmed or a new command arrives;
4. the newest commanded target (latest wins: commands that arrive while a request is in
   flight coalesce, only the newest matters; an unchanged target is not re-sent; a
   target within the target deadband of the module's target waits for the poll slot,
   below); after a failed request it waits for the backoff pause before it is sent again;
5. a status poll every ``poll_period_s``.

Every firmware reply is a full status, so each successful request is reported, and a
``set`` counts as the poll (the next poll is due ``poll_period_s`` after any reply).

Target deadband: a new target that differs from the last target the module acknowledged
(same PWM power) by at most ``target_deadband_counts`` (default: the firmware's own
30-count deadband) is not sent at once: it stays the pending target (a newer command
still replaces it) and goes out as the ``set`` that takes the place of the next poll, so
at most ``poll_period_s`` later. A larger change, a new PWM power, and the first target
after a stop, a calibration or a reboot go out at once. So a stream of small steps (50
Hz commands of a slow motion) costs one request per poll period or per deadband of
motion, whichever comes first, instead of one per command; the module's target lags the
newest command by at most that deadband for at most one poll period; the final target is
always sent; and stops are never delayed (they come before targets, above, and drop the
pending target). ``target_deadband_counts = 0`` sends every changed target at once.

Confirmed stops: a stop is a state the driver confirms, not a request it sent. The
firmware's ``reach`` sets its target to the current count; its reply carries that count.
The driver sends ``reach`` and then ``status``; the stop is *confirmed* once a ``reach``
was answered and the following status shows the count within ``STOP_STILL_COUNTS`` of the
count in the ``reach`` reply (the motor no longer moves). A lost ``reach`` (no reply) or a
count still moving sends ``reach`` again after a pause that doubles from
``STOP_RETRY_FIRST_S`` to ``STOP_RETRY_MAX_S``, until ``stop_deadline_s`` has passed. Then
the log says "stop NOT confirmed", ``stops_unconfirmed`` counts it, ``last_error`` says
so, and the stop stays wanted: the thread keeps retrying after the failure backoff. The
log says "stop sent" when the first ``reach`` goes out and "stop confirmed" only on
confirmation.

Unexpected errors: any exception other than a :class:`ModuleError` in a job (a bug, a
broken calibration object, a failing report consumer) is caught, logged with its
traceback (at most once per ``INTERNAL_ERROR_LOG_PERIOD_S``, every one counted in
``internal_errors``), reported in ``last_error``, and the loop goes on after a pause of
one poll period. The thread never dies silently: the watchdog, polls and stops keep
running. The job that failed is dropped (a command is re-sent by the next command, a
wanted stop is retried).

Failure backoff: after a failed request the next poll or ``set`` waits ``poll_period_s *
2**(failures - 1)``, at most ``max_backoff_s``. After ``offline_after_failures``
consecutive failed requests the module is reported offline and only polled (with that
backoff); the first answer brings it back online (after the reboot check).

Errors in ``last_error``: it lists the problems that are *active* now, and each clears
when its cause is gone: a failed request or an internal error on the next normal reply; a
refused or clamped command on the next command accepted as it is; a stale-stream or stall
stop on the next command; an unconfirmed stop on confirmation; a reboot on a successful
``calibrate``. ``last_error_stamp`` keeps the time of the most recent error of any kind,
so an error that came and went is not lost (the log holds its text, the counters its
number).

Stall: a module that is outside the firmware's deadband, not paused, and has not moved
by ``STALL_PROGRESS_COUNTS`` for ``stall_timeout_s`` is stalled (jammed winch, dead
motor, PWM too low): the driver warns, reports it in ``last_error`` and stops it
(confirmed stop) so the motor stops drawing stall current; the next new target drives it
again.

Two clocks: everything about the *link* (poll period, request deadlines, failure
backoff, offline, the stale-command watchdog, stop deadlines, shutdown) runs on
``clock``, the monotonic wall clock, so it keeps working whatever happens to a simulated
time. What compares the *module's motion* with time (the stall timeout, and the speed
limit of the reboot check) runs on ``motion_clock``: the same clock for a real module,
the simulation's time for a simulated robot (the driver node passes its ROS clock when
``use_sim_time`` is set), so a simulation slower than real time is not taken for a
stalled winch, nor one faster than real time for a reboot. If the simulated time stops
(simulator paused or dead), stall detection waits with it (the simulated motor does not
run either) and the reboot check falls back to the wall time elapsed; the link's own
timeouts run on.

Reboot: see :func:`softsnap_driver.core.reboot_suspected`. On a detected reboot the
driver counts it, reports it (``last_error`` and a warning), drops the pending target,
holds the module with a confirmed stop and marks it *uncalibrated*: the encoder count no
longer refers to the straight module, so a new target could drive the cable beyond the
allowed contraction. Until ``calibrate`` succeeds (call it with the module straight),
commands are refused and no measured length is reported. Nothing is re-sent as if
nothing happened.

Shutdown: :meth:`ModuleLink.stop` gives the thread ``SHUTDOWN_BUDGET_S`` (default) to end;
if a target may be active (or a stop is wanted) it runs a confirmed stop within what is
left of that budget, logs the outcome, and exits.
"""
from __future__ import annotations

import math
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field

from softsnap_driver.core import TargetCommand, reboot_suspected
from softsnap_driver.protocol import (FIRMWARE_DEADBAND_COUNTS, ModuleClient, ModuleError,
                                      ModuleStatus)
from softsnap_driver.link_config import (INTERNAL_ERROR_LOG_PERIOD_S, SHUTDOWN_BUDGET_S,
                                         STALL_PROGRESS_COUNTS, STOP_RETRY_FIRST_S,
                                         STOP_RETRY_MAX_S, STOP_STILL_COUNTS, LinkConfig,
                                         action_timeout_s, failure_backoff_s)
from softsnap_driver.link_report import Counters, LinkReport, NeedsCalibration, StopOutcome

#: Order of the active problems in ``last_error``.
_ERROR_KEYS = ('internal', 'link', 'reboot', 'stop', 'stale', 'stall', 'command')


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
    clock : callable returning seconds (monotonic): the link's timeouts.
    motion_clock : callable returning seconds, optional
        The module's time, for stall detection and the reboot speed check (see "Two
        clocks"); `clock` if None.
    client_factory : callable ``(host, port, timeout_s) -> ModuleClient``
        Builds the client (a subclass can add behaviour, e.g. in tests).
    """

    def __init__(self, config: LinkConfig, report, logger, clock=time.monotonic,
                 client_factory=ModuleClient, motion_clock=None):
        self._config = config
        self._report = report
        self._log = logger
        self._clock = clock
        self._motion_clock = clock if motion_clock is None else motion_clock
        self._client_factory = client_factory
        self.shutdown_stop: StopOutcome | None = None   # the last act (None: no stop needed)
        self._cond = threading.Condition()
        # Shared state, guarded by _cond.
        self._stop = False
        self._exit_deadline = math.inf
        self._actions: deque[_Action] = deque()
        self._pending: TargetCommand | None = None
        self._last_command_time: float | None = None
        self._last_command_stamp_ns = 0
        self._commands_accepted = 0                 # a new command supersedes a wanted stop
        self._stale_handled = True
        self._stop_wanted: str | None = None        # why a stop is wanted and not confirmed
        # Counted in place (two per command, one per request); a frozen Counters is made
        # for a report only when a count changed since the last one.
        self._counts = dict.fromkeys(Counters.__dataclass_fields__, 0)
        self._counters: Counters | None = Counters()
        self._errors: dict[str, str] = {}           # active problems by kind (_ERROR_KEYS)
        self._last_error_stamp = math.nan
        self._calibrated = True
        self._warned_at: dict[str, float] = {}
        # Worker-only state.
        self._client: ModuleClient | None = None
        self._online = True
        self._failures = 0
        self._retry_at = -math.inf                  # no poll/set before this after a failure
        self._next_poll = 0.0
        self._last_report = -math.inf
        self._status: ModuleStatus | None = None
        self._status_time = (0.0, 0.0)            # (clock, motion clock) its request left
        self._module_target: int | None = None   # what the module steers to, if known
        # Targets of sets whose reply was lost since the last known target: the module may
        # have applied any of them (the reboot check must allow for each).
        self._unacknowledged_targets: tuple[int, ...] = ()
        self._sent: tuple[int, int] | None = None  # (count, power) last acknowledged set
        self._may_move = False                   # a set went out since the last confirmed stop
        self._progress: tuple[int, float] | None = None  # (count, motion time) of last progress
        self._thread = threading.Thread(target=self._run, name=f'module_link:{config.host}:{config.port}',
                                         daemon=True)

    # -- API for the ROS side (any thread, never blocks on I/O except request()) -------
    @property
    def config(self) -> LinkConfig:
        return self._config

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float | None = None) -> None:
        """Stop the worker within ``timeout`` s (default ``SHUTDOWN_BUDGET_S``).

        If configured and a target may be active, the worker first runs a confirmed stop
        with what is left of that time, and logs whether it was confirmed.
        """
        budget = SHUTDOWN_BUDGET_S if timeout is None else timeout
        with self._cond:
            self._stop = True
            # Keep a little of the budget for the thread to finish after its last request.
            self._exit_deadline = self._clock() + max(budget - 0.1, 0.0)
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(budget)

    def update_config(self, config: LinkConfig) -> None:
        with self._cond:
            self._config = config
            self._cond.notify_all()

    def command(self, length_m: float, stamp_ns: int = 0) -> TargetCommand:
        """Accept a commanded cable length (m): clamp it if near the range and queue it.

        Latest wins. Raises ValueError (non-physical: NaN, infinite, <= 0, beyond the
        clamp margin) or :class:`NeedsCalibration`; both are counted as refused commands.
        A new command supersedes a stop that is still wanted (the sender is in control).
        `stamp_ns` (the sender's stamp, ns) is reported with the received count, so a sender
        can tell how many of its commands up to that stamp arrived.
        """
        with self._cond:
            self._count('commands_received')
            self._last_command_stamp_ns = int(stamp_ns)
            try:
                cmd = self._config.calibration.command(length_m)
                if not self._calibrated:
                    raise NeedsCalibration('module rebooted and must be recalibrated: '
                                           'command refused until calibrate succeeds')
            except ValueError as exc:
                self._count('commands_refused')
                self._set_error('command', f'command refused: {exc}')
                self._warn_throttled('refused', self._errors['command'])
                raise
            if cmd.clamped:
                self._count('commands_clamped')
                low, high = self._config.calibration.length_range_m
                self._set_error('command', f'command {cmd.requested_length_m!r} m clamped to '
                                f'{cmd.length_m:.6f} m (allowed [{low:.6f}, {high:.6f}] m)')
                self._warn_throttled('clamped', self._errors['command'])
            else:
                self._clear_error('command')
            self._clear_error('stale', 'stall')
            self._pending = cmd
            self._last_command_time = self._clock()
            self._commands_accepted += 1
            self._stale_handled = False
            superseded = self._stop_wanted is not None
            if superseded:
                self._stop_wanted = None
                self._clear_error('stop')
            # A target the worker would hold for the poll slot needs no wake: its wait
            # never outlasts the next poll, and after a request it looks again at once.
            if superseded or not self._within_deadband(self._config, cmd):
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
            config = self._config
        if timeout is None:
            # The worker may be inside a stop (up to stop_deadline_s) and then one request.
            timeout = action_timeout_s(config)
        if not action.done.wait(timeout):
            return False, f'{kind}: no result within {timeout:.3g} s'
        return action.ok, action.message

    # -- helpers -----------------------------------------------------------------------
    def _count(self, name: str) -> None:
        """Under the lock: one more event of counter ``name``."""
        self._counts[name] += 1
        self._counters = None

    def _counters_now(self) -> Counters:
        """Under the lock: the counts as a frozen snapshot."""
        if self._counters is None:
            self._counters = Counters(**self._counts)
        return self._counters

    def _set_error(self, key: str, message: str) -> None:
        """Under the lock: record an active problem and the time of the latest error."""
        self._errors[key] = message
        self._last_error_stamp = self._clock()

    def _clear_error(self, *keys: str) -> None:
        for key in keys:
            self._errors.pop(key, None)

    def _last_error(self) -> str:
        return '; '.join(self._errors[key] for key in _ERROR_KEYS if key in self._errors)

    def _warn_throttled(self, key: str, message: str, period_s: float = 1.0) -> None:
        now = self._clock()
        if now - self._warned_at.get(key, -math.inf) >= period_s:
            self._warned_at[key] = now
            self._log.warning(message)

    def _client_for(self, config: LinkConfig) -> ModuleClient:
        if (self._client is None or self._client.host != config.host or self._client.port != config.port
                or self._client.timeout_s != config.request_timeout_s):
            self._client = self._client_factory(config.host, config.port, config.request_timeout_s)
        return self._client

    # -- worker ------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._loop()
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
            if now >= stale_at:
                # Decided even while offline: the stop is retried until confirmed.
                self._stale_handled = True
                self._pending = None
                self._stop_wanted = 'stale command stream'
                return 'stale', None
        if self._stop_wanted is not None:
            if now >= self._retry_at:
                return 'stop', self._stop_wanted
        elif (self._pending is not None and self._online and self._calibrated
                and now >= self._retry_at
                and (now >= self._next_poll or not self._within_deadband(config, self._pending))):
            # A small change waits for the poll slot and goes out instead of the poll.
            pending, self._pending = self._pending, None
            return 'set', pending
        if now >= self._next_poll:
            return 'poll', None
        if now >= self._last_report + config.poll_period_s:
            return 'heartbeat', None
        wake = min(self._next_poll, self._last_report + config.poll_period_s, stale_at)
        if ((self._stop_wanted is not None or (self._pending is not None and self._online
                                               and self._calibrated))
                and self._retry_at > now):
            wake = min(wake, self._retry_at)
        return 'wait', max(wake - now, 0.0)

    def _within_deadband(self, config: LinkConfig, cmd: TargetCommand) -> bool:
        """Whether ``cmd`` may wait for the next poll slot (see "Target deadband")."""
        sent = self._sent
        return (sent is not None and sent[1] == config.pwm_power
                and abs(cmd.count - sent[0]) <= config.target_deadband_counts)

    def _loop(self) -> None:
        while True:
            job = 'next job'
            try:
                with self._cond:
                    job, arg = self._next_job()
                    while job == 'wait':
                        self._cond.wait(arg)
                        job, arg = self._next_job()
                    config = self._config
                if job == 'exit':
                    self._shutdown(config)
                    return
                self._do_job(config, job, arg)
            except Exception as exc:  # noqa: BLE001 - report, count, go on; never die silently
                if job == 'exit':
                    self._log.error(f'module link: shutdown failed: {exc!r}\n{traceback.format_exc()}')
                    return
                try:
                    self._on_internal_error(job, exc)
                except Exception:  # noqa: BLE001 - even reporting failed (a broken logger)
                    time.sleep(0.1)   # keep the loop, and with it the watchdog, alive

    def _do_job(self, config: LinkConfig, job: str, arg) -> None:
        if job == 'action':
            self._do_action(config, arg)
        elif job == 'stale':
            self._do_stale(config)
        elif job == 'stop':
            self._stop_until_confirmed(config, arg)
        elif job == 'set':
            self._do_set(config, arg)
        elif job == 'poll':
            self._exchange(config, 'status', lambda c: c.status())
        else:
            self._emit(config, fresh=False)

    def _on_internal_error(self, job: str, exc: Exception) -> None:
        with self._cond:
            self._count('internal_errors')
            self._set_error('internal', f'internal error in {job}: {type(exc).__name__}: {exc}')
            count = self._counts['internal_errors']
            config = self._config
        now = self._clock()
        if now - self._warned_at.get('internal', -math.inf) >= INTERNAL_ERROR_LOG_PERIOD_S:
            self._warned_at['internal'] = now
            self._log.error(f'module link: unexpected error in {job} (internal error #{count}; '
                            f'the link goes on):\n{traceback.format_exc()}')
        # No hot loop if the same job fails again at once: the next poll waits a period.
        self._next_poll = max(self._next_poll, now + config.poll_period_s)
        try:
            self._emit(config, fresh=False)
        except Exception:  # noqa: BLE001 - already reporting an error; _emit guards itself
            pass
        with self._cond:
            if not self._stop:
                self._cond.wait(config.poll_period_s)

    def _exchange(self, config: LinkConfig, what: str, call,
                  check_reboot: bool = True, check_stall: bool = True) -> ModuleStatus | None:
        """One request; updates online state, backoff, reboot check; reports."""
        client = self._client_for(config)
        # When the request left: the module read its encoder between this and the reply.
        sent, sent_motion = self._clock(), self._motion_clock()
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
        self._retry_at = -math.inf
        self._next_poll = now + config.poll_period_s
        with self._cond:
            self._clear_error('link', 'internal')
        motion_now = self._motion_clock()
        previous, (previous_time, previous_motion) = self._status, self._status_time
        self._status, self._status_time = status, (sent, sent_motion)
        if previous is not None and self._calibrated and check_reboot:
            # The longest time the module can have had between its two readings: from when
            # the previous request left to this reply (a reply that waited in a busy
            # server or socket must not make an ordinary move look faster than the motor:
            # 50 simulated modules in one process gave false reboots). And the larger of
            # the two clocks: a simulated time that lags (or stopped) must not either.
            elapsed = max(now - previous_time, motion_now - previous_motion)
            # Of the targets the module may steer to, the one nearest 0: a set applied
            # whose reply was lost may be why the count is back near 0 (not a reboot).
            targets = [t for t in (self._module_target, *self._unacknowledged_targets)
                       if t is not None]
            evidence = reboot_suspected(
                previous.encoder_count, previous.encoder_errors, status.encoder_count,
                status.encoder_errors, elapsed, min(targets, key=abs) if targets else None,
                config.reboot_zero_band_counts, config.reboot_min_jump_counts,
                config.max_speed_counts_per_s)
            if evidence is not None:
                self._on_reboot(config, evidence)
                self._emit(config, fresh=True)
                return status
        if check_stall and self._stalled(config, status, motion_now):
            message = (f'motor stalled: count {status.encoder_count}, target {self._module_target}, '
                       f'no progress for {config.stall_timeout_s:g} s at {status.power_w:.2f} W; '
                       'stopping it (reach)')
            with self._cond:
                self._set_error('stall', message)
                self._count('stalls_detected')
                self._stop_wanted = 'stalled motor'
                self._pending = None
            self._log.warning(message)
            self._progress = None
        self._emit(config, fresh=True)
        return status

    def _stalled(self, config: LinkConfig, status: ModuleStatus, now: float) -> bool:
        """Track progress toward the target; True once when it stopped for too long.

        `now` is the motion clock's time (the module's time).
        """
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
        message = f'{what} failed: {type(exc).__name__}: {exc}'
        with self._cond:
            self._count('request_failures')
            self._set_error('link', message)
        if self._online and self._failures >= config.offline_after_failures:
            self._online = False
            self._log.warning(f'module {config.host}:{config.port} offline after {self._failures} '
                              f'failed requests ({message}); retrying with backoff')
        # Bounded exponential backoff before the next poll or set (never at once).
        self._retry_at = now + failure_backoff_s(config, self._failures)
        self._next_poll = self._retry_at

    def _on_reboot(self, config: LinkConfig, evidence: str) -> None:
        message = (f'module reboot detected ({evidence}): position reference lost; '
                   'holding with reach; commands refused until calibrate')
        with self._cond:
            self._count('reboots_detected')
            self._calibrated = False
            self._pending = None
            self._stop_wanted = 'module reboot'
            self._set_error('reboot', message)
        self._sent = None
        self._may_move = True        # whatever the firmware drives to now is unknown
        self._module_target = None
        self._unacknowledged_targets = ()
        self._log.warning(message)

    def _do_set(self, config: LinkConfig, cmd: TargetCommand) -> None:
        # Re-derive the count with the current calibration (parameters may have changed
        # since the command was accepted); clamping was counted when it arrived.
        try:
            cmd = config.calibration.command(cmd.requested_length_m)
        except ValueError as exc:
            # The range changed since the command was accepted: it is refused now.
            with self._cond:
                self._count('commands_refused')
                self._set_error('command', f'command refused: {exc}')
            self._log.warning(f'command refused: {exc}')
            return
        low, high = config.calibration.count_range
        if not low <= cmd.count <= high:
            # Unreachable by construction (CableCalibration clamps); a last guard.
            self._log.error(f'target {cmd.count} outside [{low}, {high}] counts: not sent')
            return
        key = (cmd.count, config.pwm_power)
        if key == self._sent:
            return
        # The firmware may apply a set whose reply is lost: from here a target may be active.
        self._may_move = True
        status = self._exchange(config, 'set', lambda c: c.set_target(cmd.count, config.pwm_power))
        if status is None:
            # The module may have applied it all the same (only its reply was lost).
            self._unacknowledged_targets = (*self._unacknowledged_targets[-7:], cmd.count)
            with self._cond:
                # Retry after the backoff: keep it unless a newer command arrived meanwhile.
                if self._pending is None and self._stop_wanted is None:
                    self._pending = cmd
            return
        self._sent = key
        self._module_target = cmd.count
        self._unacknowledged_targets = ()
        with self._cond:
            self._count('targets_sent')
        self._progress = (status.encoder_count, self._motion_clock())   # a new target: re-arm

    def _do_stale(self, config: LinkConfig) -> None:
        message = (f'no command for {config.command_timeout_s:g} s: '
                   'stopping the module where it is (reach)')
        with self._cond:
            self._count('stale_stops')
            self._set_error('stale', message)
        self._log.warning(message)
        self._stop_until_confirmed(config, 'stale command stream')

    def _stop_until_confirmed(self, config: LinkConfig, why: str,
                              deadline: float | None = None) -> StopOutcome:
        """Confirmed stop within ``stop_deadline_s`` (or ``deadline``); see the module doc.

        Confirmed: the wanted stop is done. Not confirmed: counted, reported, and the stop
        stays wanted (retried after the failure backoff) unless a new command arrived.
        """
        with self._cond:
            epoch = self._commands_accepted
        outcome = self._stop_round(config, why, deadline)
        with self._cond:
            superseded = self._commands_accepted != epoch
            if outcome.confirmed:
                self._clear_error('stop')
                if not superseded:
                    self._stop_wanted = None
                    self._stale_handled = True
            elif not superseded and not self._stop:
                self._stop_wanted = why
                if 'stop' not in self._errors:
                    self._count('stops_unconfirmed')    # once per wanted stop, not per round
                self._set_error('stop', outcome.message + '; still trying')
        if not outcome.confirmed:
            # Next round after the failure backoff (also when every request was answered).
            self._retry_at = max(self._retry_at,
                                 self._clock() + failure_backoff_s(config, max(self._failures, 1)))
        self._emit(config, fresh=False)
        return outcome

    def _stop_round(self, config: LinkConfig, why: str, deadline: float | None) -> StopOutcome:
        """Send ``reach`` (then ``status``) with growing pauses until confirmed or the deadline."""
        start = self._clock()
        if deadline is None:
            deadline = start + config.stop_deadline_s
        where = f'{config.host}:{config.port}'
        attempts, pause, problem = 0, STOP_RETRY_FIRST_S, 'no attempt'
        while True:
            remaining = deadline - self._clock()
            with self._cond:
                interrupted = self._stop and why != 'shutdown'
            if remaining <= 0 or interrupted:
                break
            attempts += 1
            if attempts == 1:
                self._log.info(f'stop sent to {where} ({why}): reach')
            timeout = min(config.request_timeout_s, remaining)
            reached = self._exchange(config, 'reach', lambda c: c.reach(timeout_s=timeout),
                                     check_stall=False)
            if reached is not None:
                remaining = deadline - self._clock()
                still = None
                if remaining > 0:
                    timeout = min(config.request_timeout_s, remaining)
                    still = self._exchange(config, 'stop check', lambda c: c.status(timeout_s=timeout),
                                           check_stall=False, check_reboot=False)
                if still is not None:
                    moved = still.encoder_count - reached.encoder_count
                    if abs(moved) <= STOP_STILL_COUNTS:
                        elapsed = self._clock() - start
                        self._progress = None
                        self._sent = None
                        self._may_move = False
                        self._module_target = reached.encoder_count
                        self._unacknowledged_targets = ()
                        self._log.info(f'stop confirmed at {where} ({why}): module holds at count '
                                       f'{still.encoder_count} ({attempts} reach request(s), '
                                       f'{elapsed:.3f} s)')
                        return StopOutcome(True, still.encoder_count, attempts, elapsed,
                                           f'stopped at count {still.encoder_count} (confirmed)')
                    problem = (f'count still moving after reach ({reached.encoder_count} -> '
                               f'{still.encoder_count})')
                else:
                    problem = 'reach answered but the status check failed'
            else:
                with self._cond:
                    problem = self._errors.get('link', 'reach failed')
            self._log.warning(f'stop not yet confirmed at {where} ({why}, attempt {attempts}): '
                           f'{problem}; retrying in {pause:.3f} s')
            wait = min(pause, deadline - self._clock())
            if wait > 0:
                with self._cond:
                    if not (self._stop and why != 'shutdown'):
                        self._cond.wait(wait)
            pause = min(2 * pause, STOP_RETRY_MAX_S)
        elapsed = self._clock() - start
        if interrupted:
            message = (f'stop ({why}) interrupted by shutdown after {attempts} reach request(s); '
                       'the shutdown stop takes over')
            self._log.warning(message)
        else:
            message = (f'stop NOT confirmed after {attempts} reach request(s) in {elapsed:.3f} s '
                       f'({why}): {problem}')
            self._log.error(message + ('' if why == 'shutdown' else '; still trying'))
        return StopOutcome(False, None, attempts, elapsed, message)

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
                        self._clear_error('reboot')
                    self._sent = None
                    self._module_target = 0
                    self._unacknowledged_targets = ()
                    self._emit(config, fresh=True)
                    action.message = (f'calibrated: count 0 is now the straight length '
                                      f'{config.calibration.straight_length_m:g} m')
            elif action.kind == 'stop':
                with self._cond:
                    # The stream is not disarmed here: only a confirmed stop disarms it.
                    self._pending = None
                    self._stop_wanted = 'stop service'
                outcome = self._stop_until_confirmed(config, 'stop service')
                action.ok, action.message = outcome.confirmed, outcome.message
                if not outcome.confirmed:
                    action.message += '; the driver keeps trying to stop it'
                return
            else:
                status = self._exchange(config, action.kind,
                                        lambda c: c.pause() if action.kind == 'pause' else c.resume())
                if status is not None:
                    action.message = f'{action.kind}d: module paused={status.paused}'
            action.ok = status is not None
            if not action.ok:
                with self._cond:
                    action.message = self._errors.get('link', f'{action.kind} failed')
        finally:
            action.done.set()

    def _shutdown(self, config: LinkConfig) -> None:
        with self._cond:
            wanted = self._stop_wanted is not None
            deadline = self._exit_deadline
        if config.stop_on_shutdown and (self._may_move or wanted):
            self.shutdown_stop = self._stop_round(  # read by the node for its exit status
                config, 'shutdown', min(deadline, self._clock() + config.stop_deadline_s))

    def _emit(self, config: LinkConfig, fresh: bool) -> None:
        now = self._clock()
        self._last_report = now
        calibration = config.calibration
        status = self._status
        with self._cond:
            calibrated, counters = self._calibrated, self._counters_now()
            last_error, last_error_stamp = self._last_error(), self._last_error_stamp
            last_command_stamp_ns = self._last_command_stamp_ns
        measured = (calibration.length_m(status.encoder_count)
                    if status is not None and calibrated else math.nan)
        target = self._module_target
        report = LinkReport(
            stamp=now, fresh=fresh and status is not None, online=self._online, calibrated=calibrated,
            status=status, measured_length_m=measured,
            target_length_m=calibration.length_m(target) if target is not None and calibrated else math.nan,
            encoder_target=target if target is not None else 0, pwm_power=config.pwm_power,
            counters=counters, last_error=last_error, last_error_stamp=last_error_stamp,
            last_command_stamp_ns=last_command_stamp_ns)
        try:
            self._report(report)
        except Exception as exc:  # noqa: BLE001 - a broken consumer must not stop the link
            self._warn_throttled('report', f'publishing the module state failed: {exc!r}')
