"""``sim_robot``'s command line: options, the per-module servers and the run loop.

::

    python -m softsnap_driver.sim_robot_runner --scene brittle_star --time-factor 1

:class:`RobotServers` serves every module of a :class:`~softsnap_driver.sim_robot.SimRobot`
on its own loopback port; :class:`SimRobotRunner` starts the servers and the simulation
thread and stops both; :func:`main` is the ``sim_robot`` entry point (with ``--ros-args``
it hands over to :mod:`softsnap_driver.sim_robot_node`).
"""
from __future__ import annotations

import argparse
import math
import signal
import sys
import threading

from softsnap_driver.firmware import BatteryModel, Faults, MotorModel
from softsnap_driver.sim_module import STOP_JOIN_S, SimServer
from softsnap_driver.sim_robot import (DEFAULT_CLOCK_RATE_HZ, DEFAULT_LINKS_PER_SEGMENT,
                                      DEFAULT_PAYLOAD_HEIGHT_M, DEFAULT_PAYLOAD_MASS_KG,
                                      DEFAULT_PAYLOAD_RELEASE_MM, DEFAULT_PAYLOAD_SIZE_M,
                                      DEFAULT_PHYSICS_TIMESTEP_S, DEFAULT_SNAPSHOT_RATE_HZ,
                                      DEFAULT_STALL_TORQUE_NM, PAYLOAD_SHAPES,
                                      PHYSICS_TIMESTEP_RANGE_S, SimRobot, SimRobotError,
                                      build_simulation)
from softsnap_ros.ros_args import run_node_if_ros_args


class RobotServers:
    """One :class:`SimServer` per module of a :class:`SimRobot`, sharing its lock and clock."""

    def __init__(self, robot: SimRobot, host: str, ports: dict[str, int]):
        self.robot = robot
        self.servers: dict[str, SimServer] = {}
        try:
            for name in robot.module_names:
                port = ports[name]
                try:
                    server = SimServer(robot.modules[name], host=host, port=port, clock=robot.clock)
                except OSError as exc:
                    raise OSError(exc.errno, f'cannot listen on {host}:{port} (module {name}): '
                                             f'{exc.strerror or exc}') from exc
                # One lock for the whole robot: the simulation loop advances every
                # module's firmware under it, and each server answers under it.
                server.lock = robot.lock
                self.servers[name] = server
        except BaseException:
            self.stop()
            raise

    def start(self) -> None:
        for server in self.servers.values():
            server.start()

    def stop(self) -> None:
        for server in self.servers.values():
            server.stop(STOP_JOIN_S)

    @property
    def connections(self) -> int:
        return sum(s.connections for s in self.servers.values())


OPTIONS = {
    # name: (type, default, help)
    'scene': (str, 'brittle_star', 'scene name or YAML path'),
    'host': (str, '127.0.0.1', 'address to listen on (keep loopback)'),
    'port_base': (int, 0, "modules on consecutive ports from this one in scene order; "
                          "0: each module on its scene port"),
    'time_factor': (float, 1.0, 'simulated seconds per wall second (0: as fast as possible)'),
    'duration_s': (float, 0.0, 'stop after this much simulated time, s (0: run until stopped)'),
    'gravity': (bool, True, 'gravity on (false: the quasi-static setting, for comparisons)'),
    'payload': (str, 'none', 'payload for the gripper or ring: none, ball, box or cylinder'),
    'payload_mass_kg': (float, DEFAULT_PAYLOAD_MASS_KG, 'payload mass, kg'),
    'payload_size_m': (float, DEFAULT_PAYLOAD_SIZE_M,
                       'payload radius (ball, cylinder) or half edge (box), m'),
    'payload_height_m': (float, DEFAULT_PAYLOAD_HEIGHT_M,
                         'height of a cylinder payload (standing on its end face), m'),
    'payload_release_mm': (float, DEFAULT_PAYLOAD_RELEASE_MM,
                           "a gripper's helper hold lets go of the payload once every "
                           'module has hauled in this much cable, mm'),
    'links_per_segment': (int, DEFAULT_LINKS_PER_SEGMENT,
                          "links per segment of the MuJoCo model (0: the model's default)"),
    'physics_timestep_s': (float, DEFAULT_PHYSICS_TIMESTEP_S,
                           'fixed timestep of the MuJoCo model, s (the control period is the '
                           'nearest whole number of steps to 5 ms)'),
    'stall_torque_nm': (float, DEFAULT_STALL_TORQUE_NM, 'winch motor stall torque at 6 V, N m'),
    'no_load_rpm': (float, MotorModel.no_load_rpm, 'winch output speed at 6 V without load, rpm'),
    'battery_full_v': (float, BatteryModel.full_v, 'battery open-circuit voltage when full, V'),
    'snapshot_rate_hz': (float, DEFAULT_SNAPSHOT_RATE_HZ, 'simulated shapes sampled this often, Hz'),
    'clock_rate_hz': (float, DEFAULT_CLOCK_RATE_HZ,
                      'simulation time published on /clock this often, Hz of simulated time'),
    'seed': (int, -1, 'random seed for faults, -1 for a random one'),
    'drop_probability': (float, 0.0, 'chance a reply is dropped (connection closed)'),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='sim_robot',
        description='A whole SoftSnap robot simulated in MuJoCo, each module speaking the '
                    'firmware HTTP protocol on its own port.')
    for name, (kind, default, text) in OPTIONS.items():
        flag = f'--{name.replace("_", "-")}'
        if kind is bool:
            parser.add_argument(flag, dest=name, type=_bool_text, default=default,
                                help=f'{text} (true/false, default {str(default).lower()})')
        else:
            parser.add_argument(flag, dest=name, type=kind, default=default,
                                help=f'{text} (default {default})')
    return parser


