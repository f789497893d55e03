"""A simulated SoftSnap module: the firmware's request semantics plus a motor model (no I/O).

:class:`SimModule` answers request heads exactly as the module firmware does
(FACTS.md, "Module firmware protocol"):

- the request head is searched for a keyword in the order ``status``, ``set``,
  ``calibrate``, ``pause``, ``resume``, ``reach`` (case-sensitive, anywhere in the head,
  headers included); anything else is answered like ``status``;
- ``set``: parsing starts after the first ``=`` of the head (at the start of the head if
  there is none, like ``indexOf('=') + 1``); characters that are not ``0-9`` or upper-case
  ``A-F`` are skipped; the first 8 digits are the target (two's-complement int32), the next
  2 the PWM power. If the head ends before all digits came, the digits seen so far are
  the value (the firmware would read past the end of its buffer; the sim stops there);
- ``calibrate``: target = current = 0; ``pause``/``resume``: stop/allow motion;
  ``reach``: target = current;
- every request is answered with the JSON status line; the server closes the connection.

Motion is bang-bang toward the target at the commanded PWM while ``|target - current| >
30`` counts; inside the deadband the motor stops.

Motor model (assumptions, all parameters of :class:`MotorModel`):

- GA12-N20 with a 1:100 gearbox: about 300 rpm at the output shaft at 6 V without load;
- the N20 magnetic encoder gives 7 pulses per motor revolution per channel, decoded x4:
  28 counts per motor revolution, 2800 counts per output revolution;
- the cable load takes ``load_fraction`` of the stall torque, so the speed is
  ``(1 - load_fraction)`` of the no-load speed and the current is interpolated between the
  no-load and stall currents;
- the winch speed scales with PWM/255 and with the motor supply voltage over 6 V. The
  firmware raises a boost pin beyond 60 counts of error: the sim reads that as a boost
  converter feeding the motor 6 V; within 60 counts the motor runs from the battery;
- below ``min_pwm`` the motor does not turn (static friction) but still draws current.

Battery model (:class:`BatteryModel`): one Li-ion cell whose open-circuit voltage falls
linearly with the charge used, minus an internal-resistance drop under the module's
current (ESP32 with Wi-Fi plus the motor through the boost converter). The firmware
samples the battery every 50 ms and reports the mean of the last 8 samples. The power
history holds the last 256 samples of the module's electrical power, 4 hex digits each in
0.1 mW, oldest first.

Faults (:class:`Faults`) are decided here and acted out by the socket server
(:mod:`softsnap_driver.sim_module`): dropped, delayed or garbage replies, an outage
(connections accepted but never answered), a reboot (encoder count, target, pause and
error counter reset; connections dropped while it boots) and a stalled motor.

Examples
--------
>>> sim = SimModule(start_time=0.0)
>>> reply = sim.handle_request(b'GET /?set=00000BB8FF HTTP/1.1\\r\\n\\r\\n', now=0.0)
>>> sim.target, sim.motor_power
(3000, 255)
>>> sim.advance_to(2.0)
>>> abs(sim.target - sim.encoder_count) <= DEADBAND_COUNTS
True
"""
from __future__ import annotations

import json
import math
import random
import re
from collections import deque
from dataclasses import dataclass

from softsnap_driver.protocol import FIRMWARE_DEADBAND_COUNTS

#: Keywords in the firmware's search order.
KEYWORDS = ('status', 'set', 'calibrate', 'pause', 'resume', 'reach')
HEX_DIGITS = '0123456789ABCDEF'
#: The motor stops when |target - current| <= this many counts.
DEADBAND_COUNTS = FIRMWARE_DEADBAND_COUNTS
#: Beyond this error (counts) the firmware raises its boost pin.
BOOST_COUNTS = 60
#: Longest request head the sim keeps (bytes); the rest of a longer head is ignored.
MAX_HEAD_BYTES = 2048
POWER_HISTORY_SAMPLES = 256
#: Power history unit: 0.1 mW, 4 hex digits (so at most 6.5535 W).
POWER_UNIT_W = 1e-4
BATTERY_SAMPLE_PERIOD_S = 0.05
BATTERY_MEAN_SAMPLES = 8
#: Above this gap (s) the sim integrates the earlier part in one step without samples.
_MAX_SAMPLED_GAP_S = 60.0


