"""Client for the SoftSnap module firmware's HTTP API (no ROS).

The firmware (ESP32) serves plain HTTP/1.1, one client at a time, and closes the
connection after every reply. A request is a bare request line such as
``GET /?status HTTP/1.1``; the firmware looks for a keyword anywhere in the request head
(``status``, ``set``, ``calibrate``, ``pause``, ``resume``, ``reach``, in that order) and
answers every request with the same JSON status line. So every call here returns a
:class:`ModuleStatus`.

Layers:

- pure functions :func:`encode_request`, :func:`encode_set_request` and
  :func:`parse_reply` (bytes in, bytes or :class:`ModuleStatus` out);
- :class:`ModuleClient`, which owns the socket work: one TCP connection per request
  (the firmware closes it after its reply: there is no keep-alive), an explicit deadline
  per request, and a lock so that only one request at a time goes to the module (the
  firmware serves one client).

Errors are typed: :class:`ModuleConnectionError` (refused, reset, closed without a
reply), :class:`ModuleTimeout` (no complete reply within the deadline) and
:class:`MalformedReply` (a reply that is not the firmware's JSON status); all derive
from :class:`ModuleError`.

Examples
--------
>>> encode_set_request(3000, 80)
b'GET /?set=00000BB850 HTTP/1.1\\r\\n\\r\\n'
>>> encode_set_request(-1, 255)
b'GET /?set=FFFFFFFFFF HTTP/1.1\\r\\n\\r\\n'
"""
from __future__ import annotations

import json
import math
import re
import socket
import struct
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

#: Commands the firmware understands (keyword searched in the request head).
COMMANDS = ('status', 'set', 'calibrate', 'pause', 'resume', 'reach')

INT32_MIN = -(2 ** 31)
INT32_MAX = 2 ** 31 - 1
PWM_MAX = 255

#: Power history: samples in the reply, hex digits per sample, watts per unit (0.1 mW).
POWER_SAMPLES = 256
POWER_DIGITS = 4
POWER_UNIT_W = 1e-4

#: The firmware stops the motor within this many counts of its target.
FIRMWARE_DEADBAND_COUNTS = 30

#: A reply longer than this is not the firmware's (its JSON line is about 1.2 kB).
MAX_REPLY_BYTES = 16384

DEFAULT_PORT = 80


class ModuleError(Exception):
    """A request to a module failed; subclasses say how."""


class ModuleConnectionError(ModuleError):
    """The connection was refused, reset, or closed before a reply arrived."""


class ModuleTimeout(ModuleError):
    """The module did not answer completely within the request deadline."""


class MalformedReply(ModuleError):
    """The module answered, but not with the firmware's HTTP 200 + JSON status."""


@dataclass(frozen=True)
class ModuleStatus:
    """One status reply of the firmware, in the firmware's own units.

    Attributes
    ----------
    encoder_count : int
        ``m_current``: quadrature encoder count (counts, int32).
    motor_power : int
        ``m_power``: PWM power of the motor, 0-255.
    encoder_errors : int
        ``m_error``: invalid quadrature transitions since the module booted.
    battery_voltage : float
        ``battery``: mean of the last 8 battery samples, in volts (V).
    paused : bool
        ``pause``: motion disabled.
    power_history_w : sequence of float
        ``power``: the last power samples, oldest first, in watts (W): a
        :class:`PowerHistory` when parsed from a reply (equal to the tuple of its floats).
    ip, mac : str
        Network identity the module reports.
    """

    encoder_count: int
    motor_power: int
    encoder_errors: int
    battery_voltage: float
    paused: bool
    power_history_w: Sequence[float] = field(repr=False, default=())
    ip: str = ''
    mac: str = ''

    @property
    def power_w(self) -> float:
        """Latest power sample in watts (W); 0 when the history is empty."""
        return self.power_history_w[-1] if self.power_history_w else 0.0


def encode_request(command: str) -> bytes:
    """Request bytes for a parameterless command (``status``, ``calibrate``, ...).

    No header lines are sent on purpose: the firmware searches the whole request head for
    its keywords, so a header such as ``Accept-Charset`` (contains ``set``) or a host name
    containing ``status`` would change the meaning of the request.
    """
    if command not in COMMANDS or command == 'set':
        raise ValueError(f'command must be one of {[c for c in COMMANDS if c != "set"]}, '
                         f'got {command!r}')
    return f'GET /?{command} HTTP/1.1\r\n\r\n'.encode('ascii')


