#!/usr/bin/env python3
"""Node CPU benchmark: model_node, driver_node and rerun_logger, before and after, per module.

Every node runs as its own process and talks over DDS to load generators in other
processes; its CPU is read from the kernel (psutil ``cpu_times``, user + system) over a
measuring window after a warm-up. Cases:

- ``baseline``: an rclpy node doing nothing but a 100 Hz empty timer: the floor any
  rclpy process pays on this machine, in the same run.
- ``model5``: model_node predicting the 5-module brittle star at 100 Hz, commanded and
  measured lengths of every module changing every 10 ms (a length publisher process
  stands in for the gait and the drivers), both RobotShape topics subscribed (like the
  rerun logger in the demo).
- ``model_idle``: the same node with no lengths arriving: CPU per idle tick.
- ``model50``: a synthetic 50-module scene (written by this script) at 100 Hz, every
  length changing every tick: 10,000 lengths/s offered by ``--length-publishers``
  processes (5 by default), each publishing its share of the modules as messages
  serialised before the loop (one Python process building messages got out only
  ~3,000/s). The table says how many lengths were offered and taken, the solves, the
  node's CPU and its CPU per length, and whether it served them all within one core.
- ``driver``: driver_node polling a simulated module at 10 Hz and taking 50 Hz commands
  (a new length each time), the simulated module in a separate process.
- ``driver_idle``: the same driver_node with no commands, polling its module at 10 Hz
  (what a driver costs while the robot stands).
- ``drivers5`` and ``container5``: five modules driven like ``driver`` (one process
  serving the five simulated modules, one publishing the five command streams, as the
  gait does), by five ``driver_node`` processes or by one ``driver_container`` process;
  the CPU is the sum over the driver processes, the table divides it by five. The
  container runs for ``--before`` only if that revision has it.
- ``rerun``: rerun_logger recording the 5-module robot: both RobotShape topics at 50 Hz
  (commanded shapes change every message, predicted ones at 20 Hz: in between the
  model node re-sends them unchanged), commands at 50 Hz, measured lengths and states at
  20 Hz, the logger's default 30 Hz rate limit (550 messages/s). The publisher counts
  what it sent, so the table gives CPU per message. The recordings of "before" and
  "after" are read back and their entity sets compared (they must be equal).
  Only this case: ``--cases baseline rerun``.

``--before REF`` also runs every case with the nodes' code as of git revision REF
(extracted with ``git archive`` to a temporary directory and put first on PYTHONPATH;
messages and the rest of the environment are shared), interleaved with the current
code, so both see the same machine load. Each case is repeated ``--repeats`` times;
the table gives the median and range, and the ratio after/before of the medians.
The load average is printed at the start and the end. ``--threads`` also prints the CPU
of each thread of the node process over the same windows (``/proc/<pid>/task``): Fast
DDS names its threads (``dds.shm``, ``dds.ev``...), the Python ones all carry the
interpreter's name, the main thread (the executor) marked ``(main)``.

Usage: .venv/bin/python benchmarks/node_cost_bench.py [--seconds 10] [--repeats 3]
       [--before b3d97c3] [--cases baseline model5 model_idle model50 driver rerun]
       [--length-publishers 5] [--threads]
(the model node alone: ``--cases model5 model_idle model50``)
"""
from __future__ import annotations

import argparse
import math
import os
import random
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
NS = '/bench'
PACKAGES = ('softsnap_model', 'softsnap_driver', 'softsnap_gaits')
MAIN = {  # node -> (module with main(), what main needs in argv)
    'model_node': 'softsnap_model.model_node',
    'driver_node': 'softsnap_driver.driver_node',
    'driver_container': 'softsnap_driver.driver_container',
    'rerun_logger': 'softsnap_gaits.rerun_logger',
}
#: The container's source in a checkout (revisions before it have none).
CONTAINER_SOURCE = 'src/softsnap_driver/softsnap_driver/driver_container.py'
CASES = ('baseline', 'model5', 'model_idle', 'model50', 'driver', 'driver_idle', 'drivers5',
         'container5', 'rerun')

BASELINE_NODE = '''
import rclpy
from rclpy.executors import SingleThreadedExecutor
rclpy.init()
node = rclpy.create_node('idle_baseline')
node.create_timer(0.01, lambda: None)
executor = SingleThreadedExecutor()
executor.add_node(node)
try:
    executor.spin()
except BaseException:
    pass
'''


