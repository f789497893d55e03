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
