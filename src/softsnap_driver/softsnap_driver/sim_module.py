"""Simulated module served over TCP, like the firmware: ``sim_module`` executable.

Runs without ROS (this module imports no rclpy)::

    python -m softsnap_driver.sim_module --port 8101 --drop-probability 0.05

and, when the command line holds ``--ros-args`` (as ``ros2 run`` and ``launch_ros``
pass it), as an rclpy node (:mod:`softsnap_driver.sim_module_node`) whose parameters are
the same options, so ``--params-file``, ``-p``, ``-r __node:=`` and ``-r __ns:=`` all work::

    sim_module --ros-args -r __ns:=/brittle_star -r __node:=sim_yellow -p port:=8101

The simulator itself (:class:`SimServer`, :class:`~softsnap_driver.firmware.SimModule`)
shares no state with ROS: the node only reads its parameters and starts the servers.

:class:`SimServer` serves one :class:`~softsnap_driver.firmware.SimModule` on a loopback
port from one thread: it accepts one client at a time, reads the request head up to the
blank line, answers with the firmware's reply (or acts out an injected fault) and closes
the connection, as the firmware does.
"""
from __future__ import annotations

import argparse
import math
import select
import signal
import socket
import sys
import threading
import time

from softsnap_driver.firmware import MAX_HEAD_BYTES, BatteryModel, Faults, MotorModel, SimModule
from softsnap_ros.ros_args import run_node_if_ros_args

#: How long the server waits for a client's request head before giving up, in seconds.
HEAD_TIMEOUT_S = 2.0
#: Poll interval of the accept loop and of held connections (reaction time to stop()), s.
_LOOP_S = 0.05
#: How long the executables wait for a server thread on shutdown, s. The thread is a
#: daemon: one stuck reading a silent client's head (up to HEAD_TIMEOUT_S) must not hold
#: the process past the 2 s a SIGINT may take.
STOP_JOIN_S = 0.5
#: Most modules one process serves (one thread each): a 50-module robot's simulated modules
#: share one process, whose DDS participant counts once (docs/scaling.md).
MAX_COUNT = 512


class SimServer:
    """Serve a :class:`SimModule` on ``host:port`` (port 0 picks a free port).

    Use as a context manager, or call :meth:`start` and :meth:`stop`. The module's state
    is guarded by :attr:`lock`; take it to read or change the module from another thread.
    """

    def __init__(self, module: SimModule | None = None, host: str = '127.0.0.1', port: int = 0,
                 clock=time.monotonic):
        self.clock = clock
        self.module = module if module is not None else SimModule(start_time=clock())
        self.lock = threading.Lock()
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port))
        except OSError:
            self._listener.close()
            raise
        self._listener.listen(8)
        self._listener.settimeout(_LOOP_S)
        self.host, self.port = self._listener.getsockname()[:2]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name=f'sim_module:{self.port}',
                                        daemon=True)
        #: Connections served, and how many got each injected fault.
        self.connections = 0
        self.fault_counts: dict[str, int] = {}

    def __enter__(self) -> SimServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop serving and close the listening socket (idempotent)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._listener.close()

    def serve_forever(self) -> None:
        """Serve in the calling thread until :meth:`stop` (from another thread or a signal)."""
        self._serve()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except (socket.timeout, TimeoutError):
                continue
            except OSError:
                if self._stop.is_set():
                    break
                raise
            with conn:
                try:
                    self._handle(conn)
                except OSError:
                    pass  # the client went away; the firmware just serves the next one

    def _read_head(self, conn: socket.socket) -> bytes:
        conn.settimeout(HEAD_TIMEOUT_S)
        data = b''
        while b'\r\n\r\n' not in data and b'\n\n' not in data and len(data) < MAX_HEAD_BYTES:
            chunk = conn.recv(1024)
            if not chunk:
                break
            data += chunk
        return data

    def _handle(self, conn: socket.socket) -> None:
        self.connections += 1
        now = self.clock()
        with self.lock:
            fault = self.module.fault_for_request(now)
        if fault is not None:
            self.fault_counts[fault] = self.fault_counts.get(fault, 0) + 1
        if fault == 'outage':
            self._hold(conn)
            return
        head = self._read_head(conn)
        if fault is None and head:
            with self.lock:
                fault = self.module.fault_for_head(head)
            if fault is not None:
                self.fault_counts[f'{fault}_head'] = self.fault_counts.get(f'{fault}_head', 0) + 1
        if fault == 'drop' or not head:
            return
        if fault == 'delay':
            self._stop.wait(self.module.faults.delay_s)
        with self.lock:
            if fault == 'garbage':
                reply = self.module.garbage_reply()
            else:
                reply = self.module.handle_request(head, self.clock())
        conn.settimeout(HEAD_TIMEOUT_S)
        conn.sendall(reply)
        try:
            conn.shutdown(socket.SHUT_WR)
        except OSError:
            pass

    def _hold(self, conn: socket.socket) -> None:
        """Outage: keep the connection open, never answer, until the client leaves."""
        faults = self.module.faults
        end = self.module.start_time + faults.outage_after_s + faults.outage_duration_s
        conn.setblocking(False)
        while not self._stop.is_set() and self.clock() < end:
            readable, _, _ = select.select([conn], [], [], _LOOP_S)
            if readable:
                try:
                    if not conn.recv(4096):
                        return  # client gave up
                except BlockingIOError:
                    pass


# -- command line ---------------------------------------------------------------------