def encode_set_request(target_count: int, power: int) -> bytes:
    """Request bytes for ``set``: encoder target (int32, two's complement) and PWM power.

    Hex digits are upper case: the firmware skips lower-case ``a``-``f``.
    """
    if isinstance(target_count, bool) or not isinstance(target_count, int):
        raise ValueError(f'target_count must be an int, got {target_count!r}')
    if isinstance(power, bool) or not isinstance(power, int):
        raise ValueError(f'power must be an int, got {power!r}')
    if not INT32_MIN <= target_count <= INT32_MAX:
        raise ValueError(f'target_count {target_count} outside int32 [{INT32_MIN}, {INT32_MAX}]')
    if not 0 <= power <= PWM_MAX:
        raise ValueError(f'power {power} outside [0, {PWM_MAX}]')
    return f'GET /?set={target_count & 0xFFFFFFFF:08X}{power:02X} HTTP/1.1\r\n\r\n'.encode('ascii')


#: Largest magnitude accepted for a JSON number before any float conversion: far beyond
#: every plausible field, far below float range (so no OverflowError can arise).
_MAX_NUMBER = 1e15


def _short(value, limit: int = 40) -> str:
    """repr() of a reply value, cut to ``limit`` characters (replies come from the network)."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 - e.g. an int too long to print; never fail here
        text = f'<{type(value).__name__}>'
    return text if len(text) <= limit else text[:limit] + '...'


def _field(data: dict, key: str, kind):
    if key not in data:
        raise MalformedReply(f'reply lacks {key!r}')
    value = data[key]
    # bool is an int subclass in Python: refuse it where a number is expected.
    if kind is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise MalformedReply(f'{key!r} must be an integer, got {_short(value)}')
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MalformedReply(f'{key!r} must be a number, got {_short(value)}')
        # Compare before converting: float() of a huge JSON integer raises OverflowError.
        if isinstance(value, float) and not math.isfinite(value):
            raise MalformedReply(f'{key!r} must be finite, got {_short(value)}')
        if not -_MAX_NUMBER <= value <= _MAX_NUMBER:
            raise MalformedReply(f'{key!r} out of range, got {_short(value)}')
        return float(value)
    if kind in (bool, str) and not isinstance(value, kind):
        raise MalformedReply(f'{key!r} must be {kind.__name__}, got {_short(value)}')
    return value


_HEX_DIGITS = re.compile(r'[0-9a-fA-F]*')
_SAMPLE = struct.Struct('>H')     # POWER_DIGITS = 4 hex digits: one big-endian uint16


class PowerHistory(Sequence):
    """The ``power`` samples of one reply in watts (W), oldest first; read-only.

    Kept as the reply's raw 16-bit samples and converted when read: a driver reads one
    sample per reply (:attr:`ModuleStatus.power_w`), and making 256 floats of every
    reply was the largest cost of parsing it. Compares equal to a tuple of the same
    floats (and hashes like it).
    """

    __slots__ = ('_raw',)

    def __init__(self, raw: bytes = b''):
        if len(raw) % _SAMPLE.size:
            raise ValueError(f'power history must be whole {_SAMPLE.size}-byte samples, '
                             f'got {len(raw)} bytes')
        self._raw = bytes(raw)

    def __len__(self) -> int:
        return len(self._raw) // _SAMPLE.size

    def __getitem__(self, index):
        if isinstance(index, slice):
            return tuple(self)[index]
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f'power history index {index} outside [{-n}, {n})')
        return _SAMPLE.unpack_from(self._raw, _SAMPLE.size * (index % n))[0] * POWER_UNIT_W

    def __iter__(self):
        return (count * POWER_UNIT_W for (count,) in _SAMPLE.iter_unpack(self._raw))

    def __eq__(self, other) -> bool:
        if isinstance(other, PowerHistory):
            return self._raw == other._raw
        if isinstance(other, (tuple, list)):
            return tuple(self) == tuple(other)
        return NotImplemented

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        return f'PowerHistory({len(self)} samples)'


def parse_power_history(text: str) -> PowerHistory:
    """Decode the ``power`` field: 4 hex digits per sample in 0.1 mW (read in watts).

    Every reply carries 256 samples: they are checked with one regular expression and
    decoded with ``bytes.fromhex``; watts are computed only for the samples read.
    """
    if len(text) % POWER_DIGITS or len(text) > POWER_SAMPLES * POWER_DIGITS:
        raise MalformedReply(f'power history must be at most {POWER_SAMPLES} samples of '
                             f'{POWER_DIGITS} hex digits, got {len(text)} characters')
    if not _HEX_DIGITS.fullmatch(text):
        for i in range(0, len(text), POWER_DIGITS):  # name the first bad sample
            chunk = text[i:i + POWER_DIGITS]
            if not _HEX_DIGITS.fullmatch(chunk):
                raise MalformedReply(f'power history sample {i // POWER_DIGITS} is not hex: '
                                     f'{chunk!r}')
    return PowerHistory(bytes.fromhex(text))


#: The firmware's reply exactly as it frames it (FACTS.md: status line, two headers, one
#: JSON line with its keys in this order and no spaces), matched as bytes in one pass.
#: Each group admits only text that the general parser reads to the same value: ASCII
#: strings without quotes, escapes or control characters, JSON integers (no leading
#: zeros), a plain decimal battery voltage, upper- or lower-case hex.
_FIRMWARE_REPLY = re.compile(
    rb'HTTP/1\.1 200 OK\r\nContent-type:application/json\r\nConnection: close\r\n\r\n'
    rb'\{"status":"ok","ip":"([\x20\x21\x23-\x5b\x5d-\x7e]{0,64})",'
    rb'"mac":"([\x20\x21\x23-\x5b\x5d-\x7e]{0,64})",'
    rb'"m_current":(-?(?:0|[1-9][0-9]{0,9})),"m_power":(0|[1-9][0-9]{0,2}),'
    rb'"m_error":(0|[1-9][0-9]{0,9}),"battery":((?:0|[1-9][0-9]?)(?:\.[0-9]{1,6})?),'
    rb'"pause":(true|false),"power":"([0-9A-Fa-f]{0,1024})"\}[ \t\r\n]*')


def _parse_firmware_reply(raw: bytes) -> ModuleStatus | None:
    """The status of a reply framed exactly as the firmware frames it; None otherwise.

    The driver parses one reply per request: this single regular expression costs a
    fraction of decoding, splitting and ``json.loads``. Whatever it accepts,
    :func:`_parse_reply` accepts with the same result (a fuzz test holds them to it);
    everything else (other framing, spacing or key order, a value out of range) goes
    to :func:`_parse_reply`, which gives the reason.
    """
    if len(raw) > MAX_REPLY_BYTES:   # (trailing whitespace is unbounded in the pattern)
        return None
    match = _FIRMWARE_REPLY.fullmatch(raw)
    if match is None:
        return None
    ip, mac, count, power, errors, battery, paused, history = match.groups()
    count, power, errors = int(count), int(power), int(errors)
    if not (INT32_MIN <= count <= INT32_MAX and power <= PWM_MAX and errors <= 2 ** 32 - 1
            and len(history) % POWER_DIGITS == 0):
        return None
    return ModuleStatus(
        encoder_count=count, motor_power=power, encoder_errors=errors,
        battery_voltage=float(battery), paused=paused == b'true',
        power_history_w=PowerHistory(bytes.fromhex(history.decode('ascii'))),
        ip=ip.decode('ascii'), mac=mac.decode('ascii'))


def parse_reply(raw: bytes) -> ModuleStatus:
    """Parse a complete firmware reply (status line, headers, JSON line).

    Raises :class:`MalformedReply` with the reason for anything that is not an
    ``HTTP/1.x 200`` reply whose body is the firmware's JSON status with ``"status":
    "ok"``; never any other exception, whatever the bytes (a reply comes from the
    network, and the module has no authentication).
    """
    try:
        if type(raw) is bytes:
            status = _parse_firmware_reply(raw)
            if status is not None:
                return status
        return _parse_reply(raw)
    except MalformedReply:
        raise
    except Exception as exc:  # noqa: BLE001 - last guard: every other failure is malformed
        raise MalformedReply(f'reply could not be parsed ({type(exc).__name__}: '
                             f'{_short(str(exc), 80)})') from exc


def _parse_reply(raw: bytes) -> ModuleStatus:
    if not isinstance(raw, (bytes, bytearray)):
        raise MalformedReply(f'reply must be bytes, got {type(raw).__name__}')
    if not raw:
        raise MalformedReply('empty reply')
    if len(raw) > MAX_REPLY_BYTES:
        raise MalformedReply(f'reply of {len(raw)} bytes exceeds {MAX_REPLY_BYTES}')
    try:
        # The firmware sends ASCII; anything else is not its reply.
        text = bytes(raw).decode('utf-8')
    except UnicodeDecodeError as exc:
        raise MalformedReply(f'reply is not UTF-8 text (byte {exc.start}: '
                             f'{bytes(raw[exc.start:exc.start + 4])!r})') from exc
    # Head and body are separated by an empty line; tolerate bare LF line ends.
    normalised = text.replace('\r\n', '\n')
    head, sep, body = normalised.partition('\n\n')
    if not sep:
        raise MalformedReply('reply has no end of head')
    status_line = head.split('\n', 1)[0].split()
    if len(status_line) < 2 or not status_line[0].startswith('HTTP/1.'):
        raise MalformedReply(f'not an HTTP reply: {head[:40]!r}')
    if status_line[1] != '200':
        raise MalformedReply(f'HTTP status {status_line[1][:10]!r}, expected 200')
    line = body.strip()
    if not line:
        raise MalformedReply('reply has no JSON body')
    try:
        # ValueError covers bad JSON and integers beyond sys.get_int_max_str_digits();
        # RecursionError deep nesting.
        data = json.loads(line)
    except (ValueError, RecursionError) as exc:
        raise MalformedReply(f'reply body is not JSON ({type(exc).__name__}): {line[:40]!r}') from exc
    if not isinstance(data, dict):
        raise MalformedReply(f'reply body must be a JSON object, got {type(data).__name__}')
    status = data.get('status')
    if not (isinstance(status, str) and status == 'ok'):
        raise MalformedReply(f'reply status {_short(status)}, expected "ok"')
    count = _field(data, 'm_current', int)
    if not INT32_MIN <= count <= INT32_MAX:
        raise MalformedReply(f'm_current {_short(count)} outside int32')
    power = _field(data, 'm_power', int)
    if not 0 <= power <= PWM_MAX:
        raise MalformedReply(f'm_power {_short(power)} outside [0, {PWM_MAX}]')
    errors = _field(data, 'm_error', int)
    if not 0 <= errors <= 2 ** 32 - 1:
        raise MalformedReply(f'm_error {_short(errors)} outside uint32')
    battery = _field(data, 'battery', float)
    if not 0.0 <= battery < 100.0:
        raise MalformedReply(f'battery {battery} V is not a plausible voltage')
    identity = {}
    for key in ('ip', 'mac'):
        value = data.get(key, '')
        if not isinstance(value, str) or len(value) > 64:
            raise MalformedReply(f'{key!r} must be a string of at most 64 characters, '
                                 f'got {_short(value)}')
        identity[key] = value
    return ModuleStatus(
        encoder_count=count,
        motor_power=power,
        encoder_errors=errors,
        battery_voltage=battery,
        paused=_field(data, 'pause', bool),
        power_history_w=parse_power_history(_field(data, 'power', str)),
        ip=identity['ip'],
        mac=identity['mac'],
    )


class ModuleClient:
    """Talks to one module: one request at a time, each on its own TCP connection.

    Parameters
    ----------
    host : str
        Module address (an IP address is best: see :func:`encode_request`).
    port : int
        TCP port, 80 on the real firmware.
    timeout_s : float
        Deadline of one whole request (connect, send, read the reply until the module
        closes), in seconds.

    The socket exists only inside a request and is always closed before it returns, so
    there is nothing to release; :meth:`close` only refuses further requests.
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, timeout_s: float = 1.0):
        # bool is an int subclass: refuse True as port 1 or as a 1 s deadline.
        if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
            raise ValueError(f'port must be in [1, 65535], got {port!r}')
        if not (isinstance(timeout_s, (int, float)) and not isinstance(timeout_s, bool)
                and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f'timeout_s must be a positive number of seconds, got {timeout_s!r}')
        self.host = host
        self.port = port
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self._closed = False
        # (family, address) of the host, resolved at the first request and again after a
        # failed connect: resolving cost about as much CPU as the connect itself.
        self._addresses: list[tuple[int, tuple]] | None = None

    def __repr__(self) -> str:
        return f'ModuleClient({self.host!r}, {self.port}, timeout_s={self.timeout_s})'

    def close(self) -> None:
        self._closed = True

    def status(self, timeout_s: float | None = None) -> ModuleStatus:
        return self.request(encode_request('status'), timeout_s)

    def set_target(self, target_count: int, power: int) -> ModuleStatus:
        return self.request(encode_set_request(target_count, power))

    def calibrate(self) -> ModuleStatus:
        return self.request(encode_request('calibrate'))

    def pause(self) -> ModuleStatus:
        return self.request(encode_request('pause'))

    def resume(self) -> ModuleStatus:
        return self.request(encode_request('resume'))

    def reach(self, timeout_s: float | None = None) -> ModuleStatus:
        return self.request(encode_request('reach'), timeout_s)

    def request(self, payload: bytes, timeout_s: float | None = None) -> ModuleStatus:
        """Send one raw request and parse the reply (serialised with other callers).

        ``timeout_s`` shortens the deadline of this one request (s); it never exceeds the
        client's ``timeout_s``.
        """
        with self._lock:
            if self._closed:
                raise ModuleConnectionError(f'{self!r} is closed')
            return parse_reply(self._exchange(payload, timeout_s))

    def _connect(self, timeout: float) -> socket.socket:
        """A connected socket, trying each address of the host in turn (like
        ``socket.create_connection``); raises the last ``OSError``."""
        if self._addresses is None:
            self._addresses = [(family, address) for family, _, _, _, address in
                               socket.getaddrinfo(self.host, self.port, 0, socket.SOCK_STREAM)]
        error: OSError = OSError(f'{self.host} has no address')
        for family, address in self._addresses:
            sock = socket.socket(family, socket.SOCK_STREAM)
            try:
                sock.settimeout(timeout)
                sock.connect(address)
                return sock
            except OSError as exc:
                sock.close()
                error = exc
        self._addresses = None
        raise error

    def _exchange(self, payload: bytes, timeout_s: float | None = None) -> bytes:
        timeout = self.timeout_s if timeout_s is None else min(max(timeout_s, 1e-3), self.timeout_s)
        deadline = time.monotonic() + timeout
        try:
            sock = self._connect(timeout)
        except ConnectionRefusedError as exc:
            raise ModuleConnectionError(f'{self._where()} refused the connection') from exc
        except (socket.timeout, TimeoutError) as exc:
            raise ModuleTimeout(f'{self._where()}: no connection within {timeout:.3g} s') from exc
        except OSError as exc:
            raise ModuleConnectionError(f'{self._where()}: {exc.strerror or exc}') from exc
        chunks: list[bytes] = []
        size = 0
        try:
            with sock:
                # The request is one small write on a fresh connection: Nagle's algorithm
                # never holds it back, and the connect's timeout still bounds it.
                sock.sendall(payload)
                # The firmware closes the connection after its reply: read until EOF. A
                # reply (~1.2 kB) comes whole in one read, then the EOF.
                while True:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise socket.timeout()
                    sock.settimeout(remaining)
                    chunk = sock.recv(4096)
                    if not chunk:
                        break
                    chunks.append(chunk)
                    size += len(chunk)
                    if size > MAX_REPLY_BYTES:
                        raise MalformedReply(f'{self._where()}: reply exceeds {MAX_REPLY_BYTES} bytes')
        except (socket.timeout, TimeoutError) as exc:
            raise ModuleTimeout(f'{self._where()}: no complete reply within {timeout:.3g} s') from exc
        except OSError as exc:
            if size:
                # A reset after a complete reply is still a reply; parse what came.
                return b''.join(chunks)
            raise ModuleConnectionError(f'{self._where()}: {exc.strerror or exc}') from exc
        if not size:
            raise ModuleConnectionError(f'{self._where()} closed the connection without a reply')
        return b''.join(chunks)

    def _where(self) -> str:
        """``host:port`` for error messages (built only when one is raised)."""
        return f'{self.host}:{self.port}'
