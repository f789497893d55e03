"""Protocol client: request encoding, reply parsing, and a real loopback socket."""
import socket
import threading
import time

import pytest

from softsnap_driver.firmware import SimModule, http_reply
from softsnap_driver.protocol import (MalformedReply, ModuleClient, ModuleConnectionError,
                                      ModuleError, ModuleTimeout, encode_request,
                                      encode_set_request, parse_reply)
from softsnap_driver.sim_module import SimServer


def firmware_reply(**overrides) -> bytes:
    sim = SimModule(start_time=0.0)
    text = sim.status_json()
    for key, value in overrides.items():
        import json
        data = json.loads(text)
        data[key] = value
        text = json.dumps(data)
    return http_reply(text)


# -- encoding ---------------------------------------------------------------------------
@pytest.mark.parametrize('target, power, expected', [
    (3000, 80, b'GET /?set=00000BB850 HTTP/1.1\r\n\r\n'),          # FACTS.md example
    (0, 0, b'GET /?set=0000000000 HTTP/1.1\r\n\r\n'),
    (-1, 255, b'GET /?set=FFFFFFFFFF HTTP/1.1\r\n\r\n'),           # two's complement
    (-3000, 16, b'GET /?set=FFFFF44810 HTTP/1.1\r\n\r\n'),
    (2 ** 31 - 1, 1, b'GET /?set=7FFFFFFF01 HTTP/1.1\r\n\r\n'),
    (-2 ** 31, 171, b'GET /?set=80000000AB HTTP/1.1\r\n\r\n'),     # upper-case hex only
])
def test_set_request_encoding(target, power, expected):
    assert encode_set_request(target, power) == expected


@pytest.mark.parametrize('target, power', [(2 ** 31, 0), (-2 ** 31 - 1, 0), (0, 256), (0, -1),
                                           (1.5, 10), (True, 10), (0, 2.0)])
def test_set_request_refuses_out_of_range(target, power):
    with pytest.raises(ValueError):
        encode_set_request(target, power)


def test_plain_requests_carry_no_headers():
    # Headers would be searched for keywords by the firmware (Accept-Charset has "set").
    assert encode_request('pause') == b'GET /?pause HTTP/1.1\r\n\r\n'
    with pytest.raises(ValueError):
        encode_request('set')
    with pytest.raises(ValueError):
        encode_request('reboot')


# -- parsing ----------------------------------------------------------------------------
def test_parse_firmware_reply():
    status = parse_reply(firmware_reply(m_current=-1234, m_power=80, m_error=7, battery=3.91,
                                        pause=True, power='0001' + '00FF' + '2710' * 254))
    assert status.encoder_count == -1234
    assert status.motor_power == 80
    assert status.encoder_errors == 7
    assert status.battery_voltage == pytest.approx(3.91)
    assert status.paused is True
    assert len(status.power_history_w) == 256
    assert status.power_history_w[:2] == pytest.approx((0.0001, 0.0255))
    assert status.power_w == pytest.approx(1.0)     # 0x2710 = 10000 x 0.1 mW
    assert status.ip == '127.0.0.1'


@pytest.mark.parametrize('raw, why', [
    (b'', 'empty'),
    (b'HTTP/1.1 200 OK\r\n', 'no end of head'),
    (b'HTTP/1.1 500 Oops\r\n\r\n{}', 'HTTP status'),
    (b'SSH-2.0-OpenSSH\r\n\r\n{}', 'not an HTTP'),
    (http_reply('not json'), 'not JSON'),
    (http_reply('[1, 2]'), 'JSON object'),
    (http_reply('{"status": "error"}'), 'status'),
    (firmware_reply(m_current='12'), 'm_current'),
    (firmware_reply(m_current=2 ** 31), 'int32'),
    (firmware_reply(m_current=True), 'm_current'),
    (firmware_reply(m_power=300), 'm_power'),
    (firmware_reply(battery='4.1'), 'battery'),
    (firmware_reply(pause='false'), 'pause'),
    (firmware_reply(power='12345'), 'power history'),
    (firmware_reply(power='XYZW'), 'not hex'),
    (http_reply('{"status":"ok","m_current":1}'), 'lacks'),
    (firmware_reply() + b'x' * 20000, 'exceeds'),
    (firmware_reply() + b' ' * 20000, 'exceeds'),      # the fast path's whitespace tail too
])
def test_parse_refuses_malformed_replies(raw, why):
    with pytest.raises(MalformedReply, match=why):
        parse_reply(raw)


