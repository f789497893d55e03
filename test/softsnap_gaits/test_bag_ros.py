"""Bags of a running graph: record it, decode every message independently, play it back.

One recording is shared by the tests of this file: `bag record` starts first (so every
topic appears after it: discovery picks them up), then a simulated module, its driver,
the model node and the gait node of the brittle star; this test's own publisher sends a
known series on a probe topic. The recorder is stopped with SIGINT while the graph still
runs, which must leave a closed, readable bag.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
import yaml

from softsnap_gaits.bag import message_definition
from softsnap_gaits.graph import robot_graph
from softsnap_model.scene import load_scene

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = '/brittle_star'
PROBE = f'{NS}/test/probe'
PROBE_COUNT = 50
#: Topics of the nodes started (yellow has a driver; the gait commands every module).
EXPECTED = {f'{NS}/{t}' for t in (
    'yellow/cable_length/command', 'yellow/cable_length/measured', 'yellow/state',
    'yellow/shape/commanded', 'yellow/shape/predicted', 'blue/cable_length/command',
    'model/shape/commanded', 'model/shape/predicted', 'model/diagnostics', 'gait/phase',
    'test/probe')}


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class _Peer:
    """An rclpy node in this process (own context) with a spin_until helper."""

    def __init__(self, name: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return bool(predicate())

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture(scope='module')
def start(root_conftest):
    """start(tmp, env, package, executable, *args) -> NodeProcess (stopped by the caller)."""
    def start(tmp: Path, env: dict, package: str, name: str, *args: str):
        log = tmp / f'{name}.{len(list(tmp.glob("*.log")))}.log'
        return root_conftest.NodeProcess([str(root_conftest.executable(package, name)), *args], log, env)
    return start


@pytest.fixture(scope='module')
def recorded(tmp_path_factory, root_conftest, start):
    """(bag path, probe values, recorder exit code, recorder output, wall window ns)."""
    from softsnap_interfaces.msg import CableLength, ModuleShape

    tmp = tmp_path_factory.mktemp('bag_graph')
    env = dict(os.environ, ROS_HOME=str(tmp / 'ros_home'), PYTHONUNBUFFERED='1')
    scene = load_scene('brittle_star')
    # One simulated module per driver: drivers sharing one module see each other's moves
    # (a fall to 0 while their own target is far) as a reboot, refuse commands, and the
    # graph's shapes stop changing (this failed CI at 11ac1a6).
    ports = {m.name: root_conftest.SLOT.free_port() for m in scene.modules}
    specs = {s.name: s for s in robot_graph(scene, rerun=False, sim_ports=ports)}
    bag = tmp / 'session'
    started_ns = time.time_ns()
    recorder = start(tmp, env, 'softsnap_gaits', 'bag', 'record', '-o', str(bag),
                      '--namespace', NS, '--ros-args', '-r', '__node:=bag_recorder')
    graph = [start(tmp, env, specs[n].package, specs[n].executable,
                   *specs[n].ros_args(specs[n].write_node_params(tmp)))
             for n in (*(f'sim_{m.name}' for m in scene.modules),
                       'driver_container', 'model_node', 'gait_node')]
    peer = _Peer('bag_test_peer')
    shapes = Counter()
    try:
        for source in ('commanded', 'predicted'):
            peer.node.create_subscription(ModuleShape, f'{NS}/yellow/shape/{source}',
                                          lambda msg, s=source: shapes.update([s]), 10)
        probe = peer.node.create_publisher(CableLength, PROBE, 100)

        def recorder_on(topic):
            return any(i.node_name == 'bag_recorder'
                       for i in peer.node.get_subscriptions_info_by_topic(topic))

        assert peer.spin_until(lambda: shapes['commanded'] > 5 and shapes['predicted'] > 5, 120), (
            'graph did not come up:\n' + '\n'.join(p.output()[-1500:] for p in graph))
        assert peer.spin_until(lambda: all(recorder_on(t) for t in EXPECTED), 60), (
            [t for t in EXPECTED if not recorder_on(t)], recorder.output()[-3000:])
        # The graph shows the recorder's subscription once its node announces it; the
        # probe's writer may match that reader later (in the demo, publishers took up to
        # 3 s), and volatile samples sent before the match are lost.
        assert peer.spin_until(lambda: probe.get_subscription_count() >= 1, 60), (
            'the probe never matched the recorder', recorder.output()[-3000:])
        values = [0.1 + 0.001 * i for i in range(PROBE_COUNT)]
        for value in values:
            msg = CableLength(cable_length=value)
            msg.header.stamp = peer.node.get_clock().now().to_msg()
            msg.header.frame_id = 'probe'
            probe.publish(msg)
            peer.spin_until(lambda: False, 0.02)
        peer.spin_until(lambda: False, 3.0)  # the graph keeps running: more of everything
        # SIGINT while the graph still publishes: the bag must be closed anyway.
        os.killpg(recorder.proc.pid, signal.SIGINT)
        code = recorder.proc.wait(30)
        window = (started_ns, time.time_ns())
        output = recorder.output()
    finally:
        peer.close()
        recorder.stop()
        for p in reversed(graph):
            p.stop()
    yield bag, values, code, output, window


@pytest.fixture(scope='module')
def decoded(recorded):
    """Every message of the bag, decoded by mcap_ros2 from the schemas in the file."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)  # mcap_ros2 0.6's reader module
        from mcap_ros2.reader import read_ros2_messages
        return list(read_ros2_messages(recorded[0] / f'{recorded[0].name}.mcap'))


