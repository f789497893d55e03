"""The rerun logger's CDR readers against rclpy's own deserialisation.

Every field of every sample RobotShape, CableLength and ModuleState (strings of each
length modulo 8, empty sequences, NaN, negative stamps) must equal what rclpy's
``deserialize_message`` makes of the same bytes: serialised here, and taken raw from a
real DDS subscription fed by another process.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from softsnap_ros import cdr
from softsnap_ros.cdr import (CdrError, decode_cable_length, decode_module_state,
                              decode_robot_shape)

sys.path.insert(0, str(Path(__file__).parent))
from softsnap_ros.processes import stop_process_group
from shape_peer import sample_lengths, sample_shapes, sample_states  # noqa: E402


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def same_float(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def assert_same(decoded: cdr.RobotShapeCdr, msg) -> None:
    """Every field of ``decoded`` equals the rclpy message ``msg``, bit for bit."""
    assert decoded.stamp_ns == stamp_ns(msg.header.stamp)
    assert decoded.frame_id == msg.header.frame_id
    assert decoded.robot == msg.robot
    assert len(decoded.modules) == len(msg.modules)
    for got, want in zip(decoded.modules, msg.modules):
        assert got.stamp_ns == stamp_ns(want.header.stamp)
        assert got.frame_id == want.header.frame_id
        assert (got.module, got.source) == (want.module, want.source)
        assert got.cable_length == want.cable_length
        np.testing.assert_array_equal(got.angles, np.array(want.angles, dtype=float))
        assert got.angles.shape == (len(want.angles),)
        np.testing.assert_array_equal(
            got.rib_centers, np.array([(p.x, p.y, p.z) for p in want.rib_centers],
                                      dtype=float).reshape(-1, 3))
        for name in ('tension', 'energy', 'residual', 'solve_time'):
            assert same_float(getattr(got, name), getattr(want, name)), name
        assert got.converged is want.converged
    np.testing.assert_array_equal(decoded.base_poses, np.array(
        [(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
          p.orientation.z, p.orientation.w) for p in msg.base_poses], dtype=float).reshape(-1, 7))


def test_every_sample_decodes_to_rclpys_deserialisation_of_the_same_bytes():
    from rclpy.serialization import deserialize_message, serialize_message
    from softsnap_interfaces.msg import RobotShape

    samples = sample_shapes()
    assert sum(len(m.modules) for m in samples) >= 25
    for msg in samples:
        data = serialize_message(msg)
        assert_same(decode_robot_shape(data), deserialize_message(data, RobotShape))


def test_the_fallback_from_an_rclpy_message_gives_the_same_structure():
    """What the logger uses for bytes the reader refuses: rclpy's message, converted."""
    from rclpy.serialization import deserialize_message, serialize_message
    from softsnap_interfaces.msg import RobotShape

    for msg in sample_shapes():
        converted = cdr.from_message(deserialize_message(serialize_message(msg), RobotShape))
        assert_same(converted, msg)
        assert type(converted) is cdr.RobotShapeCdr and all(
            type(m) is cdr.ModuleShapeCdr and m.rib_centers.shape[1:] == (3,)
            for m in converted.modules)


def assert_same_length(decoded: tuple[int, float], msg) -> None:
    assert decoded[0] == stamp_ns(msg.header.stamp)
    assert same_float(decoded[1], msg.cable_length)


def assert_same_state(decoded: tuple[int, str, float], msg) -> None:
    # float32 on the wire: a message built in Python holds the unrounded value.
    assert decoded == (stamp_ns(msg.header.stamp), msg.module,
                       float(np.float32(msg.battery_voltage)))


def test_lengths_and_states_decode_to_rclpys_deserialisation_of_the_same_bytes():
    from rclpy.serialization import deserialize_message, serialize_message
    from softsnap_interfaces.msg import CableLength, ModuleState

    for msg in sample_lengths():
        data = serialize_message(msg)
        assert_same_length(decode_cable_length(data), deserialize_message(data, CableLength))
    for msg in sample_states():
        data = serialize_message(msg)
        assert_same_state(decode_module_state(data), deserialize_message(data, ModuleState))
    # A float32 battery voltage: the value rclpy gives is the rounded one, and so is ours.
    assert decode_module_state(serialize_message(sample_states()[1]))[2] == np.float32(7.275)
    with pytest.raises(CdrError, match='truncated'):
        decode_cable_length(serialize_message(sample_lengths()[3])[:20])
    with pytest.raises(CdrError, match='0x0000'):
        decode_module_state(b'\x00\x00\x00\x00' + bytes(60))


