"""One demo run: start the robot's graph as supervised processes (softsnap_ros.processes),
watch it with the observer for the run, stop it in order and report."""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path


from softsnap_ros.lifeline import Lifeline
from softsnap_ros.processes import ChildProcess
from softsnap_model.scene import load_scene

from .demo_camera import CameraObserver, print_camera, with_camera
from .graph import NodeSpec, robot_graph
from .isolation import Slot, claim_slot
from .supervision import shutdown_problems, stop_in_order
from .demo_config import CLOCK_STALL_S, PHYSICS_PAYLOADS, SHARED_SIMS_ABOVE, STOP_TIMEOUT_S
from .demo_metrics import physics_summary
from .demo_observer import Observer, recorder_missing
from .demo_report import bag_summary, print_summary, summarise


class Process(ChildProcess):
    """A node of the demo in its own process group, its output in ``<log_dir>/<name>.log``."""

    def __init__(self, spec: NodeSpec, log_dir: Path, env: dict[str, str], pass_fds=()):
        from ament_index_python.packages import get_package_prefix
        self.spec = spec
        exe = Path(get_package_prefix(spec.package)) / 'lib' / spec.package / spec.executable
        # pass_fds: the slot's lock (isolation.py) stays held while any child lives.
        # A driver_container's drivers get their parameters from a file beside the log.
        ros_args = spec.ros_args(spec.write_node_params(log_dir))
        # Untagged: each node stops with its own lifeline and the ordered shutdown
        # (supervision.py); the demo's own runner is what tests tag.
        super().__init__([str(exe), *spec.arguments, *ros_args], log_dir / f'{spec.name}.log',
                         env, tagged=False, pass_fds=pass_fds)


def stop_gait(processes: list[Process]) -> None:
    """SIGINT the gait node and wait until it exited (no more commands or phases).

    One that ignores SIGINT is left to the final shutdown (which kills it and says so).
    """
    for p in processes:
        if p.spec.name == 'gait_node':
            p.signal(signal.SIGINT)
            try:
                p.popen.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                pass


def shared_sim_modules(mode: str, n_modules: int) -> str:
    """``--sim-modules`` resolved: 'auto' shares one process above SHARED_SIMS_ABOVE modules."""
    if mode != 'auto':
        return mode
    return 'shared' if n_modules > SHARED_SIMS_ABOVE else 'separate'


def run(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene)
    # A private slot: ROS domain id and loopback ports no other demo or test here uses.
    slot, warning = claim_slot()
    if warning:
        print(f'demo: warning: {warning}', file=sys.stderr)
    try:
        return _run(args, scene, slot)
    finally:
        slot.release()  # children that still live keep the lock (pass_fds)