@dataclass(frozen=True)
class ParsedRequest:
    """What the firmware makes of a request head."""

    command: str
    target: int | None = None
    power: int | None = None


#: Everything that is not one of HEX_DIGITS.
_NON_HEX = re.compile('[^0-9A-F]+')


def _hex_value(digits: str) -> int:
    # Only HEX_DIGITS reach here (upper case); none: 0, as the firmware's loop gives.
    return int(digits, 16) if digits else 0


def parse_request(head: bytes) -> ParsedRequest:
    """Interpret a request head like the firmware; never raises for any bytes."""
    text = bytes(head[:MAX_HEAD_BYTES]).decode('latin-1')
    command = next((word for word in KEYWORDS if word in text), 'status')
    if command != 'set':
        return ParsedRequest(command)
    start = text.find('=') + 1
    # The first 10 hex digits after '=', skipping anything else (in C, not per char).
    digits = _NON_HEX.sub('', text[start:start + 10])
    if len(digits) < 10:
        digits = _NON_HEX.sub('', text[start:])
    raw_target = _hex_value(digits[:8])
    target = raw_target - (1 << 32) if raw_target & 0x80000000 else raw_target
    power = _hex_value(digits[8:10])
    return ParsedRequest('set', target, power)


@dataclass(frozen=True)
class MotorModel:
    """GA12-N20 1:100 with a quadrature encoder, driving the cable winch."""

    no_load_rpm: float = 300.0        # output shaft, at rated_voltage_v
    rated_voltage_v: float = 6.0
    counts_per_rev: float = 2800.0    # 7 PPR x 4 (quadrature) x 100 (gearbox)
    load_fraction: float = 0.25       # cable load / stall torque, 0 to 1
    no_load_current_a: float = 0.06
    stall_current_a: float = 0.75
    min_pwm: int = 20

    def __post_init__(self):
        for name in ('no_load_rpm', 'rated_voltage_v', 'counts_per_rev', 'stall_current_a'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be positive and finite, got {value!r}')
        if not 0.0 <= self.load_fraction < 1.0:
            raise ValueError(f'load_fraction must be in [0, 1), got {self.load_fraction!r}')
        if not 0 <= self.min_pwm <= 255:
            raise ValueError(f'min_pwm must be in [0, 255], got {self.min_pwm!r}')

    def speed_counts_per_s(self, pwm: int, supply_v: float) -> float:
        """Winch speed at a PWM duty (0-255) and motor supply voltage, in counts/s."""
        if pwm < self.min_pwm:
            return 0.0
        no_load = self.no_load_rpm / 60.0 * self.counts_per_rev
        return no_load * (pwm / 255.0) * (supply_v / self.rated_voltage_v) * (1.0 - self.load_fraction)

    def current_a(self, pwm: int, supply_v: float, stalled: bool) -> float:
        """Mean current from the motor supply, in amperes (A)."""
        load = 1.0 if stalled or pwm < self.min_pwm else self.load_fraction
        full = self.no_load_current_a + (self.stall_current_a - self.no_load_current_a) * load
        return full * (pwm / 255.0) * (supply_v / self.rated_voltage_v)


@dataclass(frozen=True)
class BatteryModel:
    """One Li-ion cell feeding the ESP32 and, through a boost converter, the motor."""

    full_v: float = 4.15
    empty_v: float = 3.3
    capacity_mah: float = 600.0
    internal_resistance_ohm: float = 0.25
    idle_current_a: float = 0.12      # ESP32 with Wi-Fi on
    boost_efficiency: float = 0.85

    def open_circuit_v(self, charge_used_mah: float) -> float:
        fraction = min(max(charge_used_mah / self.capacity_mah, 0.0), 1.0)
        return self.full_v - (self.full_v - self.empty_v) * fraction


@dataclass
class Faults:
    """Fault injection. Probabilities are per request; times are seconds since start.

    ``drop_probability``: the connection is closed without a reply.
    ``delay_probability``/``delay_s``: the reply is sent ``delay_s`` late.
    ``garbage_probability``: the reply is garbage (several kinds, see ``garbage_reply``).
    ``reboot_after_s``: the module reboots once at this time; for ``reboot_downtime_s``
    afterwards connections are dropped (booting).
    ``stall_after_s``/``stall_duration_s``: the motor is stalled (draws stall current,
    does not turn) in this window; ``inf`` duration for ever.
    ``outage_after_s``/``outage_duration_s``: connections are accepted but never answered.
    ``drop_first_reach``: the first this many ``reach`` requests are read and then dropped
    (connection closed without a reply, the module keeps its target): a lost stop.
    """

    drop_probability: float = 0.0
    delay_probability: float = 0.0
    delay_s: float = 0.0
    garbage_probability: float = 0.0
    reboot_after_s: float = math.inf
    reboot_downtime_s: float = 0.5
    stall_after_s: float = math.inf
    stall_duration_s: float = math.inf
    outage_after_s: float = math.inf
    outage_duration_s: float = 0.0
    drop_first_reach: int = 0
    seed: int | None = None

    def __post_init__(self):
        if (isinstance(self.drop_first_reach, bool) or not isinstance(self.drop_first_reach, int)
                or self.drop_first_reach < 0):
            raise ValueError(f'drop_first_reach must be an int >= 0, got {self.drop_first_reach!r}')
        for name in ('drop_probability', 'delay_probability', 'garbage_probability'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f'{name} must be in [0, 1], got {value!r}')
        for name in ('delay_s', 'reboot_after_s', 'reboot_downtime_s', 'stall_after_s',
                     'stall_duration_s', 'outage_after_s', 'outage_duration_s'):
            value = getattr(self, name)
            if math.isnan(value) or value < 0:
                raise ValueError(f'{name} must be >= 0 seconds, got {value!r}')


@dataclass(frozen=True)
class ReceivedTarget:
    """A ``set`` the sim accepted: when (sim time, s), target (counts) and PWM power."""

    time_s: float
    target: int
    power: int


class SimModule:
    """State and semantics of one simulated module. Not thread-safe: one caller at a time.

    Parameters
    ----------
    motor, battery, faults : see the dataclasses above.
    start_time : float
        Clock value (s) the module boots at; every time argument is on the same clock.
    ip, mac : str
        Reported in the status JSON.
    power_sample_period_s : float
        Interval between power history samples, in seconds.
    """

    def __init__(self, motor: MotorModel | None = None, battery: BatteryModel | None = None,
                 faults: Faults | None = None, start_time: float = 0.0, ip: str = '127.0.0.1',
                 mac: str = '02:53:4E:41:50:01', power_sample_period_s: float = 0.05):
        if not (math.isfinite(power_sample_period_s) and power_sample_period_s > 0):
            raise ValueError(f'power_sample_period_s must be positive, got {power_sample_period_s!r}')
        self.motor = motor or MotorModel()
        self.battery = battery or BatteryModel()
        self.faults = faults or Faults()
        self.ip = ip
        self.mac = mac
        self.power_sample_period_s = power_sample_period_s
        self.start_time = start_time
        self.time = start_time
        self.rng = random.Random(self.faults.seed)
        self.charge_used_mah = 0.0
        self.reboots = 0
        self.requests = 0
        #: ``reach`` requests dropped so far by ``Faults.drop_first_reach``.
        self.reaches_dropped = 0
        #: Every accepted ``set`` (bounded), so tests can check what reached the module.
        self.received_targets: deque[ReceivedTarget] = deque(maxlen=100_000)
        self._reboot_pending = math.isfinite(self.faults.reboot_after_s)
        self._boot(start_time)

    # -- state -------------------------------------------------------------------------
    def _boot(self, now: float) -> None:
        self.booted_at = now
        self.position = 0.0          # encoder count, float inside the sim
        self.target = 0
        self.motor_power = 0
        self.paused = False
        self.encoder_errors = 0
        self.current_a = self.battery.idle_current_a
        self.power_history = deque([0] * POWER_HISTORY_SAMPLES, maxlen=POWER_HISTORY_SAMPLES)
        # The same samples as 4-digit hex, kept beside them: formatting all 257 for every
        # status reply was ~8 % of sim_robot's loop.
        self._power_hex = deque(['0000'] * POWER_HISTORY_SAMPLES, maxlen=POWER_HISTORY_SAMPLES)
        self._power_text: str | None = None   # ''.join(_power_hex), None when stale
        self.battery_samples = deque([self.battery.open_circuit_v(self.charge_used_mah)],
                                     maxlen=BATTERY_MEAN_SAMPLES)
        self._next_battery_sample = now + BATTERY_SAMPLE_PERIOD_S
        self._next_power_sample = now + self.power_sample_period_s

    @property
    def encoder_count(self) -> int:
        return int(round(self.position))

    @property
    def battery_voltage(self) -> float:
        return sum(self.battery_samples) / len(self.battery_samples)

    def since_start(self, now: float) -> float:
        return now - self.start_time

    def stalled_at(self, now: float) -> bool:
        start = self.faults.stall_after_s
        return start <= self.since_start(now) < start + self.faults.stall_duration_s

    def moving(self) -> bool:
        return (not self.paused and abs(self.target - self.position) > DEADBAND_COUNTS
                and self.motor_power >= self.motor.min_pwm)

    def reboot(self, now: float | None = None) -> None:
        """Power-cycle: encoder, target, pause, error counter and histories reset."""
        now = self.time if now is None else now
        self.advance_to(now)
        self.reboots += 1
        self._boot(now)

    # -- time --------------------------------------------------------------------------
    def advance_to(self, now: float) -> None:
        """Integrate motion, battery and power samples up to clock time ``now`` (s)."""
        if self._reboot_pending:
            reboot_at = self.start_time + self.faults.reboot_after_s
            if reboot_at <= now:
                self._reboot_pending = False
                self._advance(max(reboot_at, self.time))
                self.reboots += 1
                self._boot(max(reboot_at, self.time))
        self._advance(now)

    def _advance(self, now: float) -> None:
        if now <= self.time:
            return
        if (now < self._next_power_sample and now < self._next_battery_sample
                and now - self.time <= _MAX_SAMPLED_GAP_S and not self.moving()):
            # An idle module between samples: only the clock and the idle drain move.
            # The same float operations as the general path below (sim_robot advances
            # five modules every 6 ms, mostly idle ones), so the result is bit-identical.
            dt = now - self.time
            self.current_a = self.battery.idle_current_a
            self.charge_used_mah += self.current_a * dt / 3.6
            self.time += dt
            return
        if now - self.time > _MAX_SAMPLED_GAP_S:
            self._integrate(now - _MAX_SAMPLED_GAP_S - self.time)
            self._next_battery_sample = max(self._next_battery_sample, self.time)
            self._next_power_sample = max(self._next_power_sample, self.time)
        while True:
            step_end = min(now, self._next_battery_sample, self._next_power_sample)
            self._integrate(step_end - self.time)
            if step_end >= self._next_battery_sample:
                self.battery_samples.append(self._terminal_voltage())
                self._next_battery_sample += BATTERY_SAMPLE_PERIOD_S
            if step_end >= self._next_power_sample:
                watts = self._terminal_voltage() * self.current_a
                sample = min(int(round(watts / POWER_UNIT_W)), 0xFFFF)
                self.power_history.append(sample)
                self._power_hex.append(f'{sample:04X}')
                self._power_text = None
                self._next_power_sample += self.power_sample_period_s
            if step_end >= now:
                break

    def _terminal_voltage(self) -> float:
        open_v = self.battery.open_circuit_v(self.charge_used_mah)
        return max(open_v - self.current_a * self.battery.internal_resistance_ohm, 0.0)

    def _integrate(self, dt: float) -> None:
        """Advance by dt seconds with a piecewise-constant drive (exact for bang-bang)."""
        if dt <= 0:
            return
        stalled = self.stalled_at(self.time)
        remaining = dt
        while remaining > 0:
            battery_v = self._terminal_voltage()
            if not self.moving():
                self.current_a = self.battery.idle_current_a
                self._drain(remaining)
                break
            error = self.target - self.position
            boosted = abs(error) > BOOST_COUNTS
            supply_v = self.motor.rated_voltage_v if boosted else battery_v
            motor_current = self.motor.current_a(self.motor_power, supply_v, stalled)
            if boosted:
                battery_motor_a = motor_current * supply_v / max(battery_v, 0.1) / self.battery.boost_efficiency
            else:
                battery_motor_a = motor_current
            self.current_a = self.battery.idle_current_a + battery_motor_a
            speed = 0.0 if stalled else self.motor.speed_counts_per_s(self.motor_power, supply_v)
            if speed <= 0:
                self._drain(remaining)
                break
            # Distance to the next regime change: the boost threshold, then the deadband.
            edge = BOOST_COUNTS if boosted else DEADBAND_COUNTS
            distance = abs(error) - edge
            step = min(remaining, distance / speed)
            self.position += math.copysign(speed * step, error)
            if step >= distance / speed:
                # Land exactly on the edge (avoid creeping by rounding).
                self.position = self.target - math.copysign(edge, error)
            self._drain(step)
            remaining -= step
            if step <= 0:
                break
        self.time += dt

    def _drain(self, dt: float) -> None:
        self.charge_used_mah += self.current_a * dt / 3.6

    # -- protocol ----------------------------------------------------------------------
    def handle_request(self, head: bytes, now: float) -> bytes:
        """Apply one request head at clock time ``now`` and return the full HTTP reply."""
        self.advance_to(now)
        self.requests += 1
        request = parse_request(head)
        if request.command == 'set':
            self.target = request.target
            self.motor_power = request.power
            self.received_targets.append(ReceivedTarget(now, request.target, request.power))
        elif request.command == 'calibrate':
            self.position = 0.0
            self.target = 0
        elif request.command == 'pause':
            self.paused = True
        elif request.command == 'resume':
            self.paused = False
        elif request.command == 'reach':
            self.target = self.encoder_count
        return self.reply()

    def status_json(self) -> str:
        # The 257 samples change every 50 ms; a set reply comes every 20 ms per module.
        if self._power_text is None:
            self._power_text = ''.join(self._power_hex)
        power = self._power_text
        return json.dumps({
            'status': 'ok', 'ip': self.ip, 'mac': self.mac,
            'm_current': self.encoder_count, 'm_power': self.motor_power,
            'm_error': self.encoder_errors, 'battery': round(self.battery_voltage, 3),
            'pause': self.paused, 'power': power,
        }, separators=(',', ':'))

    def reply(self) -> bytes:
        return http_reply(self.status_json())

    # -- faults ------------------------------------------------------------------------
    def fault_for_request(self, now: float) -> str | None:
        """The fault to act out for a request arriving at ``now``, or None.

        One of ``'outage'`` (hold the connection, never answer), ``'drop'`` (close without
        a reply), ``'garbage'`` or ``'delay'``. A booting module drops connections.
        """
        self.advance_to(now)
        f = self.faults
        if f.outage_after_s <= self.since_start(now) < f.outage_after_s + f.outage_duration_s:
            return 'outage'
        if self.reboots and now - self.booted_at < f.reboot_downtime_s:
            return 'drop'
        draw = self.rng.random()
        if draw < f.drop_probability:
            return 'drop'
        draw -= f.drop_probability
        if draw < f.garbage_probability:
            return 'garbage'
        if f.delay_probability and self.rng.random() < f.delay_probability:
            return 'delay'
        return None

    def fault_for_head(self, head: bytes) -> str | None:
        """The fault to act out once the request head is read: ``'drop'`` or None.

        ``Faults.drop_first_reach``: the first N ``reach`` requests are dropped, so the
        module does not stop (a lost stop). Nothing of the request is applied.
        """
        if (parse_request(head).command == 'reach'
                and self.reaches_dropped < self.faults.drop_first_reach):
            self.reaches_dropped += 1
            return 'drop'
        return None

    def garbage_reply(self) -> bytes:
        """One of several kinds of broken reply, picked at random."""
        kind = self.rng.randrange(7)
        good = self.reply()
        if kind == 0:
            return bytes(self.rng.randrange(256) for _ in range(self.rng.randrange(1, 200)))
        if kind == 1:
            return good[:self.rng.randrange(1, len(good))]
        if kind == 2:
            return http_reply('{"status":"ok","m_current":"12ab"}')
        if kind == 3:
            return b'HTTP/1.1 500 Internal Server Error\r\nConnection: close\r\n\r\n'
        if kind == 4:
            return http_reply('not json at all')
        if kind == 5:
            return http_reply(self.status_json().replace('"m_current"', '"m_curr"'))
        return good + b'X' * 20000


def http_reply(json_line: str) -> bytes:
    """The firmware's reply framing around one JSON line."""
    return ('HTTP/1.1 200 OK\r\nContent-type:application/json\r\nConnection: close\r\n\r\n'
            + json_line + '\r\n\r\n').encode('utf-8')