def test_sigint_closes_the_bag(recorded):
    bag, _, code, output, _ = recorded
    assert code == 0, output[-3000:]
    assert f'to {bag}' in output and 'wrote' in output
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'session.mcap']
    from mcap.reader import make_reader
    with open(bag / 'session.mcap', 'rb') as f:
        summary = make_reader(f).get_summary()  # None if the file was never finished
    assert summary is not None and summary.statistics.message_count > 100


def test_every_message_decodes_with_its_recorded_content(recorded, decoded):
    bag, values, _, _, (start_ns, end_ns) = recorded
    by_topic = defaultdict(list)
    for m in decoded:
        by_topic[m.channel.topic].append(m)
    assert EXPECTED <= set(by_topic), sorted(EXPECTED - set(by_topic))

    # The probe: exactly what this test published, in order, header untouched.
    probes = [m.ros_msg for m in by_topic[PROBE]]
    assert [p.cable_length for p in probes] == values
    assert all(p.header.frame_id == 'probe' for p in probes)
    assert [_stamp_ns(p) for p in probes] == sorted(_stamp_ns(p) for p in probes)

    straight_m = 0.25  # a module is ~200 mm; no length is beyond 0.25 m or below 0.05 m
    for topic in (f'{NS}/yellow/cable_length/command', f'{NS}/blue/cable_length/command',
                  f'{NS}/yellow/cable_length/measured'):
        lengths = [m.ros_msg.cable_length for m in by_topic[topic]]
        assert len(lengths) > 20, topic
        assert all(0.05 < x < straight_m for x in lengths), (topic, min(lengths), max(lengths))
        # Receive time (the bag's log time) is after the sender's stamp, within the run.
        for m in by_topic[topic]:
            assert _stamp_ns(m.ros_msg) <= m.log_time_ns + 1_000_000 and start_ns <= m.log_time_ns <= end_ns
    commands = [m.ros_msg.cable_length for m in by_topic[f'{NS}/yellow/cable_length/command']]
    assert max(commands) - min(commands) > 0.005  # the gait moved the leg

    states = [m.ros_msg for m in by_topic[f'{NS}/yellow/state']]
    assert states and all(s.module == 'yellow' for s in states)
    assert states[-1].online and 3.0 < states[-1].battery_voltage < 4.3
    assert states[-1].commands_received > 0

    for source in ('commanded', 'predicted'):
        shapes = [m.ros_msg for m in by_topic[f'{NS}/yellow/shape/{source}']]
        assert shapes and all(s.module == 'yellow' and s.source == source for s in shapes)
        assert all(len(s.angles) == 11 and s.converged for s in shapes)
        assert all(len(s.rib_centers) == 12 for s in shapes)  # the recorder asked for them
        robots = [m.ros_msg for m in by_topic[f'{NS}/model/shape/{source}']]
        assert robots and all([s.module for s in r.modules] == ['yellow', 'blue', 'green', 'red', 'orange']
                              for r in robots)
    phases = [m.ros_msg for m in by_topic[f'{NS}/gait/phase']]
    assert phases[-1].gait and phases[-1].modules == ['yellow', 'blue', 'green', 'red', 'orange']
    diagnostics = [m.ros_msg for m in by_topic[f'{NS}/model/diagnostics']]
    assert diagnostics[-1].solves > 0

    # Schemas: the type names of the metadata, decodable without our packages.
    assert {m.schema.name for m in by_topic[f'{NS}/yellow/state']} == {'softsnap_interfaces/msg/ModuleState'}