def _bool_text(text: str) -> bool:
    if text.lower() in ('true', '1', 'yes'):
        return True
    if text.lower() in ('false', '0', 'no'):
        return False
    raise argparse.ArgumentTypeError(f'expected true or false, got {text!r}')


def check_options(opts: argparse.Namespace) -> None:
    """Raise SimRobotError naming the first option outside its range."""
    def number(name, low, high):
        value = getattr(opts, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
            raise SimRobotError(f'{name} must be in [{low:g}, {high:g}], got {value!r}')

    number('port_base', 0, 65535)
    number('time_factor', 0.0, 1000.0)
    number('duration_s', 0.0, 1e7)
    number('stall_torque_nm', 1e-4, 100.0)
    number('no_load_rpm', 0.001, 100000.0)
    number('battery_full_v', 0.1, 50.0)
    number('snapshot_rate_hz', 0.1, 1000.0)
    number('clock_rate_hz', 1.0, 1000.0)
    number('seed', -1, 2**31 - 1)
    number('drop_probability', 0.0, 1.0)
    number('payload_release_mm', 0.0, 200.0)
    number('links_per_segment', 0, 64)
    number('physics_timestep_s', *PHYSICS_TIMESTEP_RANGE_S)
    build_payload(opts)


def build_payload(opts: argparse.Namespace):
    """The physics model's payload for the options, or None (SimRobotError if bad)."""
    if opts.payload not in PAYLOAD_SHAPES:
        raise SimRobotError(f'payload must be one of {", ".join(PAYLOAD_SHAPES)}, '
                            f'got {opts.payload!r}')
    if opts.payload == 'none':
        return None
    from softsnap_model.physics.parameters import Payload
    size = opts.payload_size_m
    height = opts.payload_height_m
    if opts.payload == 'cylinder' and not (isinstance(height, (int, float))
                                           and math.isfinite(height) and 0.0 < height <= 0.4):
        raise SimRobotError(f'payload_height_m must be in (0, 0.4] m, got {height!r}')
    sizes = {'ball': size, 'box': (size, size, size), 'cylinder': (size, 0.5 * height)}
    try:
        return Payload(opts.payload, opts.payload_mass_kg, sizes[opts.payload])
    except ValueError as exc:
        raise SimRobotError(str(exc)) from None


def build_robot(opts: argparse.Namespace) -> SimRobot:
    """Scene, physics model and firmware from options (SimRobotError/SceneError if bad)."""
    check_options(opts)
    from softsnap_model.scene import load_scene
    scene = load_scene(opts.scene)
    simulation = build_simulation(scene, gravity=opts.gravity, payload=build_payload(opts),
                                  links_per_segment=opts.links_per_segment,
                                  timestep_s=opts.physics_timestep_s)
    motor = MotorModel(no_load_rpm=opts.no_load_rpm)
    battery = BatteryModel(full_v=opts.battery_full_v)
    faults = Faults(drop_probability=opts.drop_probability,
                    seed=None if opts.seed < 0 else opts.seed)
    return SimRobot(scene, simulation, motor=motor, battery=battery, faults=faults,
                    stall_torque_nm=opts.stall_torque_nm, snapshot_rate_hz=opts.snapshot_rate_hz,
                    seed=None if opts.seed < 0 else opts.seed,
                    payload_release_mm=opts.payload_release_mm, clock_rate_hz=opts.clock_rate_hz)


def module_ports(scene, port_base: int) -> dict[str, int]:
    """Port per module: consecutive from `port_base`, or the scene's ports if 0."""
    if port_base:
        if port_base + len(scene.modules) - 1 > 65535:
            raise SimRobotError(f'port_base must leave room for {len(scene.modules)} ports '
                                f'below 65536, got {port_base}')
        return {m.name: port_base + i for i, m in enumerate(scene.modules)}
    return {m.name: m.port for m in scene.modules}


class SimRobotRunner:
    """A :class:`SimRobot` with its servers and its simulation thread (start/stop)."""

    def __init__(self, opts: argparse.Namespace):
        self.opts = opts
        self.robot = build_robot(opts)
        self.servers = RobotServers(self.robot, opts.host, module_ports(self.robot.scene, opts.port_base))
        self.stop_event = threading.Event()
        self.finished = threading.Event()
        self._thread = threading.Thread(target=self._loop, name='sim_robot', daemon=True)

    def _loop(self) -> None:
        try:
            if self.opts.duration_s > 0:
                end = threading.Event()
                timer_stop = _SimTimeStop(self.robot, self.opts.duration_s, self.stop_event, end)
                self.robot.run(timer_stop, self.opts.time_factor, failed=self._failed)
            else:
                self.robot.run(self.stop_event, self.opts.time_factor, failed=self._failed)
        finally:
            self.finished.set()

    def _failed(self, message: str) -> None:
        print(f'[sim_robot] ERROR: {message}', file=sys.stderr, flush=True)

    def start(self) -> None:
        self.servers.start()
        self._thread.start()

    def stop(self) -> None:
        self.stop_event.set()
        self._thread.join(5.0)
        self.servers.stop()


class _SimTimeStop:
    """A stop flag that is also set once the simulation reaches `duration_s`."""

    def __init__(self, robot: SimRobot, duration_s: float, stop: threading.Event,
                 end: threading.Event):
        self.robot, self.duration_s, self.stop, self.end = robot, duration_s, stop, end

    def is_set(self) -> bool:
        if self.robot.clock() >= self.duration_s - 1e-12:
            self.end.set()
        return self.stop.is_set() or self.end.is_set()

    def wait(self, timeout: float) -> bool:
        return self.stop.wait(timeout) or self.is_set()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    status = run_node_if_ros_args(argv, 'softsnap_driver.sim_robot_node')
    if status is not None:
        return status
    parser = build_parser()
    opts = parser.parse_args(argv)
    try:
        runner = SimRobotRunner(opts)
    except (ValueError, OSError) as exc:   # SimRobotError, SceneError, port in use
        parser.error(str(exc))
    runner.start()
    for name, server in runner.servers.servers.items():
        print(f'[sim_robot] {name}: serving the firmware protocol on {server.host}:{server.port}',
              flush=True)
    stopping = threading.Event()

    def stop(signum, frame):
        stopping.set()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        while not stopping.wait(0.2) and not runner.finished.is_set():
            pass
    except KeyboardInterrupt:
        pass
    finally:
        runner.stop()
    return report_stop(runner)


def report_stop(runner: SimRobotRunner) -> int:
    """Print what a stopped runner did; its exit status (1 after a simulation fault)."""
    stats = runner.robot.stats()
    print(f'[sim_robot] stopped at t = {stats.sim_time_s:.3f} s after '
          f'{runner.servers.connections} connections; real-time factor '
          f'{stats.real_time_factor:.1f} while stepping', flush=True)
    return 1 if runner.robot.fault else 0


if __name__ == '__main__':
    sys.exit(main())