# ------------------------------------------------------------------ processes
def _env(code_dir: Path | None, log_home: str) -> dict:
    env = dict(os.environ, ROS_HOME=log_home, PYTHONUNBUFFERED='1')
    if code_dir is not None:
        paths = [str(code_dir / 'src' / pkg) for pkg in PACKAGES]
        env['PYTHONPATH'] = os.pathsep.join(paths + [env.get('PYTHONPATH', '')]).rstrip(os.pathsep)
    return env


def start(argv: list[str], code_dir: Path | None, log: Path) -> subprocess.Popen:
    out = open(log, 'w')
    return subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                            env=_env(code_dir, tempfile.mkdtemp()), stdin=subprocess.DEVNULL)


def start_ros_node(node: str, ros_args: list[str], code_dir: Path | None, log: Path):
    """A node's main() in a fresh interpreter, from ``code_dir`` (None: the current code)."""
    code = f'from {MAIN[node]} import main; import sys; sys.exit(main())'
    return start([sys.executable, '-c', code, '--ros-args', *ros_args], code_dir, log)


def stop(proc: subprocess.Popen) -> None:
    """SIGINT the child's process group, SIGKILL after 15 s (softsnap_ros.processes says how)."""
    from softsnap_ros.processes import stop_process_group  # here: children import this file from elsewhere
    stop_process_group(proc, 15.0)


def cpu_seconds(ps: psutil.Process) -> float:
    t = ps.cpu_times()
    return t.user + t.system


def read_counters(path: Path | list[Path]) -> dict[str, float]:
    """The counters children last wrote ('name value' lines; {} before any), summed over
    the files if several."""
    if isinstance(path, list):
        total: dict[str, float] = {}
        for one in path:
            for k, v in read_counters(one).items():
                total[k] = total.get(k, 0.0) + v
        return total
    try:
        return {k: float(v) for k, v in (line.split() for line in path.read_text().splitlines())}
    except (OSError, ValueError):
        return {}


def measure(proc: subprocess.Popen | list[subprocess.Popen], warmup: float, seconds: float,
            log: Path, counters: Path | list[Path] | None = None,
            ready=None) -> tuple[float, dict[str, float]]:
    """(CPU of ``proc`` (summed over the processes of a list) over ``seconds`` in % of one
    core, rates per second of the node's own counters over the same window, read from
    ``counters``).

    The window starts ``warmup`` s after the node is working: its counters move (or
    ``ready()`` is true), so that start-up (imports take seconds on a loaded machine)
    is never measured.
    """
    procs = proc if isinstance(proc, list) else [proc]
    deadline = time.monotonic() + 180.0
    while ready is not None and not ready():
        if any(p.poll() is not None for p in procs) or time.monotonic() > deadline:
            raise RuntimeError(f'node not working after 180 s:\n{log.read_text()[-3000:]}')
        time.sleep(0.2)
    time.sleep(warmup)
    if any(p.poll() is not None for p in procs):
        raise RuntimeError(f'process ended early:\n{log.read_text()[-3000:]}')
    ps = [psutil.Process(p.pid) for p in procs]
    n0 = read_counters(counters) if counters else {}
    c0, t0 = sum(map(cpu_seconds, ps)), time.monotonic()
    threads0 = thread_ticks(procs[0].pid)
    time.sleep(seconds)
    c1, t1 = sum(map(cpu_seconds, ps)), time.monotonic()
    threads1 = thread_ticks(procs[0].pid)
    n1 = read_counters(counters) if counters else {}
    if any(p.poll() is not None for p in procs):
        raise RuntimeError(f'process ended early:\n{log.read_text()[-3000:]}')
    rates = {k: (n1[k] - n0.get(k, 0.0)) / (t1 - t0) for k in n1}
    write_thread_shares(log.parent / THREADS_FILE, threads0, threads1, t1 - t0)
    return 100.0 * (c1 - c0) / (t1 - t0), rates


#: Per-thread CPU of a case's (first) node process over the window, next to its log.
THREADS_FILE = 'threads'


def thread_ticks(pid: int) -> dict[tuple[int, str], int]:
    """(thread id, name) -> CPU clock ticks (user + system) of every thread of ``pid``.

    Python threads all show as the interpreter's name: the main thread (the executor in
    our nodes) is told apart by its id, which is the process id.
    """
    out = {}
    try:
        tids = os.listdir(f'/proc/{pid}/task')
    except OSError:
        return out
    for tid in tids:
        try:
            stat = Path(f'/proc/{pid}/task/{tid}/stat').read_text()
        except OSError:
            continue   # the thread ended meanwhile
        name = stat[stat.index('(') + 1:stat.rindex(')')]
        fields = stat[stat.rindex(')') + 2:].split()
        if int(tid) == pid:
            name += '(main)'
        out[(int(tid), name)] = int(fields[11]) + int(fields[12])  # utime, stime
    return out