def test_parse_refuses_non_finite_battery():
    raw = firmware_reply().replace(b'"battery":4.15', b'"battery":NaN')
    with pytest.raises(MalformedReply, match='finite'):
        parse_reply(raw)


# -- client over real sockets -----------------------------------------------------------
def test_client_commands_against_sim(sim_server):
    server = sim_server()
    client = ModuleClient('127.0.0.1', server.port, timeout_s=1.0)
    assert client.status().encoder_count == 0
    status = client.set_target(-2000, 255)
    assert server.module.target == -2000 and server.module.motor_power == 255
    assert status.motor_power == 255
    assert client.pause().paused and server.module.paused
    assert not client.resume().paused
    deadline = time.monotonic() + 3.0
    while abs(client.status().encoder_count + 2000) > 30 and time.monotonic() < deadline:
        pass
    assert abs(client.status().encoder_count + 2000) <= 30
    client.set_target(4000, 255)
    time.sleep(0.05)
    moving = client.reach().encoder_count
    assert server.module.target == moving != 4000
    assert client.calibrate().encoder_count == 0 and server.module.target == 0


def test_client_resolves_its_host_once_and_again_after_a_failed_connect(free_port, monkeypatch):
    lookups = []
    real = socket.getaddrinfo
    monkeypatch.setattr(socket, 'getaddrinfo', lambda *a, **k: lookups.append(a[0]) or real(*a, **k))
    client = ModuleClient('localhost', free_port, timeout_s=0.5)   # a name, not an address
    with pytest.raises(ModuleConnectionError, match='refused'):
        client.status()
    with SimServer(SimModule(start_time=time.monotonic()), port=free_port):
        for _ in range(3):
            assert client.set_target(100, 200).motor_power == 200
    assert lookups == ['localhost', 'localhost']     # the failed connect, then once


def test_refused_connection_is_typed(free_port):
    with pytest.raises(ModuleConnectionError, match='refused'):
        ModuleClient('127.0.0.1', free_port, timeout_s=0.5).status()


def test_silent_module_times_out(raw_server):
    def silent(conn, stopping):
        stopping.wait(5)

    server = raw_server(silent)
    client = ModuleClient('127.0.0.1', server.port, timeout_s=0.2)
    start = time.monotonic()
    with pytest.raises(ModuleTimeout):
        client.status()
    assert time.monotonic() - start < 1.0


def test_trickling_module_hits_the_whole_request_deadline(raw_server):
    # A byte every 50 ms never lets a per-recv timeout fire; the request deadline must.
    def trickle(conn, stopping):
        conn.recv(1024)
        for byte in firmware_reply():
            if stopping.wait(0.05):
                return
            conn.sendall(bytes([byte]))

    server = raw_server(trickle)
    start = time.monotonic()
    with pytest.raises(ModuleTimeout):
        ModuleClient('127.0.0.1', server.port, timeout_s=0.3).status()
    assert time.monotonic() - start < 1.0


def test_closed_without_reply_and_garbage_are_typed(raw_server):
    def close(conn, stopping):
        conn.recv(1024)

    def garbage(conn, stopping):
        conn.recv(1024)
        conn.sendall(b'\x00\xffgarbage\r\n\r\n')

    with pytest.raises(ModuleConnectionError, match='without a reply'):
        ModuleClient('127.0.0.1', raw_server(close).port, 0.5).status()
    with pytest.raises(MalformedReply):
        ModuleClient('127.0.0.1', raw_server(garbage).port, 0.5).status()