def test_metadata_matches_the_mcap(recorded, decoded):
    bag = recorded[0]
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    # The fields Jazzy's rosbag2 (ros2 bag info / play) reads for format version 9.
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['session.mcap']
    assert meta['compression_mode'] == '' and meta['compression_format'] == ''
    assert isinstance(meta['custom_data'], dict) and isinstance(meta['ros_distro'], str)
    counts = Counter(m.channel.topic for m in decoded)
    listed = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert {name: t['message_count'] for name, t in listed.items() if t['message_count']} == dict(counts)
    assert meta['message_count'] == len(decoded) == sum(t['message_count'] for t in listed.values())
    assert meta['files'][0]['path'] == 'session.mcap' and meta['files'][0]['message_count'] == len(decoded)
    log_times = [m.log_time_ns for m in decoded]
    assert meta['starting_time']['nanoseconds_since_epoch'] == min(log_times)
    assert meta['duration']['nanoseconds'] == max(log_times) - min(log_times)
    for name, t in listed.items():
        topic = t['topic_metadata']
        assert topic['serialization_format'] == 'cdr'
        assert topic['type_description_hash'] == message_definition(topic['type']).type_hash
        assert isinstance(topic['offered_qos_profiles'], list) and topic['offered_qos_profiles'], name
        assert {q['reliability'] for q in topic['offered_qos_profiles']} <= {'reliable', 'best_effort'}