def write_thread_shares(path: Path, before: dict, after: dict, seconds: float) -> None:
    """'name percent' lines: % of one core per thread name over the window, threads of
    the same name summed (Fast DDS numbers some of its threads: the digits are dropped)."""
    hz = os.sysconf('SC_CLK_TCK')
    shares: dict[str, float] = {}
    for (tid, name), ticks in after.items():
        key = re.sub(r'\.\d+$', '', name).replace(' ', '_')
        spent = 100.0 * (ticks - before.get((tid, name), 0)) / hz / seconds
        shares[key] = shares.get(key, 0.0) + spent
    path.write_text(''.join(f'{k} {v:.3f}\n' for k, v in sorted(shares.items())))


# ------------------------------------------------------------------ load generators
def publish_lengths(scene_path: str, rate: float, moving: bool, share: int = 0,
                    shares: int = 1, counts: str = '') -> None:
    """(child process) Commanded and measured lengths at ``rate`` Hz of every ``shares``-th
    module of the scene from the ``share``-th on (several processes split a big robot).

    The messages of a whole cycle of the pattern are serialised before the loop and
    published as bytes, so that one process can offer thousands of lengths per second;
    the number published so far is written to ``counts`` ('published N') every second.
    """
    import rclpy
    from rclpy.serialization import serialize_message
    from softsnap_interfaces.msg import CableLength
    from softsnap_model.scene import load_scene

    scene = load_scene(scene_path)
    rclpy.init()
    node = rclpy.create_node(f'length_publisher_{share}')
    # Each topic's place in the whole robot (module, then command/measured) sets its
    # phase, as with a single publisher: no two modules get the same lengths, however
    # the modules are shared out.
    pubs = [(m, node.create_publisher(CableLength, f'{NS}/{m.name}/cable_length/{topic}', 10),
             off, 2 * index + t)
            for index, m in enumerate(scene.modules) if index % shares == share
            for t, (topic, off) in enumerate((('command', 0.0), ('measured', 0.7)))]
    cycle = 1000 if moving else 1  # the contraction pattern repeats every 1000 ticks
    msg = CableLength()
    ticks = []
    for tick in range(cycle):
        row = []
        for m, pub, offset, i in pubs:
            contraction = (30.0 + 20.0 * ((tick * 0.013 + 0.037 * i) % 1.0)) if moving else 30.0
            msg.cable_length = (m.straight_length_mm - contraction - offset) / 1000.0
            row.append((pub.publish, serialize_message(msg)))
        ticks.append(row)
    period = 1.0 / rate
    start = time.monotonic()
    tick = published = 0
    reported = start
    try:
        while True:
            for publish, data in ticks[tick % cycle]:
                publish(data)
            published += len(pubs)
            tick += 1
            now = time.monotonic()
            if counts and now - reported >= 1.0:
                tmp = Path(counts).with_suffix('.tmp')
                tmp.write_text(f'published {published}\n')
                tmp.rename(counts)
                reported = now
            time.sleep(max(0.0, start + tick * period - now))
    except KeyboardInterrupt:
        pass


def publish_driver_commands(rate: float, straight_m: float, modules: int = 1) -> None:
    """(child process) 50 Hz cable-length commands to modules m1 (m1-m5 for 5), a new length
    each time, all modules in the same tick (as the gait sends them)."""
    import rclpy
    from softsnap_interfaces.msg import CableLength

    rclpy.init()
    node = rclpy.create_node('command_publisher')
    pubs = [node.create_publisher(CableLength, f'{NS}/m{i + 1}/cable_length/command', 10)
            for i in range(modules)]
    msg = CableLength()
    period = 1.0 / rate
    start = time.monotonic()
    tick = 0
    try:
        while True:
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.cable_length = straight_m - 0.010 - 0.030 * ((tick * 0.01) % 1.0)
            for pub in pubs:
                pub.publish(msg)
            tick += 1
            time.sleep(max(0.0, start + tick * period - time.monotonic()))
    except KeyboardInterrupt:
        pass