OPTIONS = {
    # name: (type, default, help)
    'host': (str, '127.0.0.1', 'address to listen on (keep loopback)'),
    'port': (int, 8101, 'TCP port (the firmware uses 80)'),
    'count': (int, 1, f'number of modules (at most {MAX_COUNT}), on ports port, port+1, ...'),
    'seed': (int, -1, 'random seed for faults, -1 for a random one'),
    'drop_probability': (float, 0.0, 'chance a reply is dropped (connection closed)'),
    'delay_probability': (float, 0.0, 'chance a reply is delayed by delay_s'),
    'delay_s': (float, 0.0, 'delay of delayed replies, s'),
    'garbage_probability': (float, 0.0, 'chance a reply is garbage'),
    'reboot_after_s': (float, -1.0, 'reboot once this long after start, s (-1: never)'),
    'reboot_downtime_s': (float, 0.5, 'connections dropped while rebooting, s'),
    'stall_after_s': (float, -1.0, 'motor stalls this long after start, s (-1: never)'),
    'stall_duration_s': (float, -1.0, 'how long the stall lasts, s (-1: for ever)'),
    'outage_after_s': (float, -1.0, 'stop answering this long after start, s (-1: never)'),
    'outage_duration_s': (float, 0.0, 'how long the outage lasts, s'),
    'drop_first_reach': (int, 0, 'drop the first N reach (stop) requests after reading them'),
    'no_load_rpm': (float, MotorModel.no_load_rpm, 'output shaft speed at 6 V, rpm'),
    'counts_per_rev': (float, MotorModel.counts_per_rev, 'encoder counts per output revolution'),
    'load_fraction': (float, MotorModel.load_fraction, 'cable load as a fraction of stall torque'),
    'battery_full_v': (float, BatteryModel.full_v, 'battery open-circuit voltage when full, V'),
    'battery_capacity_mah': (float, BatteryModel.capacity_mah, 'battery capacity, mAh'),
    'power_sample_period_s': (float, 0.05, 'interval of the power history samples, s'),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='sim_module', description='Simulated SoftSnap module speaking the firmware HTTP protocol.')
    for name, (kind, default, text) in OPTIONS.items():
        parser.add_argument(f'--{name.replace("_", "-")}', dest=name, type=kind, default=default,
                            help=f'{text} (default {default})')
    return parser


def module_from_options(opts: argparse.Namespace, start_time: float) -> SimModule:
    def when(value: float) -> float:
        return math.inf if value < 0 else value

    faults = Faults(
        drop_probability=opts.drop_probability, delay_probability=opts.delay_probability,
        delay_s=opts.delay_s, garbage_probability=opts.garbage_probability,
        reboot_after_s=when(opts.reboot_after_s), reboot_downtime_s=opts.reboot_downtime_s,
        stall_after_s=when(opts.stall_after_s), stall_duration_s=when(opts.stall_duration_s),
        outage_after_s=when(opts.outage_after_s), outage_duration_s=opts.outage_duration_s,
        drop_first_reach=opts.drop_first_reach, seed=None if opts.seed < 0 else opts.seed)
    motor = MotorModel(no_load_rpm=opts.no_load_rpm, counts_per_rev=opts.counts_per_rev,
                       load_fraction=opts.load_fraction)
    battery = BatteryModel(full_v=opts.battery_full_v, capacity_mah=opts.battery_capacity_mah)
    return SimModule(motor=motor, battery=battery, faults=faults, start_time=start_time,
                     power_sample_period_s=opts.power_sample_period_s)


def start_servers(opts: argparse.Namespace) -> list[SimServer]:
    """Start ``opts.count`` servers on ``opts.port``, ``opts.port + 1``, ... (0: free ports).

    Raises ValueError for a bad option and OSError naming the address that cannot be
    bound; servers already started are stopped first.
    """
    if not 1 <= opts.count <= MAX_COUNT:
        raise ValueError(f'count must be in [1, {MAX_COUNT}], got {opts.count}')
    servers: list[SimServer] = []
    try:
        for i in range(opts.count):
            module = module_from_options(opts, time.monotonic())
            if opts.seed >= 0:
                module.rng.seed(opts.seed + i)
            port = opts.port + i if opts.port else 0
            try:
                servers.append(SimServer(module, host=opts.host, port=port))
            except OSError as exc:
                raise OSError(exc.errno, f'cannot listen on {opts.host}:{port}: '
                                         f'{exc.strerror or exc}') from exc
    except BaseException:
        for server in servers:
            server.stop(STOP_JOIN_S)
        raise
    for server in servers:
        server.start()
    return servers


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # Started by ros2 run or launch_ros: parameters, remaps and params files go through
    # rclpy (imported only then, so the plain simulator needs no ROS).
    status = run_node_if_ros_args(argv, 'softsnap_driver.sim_module_node')
    if status is not None:
        return status
    parser = build_parser()
    opts = parser.parse_args(argv)
    try:
        servers = start_servers(opts)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))
    for server in servers:
        print(f'[sim_module] serving the firmware protocol on {server.host}:{server.port}', flush=True)
    stopping = threading.Event()

    def stop(signum, frame):
        stopping.set()

    # Explicit handlers: a shell starting us in the background may have ignored SIGINT.
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        while not stopping.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        for server in servers:
            server.stop(STOP_JOIN_S)
        print(f'[sim_module] stopped after {sum(s.connections for s in servers)} connections', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