def test_a_robot_shape_of_the_brittle_star_decodes_with_its_points():
    """The logger's case: 5 modules of 11 angles and 12 rib centres, known values."""
    from geometry_msgs.msg import Point
    from rclpy.serialization import serialize_message
    from softsnap_interfaces.msg import ModuleShape, RobotShape

    msg = RobotShape(robot='brittle_star')
    for k, name in enumerate(('yellow', 'blue', 'green', 'red', 'orange')):
        shape = ModuleShape(module=name, source='predicted', solve_time=1.5e-4)
        shape.angles = [0.01 * k + 0.001 * j for j in range(11)]
        shape.rib_centers = [Point(x=0.0165 * j, y=0.001 * k, z=0.0) for j in range(12)]
        msg.modules.append(shape)
    decoded = decode_robot_shape(serialize_message(msg))
    assert [m.module for m in decoded.modules] == ['yellow', 'blue', 'green', 'red', 'orange']
    red = decoded.modules[3]
    assert red.rib_centers.shape == (12, 3)
    assert red.rib_centers[11].tolist() == [0.0165 * 11, 0.003, 0.0]
    assert red.angles[10] == 0.03 + 0.010
    assert red.solve_time == 1.5e-4 and decoded.base_poses.shape == (0, 7)


def test_truncated_bytes_are_refused_with_the_offset():
    from rclpy.serialization import serialize_message

    msg = sample_shapes()[4]  # 4 modules, with poses
    data = serialize_message(msg)
    refused, decoded_at = [], []
    for cut in range(len(data)):
        try:
            decoded = decode_robot_shape(data[:cut])
        except CdrError as exc:
            refused.append(cut)
            assert 'header' in str(exc) or 'truncated' in str(exc) or 'NUL' in str(exc)
        else:  # only what follows the last field (rmw's slack, up to 8 bytes) may be cut
            decoded_at.append(cut)
            assert_same(decoded, msg)
    assert refused == list(range(len(refused))) and len(refused) >= len(data) - 8


def test_other_encodings_are_refused_for_the_fallback():
    from rclpy.serialization import serialize_message

    data = bytearray(serialize_message(sample_shapes()[2]))
    for representation in (b'\x00\x00', b'\x00\x07', b'\x00\x0b'):  # CDR BE, XCDR2 LE/BE
        data[:2] = representation
        with pytest.raises(CdrError, match=f'0x{representation.hex()}'):
            decode_robot_shape(bytes(data))
    with pytest.raises(CdrError, match='4-byte header'):
        decode_robot_shape(b'\x00\x01')


def test_a_string_without_its_nul_is_refused():
    from rclpy.serialization import serialize_message
    from softsnap_interfaces.msg import RobotShape

    data = bytearray(serialize_message(RobotShape(robot='abc')))
    # header: stamp (8), frame_id '' (4 + 1), pad to 4 -> robot's length at body offset 16.
    body = cdr.HEADER_SIZE
    assert data[body + 16:body + 24] == b'\x04\x00\x00\x00abc\x00'
    data[body + 23] = ord('d')
    with pytest.raises(CdrError, match='robot.*NUL'):
        decode_robot_shape(bytes(data))


@pytest.mark.ros
def test_raw_dds_samples_decode_to_what_rclpy_delivers(ros_node, tmp_path):
    """Another process publishes the samples; this one subscribes twice to each topic,
    raw and deserialised, and the raw bytes must decode to the same messages."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from softsnap_interfaces.msg import RobotShape

    from softsnap_interfaces.msg import CableLength, ModuleState

    topic = f'cdr_{os.getpid()}'
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    cases = [(RobotShape, topic, sample_shapes(), decode_robot_shape, assert_same),
             (CableLength, f'{topic}_length', sample_lengths(), decode_cable_length,
              assert_same_length),
             (ModuleState, f'{topic}_state', sample_states(), decode_module_state,
              assert_same_state)]
    received = []  # (raw bytes, rclpy messages) per case
    for msg_type, name, *_ in cases:
        raw, rclpy_msgs = [], []
        ros_node.create_subscription(msg_type, name, raw.append, qos, raw=True)
        ros_node.create_subscription(msg_type, name, rclpy_msgs.append, qos)
        received.append((raw, rclpy_msgs))
    log = open(tmp_path / 'peer.log', 'w')
    peer = subprocess.Popen([sys.executable, str(Path(__file__).parent / 'shape_peer.py'), topic],
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    def all_received() -> bool:
        return all(len(raw) >= len(case[2]) and len(msgs) >= len(case[2])
                   for (raw, msgs), case in zip(received, cases))

    try:
        assert ros_node.spin_until(all_received, 60.0), (
            [(len(r), len(m)) for r, m in received], (tmp_path / 'peer.log').read_text())
    finally:
        stop_process_group(peer, 15.0)
        log.close()
    for (raw, rclpy_msgs), (_, _, sent, decode, check) in zip(received, cases):
        assert all(isinstance(b, bytes) for b in raw)
        assert len(raw) == len(rclpy_msgs) == len(sent)
        for data, msg, original in zip(raw, rclpy_msgs, sent):
            check(decode(data), msg)
            check(decode(data), original)  # and what was sent, in publishing order