def test_one_request_at_a_time(raw_server):
    lock = threading.Lock()
    active = [0, 0]            # requests being answered now, most at once

    def slow_reply(conn, stopping):
        conn.recv(1024)
        with lock:
            active[0] += 1
            active[1] = max(active)
        stopping.wait(0.05)
        with lock:
            active[0] -= 1     # before the reply: the client may start its next request
        conn.sendall(firmware_reply())

    server = raw_server(slow_reply)
    client = ModuleClient('127.0.0.1', server.port, timeout_s=2.0)
    errors = []

    def worker():
        try:
            for _ in range(3):
                client.status()
        except ModuleError as exc:
            errors.append(exc)

    threads = [threading.Thread(target=worker) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)
    assert not errors
    assert active[1] == 1


def test_client_refuses_bad_arguments():
    with pytest.raises(ValueError):
        ModuleClient('127.0.0.1', 0)
    with pytest.raises(ValueError):
        ModuleClient('127.0.0.1', 80, timeout_s=float('nan'))


# -- boundaries and refusals that mutation testing showed unchecked (docs/testing.md) ----
from softsnap_driver.protocol import (INT32_MAX, INT32_MIN, MAX_REPLY_BYTES,  # noqa: E402
                                      _parse_firmware_reply)


def test_closed_client_sends_nothing_and_says_so(sim_server):
    # After close() no request may reach the module: a set_target would move the motor.
    server = sim_server()
    client = ModuleClient('127.0.0.1', server.port, timeout_s=1.0)
    assert client.set_target(500, 40).motor_power == 40
    connections = server.connections
    client.close()
    calls = [client.status, lambda: client.set_target(3000, 255), client.calibrate,
             client.pause, client.resume, client.reach,
             lambda: client.request(encode_request('status'))]
    for call in calls:
        with pytest.raises(ModuleConnectionError, match='is closed'):
            call()
    assert server.connections == connections
    assert server.module.target == 500 and server.module.motor_power == 40


def framed(**fields) -> bytes:
    """A reply framed exactly as the firmware frames it (the fast path's input)."""
    values = dict(ip='"10.0.0.7"', mac='"02:00"', m_current='0', m_power='0', m_error='0',
                  battery='4.15', pause='false', power='"00FF"')
    values.update({k: str(v) for k, v in fields.items()})
    body = ('{"status":"ok","ip":%(ip)s,"mac":%(mac)s,"m_current":%(m_current)s,'
            '"m_power":%(m_power)s,"m_error":%(m_error)s,"battery":%(battery)s,'
            '"pause":%(pause)s,"power":%(power)s}' % values)
    return http_reply(body)


@pytest.mark.parametrize('fields', [
    dict(m_current=INT32_MAX), dict(m_current=INT32_MIN), dict(m_power=255),
    dict(m_error=2 ** 32 - 1), dict(battery='99.999999'), dict(power='""'),
    dict(pause='true', m_current=-7, m_power=9, m_error=3, battery='3.7', power='"0001ABCD"'),
])
def test_fast_path_takes_the_limits_of_every_field(fields):
    raw = framed(**fields)
    fast = _parse_firmware_reply(raw)
    assert fast is not None and fast == parse_reply(raw)
    for key, attr in (('m_current', 'encoder_count'), ('m_power', 'motor_power'),
                      ('m_error', 'encoder_errors')):
        if key in fields:
            assert getattr(fast, attr) == fields[key]
    assert (fast.ip, fast.mac) == ('10.0.0.7', '02:00')
    assert fast.paused is (fields.get('pause') == 'true')