def test_played_bag_reproduces_the_session_in_a_fresh_model_node_and_rerun_logger(
        recorded, decoded, tmp_path, read_rrd, start, root_conftest):
    """Only the lengths are played; a new model node solves them into the same shapes,
    stamped as recorded, and a rerun logger records the past session on its timeline."""
    from softsnap_interfaces.msg import ModuleShape
    bag = recorded[0]
    recorded_shapes = defaultdict(dict)  # source -> stamp -> angles
    length_stamps = set()
    for m in decoded:
        if m.channel.topic.startswith(f'{NS}/yellow/shape/'):
            recorded_shapes[m.ros_msg.source][_stamp_ns(m.ros_msg)] = np.asarray(m.ros_msg.angles)
        if '/cable_length/' in m.channel.topic:
            length_stamps.add(_stamp_ns(m.ros_msg))
    env = dict(os.environ, ROS_HOME=str(tmp_path / 'ros_home'), PYTHONUNBUFFERED='1')
    scene = load_scene('brittle_star')
    specs = {s.name: s for s in robot_graph(scene, recording=tmp_path / 'replay.rrd')}
    model = start(tmp_path, env, 'softsnap_model', 'model_node', *specs['model_node'].ros_args())
    logger = start(tmp_path, env, 'softsnap_gaits', 'rerun_logger', *specs['rerun_logger'].ros_args())
    peer = _Peer('bag_replay_peer')
    replayed = defaultdict(dict)
    try:
        for source in ('commanded', 'predicted'):
            peer.node.create_subscription(
                ModuleShape, f'{NS}/yellow/shape/{source}',
                lambda msg, s=source: replayed[s].__setitem__(_stamp_ns(msg), np.asarray(msg.angles)), 100)
        lengths = [f'{NS}/{m.name}/cable_length/{kind}' for m in scene.modules
                   for kind in ('command', 'measured')]
        # Every played topic has a subscriber (the model node) before the first message.
        player = subprocess.run(
            [str(root_conftest.executable('softsnap_gaits', 'bag')), 'play', str(bag), '--rate', '1',
             '--wait-for-subscribers', '90', '--delay', '1', '--topics', *lengths],
            capture_output=True, text=True, timeout=240, env=env)
        assert player.returncode == 0, player.stdout + player.stderr
        assert 'played' in player.stdout
        peer.spin_until(lambda: False, 2.0)  # the last shapes arrive
    finally:
        peer.close()
        model.stop()
        code = logger.stop()
    for source in ('commanded', 'predicted'):
        got, want = replayed[source], recorded_shapes[source]
        assert got, f'no {source} shapes from the played lengths'
        # Shapes carry the stamp of the length they were solved from: the recorded stamps.
        assert set(got) <= length_stamps, source
        common = sorted(set(got) & set(want))
        assert len(common) >= 5, (source, len(got), len(want))
        for stamp in common:
            np.testing.assert_allclose(got[stamp], want[stamp], atol=1e-9, err_msg=f'{source} {stamp}')
    assert code in (0, -2)
    rrd = read_rrd(tmp_path / 'replay.rrd')
    times = rrd.times('robot/yellow/predicted/spine')
    assert times and set(times) <= length_stamps  # the past session's time line


def test_rerun_loads_the_bag_and_decodes_our_types(recorded, decoded, tmp_path, read_rrd, root_conftest):
    """rerun's own MCAP importer (rerun-sdk 0.41: `rerun mcap convert`) reads the bag and
    decodes softsnap_interfaces messages from the embedded definitions."""
    rerun = Path(sys.prefix) / 'bin' / 'rerun'
    help_text = subprocess.run([str(rerun), 'mcap', '--help'], capture_output=True, text=True,
                               timeout=60).stdout
    if 'convert' not in help_text:
        pytest.skip('the installed rerun has no MCAP importer (`rerun mcap convert`)')
    bag = recorded[0]
    out = tmp_path / 'bag.rrd'
    proc = subprocess.run([str(rerun), 'mcap', 'convert', str(bag / 'session.mcap'), '-o', str(out)],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rrd = read_rrd(out)
    counts = Counter(m.channel.topic for m in decoded)
    for topic in EXPECTED:
        assert len(rrd.rows[topic.lstrip('/')]) == counts[topic], topic
    probes = rrd.values(PROBE.lstrip('/'), 'softsnap_interfaces.msg.CableLength:message')
    assert [p[0]['cable_length'] for p in probes] == recorded[1]
    states = rrd.values(f'{NS}/yellow/state'.lstrip('/'), 'softsnap_interfaces.msg.ModuleState:message')
    assert states and all(s[0]['module'] == 'yellow' for s in states)
    shapes = rrd.values(f'{NS}/yellow/shape/predicted'.lstrip('/'), 'softsnap_interfaces.msg.ModuleShape:message')
    assert all(len(s[0]['angles']) == 11 for s in shapes)

    # The viewer's own file loader (what `rerun bag.mcap` opens), saved instead of shown.
    loaded = tmp_path / 'loaded.rrd'
    proc = subprocess.run([str(rerun), str(bag / 'session.mcap'), '--save', str(loaded),
                           '--bind', '127.0.0.1', '--port', str(root_conftest.SLOT.free_port())],
                          capture_output=True, text=True, timeout=180, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-3000:]
    viewer = read_rrd(loaded)
    for topic in EXPECTED:
        assert len(viewer.rows[topic.lstrip('/')]) == counts[topic], topic
