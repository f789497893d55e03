"""A reply that waited on its way is not a reboot (issue 37: 50 modules in one process).

With 50 simulated modules in one process, a status reply sometimes reached its driver
long after the module read its encoder. The next, prompt reply then showed the winch much
nearer to 0 than the driver's receive-to-receive time allowed, and the driver took an
ordinary move for a reboot (holding the module until recalibrated). Here a real loopback
proxy holds one reply of a module running home at full speed; the driver must not call it
a reboot, and a real reboot behind the same proxy must still be caught.
"""
from __future__ import annotations

import json
import socket
import threading
import time

from softsnap_driver.core import CableCalibration
from softsnap_driver.firmware import Faults
from softsnap_driver.link import ModuleLink
from softsnap_driver.link_config import LinkConfig

CAL = CableCalibration(counts_per_mm=89.13, straight_length_m=0.198, max_contraction_m=0.080)
HOLD_S = 0.35
HOLD_BAND = (1800, 2600)   # counts: hold the first reply read while the winch passes here


class Log:
    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(('info', text))

    warning = error = info


class HoldingProxy:
    """Forwards each HTTP exchange to `port`; the first reply whose encoder count lies in
    `band` is held for `hold_s` before it goes on (a reply that waited in a busy server)."""

    def __init__(self, port: int, band, hold_s: float):
        self.port, self.band, self.hold_s = port, band, hold_s
        self.held: list[int] = []
        self.armed = False   # set once the module is out: hold on its way home only
        self.swallow_sets_until = 0.0   # monotonic time: until then, set replies are lost
        self.swallowed = 0
        self._sock = socket.socket()
        self._sock.bind(('127.0.0.1', 0))
        self._sock.listen(16)
        self._sock.settimeout(0.1)
        self.listen_port = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                client, _ = self._sock.accept()
            except socket.timeout:
                continue
            with client:
                client.settimeout(2.0)
                try:
                    self._exchange(client)
                except OSError:
                    pass

    def _exchange(self, client):
        head = b''
        while b'\r\n\r\n' not in head:
            chunk = client.recv(1024)
            if not chunk:
                return
            head += chunk
        with socket.create_connection(('127.0.0.1', self.port), timeout=2.0) as upstream:
            upstream.sendall(head)
            reply = b''
            while chunk := upstream.recv(4096):
                reply += chunk
        if b'set=' in head and time.monotonic() < self.swallow_sets_until:
            # The module applied the set; its reply is lost on the way (as on a bad Wi-Fi).
            self.swallowed += 1
            return
        body = reply.split(b'\r\n\r\n', 1)[-1].strip()
        try:
            count = json.loads(body)['m_current']
        except (ValueError, KeyError):
            count = None
        if self.armed and not self.held and count is not None and self.band[0] <= count <= self.band[1]:
            self.held.append(count)
            time.sleep(self.hold_s)
        client.sendall(reply)

    def close(self):
        self._stop.set()
        self._thread.join(2.0)
        self._sock.close()


def _wait_for(predicate, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def _link(port, reports):
    link = ModuleLink(LinkConfig(host='127.0.0.1', port=port, calibration=CAL, pwm_power=255,
                                 poll_period_s=0.02, command_timeout_s=0.0,
                                 request_timeout_s=1.0, max_backoff_s=0.2), reports.append, Log())
    link.start()
    return link


def test_a_held_reply_of_a_module_running_home_is_not_a_reboot(sim_server):
    server = sim_server()
    proxy = HoldingProxy(server.port, HOLD_BAND, HOLD_S)
    reports = []
    link = _link(proxy.listen_port, reports)
    try:
        link.command(CAL.straight_length_m - 0.040)          # ~3565 counts out
        assert _wait_for(lambda: reports and reports[-1].status
                         and reports[-1].status.encoder_count > 3400, 10.0)
        proxy.armed = True
        link.command(CAL.straight_length_m)                    # home at full speed
        assert _wait_for(lambda: reports[-1].status and abs(reports[-1].status.encoder_count) <= 60,
                         10.0)
        time.sleep(0.2)
        assert proxy.held, 'the proxy never held a reply: the test did not test anything'
        assert reports[-1].counters.reboots_detected == 0, reports[-1].last_error
        assert reports[-1].calibrated
    finally:
        link.stop()
        proxy.close()


def test_a_real_reboot_behind_the_same_proxy_is_still_caught(sim_server):
    # The module reboots while its target is far from 0: the count falls to 0 at once.
    server = sim_server(Faults(reboot_after_s=1.5, reboot_downtime_s=0.2))
    proxy = HoldingProxy(server.port, HOLD_BAND, HOLD_S)
    proxy.armed = True
    reports = []
    link = _link(proxy.listen_port, reports)
    try:
        link.command(CAL.straight_length_m - 0.040)
        assert _wait_for(lambda: reports and reports[-1].counters.reboots_detected == 1, 10.0)
        assert not reports[-1].calibrated
    finally:
        link.stop()
        proxy.close()


def test_a_set_whose_reply_was_lost_may_be_what_the_module_steers_to(sim_server):
    # The module applies a set whose reply never arrives: for the driver the set failed,
    # but the winch runs home. Its count reaching 0 is then no evidence of a reboot.
    server = sim_server()
    proxy = HoldingProxy(server.port, HOLD_BAND, HOLD_S)
    reports = []
    link = _link(proxy.listen_port, reports)
    try:
        link.command(CAL.straight_length_m - 0.040)
        assert _wait_for(lambda: reports and reports[-1].status
                         and reports[-1].status.encoder_count > 3400, 10.0)
        proxy.swallow_sets_until = time.monotonic() + 1.0
        link.command(CAL.straight_length_m)                    # applied, reply lost
        assert _wait_for(lambda: reports[-1].status and abs(reports[-1].status.encoder_count) <= 60,
                         10.0)
        assert _wait_for(lambda: time.monotonic() > proxy.swallow_sets_until + 0.5, 5.0)
        assert proxy.swallowed > 0, 'no set reply was lost: the test did not test anything'
        assert reports[-1].counters.reboots_detected == 0, reports[-1].last_error
        assert reports[-1].calibrated
    finally:
        link.stop()
        proxy.close()