@pytest.mark.parametrize('fields, why', [
    (dict(m_error=2 ** 32), 'm_error 4294967296 outside uint32'),
    (dict(m_current=INT32_MAX + 1), 'm_current 2147483648 outside int32'),
    (dict(m_current=INT32_MIN - 1), 'm_current -2147483649 outside int32'),
    (dict(m_power=256), r'm_power 256 outside \[0, 255\]'),
    (dict(power='"00F"'), 'power history must be'),
    (dict(battery='100.0'), 'not a plausible voltage'),
])
def test_fast_path_leaves_out_of_range_values_to_the_general_parser(fields, why):
    raw = framed(**fields)
    assert _parse_firmware_reply(raw) is None
    with pytest.raises(MalformedReply, match=why):
        parse_reply(raw)


@pytest.mark.parametrize('fields, why', [
    (dict(m_error=-1), 'm_error -1 outside uint32'),
    (dict(m_power=-1), r'm_power -1 outside \[0, 255\]'),
    (dict(battery=-0.5), 'battery -0.5 V'),
    (dict(ip=12), "'ip' must be a string"),
    (dict(mac='x' * 65), "'mac' must be a string of at most 64"),
    (dict(m_error=1.5), "'m_error' must be an integer"),
    (dict(battery=True), "'battery' must be a number"),
    (dict(battery=1e16), "'battery' out of range"),
    (dict(battery=float('inf')), "'battery' must be finite"),
    (dict(pause=1), "'pause' must be bool"),
    (dict(power=5), "'power' must be str"),
])
def test_general_parser_refuses_each_bad_field(fields, why):
    with pytest.raises(MalformedReply, match=why):
        parse_reply(firmware_reply(**fields))


def test_general_parser_takes_the_limits_and_defaults():
    status = parse_reply(firmware_reply(m_error=0, battery=0, m_current=INT32_MIN,
                                        mac='m' * 64, power=''))
    assert (status.encoder_errors, status.battery_voltage, status.encoder_count) == (0, 0.0, INT32_MIN)
    assert status.mac == 'm' * 64 and status.power_w == 0.0 and len(status.power_history_w) == 0
    assert isinstance(status.battery_voltage, float)
    minimal = http_reply('{"status": "ok", "m_current": 5, "m_power": 1, "m_error": 0, '
                         '"battery": 4, "pause": false, "power": "0010"}')
    status = parse_reply(minimal)
    assert (status.ip, status.mac, status.encoder_count, status.power_w) == ('', '', 5, 0.0016)
    assert parse_reply(bytearray(minimal)) == status          # bytearray: the general path


def test_reply_size_limit_is_exact():
    # Both paths: a reply of exactly MAX_REPLY_BYTES is read, one byte more is refused.
    # (firmware_reply with an override has spaces in its JSON: the general path)
    for base in (firmware_reply(pause=False), framed(battery='4.15')):
        exact = base + b' ' * (MAX_REPLY_BYTES - len(base))
        for raw in (exact, bytearray(exact)):
            assert parse_reply(raw).battery_voltage == pytest.approx(4.15)
            with pytest.raises(MalformedReply, match='exceeds'):
                parse_reply(raw + b' ')


def test_reply_head_variants():
    body = SimModule(start_time=0.0).status_json()
    lf_only = ('HTTP/1.0 200 OK\nContent-type: application/json\n\n' + body + '\n').encode()
    assert parse_reply(lf_only).encoder_count == 0
    no_reason = ('HTTP/1.1 200\r\n\r\n' + body).encode()   # no reason phrase
    assert parse_reply(no_reason).encoder_count == 0
    for raw, why in ((b'HTTP/1.1\r\n\r\n{}', 'not an HTTP'), (b'HTTP/2 200\r\n\r\n{}', 'not an HTTP'),
                     (b'HTTP/1.1 200 OK\r\n\r\n \r\n', 'no JSON body'),
                     (http_reply(body.replace('"ok"', '"OK"')), 'reply status')):
        with pytest.raises(MalformedReply, match=why):
            parse_reply(raw)


