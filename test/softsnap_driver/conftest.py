"""Fixtures of the driver tests: simulated modules on loopback ports, always shut down."""
from __future__ import annotations

import socket
import threading
import time

import pytest

from softsnap_driver.firmware import Faults, SimModule
from softsnap_driver.sim_module import SimServer


@pytest.fixture
def sim_server():
    """Factory: sim_server(faults=Faults(...), **SimModule kwargs) -> started SimServer."""
    servers: list[SimServer] = []

    def start(faults: Faults | None = None, **kwargs) -> SimServer:
        module = SimModule(faults=faults, start_time=time.monotonic(), **kwargs)
        server = SimServer(module)
        server.start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.stop()


@pytest.fixture
def free_port(slot_port):
    """A loopback TCP port nobody listens on, from this session's own block (conftest)."""
    return slot_port()


class RawServer:
    """A loopback server answering every connection with `handler(conn)`; for odd peers."""

    def __init__(self, handler):
        self.handler = handler
        self.listener = socket.socket()
        self.listener.bind(('127.0.0.1', 0))
        self.listener.listen(8)
        self.listener.settimeout(0.05)
        self.port = self.listener.getsockname()[1]
        self.stopping = threading.Event()
        self.max_concurrent = 0
        self._active = 0
        self._lock = threading.Lock()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while not self.stopping.is_set():
            try:
                conn, _ = self.listener.accept()
            except OSError:
                continue
            threading.Thread(target=self._one, args=(conn,), daemon=True).start()

    def _one(self, conn):
        with self._lock:
            self._active += 1
            self.max_concurrent = max(self.max_concurrent, self._active)
        try:
            with conn:
                self.handler(conn, self.stopping)
        except OSError:
            pass
        finally:
            with self._lock:
                self._active -= 1

    def stop(self):
        self.stopping.set()
        self.thread.join(5)
        self.listener.close()


@pytest.fixture
def raw_server():
    servers: list[RawServer] = []

    def start(handler) -> RawServer:
        server = RawServer(handler)
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.stop()