def publish_robot(rate: float, out: str) -> None:
    """(child process) What the rerun logger sees in the demo of the 5-module brittle star;
    writes the count of messages published so far to ``out`` twice a second."""
    import rclpy
    from geometry_msgs.msg import Point, Pose
    from softsnap_interfaces.msg import CableLength, ModuleShape, ModuleState, RobotShape
    from softsnap_model import geometry
    from softsnap_model.scene import load_scene

    scene = load_scene('brittle_star')
    rclpy.init()
    node = rclpy.create_node('robot_publisher')
    shape_pubs = {s: node.create_publisher(RobotShape, f'{NS}/model/shape/{s}', 10)
                  for s in ('commanded', 'predicted')}
    pubs = {(m.name, kind): node.create_publisher(
        ModuleState if kind == 'state' else CableLength,
        f'{NS}/{m.name}/' + {'command': 'cable_length/command',
                             'measured': 'cable_length/measured', 'state': 'state'}[kind], 10)
        for m in scene.modules for kind in ('command', 'measured', 'state')}
    poses = []
    for m in scene.modules:
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = m.base_position_m
        (pose.orientation.x, pose.orientation.y, pose.orientation.z,
         pose.orientation.w) = m.base_orientation_xyzw
        poses.append(pose)
    spacing = scene.skeleton.spacing_mm
    cached: dict = {}

    def module_shape(m, i, source, phase, stamp):
        key = (m.name, source, phase)
        if key not in cached:  # like the model node: one message per solved shape
            total = 0.4 * math.sin(phase * 0.07 + i) * (1.0 if source == 'commanded' else 0.9)
            angles = [total / 11] * 11
            shape = ModuleShape(module=m.name, source=source, converged=True, solve_time=1.5e-4)
            shape.header.stamp = stamp
            shape.angles = angles
            shape.rib_centers = [Point(x=float(x) / 1000, y=float(y) / 1000, z=0.0)
                                 for x, y in geometry.rib_centers(angles, spacing)]
            cached.clear() if len(cached) > 100 else None
            cached[key] = shape
        return cached[key]

    period = 1.0 / rate
    start = time.monotonic()
    tick = 0
    sent = 0
    counters = Path(out)
    try:
        while True:
            stamp = node.get_clock().now().to_msg()
            for source, phase in (('commanded', tick), ('predicted', tick * 2 // 5)):
                robot = RobotShape(robot='brittle_star')
                robot.header.stamp = stamp
                robot.modules = [module_shape(m, i, source, phase, stamp)
                                 for i, m in enumerate(scene.modules)]
                robot.base_poses = poses
                shape_pubs[source].publish(robot)
                sent += 1
            for i, m in enumerate(scene.modules):
                length = CableLength(cable_length=0.17 + 0.01 * math.sin(tick * 0.07 + i))
                length.header.stamp = stamp
                pubs[(m.name, 'command')].publish(length)
                sent += 1
                if tick % 5 in (0, 2):  # 20 Hz at a 50 Hz tick
                    pubs[(m.name, 'measured')].publish(length)
                    state = ModuleState(module=m.name, online=True, battery_voltage=7.4)
                    state.header.stamp = stamp
                    pubs[(m.name, 'state')].publish(state)
                    sent += 2
            tick += 1
            if tick % int(max(1, rate // 2)) == 0:
                tmp = counters.with_suffix('.tmp')
                tmp.write_text(f'messages {sent}\n')
                tmp.rename(counters)
            time.sleep(max(0.0, start + tick * period - time.monotonic()))
    except KeyboardInterrupt:
        pass


def run_child(kind: str, *args: str) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), '--child', kind, *args]


# ------------------------------------------------------------------ scenes
def write_scene(path: Path, n_modules: int) -> Path:
    """A synthetic scene: the brittle star's connector and its five threadings repeated
    to ``n_modules`` legs named m00, m01, ..., spread around the connector."""
    data = yaml.safe_load((ROOT / 'src/softsnap_gaits/scenes/brittle_star.yaml').read_text())
    legs = data['modules']
    modules = []
    for i in range(n_modules):
        leg = dict(legs[i % len(legs)])
        leg['name'] = f'm{i:02d}'
        leg['color'] = leg.get('color', 'grey')
        leg['port'] = 9000 + i
        yaw = 360.0 * i / n_modules
        radius = 72.5 + 30.0 * (i // len(legs))
        leg['base'] = {'position_mm': [radius * math.cos(math.radians(yaw)),
                                       radius * math.sin(math.radians(yaw)), 0.0],
                       'rpy_deg': [0.0, 0.0, yaw]}
        leg.pop('parent', None)
        modules.append(leg)
    data['name'] = f'synthetic_{n_modules}'
    data['modules'] = modules
    names = [m['name'] for m in modules]
    walk = dict(data['gaits'][data['default_gait']])
    walk['groups'] = [names[0::2], names[1::2]]
    data['gaits'] = {'walk': walk}
    data['default_gait'] = 'walk'
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# ------------------------------------------------------------------ cases
def model_args(scene: str, extra=()) -> list[str]:
    return ['-r', f'__ns:={NS}', '-p', f'scene:={scene}', '-p', 'rate:=100.0', *extra]


def case_model(code_dir, work: Path, scene: str, moving: bool | None, warmup, seconds,
               publishers: int = 1):
    """model_node with lengths from ``publishers`` publisher processes, each taking a
    share of the modules (None: no lengths at all), and both RobotShape topics
    subscribed by a listener process."""
    log = work / 'model.log'
    node = start_ros_node('model_node', model_args(scene, ['-p', 'diagnostics_period:=0.5']),
                          code_dir, log)
    helpers = [start(run_child('listen', 'model', str(work / 'counters')), None,
                     work / 'listen.log')]
    counters = [work / 'counters']
    if moving is not None:
        for share in range(publishers):
            counters.append(work / f'published{share}')
            helpers.append(start(run_child('lengths', scene, '100', str(int(moving)), str(share),
                                           str(publishers), str(counters[-1])),
                                 None, work / f'lengths{share}.log'))

    def working() -> bool:  # diagnostics arrive, and lengths are taken unless idle
        taken = read_counters(work / 'counters')
        return 'solves' in taken and (moving is None or taken['lengths'] > 0)

    try:
        return measure(node, warmup, seconds, log, counters, working)
    finally:
        for p in helpers:
            stop(p)
        stop(node)


def listen(kind: str, out: str) -> None:
    """(child process) Subscribe like the demo's consumers and write the node's own
    counters to ``out``: model: both RobotShape topics (as the rerun logger) and
    model/diagnostics (solves, lengths taken); driver: m1/state (commands received,
    targets sent)."""
    import rclpy
    from softsnap_interfaces.msg import ModelDiagnostics, ModuleState, RobotShape
    rclpy.init()
    node = rclpy.create_node('bench_listener')
    path = Path(out)

    def write(values: dict) -> None:
        tmp = path.with_suffix('.tmp')
        tmp.write_text(''.join(f'{k} {v}\n' for k, v in values.items()))
        tmp.rename(path)

    if kind == 'model':
        for source in ('commanded', 'predicted'):
            node.create_subscription(RobotShape, f'{NS}/model/shape/{source}', lambda m: None, 10)
        node.create_subscription(ModelDiagnostics, f'{NS}/model/diagnostics', lambda m: write({
            'solves': m.solves,
            'lengths': sum(m.commanded_lengths) + sum(m.measured_lengths)}), 10)
    else:   # driver: m1's counters; drivers5: m1-m5 summed
        seen: dict[str, tuple[int, int]] = {}

        def state(m) -> None:
            seen[m.module] = (m.commands_received, m.targets_sent)
            write({'commands': sum(c for c, _ in seen.values()),
                   'targets': sum(t for _, t in seen.values())})

        for i in range(5 if kind == 'drivers5' else 1):
            node.create_subscription(ModuleState, f'{NS}/m{i + 1}/state', state, 10)
    try:
        rclpy.spin(node)
    except BaseException:
        pass


DRIVER_PARAMS = ['-p', 'counts_per_mm:=89.13', '-p', 'straight_length_m:=0.198',
                 '-p', 'pwm_power:=255', '-p', 'poll_rate_hz:=10.0', '-p', 'command_timeout_s:=0.0']


def case_driver(code_dir, work: Path, warmup, seconds, modules: int = 1,
                container: bool = False, commands: bool = True):
    """``modules`` simulated modules (one process) driven by one driver_node process
    each, or by one driver_container process; CPU summed over the driver processes.
    Without ``commands`` no command publisher runs (the drivers only poll)."""
    log = work / 'driver.log'
    procs = [start(run_child('sim', str(modules)), None, work / 'sim.log')]
    try:
        port_file = work / 'sim.port'
        deadline = time.monotonic() + 60
        while not port_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        ports = [int(p) for p in port_file.read_text().split()]
        names = [f'm{i + 1}' for i in range(modules)]
        if container:
            drivers = [start_ros_node('driver_container', [
                '-r', f'__ns:={NS}', '-p', f'modules:=[{",".join(names)}]',
                '-p', f'ports:=[{",".join(map(str, ports))}]', *DRIVER_PARAMS], code_dir, log)]
        else:
            drivers = [start_ros_node('driver_node', [
                '-r', f'__ns:={NS}', '-p', f'module:={name}', '-p', f'port:={port}',
                *DRIVER_PARAMS], code_dir, log if i == 0 else work / f'driver{i}.log')
                for i, (name, port) in enumerate(zip(names, ports))]
        procs += drivers
        procs.append(start(run_child('listen', 'drivers5' if modules > 1 else 'driver',
                                     str(work / 'counters')), None, work / 'listen.log'))
        if not commands:   # working once its state arrives
            return measure(drivers, warmup, seconds, log, work / 'counters',
                           lambda: 'commands' in read_counters(work / 'counters'))
        procs.append(start(run_child('commands', '50', '0.198', str(modules)), None,
                           work / 'commands.log'))
        return measure(drivers, warmup, seconds, log, work / 'counters',
                       lambda: read_counters(work / 'counters').get('commands', 0) > 0)
    finally:
        for p in reversed(procs):
            stop(p)


def run_sim(work: str, count: int = 1) -> None:
    """(child process) ``count`` simulated modules; writes their ports to <work>/sim.port
    (one line, separated by spaces)."""
    from softsnap_driver.sim_module import SimServer
    servers = [SimServer() for _ in range(count)]
    for server in servers:
        server.start()
    try:
        tmp = Path(work) / 'sim.port.tmp'
        tmp.write_text(' '.join(str(server.port) for server in servers))
        tmp.rename(Path(work) / 'sim.port')
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        for server in servers:
            server.stop()


def case_rerun(code_dir, work: Path, warmup, seconds, recording: Path):
    log = work / 'rerun.log'
    node = start_ros_node('rerun_logger', [
        '-r', f'__ns:={NS}', '-p', f'output:={recording}', '-p', 'scene:=brittle_star'],
        code_dir, log)
    pub = start(run_child('robot', '50', str(work / 'counters')), None, work / 'robot.log')

    def recording_grows() -> bool:  # the node logs: its file has grown past the static part
        return recording.exists() and recording.stat().st_size > 200_000

    try:
        # The publisher's count: every message offered to the node (it takes them all
        # unless starved for a second: its queues hold 100 each, drained every 100 ms).
        return measure(node, warmup, seconds, log, work / 'counters', ready=recording_grows)
    finally:
        stop(pub)
        stop(node)
        logged = re.search(r'(\d+) messages logged', log.read_text(errors='replace'))
        print(f'    rerun_logger: {logged.group(0) if logged else "no summary line"}', flush=True)


def case_baseline(code_dir, work: Path, warmup, seconds):
    log = work / 'baseline.log'
    node = start([sys.executable, '-c', BASELINE_NODE], None, log)
    try:
        return measure(node, warmup, seconds, log)
    finally:
        stop(node)


#: Modules each case serves (the tables' "per module" divides by it).
PER_MODULE = {'baseline': 1, 'model5': 5, 'model_idle': 5, 'model50': 50, 'driver': 1,
              'driver_idle': 1, 'drivers5': 5, 'container5': 5, 'rerun': 5}


def run_case(case: str, code_dir, run_dir: Path, warmup: float, seconds: float, *,
             scene50: Path | None = None, length_publishers: int = 5,
             recording: Path | None = None) -> tuple[float, dict[str, float]]:
    """(% of a core, the node's own counters per second) of one case (see the module's
    docstring); ``model50`` needs the synthetic scene ``scene50``, ``rerun`` the
    ``recording`` to write."""
    if case == 'baseline':
        return case_baseline(code_dir, run_dir, warmup, seconds)
    if case == 'model5':
        return case_model(code_dir, run_dir, 'brittle_star', True, warmup, seconds)
    if case == 'model_idle':
        return case_model(code_dir, run_dir, 'brittle_star', None, warmup, seconds)
    if case == 'model50':
        return case_model(code_dir, run_dir, str(scene50), True, warmup, seconds,
                          length_publishers)
    if case == 'driver':
        return case_driver(code_dir, run_dir, warmup, seconds)
    if case == 'driver_idle':
        return case_driver(code_dir, run_dir, warmup, seconds, commands=False)
    if case in ('drivers5', 'container5'):
        return case_driver(code_dir, run_dir, warmup, seconds, 5, case == 'container5')
    return case_rerun(code_dir, run_dir, warmup, seconds, recording)


def entities(path: Path) -> set[str]:
    from rerun.chunk import RrdReader
    return {c.entity_path.lstrip('/') for c in RrdReader(str(path)).stream().to_chunks()}


# ------------------------------------------------------------------ main
def extract(ref: str) -> Path:
    from benchlib import checkout_src     # here: children import this file from elsewhere
    into = checkout_src(ref)
    # Compiled once here: the nodes run with PYTHONDONTWRITEBYTECODE and would otherwise
    # compile the old sources at every start.
    subprocess.run([sys.executable, '-m', 'compileall', '-q', str(into / 'src')], check=True)
    return into


def summary(values: list[float]) -> str:
    if not values:
        return '-'
    return f'{statistics.median(values):6.2f} [{min(values):.2f}-{max(values):.2f}]'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=10.0, help='measuring window (s)')
    parser.add_argument('--warmup', type=float, default=4.0, help='before the window (s)')
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--before', default='', help='git revision to compare against')
    parser.add_argument('--cases', nargs='+', default=list(CASES), choices=CASES,
                        help='cases to run (e.g. --cases model5 model_idle model50 for the '
                             'model node only)')
    parser.add_argument('--length-publishers', type=int, default=5,
                        help='processes sharing the 50-module length load (model50)')
    parser.add_argument('--threads', action='store_true',
                        help="also print each node process's CPU per thread (from /proc)")
    parser.add_argument('--child', nargs='+', help=argparse.SUPPRESS)
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(120, 200) % 101 + 100))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if args.child:
        kind, rest = args.child[0], args.child[1:]
        {'lengths': lambda: publish_lengths(rest[0], float(rest[1]), bool(int(rest[2])),
                                            *(int(v) for v in rest[3:5]), *rest[5:6]),
         'commands': lambda: publish_driver_commands(float(rest[0]), float(rest[1]),
                                                     int(rest[2]) if len(rest) > 2 else 1),
         'robot': lambda: publish_robot(float(rest[0]), rest[1]),
         'listen': lambda: listen(rest[0], rest[1]),
         'sim': lambda: run_sim(os.environ['NODE_COST_WORK'], int(rest[0]) if rest else 1)}[kind]()
        return 0

    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())} '
          f'({os.cpu_count()} cores)', flush=True)
    work = Path(tempfile.mkdtemp(prefix='node_cost_'))
    os.environ['NODE_COST_WORK'] = str(work)
    scene50 = write_scene(work / 'synthetic_50.yaml', 50)
    versions = {'after': None}
    if args.before:
        versions = {'before': extract(args.before),
                    'after': None}
    results: dict[tuple[str, str], list[float]] = {}
    recordings: dict[str, Path] = {}
    throughput: dict[tuple[str, str, str], list[float]] = {}
    per_thread: dict[tuple[str, str, str], list[float]] = {}
    for repeat in range(args.repeats):
        for case in args.cases:
            for label, code_dir in versions.items():
                if label == 'before' and (case == 'baseline' or (
                        case == 'container5'
                        and not (code_dir / CONTAINER_SOURCE).exists())):
                    continue   # no old code to compare (the container is new since cf2cb37)
                run_dir = work / f'{case}-{label}-{repeat}'
                run_dir.mkdir()
                os.environ['NODE_COST_WORK'] = str(run_dir)
                if case == 'rerun':
                    recordings[label] = run_dir / 'robot.rrd'
                cpu, rates = run_case(case, code_dir, run_dir, args.warmup, args.seconds,
                                      scene50=scene50,
                                      length_publishers=args.length_publishers,
                                      recording=recordings.get(label))
                results.setdefault((case, label), []).append(cpu)
                for name, share in read_counters(run_dir / THREADS_FILE).items():
                    per_thread.setdefault((case, label, name), []).append(share)
                for name, rate in rates.items():
                    throughput.setdefault((case, label, name), []).append(rate)
                print(f'  repeat {repeat + 1}: {case:10s} {label:6s} {cpu:6.1f}% of a core'
                      + ''.join(f', {name} {rate:.0f}/s' for name, rate in rates.items()),
                      flush=True)

    what = {'baseline': 'idle rclpy node, 100 Hz empty timer',
            'model5': 'model_node, 5 modules, 100 Hz, all lengths changing',
            'model_idle': 'model_node, 5 modules, 100 Hz, no lengths (idle)',
            'model50': 'model_node, 50 modules, 100 Hz, all lengths changing',
            'driver': 'driver_node, 10 Hz polls + 50 Hz commands',
            'driver_idle': 'driver_node, 10 Hz polls, no commands',
            'drivers5': '5 driver_node processes, each as driver',
            'container5': '1 driver_container process, 5 modules, each as driver',
            'rerun': 'rerun_logger, 5 modules at 50 Hz'}
    print()
    print(f'CPU in % of one core, median [range] of {args.repeats} runs of {args.seconds:g} s'
          + (f'; before = {args.before}' if args.before else ''))
    print(f'{"case":56s} {"before":>22s} {"after":>22s} {"after/before":>12s} '
          f'{"after per module":>16s}')
    for case in args.cases:
        before = results.get((case, 'before'), [])
        after = results.get((case, 'after'), [])
        ratio = (f'{statistics.median(after) / statistics.median(before):.2f}'
                 if before and after and statistics.median(before) > 0 else '-')
        print(f'{what[case]:56s} {summary(before):>22s} {summary(after):>22s} {ratio:>12s} '
              f'{statistics.median(after) / PER_MODULE[case]:15.2f}%')
    print('The nodes\' own counters over the same windows (median [range] per second), and '
          'CPU per event (the machine\'s load changes how many events a starved node takes):')
    for (case, label, name), rates in sorted(throughput.items()):
        cpu = statistics.median(results[(case, label)])
        rate = statistics.median(rates)
        per = f', {cpu * 1e4 / rate:.0f} µs of CPU per {name[:-1]}' if rate > 0 else ''
        print(f'  {case} {label}: {name} {rate:.0f}/s [{min(rates):.0f}-{max(rates):.0f}]{per}')
    if ('container5', 'after') in results and ('drivers5', 'after') in results:
        one = statistics.median(results[('container5', 'after')])
        five = statistics.median(results[('drivers5', 'after')])
        print(f'5 modules in one driver_container process: {one / 5:.2f}% of a core per module '
              f'against {five / 5:.2f}% in 5 driver_node processes ({one / five:.2f}x)')
    if args.threads:
        print('CPU per thread of the node process (of the first one for several), % of one '
              'core, median [range]; Python threads other than the main one share a name:')
        for (case, label, name), shares in sorted(per_thread.items()):
            if statistics.median(shares) >= 0.05:
                print(f'  {case} {label}: {name:24s} {summary(shares)}')
    if 'model_idle' in args.cases:
        idle = statistics.median(results[('model_idle', 'after')])
        print(f'model_node idle tick (after): {idle / 100 * 10:.3f} ms of CPU per 10 ms tick')
    for case in ('model5', 'model50'):
        for label in versions:
            if (case, label) not in results:
                continue
            cpu = statistics.median(results[(case, label)])
            rate = {name: statistics.median(throughput.get((case, label, name), [0.0]))
                    for name in ('lengths', 'solves', 'published')}
            per_length = cpu * 1e4 / rate['lengths'] if rate['lengths'] > 0 else math.nan
            line = (f'{case} {label}: offered {rate["published"]:.0f} lengths/s, took '
                    f'{rate["lengths"]:.0f}/s, {rate["solves"]:.0f} solves/s, {cpu:.1f}% of '
                    f'one core ({cpu / PER_MODULE[case]:.2f}% per module), {per_length:.0f} µs '
                    'of CPU per length')
            if case == 'model50':
                # Serving: it takes (nearly) all that is offered, within one core.
                serves = rate['lengths'] >= 0.95 * rate['published'] > 0 and cpu < 100.0
                line += (f'; one core at this rate of CPU per length would take '
                         f'{1e6 / per_length:.0f} lengths/s (100 Hz x 50 modules x 2 = '
                         f'10000/s): {"served" if serves else "NOT served"} here')
            print(line)
    for label in versions:
        if ('model5', label) in results and ('model50', label) in results:
            five = statistics.median(results[('model5', label)])
            fifty = statistics.median(results[('model50', label)])
            # The target is the 5-module average above; this is what each further module
            # adds (the fixed per-prediction cost cancels out).
            print(f'model_node {label}: per-module marginal cost (cost(50) - cost(5)) / 45 = '
                  f'{(fifty - five) / 45:.2f}% of a core per module (the target figure is '
                  f'the 5-module average, {five / 5:.2f}%)')
    if 'before' in recordings and 'after' in recordings:
        e_before, e_after = entities(recordings['before']), entities(recordings['after'])
        same = e_before == e_after
        print(f'rerun recordings: {len(e_after)} entities after, {len(e_before)} before: '
              f'{"the same set" if same else "DIFFERENT: " + str(e_before ^ e_after)}')
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    print(f'(python {sys.version.split()[0]}; logs in {work})')
    if 'before' in recordings and 'after' in recordings and not same:
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