def test_any_failure_inside_the_parser_is_a_malformed_reply():
    # The parser's last guard: a bytes object that fails when read (here its conversion
    # raises) still gives MalformedReply, never another exception nor None.
    class Hostile(bytes):
        def __bytes__(self):
            raise RuntimeError('unreadable')

    with pytest.raises(MalformedReply, match=r'could not be parsed \(RuntimeError: .unreadable'):
        parse_reply(Hostile(firmware_reply()))
    with pytest.raises(MalformedReply, match='must be bytes, got str'):
        parse_reply(firmware_reply().decode())


@pytest.mark.parametrize('target, power', [(0, True), (0, False), (False, 0), ('10', 0), (0, '1'),
                                           (0, None)])
def test_set_request_refuses_bools_and_strings(target, power):
    with pytest.raises(ValueError, match='must be an int'):
        encode_set_request(target, power)


def test_set_request_range_messages():
    with pytest.raises(ValueError, match='outside int32'):
        encode_set_request(INT32_MAX + 1, 0)
    with pytest.raises(ValueError, match=r'power 256 outside \[0, 255\]'):
        encode_set_request(0, 256)
    assert encode_set_request(INT32_MIN, 0) == b'GET /?set=8000000000 HTTP/1.1\r\n\r\n'


@pytest.mark.parametrize('command', ['status', 'calibrate', 'pause', 'resume', 'reach'])
def test_every_plain_command_encodes(command):
    assert encode_request(command) == f'GET /?{command} HTTP/1.1\r\n\r\n'.encode()


def test_connect_timeout_is_typed(raw_server):
    # A listener whose accept queue is full drops further SYNs: the connect times out.
    listener = socket.socket()
    listener.bind(('127.0.0.1', 0))
    listener.listen(0)
    port = listener.getsockname()[1]
    fillers = []
    try:
        for _ in range(4):
            filler = socket.socket()
            filler.setblocking(False)
            filler.connect_ex(('127.0.0.1', port))
            fillers.append(filler)
        with pytest.raises(ModuleTimeout, match='no connection within 0.2 s'):
            ModuleClient('127.0.0.1', port, timeout_s=0.2).status()
    finally:
        for sock in fillers:
            sock.close()
        listener.close()


def test_per_request_timeout_is_bounded_by_the_client_timeout(raw_server):
    def silent(conn, stopping):
        stopping.wait(5)

    server = raw_server(silent)
    client = ModuleClient('127.0.0.1', server.port, timeout_s=0.3)
    with pytest.raises(ModuleTimeout, match='within 0.3 s'):
        client.status(timeout_s=60.0)                  # never longer than the client's
    with pytest.raises(ModuleTimeout, match='within 0.1 s'):
        client.reach(timeout_s=0.1)                    # shorter for this request
    with pytest.raises(ModuleTimeout, match='within 0.001 s'):
        client.status(timeout_s=0.0)                   # floored at 1 ms, never 0 (blocking)


def test_reset_after_a_reply_still_parses_and_reset_before_is_typed(raw_server):
    def reply_then_reset(conn, stopping):
        conn.recv(1024)
        conn.sendall(firmware_reply())
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b'\x01\x00\x00\x00\x00\x00\x00\x00')

    def reset(conn, stopping):
        conn.recv(1024)
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b'\x01\x00\x00\x00\x00\x00\x00\x00')

    assert ModuleClient('127.0.0.1', raw_server(reply_then_reset).port, 1.0).status().ip == '127.0.0.1'
    with pytest.raises(ModuleConnectionError):
        ModuleClient('127.0.0.1', raw_server(reset).port, 1.0).status()


def test_oversized_reply_from_the_network_is_refused(raw_server):
    def flood(conn, stopping):
        conn.recv(1024)
        try:
            conn.sendall(b'x' * (MAX_REPLY_BYTES + 1))
        except OSError:
            pass

    def exact(conn, stopping):
        conn.recv(1024)
        reply = firmware_reply()
        conn.sendall(reply + b' ' * (MAX_REPLY_BYTES - len(reply)))

    with pytest.raises(MalformedReply, match=f'reply exceeds {MAX_REPLY_BYTES} bytes'):
        ModuleClient('127.0.0.1', raw_server(flood).port, 2.0).status()
    assert ModuleClient('127.0.0.1', raw_server(exact).port, 2.0).status().encoder_count == 0


