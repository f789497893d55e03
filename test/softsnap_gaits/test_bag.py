"""The bag core (softsnap_gaits.bag): definitions, writing, reading, selection, timing.

Messages are serialised by rclpy (the same CDR bytes DDS carries) and read back with
independent readers: mcap_ros2 decodes from the schema embedded in the file, not from
this project's installed types.
"""
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from softsnap_gaits.bag import (PLAY_DEPTH, RECORD_DEPTH, BagError, BagWriter, DefinitionError,
                                PlaybackClock, TopicFilter, bag_info, message_definition,
                                playback_qos, read_messages, recording_qos)

OUR_TYPES = ['CableLength', 'Design', 'GaitPhase', 'ModelDiagnostics', 'ModuleShape',
             'ModuleState', 'RobotShape']


@pytest.mark.parametrize('name', OUR_TYPES)
def test_definition_is_complete_its_hash_equals_the_installed_type_hash(name):
    """rosbags recomputes the RIHS01 hash from nothing but our definition text; it equals
    the hash rosidl generated for the installed type, so no field or nested type is
    missing or different."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    definition = message_definition(f'softsnap_interfaces/msg/{name}')
    assert definition.type_hash.startswith('RIHS01_')
    blocks = definition.text.split('=' * 80 + '\nMSG: ')
    assert len(blocks) == 1 + len(definition.dependencies)
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(blocks[0], definition.type_name))
    for block, dep in zip(blocks[1:], definition.dependencies):
        header, text = block.split('\n', 1)
        assert header == dep.replace('/msg/', '/')
        store.register(get_types_from_msg(text, dep))
    assert store.hash_rihs01(definition.type_name) == definition.type_hash


def test_nested_definitions_are_all_there():
    d = message_definition('softsnap_interfaces/RobotShape')
    assert d.type_name == 'softsnap_interfaces/msg/RobotShape'
    assert set(d.dependencies) == {
        'std_msgs/msg/Header', 'builtin_interfaces/msg/Time', 'softsnap_interfaces/msg/ModuleShape',
        'geometry_msgs/msg/Point', 'geometry_msgs/msg/Pose', 'geometry_msgs/msg/Quaternion'}
    # The root's own text first, with its comments (units) as rosbag2 embeds it.
    assert d.text.startswith('# Shapes of all modules')


def test_unknown_types_are_refused_with_the_name():
    with pytest.raises(DefinitionError, match='no_such_package'):
        message_definition('no_such_package/msg/Thing')
    with pytest.raises(DefinitionError, match='NoSuchType'):
        message_definition('softsnap_interfaces/msg/NoSuchType')
    with pytest.raises(DefinitionError, match="'package/msg/Type'"):
        message_definition('softsnap_interfaces/srv/SetGait')


def _serialize(msg) -> bytes:
    from rclpy.serialization import serialize_message
    return serialize_message(msg)


def _state(i):
    from softsnap_interfaces.msg import ModuleState
    msg = ModuleState(module='yellow', online=True, battery_voltage=4.0, commands_received=i)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + i, 5
    msg.last_error = 'stall' if i % 2 else ''
    return msg


# mcap_ros2 0.6 marks its reader module deprecated (in favour of make_reader + DecoderFactory,
# which it wraps); read_ros2_messages is still the documented one-call reader.
@pytest.mark.filterwarnings('ignore::DeprecationWarning')
def test_written_bag_is_decoded_by_independent_readers(tmp_path):
    from mcap_ros2.reader import read_ros2_messages
    from softsnap_interfaces.msg import ModuleShape, RobotShape

    path = tmp_path / 'bag'
    writer = BagWriter(path)
    writer.add_topic('/r/yellow/state', 'softsnap_interfaces/msg/ModuleState')
    writer.add_topic('/r/model/shape/predicted', 'softsnap_interfaces/msg/RobotShape')
    writer.add_topic('/r/yellow/cable_length/command', 'softsnap_interfaces/msg/CableLength')
    t0 = 1_700_000_000_000_000_000
    for i in range(30):
        writer.write('/r/yellow/state', t0 + i * 10_000_000, _serialize(_state(i)))
    for i in range(20):
        shape = RobotShape(robot='r', modules=[ModuleShape(module='yellow', angles=[0.01 * i] * 11)])
        writer.write('/r/model/shape/predicted', t0 + i * 7_000_000, _serialize(shape))
    summary = writer.close()
    assert summary.message_counts == {'/r/yellow/state': 30, '/r/model/shape/predicted': 20,
                                      '/r/yellow/cable_length/command': 0}
    assert (summary.start_ns, summary.end_ns) == (t0, t0 + 290_000_000)

    decoded = list(read_ros2_messages(path / 'bag.mcap'))
    assert len(decoded) == 50
    states = [m.ros_msg for m in decoded if m.channel.topic == '/r/yellow/state']
    assert [s.commands_received for s in states] == list(range(30))
    assert all(s.module == 'yellow' and s.online for s in states)
    assert [s.header.stamp.sec for s in states] == [100 + i for i in range(30)]
    assert states[1].last_error == 'stall' and abs(states[1].battery_voltage - 4.0) < 1e-6
    shapes = [m.ros_msg for m in decoded if m.channel.topic == '/r/model/shape/predicted']
    assert [s.modules[0].angles[0] for s in shapes] == pytest.approx([0.01 * i for i in range(20)])
    assert {m.schema.name for m in decoded} == {'softsnap_interfaces/msg/ModuleState',
                                                'softsnap_interfaces/msg/RobotShape'}
    # Receive times are the MCAP log times, in time order.
    assert [m.log_time_ns for m in decoded] == sorted(m.log_time_ns for m in decoded)

    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['bag.mcap'] and meta['message_count'] == 50
    counts = {t['topic_metadata']['name']: t['message_count'] for t in meta['topics_with_message_count']}
    assert counts == summary.message_counts
    hashes = {t['topic_metadata']['name']: t['topic_metadata']['type_description_hash']
              for t in meta['topics_with_message_count']}
    assert hashes['/r/yellow/state'] == message_definition('softsnap_interfaces/msg/ModuleState').type_hash

    # Our reader (the player's) gives back the same bytes, in receive-time order.
    # (Compared decoded: CDR padding bytes are not defined, so equal messages may differ.)
    from rclpy.serialization import deserialize_message
    from softsnap_interfaces.msg import ModuleState
    read = list(read_messages(path, ['/r/yellow/state']))
    assert [deserialize_message(d, ModuleState) for _, _, _, d in read] == [_state(i) for i in range(30)]
    assert [t for _, _, t, _ in read] == [t0 + i * 10_000_000 for i in range(30)]
    info = bag_info(path)
    assert info.message_count == 50 and info.storage_identifier == 'mcap'
    assert {t.name: t.message_count for t in info.topics} == summary.message_counts


def test_writer_refuses_what_would_lose_data(tmp_path):
    (tmp_path / 'old').mkdir()
    with pytest.raises(BagError, match='never overwritten'):
        BagWriter(tmp_path / 'old')
    writer = BagWriter(tmp_path / 'new')
    writer.add_topic('/a', 'std_msgs/msg/String')
    with pytest.raises(BagError, match='already in the bag'):
        writer.add_topic('/a', 'std_msgs/msg/String')
    with pytest.raises(BagError, match='/b was not added'):
        writer.write('/b', 1, b'')
    with pytest.raises(DefinitionError):
        writer.add_topic('/c', 'nope/msg/Nope')
    writer.close()
    with pytest.raises(BagError, match='closed'):
        writer.write('/a', 1, b'\x00\x01\x00\x00\x01\x00\x00\x00\x00')
    assert writer.close().message_counts == {'/a': 0}  # closing twice is harmless


def test_reading_a_directory_without_metadata_says_why(tmp_path):
    with pytest.raises(BagError, match='no metadata.yaml'):
        bag_info(tmp_path)


def test_topic_filter():
    f = TopicFilter(topics=('/x/_hidden',), namespaces=('/brittle_star',), exclude=('rosout',))
    assert f.matches('/brittle_star/yellow/state')
    assert not f.matches('/brittle_starfish/yellow/state')  # a prefix is not a namespace
    assert not f.matches('/brittle_star/_private/a')  # hidden unless named
    assert f.matches('/x/_hidden')
    assert not f.matches('/other')
    everything = TopicFilter(all=True, exclude=('^/parameter_events$',))
    assert everything.matches('/diagnostics') and everything.matches('/rosout')
    assert not everything.matches('/parameter_events')
    with pytest.raises(BagError, match='empty'):
        TopicFilter(topics=('/',))
    relative = TopicFilter(topics=('yellow/state',), namespaces=('/abs/',)).resolved(
        lambda name: name if name.startswith('/') else '/ns/' + name)
    assert relative.topics == ('/ns/yellow/state',) and relative.namespaces == ('/abs',)
    assert relative.matches('/ns/yellow/state') and relative.matches('/abs/x')
    with pytest.raises(BagError, match='nothing to record'):
        TopicFilter()
    with pytest.raises(BagError, match=r'\[unclosed'):
        TopicFilter(all=True, exclude=('[unclosed',))


def test_qos_follows_the_publishers():
    from rosbags.interfaces import QosDurability, QosReliability
    reliable = recording_qos([])._replace(depth=0)  # a reliable volatile profile
    best_effort = reliable._replace(reliability=QosReliability.BEST_EFFORT)
    latched = reliable._replace(durability=QosDurability.TRANSIENT_LOCAL)
    q = recording_qos([reliable, best_effort])
    assert q.reliability == QosReliability.BEST_EFFORT and q.depth == RECORD_DEPTH
    assert recording_qos([reliable]).reliability == QosReliability.RELIABLE
    assert recording_qos([latched]).durability == QosDurability.TRANSIENT_LOCAL
    assert recording_qos([latched, reliable]).durability == QosDurability.VOLATILE
    assert playback_qos([best_effort]).reliability == QosReliability.BEST_EFFORT
    assert playback_qos([reliable, best_effort]).reliability == QosReliability.RELIABLE
    assert playback_qos([reliable]).depth == PLAY_DEPTH  # DDS did not tell the depth
    assert playback_qos([reliable._replace(depth=7)]).depth == 7
    assert playback_qos([latched]).durability == QosDurability.TRANSIENT_LOCAL


def test_playback_clock_scales_the_recorded_gaps():
    clock = PlaybackClock(2.0, first_ns=5_000_000_000, start_s=100.0)
    assert clock.due(5_000_000_000) == 100.0
    assert clock.due(6_000_000_000) == pytest.approx(100.5)
    for bad in (0.0, -1.0, float('nan'), float('inf'), 1001.0):
        with pytest.raises(BagError, match='rate must be'):
            PlaybackClock(bad, 0, 0.0)


def _bag_cli(*args):
    return subprocess.run([sys.executable, '-m', 'softsnap_gaits.bag', *args], capture_output=True,
                          text=True, timeout=120, stdin=subprocess.DEVNULL)


def test_cli_info_and_errors(tmp_path):
    writer = BagWriter(tmp_path / 'b')
    writer.add_topic('/r/yellow/state', 'softsnap_interfaces/msg/ModuleState')
    for i in range(3):
        writer.write('/r/yellow/state', 1_000_000_000 * (i + 1), _serialize(_state(i)))
    writer.close()
    out = _bag_cli('info', str(tmp_path / 'b'), '--json')
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info['message_count'] == 3 and info['duration_ns'] == 2_000_000_000
    assert info['topics'] == [{'name': '/r/yellow/state', 'type': 'softsnap_interfaces/msg/ModuleState',
                               'message_count': 3}]
    text = _bag_cli('info', str(tmp_path / 'b'))
    assert 'Storage id: mcap' in text.stdout and '/r/yellow/state' in text.stdout

    bad = _bag_cli('record', '-o', str(tmp_path / 'b'), '--all')
    assert bad.returncode == 1 and 'never overwritten' in bad.stderr
    assert not (tmp_path / 'b' / 'b_0.mcap').exists()
    bad = _bag_cli('play', str(tmp_path / 'b'), '--rate', '0')
    assert bad.returncode == 1 and 'rate must be > 0' in bad.stderr
    bad = _bag_cli('play', str(tmp_path / 'nothing'))
    assert bad.returncode == 1 and 'no metadata.yaml' in bad.stderr
    bad = _bag_cli('record', '-o', str(tmp_path / 'c'))
    assert bad.returncode == 1 and 'nothing to record' in bad.stderr
    assert not Path(tmp_path / 'c').exists()
    bad = _bag_cli('record', '-o', str(tmp_path / 'd'), 'bad name!')
    assert bad.returncode == 1 and 'bad topic or namespace name' in bad.stderr
    assert not Path(tmp_path / 'd').exists()  # a recorder that never started leaves no bag


def test_robot_graph_adds_a_recorder_of_every_topic_only_when_asked(tmp_path):
    from softsnap_gaits.graph import robot_graph
    from softsnap_gaits.launching import node_action_kwargs
    from softsnap_model.scene import load_scene
    scene = load_scene('snake')
    assert all(s.executable != 'bag' for s in robot_graph(scene))
    spec = robot_graph(scene, bag=tmp_path / 'b')[-1]
    assert (spec.package, spec.executable, spec.name, spec.namespace) == (
        'softsnap_gaits', 'bag', 'bag_recorder', '/snake')
    assert spec.arguments == ('record', '-o', str(tmp_path / 'b'), '--namespace', '/snake',
                              '/tf', '/tf_static', '/robot_description', '/joint_states',
                              '/diagnostics', '/clock', '/rosout',
                              '--exclude', '^/parameter_events$')
    everything = robot_graph(scene, bag=tmp_path / 'b', bag_all=True)[-1]
    assert everything.arguments == ('record', '-o', str(tmp_path / 'b'), '--all',
                                    '--exclude', '^/parameter_events$')
    assert spec.ros_args()[:3] == ['--ros-args', '-r', '__node:=bag_recorder']
    assert node_action_kwargs(spec)['arguments'] == list(spec.arguments)
    assert 'arguments' not in node_action_kwargs(robot_graph(scene)[0])