def _run(args: argparse.Namespace, scene, slot: Slot) -> int:
    stamp = dt.datetime.now(dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')
    run_dir = Path(args.run_dir or Path('runs') / f'{scene.name}-{stamp}')
    run_dir.mkdir(parents=True, exist_ok=True)
    recording = None if args.no_rerun else (Path(args.output) if args.output
                                            else run_dir / f'{scene.name}.rrd').resolve()
    bag = None if args.no_bag else (Path(args.bag) if args.bag else _free_name(run_dir / 'bag')).resolve()
    # Simulated modules get free ports of the slot (their drivers the same ones); real
    # modules, and --scene-ports, keep the scene's addresses.
    sim_ports = None
    sim_modules = shared_sim_modules(args.sim_modules, len(scene.modules))
    if not args.real and not args.scene_ports:
        if args.physics or sim_modules == 'shared':   # one process serves consecutive ports
            first = slot.free_port(len(scene.modules))
            sim_ports = {m.name: first + i for i, m in enumerate(scene.modules)}
        else:
            sim_ports = {m.name: slot.free_port() for m in scene.modules}
    sim_robot_parameters = dict(PHYSICS_PAYLOADS.get(scene.name, {}),
                                time_factor=float(args.time_factor))
    specs = robot_graph(scene, simulate=not args.real, gait=args.gait,
                        gait_rate_hz=args.gait_rate, model_rate_hz=args.model_rate,
                        recording=recording, rerun=not args.no_rerun, sim_ports=sim_ports,
                        bag=bag, bag_all=args.bag_all, physics=args.physics,
                        sim_robot_parameters=sim_robot_parameters, drivers=args.drivers,
                        sim_modules=sim_modules)
    if args.camera:
        specs = with_camera(specs, scene)
    # The observer in this process and every child use the slot's domain.
    os.environ['ROS_DOMAIN_ID'] = str(slot.domain_id)
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    env.setdefault('ROS_HOME', str(run_dir / 'ros_home'))
    if not args.real:  # a simulated robot needs no traffic beyond this machine
        env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    stop_requested = []

    def request_stop(signum, _frame):
        stop_requested.append(signum)

    # SIGHUP (a closed terminal) like SIGTERM; if this process dies, the children see
    # their lifeline end and stop too (softsnap_ros.lifeline).
    old_handlers = {sig: signal.signal(sig, request_stop)
                    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    lifeline = Lifeline()
    env = lifeline.env(env)
    processes: list[Process] = []
    observer = camera = None
    elapsed, usage_start, usage_end = 0.0, {}, {}
    window_ns = (0, 2**63)  # ROS time of the run: set below
    startup_s = None
    crashed: list[Process] = []
    not_ready: dict[str, list[str]] = {}
    started = False
    clock_stalled = False
    try:
        ports = (', '.join(f'{p.parameters["port"]}' for p in specs if p.executable == 'sim_module')
                 or ', '.join(f'{p.parameters["port_base"] or "the scene ports"} and up (sim_robot)'
                              for p in specs if p.executable == 'sim_robot')
                 or 'the scene\'s addresses')
        print(f'starting {len(specs)} processes for {scene.name} ({len(scene.modules)} modules; '
              f'ROS domain {slot.domain_id}; modules on {ports}; logs in {run_dir})', flush=True)
        observer = Observer(scene, f'/{scene.name}', physics=args.physics,
                            streams='robot' if len(scene.modules) > SHARED_SIMS_ABOVE
                            else 'modules')
        camera = CameraObserver(observer.node, scene) if args.camera else None
        launched_at = time.monotonic()
        for spec in specs:
            processes.append(Process(spec, run_dir, env,
                                     pass_fds=(slot.lock_fd, *lifeline.pass_fds)))
            if spec.executable == 'sim_robot':
                # The robot first: the gait starts once the simulation runs, so its first
                # cycle (the gripper's first grasp) happens in the physics.
                deadline = time.monotonic() + args.ready_timeout
                while (not observer.base_positions and processes[-1].popen.poll() is None
                       and not stop_requested and time.monotonic() < deadline):
                    observer.spin_for(0.1)

        def check_children() -> bool:
            for p in processes:
                if p.popen.poll() is not None and p not in crashed:
                    crashed.append(p)
            return not crashed and not stop_requested

        def ready() -> bool:
            # The recorder too: on a loaded machine rerun_logger came up seconds after the
            # nodes it records, or took their messages seconds after it had subscribed,
            # and a short run's recording lacked shapes.
            return (observer.ready() and (camera is None or camera.ready())
                    and (args.no_rerun or not recorder_missing(observer, args.physics)))

        deadline = time.monotonic() + args.ready_timeout
        while check_children() and not ready() and time.monotonic() < deadline:
            observer.spin_for(0.1)
        if check_children() and not observer.ready():
            not_ready = observer.missing()
        elif check_children() and camera is not None and not camera.ready():
            not_ready = {'camera': camera.missing()}
        elif check_children() and not ready():
            not_ready = {'rerun_logger': ['nothing taken from ' + ', '.join(
                recorder_missing(observer, args.physics))]}
        # Started: every process alive and every module seen end to end. Otherwise stop
        # here and say what failed; a table of a robot that never ran would be zeros.
        started = check_children() and not not_ready
        startup_s = time.monotonic() - launched_at
        if started:
            observer.reset()
            start = time.monotonic()
            window_start_ns = observer.now_ns()
            usage_start = {p.spec.name: p.usage() for p in processes}
            if args.physics:
                # Simulated seconds: the gait runs on /clock, so does the run.
                clock_stalled = run_for_sim_time(observer, args.seconds, check_children)
            else:
                while check_children() and time.monotonic() - start < args.seconds:
                    observer.spin_for(0.1)
            elapsed = time.monotonic() - start
            window_ns = (window_start_ns, observer.now_ns())
            if args.physics:
                # The run is the stamps of exactly `seconds` of simulated time: the loop
                # sees the end a spin late (0.1 s of wall time, more when this process is
                # starved), which at a real-time factor of 2 is 0.2 s or more of sim time.
                window_ns = (window_start_ns,
                             min(window_ns[1], window_start_ns + round(args.seconds * 1e9)))
            usage_end = {p.spec.name: p.usage() for p in processes}
            observer.spin_for(0.2)
            if check_children():
                # The gait node first: while it publishes, an observer starved on a loaded
                # machine takes its 50 Hz streams slower than they come (rclpy serves one
                # message per subscription per wait) and never catches up; stopped, what
                # it sent stays queued (STREAM_DEPTH) and is taken afterwards.
                stop_gait(processes)
                observer.drain(window_ns[1], lambda: not stop_requested)
                if camera is not None:
                    camera.wait_for_truth(observer.spin_for, window_ns[1])
    finally:
        # Dependency order (supervision.py): gait, drivers (confirming their stops while
        # the modules answer), then simulators, model and recorders.
        stops = stop_in_order(processes, STOP_TIMEOUT_S,
                              warn=lambda text: print(text, file=sys.stderr))
        for p in processes:
            p.close()
        lifeline.close()
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
    exit_codes = {p.spec.name: p.popen.returncode for p in processes}
    problems = shutdown_problems(exit_codes, {p.spec.name: p.spec.executable for p in processes},
                                 {r.name for r in stops if r.killed})
    for p in crashed:
        print(f'\n{p.spec.name} exited early with code {p.popen.returncode}'
              f'{"" if started else " (the robot did not start)"}; its last output:\n'
              f'{p.tail()}', file=sys.stderr)
    if not started and not stop_requested:
        return _report_start_failure(args, scene, processes, crashed, not_ready, exit_codes,
                                     run_dir, observer)
    seconds = (window_ns[1] - window_ns[0]) * 1e-9 if args.physics else elapsed
    summary = summarise(scene, observer, round(seconds, 2), recording, exit_codes, window_ns)
    summary['wall_seconds'] = round(elapsed, 2)
    summary['sim_time'] = bool(args.physics)
    if clock_stalled:
        summary['clock_stalled'] = True
        print(f'demo: the simulated time stood still for {CLOCK_STALL_S:g} s (sim_robot '
              'stalled?): the run ended early', file=sys.stderr)
    summary.update(bag_summary(bag))
    summary['shutdown_problems'] = problems
    summary['shutdown_order'] = [r.name for r in stops]
    summary['shutdown_seconds'] = {r.name: r.seconds for r in stops}  # from its stage's SIGINT
    summary['started'] = started
    # First process launched -> every module seen end to end (and the recorder taking).
    summary['startup_seconds'] = startup_s
    summary['ros_domain_id'] = slot.domain_id
    if args.physics:
        sim = next((p for p in processes if p.spec.executable == 'sim_robot'), None)
        summary['physics'] = physics_summary(scene, args.gait or scene.default_gait, observer,
                                             window_ns, sim.tail(50) if sim else '')
    if camera is not None:
        summary['camera'] = camera.summary(window_ns)
    summary['processes'] = {
        name: {'cpu_percent': 100.0 * (usage_end[name][0] - usage_start[name][0]) / elapsed,
               'rss_mib': usage_end[name][1] / 2**20}
        for name in usage_start if usage_start[name] and usage_end.get(name)}
    observer.close()
    if args.json:
        print(json.dumps(summary, indent=2, default=float))
    else:
        print_summary(summary)
        if camera is not None:
            print_camera(summary['camera'])
    if crashed or problems:
        return 1
    return 130 if stop_requested else 0


def run_for_sim_time(observer: Observer, seconds: float, keep_going) -> bool:
    """Spin until the observer's ROS time (the simulation's) advanced by `seconds`.

    Ends early when `keep_going()` is false, or when the time stood still for
    CLOCK_STALL_S wall seconds; returns True in that last case.
    """
    start_ns = last_ns = observer.now_ns()
    moved_at = time.monotonic()
    while keep_going():
        now_ns = observer.now_ns()
        if now_ns - start_ns >= seconds * 1e9:
            return False
        if now_ns != last_ns:
            last_ns, moved_at = now_ns, time.monotonic()
        elif time.monotonic() - moved_at > CLOCK_STALL_S:
            return True
        observer.spin_for(0.1)
    return False


def _free_name(path: Path) -> Path:
    """`path`, or `path`-2, -3, ... if taken (a bag is never written over)."""
    candidate, n = path, 1
    while candidate.exists():
        n += 1
        candidate = path.with_name(f'{path.name}-{n}')
    return candidate


def _report_start_failure(args, scene, processes, crashed, not_ready, exit_codes, run_dir,
                          observer) -> int:
    """The robot never ran: say which process or module failed, with logs; exit 1."""
    if observer is not None:
        observer.close()
    if not_ready and not crashed:
        print(f'\n{scene.name} did not start within {args.ready_timeout:g} s; not seen:', file=sys.stderr)
        for module, lacks in not_ready.items():
            print(f'  {module}: {", ".join(lacks)}', file=sys.stderr)
        # The logs of the processes those modules depend on.
        names = {f'sim_{m}' for m in not_ready} | {f'{m}_driver' for m in not_ready} | {
            'driver_container', 'model_node', 'gait_node', 'sim_robot', 'sim_modules'} | (
            {'rerun_logger'} & set(not_ready))
        for p in processes:
            if p.spec.name in names:
                print(f'\n{p.spec.name} (still running); its last output:\n{p.tail()}',
                      file=sys.stderr)
    print(f'\ndemo: {scene.name} failed to start: no summary (logs in {run_dir})', file=sys.stderr)
    if args.json:
        print(json.dumps({'scene': scene.name, 'started': False,
                          'failed_processes': {p.spec.name: p.popen.returncode for p in crashed},
                          'not_seen': not_ready, 'exit_codes': exit_codes}, indent=2))
    return 1