@pytest.mark.parametrize('kwargs', [dict(port=65536), dict(port=True), dict(port='80'),
                                    dict(timeout_s=0), dict(timeout_s=-1.0),
                                    dict(timeout_s=float('inf')), dict(timeout_s=True),
                                    dict(timeout_s='1')])
def test_client_refuses_more_bad_arguments(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        ModuleClient('127.0.0.1', **kwargs)


def test_client_limits_are_accepted():
    default = ModuleClient('127.0.0.1')
    assert (default.port, default.timeout_s) == (80, 1.0)        # the firmware's port (FACTS.md)
    assert ModuleClient('127.0.0.1', 65535, timeout_s=1).timeout_s == 1.0
    assert repr(ModuleClient('h', 1, timeout_s=0.25)) == "ModuleClient('h', 1, timeout_s=0.25)"


def test_reply_values_in_messages_are_cut_at_40_characters():
    exact = 'x' * 38                                   # repr: 40 characters with its quotes
    with pytest.raises(MalformedReply, match=f"got '{exact}'$"):
        parse_reply(firmware_reply(m_current=exact))
    with pytest.raises(MalformedReply, match=f"got '{exact}x\\.\\.\\.$"):  # first 40, then ...
        parse_reply(firmware_reply(m_current=exact + 'xy'))


def test_number_limit_is_checked_before_the_voltage():
    # 1e15 is the largest magnitude taken before any float conversion.
    with pytest.raises(MalformedReply, match="'battery' out of range"):
        parse_reply(firmware_reply(battery=10 ** 15 + 1))
    with pytest.raises(MalformedReply, match='not a plausible voltage'):
        parse_reply(firmware_reply(battery=10 ** 15))
    with pytest.raises(MalformedReply, match='not a plausible voltage'):
        parse_reply(firmware_reply(battery=-10 ** 15))
    with pytest.raises(MalformedReply, match="'battery' out of range"):
        parse_reply(firmware_reply(battery=-10 ** 15 - 1))


def test_power_history_reads_like_a_tuple_of_watts():
    from softsnap_driver.protocol import PowerHistory, parse_power_history
    history = parse_power_history('0001' + '2710' + 'ffff')
    watts = (1 * 1e-4, 10000 * 1e-4, 65535 * 1e-4)     # 0.1 mW per unit
    assert len(history) == 3 and history.count(watts[0]) == 1
    assert (history[0], history[1], history[-1]) == watts[::2][:1] + watts[1:]
    assert history[-3] == history[0] and history[2] == history[-1] == pytest.approx(6.5535)
    for index in (3, -4, 300):
        with pytest.raises(IndexError, match=rf'power history index {index} outside \[-3, 3\)'):
            history[index]
    assert history[1:] == watts[1:] and isinstance(history[:1], tuple)
    assert list(history) == list(watts)
    assert history == watts == history and history == list(watts)
    assert history == PowerHistory(bytes.fromhex('00012710ffff'))
    assert history != PowerHistory(bytes.fromhex('00012710fffe')) and history != watts[:2]
    assert (history == 'text') is False and hash(history) == hash(watts)
    assert repr(history) == 'PowerHistory(3 samples)' and len(PowerHistory()) == 0
    with pytest.raises(ValueError, match='whole 2-byte samples, got 3 bytes'):
        PowerHistory(b'abc')
    assert len(parse_power_history('0' * 1024)) == 256
    for bad, why in (('0' * 1028, 'at most 256 samples of 4 hex digits, got 1028'),
                     ('000', 'got 3 characters'), ('0000' + '00g0', "sample 1 is not hex: '00g0'")):
        with pytest.raises(MalformedReply, match=why):
            parse_power_history(bad)
