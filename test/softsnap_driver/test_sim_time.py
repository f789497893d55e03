"""Simulated time over DDS: sim_robot's /clock drives the gait, the drivers keep safe.

Real processes (sim_robot, the drivers' driver_container, gait_node) started with the parameters the demo
and the launch files give them (softsnap_gaits.graph with physics: ``use_sim_time`` on
every node but sim_robot). The gripper is the cheapest robot to simulate; one link per
segment keeps the physics light on a busy machine.
"""
from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from softsnap_driver.core import STOP_UNCONFIRMED_EXIT

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = '/gripper'
TIMEOUT_S = 180.0    # model build, discovery and a simulation paced below real time
#: The gait of test (a): the gripper's grasp with a 2 s period of simulated time and a
#: 20 mm amplitude (slow enough for the winches at that period).
PERIOD_S, AMPLITUDE_M = 2.0, 0.020


def graph(port_base: int, **sim_params):
    from softsnap_gaits.graph import robot_graph
    from softsnap_model.scene import load_scene
    scene = load_scene('gripper')
    ports = {m.name: port_base + i for i, m in enumerate(scene.modules)}
    return robot_graph(scene, physics=True, sim_ports=ports, rerun=False,
                       sim_robot_parameters={'links_per_segment': 1, **sim_params})


def start(start_node, tmp_path, specs, names, drivers=None, **overrides):
    """Start the processes named in `names` with `overrides` by executable and `drivers`
    added to every driver's parameters."""
    from softsnap_gaits.graph import with_driver_parameters
    procs = {}
    for spec in with_driver_parameters(specs, **(drivers or {})):
        if spec.name in names:
            spec.parameters.update(overrides.get(spec.executable, {}))
            procs[spec.name] = start_node(spec.package, spec.executable,
                                          *spec.ros_args(spec.write_node_params(tmp_path)))
    return procs


def driver_log(proc, module):
    """The lines of module's driver in the container's output."""
    return '\n'.join(line for line in proc.output().splitlines() if f'{module}_driver' in line)


class Watch:
    """/clock, gait phases, commands and driver states as they arrive (wall time kept)."""

    def __init__(self, node, modules):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from softsnap_interfaces.msg import CableLength, GaitPhase, ModuleState
        self.node = node
        self.clock_ns = []          # every /clock received, ns of simulated time
        self.phases = []            # (wall s, stamp ns, cycle, phase) while running
        self.commands = {m: [] for m in modules}   # (stamp ns, length m)
        self.states = {m: [] for m in modules}
        self.measured = {m: [] for m in modules}   # stamp ns
        node.create_subscription(
            Clock, '/clock', lambda msg: self.clock_ns.append(_ns(msg.clock)),
            QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        node.create_subscription(GaitPhase, f'{NS}/gait/phase', self._phase, 500)
        for m in modules:
            node.create_subscription(
                CableLength, f'{NS}/{m}/cable_length/command',
                lambda msg, m=m: self.commands[m].append((_ns(msg.header.stamp), msg.cable_length)),
                500)
            node.create_subscription(ModuleState, f'{NS}/{m}/state', self.states[m].append, 100)
            node.create_subscription(
                CableLength, f'{NS}/{m}/cable_length/measured',
                lambda msg, m=m: self.measured[m].append(_ns(msg.header.stamp)), 100)

    def _phase(self, msg) -> None:
        if msg.running:
            self.phases.append((time.monotonic(), _ns(msg.header.stamp), msg.cycle, msg.phase))

    def online(self) -> bool:
        return all(s and s[-1].online for s in self.states.values())

    def cycle_starts(self):
        """(wall s, stamp ns) of the first phase message of each new cycle."""
        starts = []
        for (_, _, c0, _), (wall, stamp, c1, _) in zip(self.phases, self.phases[1:]):
            if c1 > c0:
                starts.append((wall, stamp))
        return starts


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _alive(procs):
    dead = {name: p.output()[-2000:] for name, p in procs.items() if not p.alive()}
    assert not dead, dead


def test_gait_plays_its_period_in_simulated_time_when_the_simulation_runs_slow(
        start_node, ros_node, slot_port, tmp_path):
    """(a) sim_robot at 0.2 x real time: the commanded cycle is the gait's period in
    simulated time (command stamps), and five times that in wall time."""
    specs = graph(slot_port(4), time_factor=0.2)
    modules = ['front_left', 'back_right']
    procs = start(start_node, tmp_path, specs, {'sim_robot', 'gait_node', 'driver_container'},
                  gait_node={'period': PERIOD_S, 'amplitude': AMPLITUDE_M})
    from softsnap_gaits.graph import driver_parameters
    for spec in specs:
        if spec.name not in ('sim_robot', 'driver_container'):
            assert spec.parameters['use_sim_time'] is True, spec
    assert all(p['use_sim_time'] is True for p in driver_parameters(specs).values())
    watch = Watch(ros_node, modules)
    # Three cycle starts: two whole cycles of simulated time (about 20 s of wall time).
    ok = ros_node.spin_until(lambda: _alive(procs) or len(watch.cycle_starts()) >= 3, TIMEOUT_S)
    assert ok, ({n: p.output()[-1500:] for n, p in procs.items()}, watch.phases[-3:])
    starts = watch.cycle_starts()
    sim_cycles = np.diff([stamp for _, stamp in starts]) * 1e-9
    wall_cycles = np.diff([wall for wall, _ in starts])
    # One gait tick (20 ms) plus one /clock step (20 ms at 50 Hz) of quantisation.
    assert np.allclose(sim_cycles, PERIOD_S, atol=0.041), sim_cycles
    assert np.all(wall_cycles > 2.0 * PERIOD_S), wall_cycles    # 5x at 0.2 x real time
    # The commands repeat with the period in their own stamps: the commanded length at
    # stamp t equals the one at t + period.
    for m in modules:
        by_stamp = dict(watch.commands[m])
        shift = round(PERIOD_S * 1e9)
        pairs = [(length, by_stamp[t + shift]) for t, length in watch.commands[m]
                 if t + shift in by_stamp and starts[0][1] <= t]
        assert len(pairs) > 40, (m, len(pairs))
        a, b = np.array(pairs).T
        assert np.max(np.abs(a - b)) < 1e-9, m
        assert np.ptp(a) > 0.015, m          # the gait did move (20 mm amplitude)
        stamps = np.array([t for t, _ in watch.commands[m]])
        assert np.median(np.diff(stamps)) == pytest.approx(0.02e9, abs=0.0101e9)  # 50 Hz sim
    # Every stamp is simulated time: within the /clock seen (the wall clock is ~1.7e18 ns).
    last_clock = max(watch.clock_ns)
    for m in modules:
        assert max(t for t, _ in watch.commands[m]) <= last_clock + 0.1e9
        assert 0 < max(watch.measured[m]) <= last_clock + 0.1e9
        assert watch.states[m][-1].stalls_detected == 0, watch.states[m][-1]
        assert watch.states[m][-1].stale_stops == 0, watch.states[m][-1]
    for name, proc in procs.items():
        assert proc.stop() == 0, f'{name}: {proc.output()[-2000:]}'


def test_a_stopped_clock_freezes_the_gait_but_not_the_drivers_safety(
        start_node, ros_node, slot_port, tmp_path):
    """(b) sim_robot paused (SIGSTOP): no /clock, no answers. The gait stops in its
    simulated time, the drivers find the modules offline and stop the stale command
    stream on the wall clock; resumed, the gait goes on where its time stopped. Then
    sim_robot dies: the drivers report the modules offline."""
    specs = graph(slot_port(4))
    modules = ['front_left', 'back_right']
    procs = start(start_node, tmp_path, specs, {'sim_robot', 'gait_node', 'driver_container'})
    watch = Watch(ros_node, modules)

    def commanding():
        # ... and this watcher has /clock too (best effort: its first samples may be missed).
        # ... and its own command subscriptions: the drivers' counters can pass 20 before a
        # loaded watcher matched the command topics (CI: none seen for a module).
        return watch.online() and len(watch.clock_ns) > 5 and all(
            s[-1].targets_sent > 3 and s[-1].commands_received > 20 for s in watch.states.values()
        ) and all(len(c) > 5 for c in watch.commands.values())

    assert ros_node.spin_until(lambda: _alive(procs) or commanding(), TIMEOUT_S), \
        {n: p.output()[-1500:] for n, p in procs.items()}
    sim = procs['sim_robot'].proc
    os.killpg(sim.pid, signal.SIGSTOP)
    try:
        paused_at = time.monotonic()
        ros_node.spin_until(lambda: False, 1.0)     # what was on its way arrives
        frozen_clock = max(watch.clock_ns)
        states_then = {m: len(s) for m, s in watch.states.items()}

        def safe():
            return all(not s[-1].online and s[-1].stale_stops >= 1 for s in watch.states.values())

        assert ros_node.spin_until(safe, 60.0), {m: s[-1] for m, s in watch.states.items()}
        ros_node.spin_until(lambda: False, 1.0)
        # Nothing moved the simulated time, the gait sent nothing more, and the drivers
        # kept reporting on the wall clock. Judged by stamps, not by what arrived after a
        # wall-clock second: with both cores busy this watcher was still taking commands
        # sent before the pause (12 more arrived). A command stamped after the last /clock
        # seen is one whose /clock step this best-effort watcher missed.
        assert max(watch.clock_ns) == frozen_clock
        for m in modules:
            late = [t for t, _ in watch.commands[m] if t > frozen_clock]
            assert len(late) <= 2 and all(t <= frozen_clock + 0.1e9 for t in late), \
                (m, late, frozen_clock)
            assert len(watch.states[m]) - states_then[m] >= 5, m
            state = watch.states[m][-1]
            assert 'no command' in state.last_error, state.last_error
            assert _ns(state.header.stamp) <= frozen_clock + 0.1e9   # stamped in sim time
        paused_s = time.monotonic() - paused_at
    finally:
        os.killpg(sim.pid, signal.SIGCONT)
    # Resumed: the modules answer, the stale stop is confirmed or superseded by the
    # gait's next commands, which continue its simulated time without a jump.
    before = {m: watch.commands[m][-1][0] for m in modules}
    assert ros_node.spin_until(
        lambda: watch.online() and all(len(watch.commands[m]) > 0 and watch.commands[m][-1][0]
                                       > before[m] + 0.5e9 for m in modules), TIMEOUT_S)
    for m in modules:
        stamps = np.array([t for t, _ in watch.commands[m]])
        gap_s = np.max(np.diff(stamps[stamps >= before[m] - 1e9])) * 1e-9
        # No jump by the pause (a tick or a few /clock steps the starved gait missed).
        assert gap_s < 0.5 < 1.0 < paused_s, (m, gap_s, paused_s)
    # Dead: SIGKILL. The drivers find the modules offline, on the wall clock.
    os.killpg(sim.pid, signal.SIGKILL)
    sim.wait(10.0)
    assert ros_node.spin_until(lambda: all(not s[-1].online for s in watch.states.values()), 60.0)
    for name, proc in procs.items():
        if name != 'sim_robot':
            # The drivers' modules died with sim_robot: a last stop nobody can confirm is
            # reported by the container's exit status (STOP_UNCONFIRMED_EXIT), never a 0.
            expected = (0, STOP_UNCONFIRMED_EXIT) if name == 'driver_container' else (0,)
            code = proc.stop()
            assert code in expected, f'{name} exited {code}: {proc.output()[-2000:]}'


def test_a_frozen_simulated_time_with_the_modules_answering_still_confirms_stops(
        start_node, ros_node, slot_port, tmp_path):
    """(b) sim_robot stops stepping after 0.5 s of simulated time (``duration_s``) but
    keeps serving the modules: the /clock stands still (or, for a driver that came up
    after its last message, never came: time 0). A driver on that clock still stops a
    stale command stream with a confirmed stop, and its stop service confirms."""
    from softsnap_interfaces.msg import CableLength
    from std_srvs.srv import Trigger
    specs = graph(slot_port(4), duration_s=0.5)
    module = 'front_left'
    procs = start(start_node, tmp_path, specs, {'sim_robot', 'driver_container'},
                  drivers={'command_timeout_s': 1.0})
    watch = Watch(ros_node, [module])
    assert ros_node.spin_until(lambda: _alive(procs) or watch.online(), TIMEOUT_S), \
        {n: p.output()[-1500:] for n, p in procs.items()}
    publisher = ros_node.create_publisher(CableLength, f'{NS}/{module}/cable_length/command', 10)
    assert ros_node.spin_until(lambda: publisher.get_subscription_count() > 0, 30.0)
    from softsnap_gaits.graph import driver_parameters
    straight = driver_parameters(specs)[module]['straight_length_m']
    msg = CableLength()
    msg.cable_length = straight - 0.010

    def sent_once() -> bool:
        # A short stream until the driver sent the target (a first message can be lost
        # while discovery completes on the driver's side), then silence.
        if watch.states[module][-1].targets_sent >= 1:
            return True
        msg.header.stamp = ros_node.get_clock().now().to_msg()
        publisher.publish(msg)
        ros_node.spin_until(lambda: False, 0.1)
        return False

    # The driver sent the target; the simulated winch cannot move (its time stands still).
    assert ros_node.spin_until(sent_once, 30.0), watch.states[module][-1]
    assert ros_node.spin_until(lambda: watch.states[module][-1].stale_stops >= 1, 30.0), \
        watch.states[module][-1]
    driver = procs['driver_container']
    assert ros_node.spin_until(lambda: 'stop confirmed' in driver_log(driver, module), 30.0), \
        driver.output()[-2000:]
    # Held where it is (the state after the confirmed stop may come a moment after the log).
    assert ros_node.spin_until(lambda: watch.states[module][-1].encoder_target
                               == watch.states[module][-1].encoder_count, 30.0), watch.states[module][-1]
    state = watch.states[module][-1]
    assert state.stops_unconfirmed == 0 and state.online, state
    # By now (seconds of wall time later) the simulation has long stopped at 0.5 s: the
    # driver's stamps stand at or before it (0 if it came up after the last /clock).
    frozen = _ns(state.header.stamp)
    assert frozen <= 0.5e9 + 1, frozen
    client = ros_node.create_client(Trigger, f'{NS}/{module}/stop')
    response = ros_node.call(client, Trigger.Request())
    assert response.success and 'confirmed' in response.message, response.message
    ros_node.spin_until(lambda: False, 1.0)
    # The simulated time never moved: the driver's latest stamp, and any /clock seen.
    assert _ns(watch.states[module][-1].header.stamp) == frozen
    assert max(watch.clock_ns, default=0) <= 0.5e9 + 1, max(watch.clock_ns)
    for name, proc in procs.items():
        assert proc.stop() == 0, f'{name}: {proc.output()[-2000:]}'
