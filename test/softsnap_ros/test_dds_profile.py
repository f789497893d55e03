"""The nodes' Fast DDS profile (softsnap_ros.dds_profile), observed from outside.

Service replies wait for a client that has just started. Fast DDS drops a service reply when, by the time the server sends it, the server has not
discovered the calling client's reply reader; it waits its reply writer's
max_blocking_time for it (0.1 s by default). On the loaded CI machine an action goal sent
by a client that had just started never got its goal response that way. Every node's main
loads a profile that makes the wait SERVICE_REPLY_WAIT_S, unless the user chose a
profiles file of their own. The same profile makes each node announce its participant
every ANNOUNCEMENT_PERIOD_S (3 s by default), so that a process joining a running graph
finds the nodes soon.

The wait is observed from outside, in real node processes: a client whose reply reader
can never match (it asks for transient-local replies, the server offers volatile ones)
calls a node's parameter service, and the node reports the dropped reply only after the
whole wait. The announcements are read off the loopback: every participant sends them,
as UDP datagrams, to the discovery ports of participant ids 0-31 of its domain, and a
test socket holding one of those ports receives them.
"""
from __future__ import annotations

import os
import socket
import statistics
import time
import xml.etree.ElementTree as ET

import pytest

from softsnap_ros.dds_profile import (ANNOUNCEMENT_PERIOD_S, NODE_PROFILE,
                                      PROFILES_FILE_VARIABLES, SERVICE_REPLY_WAIT_S,
                                      use_node_profile)

DROPPED = 'client will not receive response'
FASTDDS_NS = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'


@pytest.mark.parametrize('environ, chosen', [
    ({}, True),
    ({'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'}, True),
    ({'RMW_IMPLEMENTATION': 'rmw_fastrtps_dynamic_cpp'}, True),
    ({'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}, False),
    ({'FASTRTPS_DEFAULT_PROFILES_FILE': '/home/me/mine.xml'}, False),
    ({'FASTDDS_DEFAULT_PROFILES_FILE': '/home/me/mine.xml'}, False),
    ({'FASTRTPS_DEFAULT_PROFILES_FILE': ''}, False),
])
def test_the_profile_is_used_only_where_the_user_chose_none(environ, chosen):
    before = dict(environ)
    returned = use_node_profile(environ)
    if chosen:
        assert returned == NODE_PROFILE
        assert environ == {**before, **dict.fromkeys(PROFILES_FILE_VARIABLES,
                                                     str(NODE_PROFILE))}
    else:
        assert returned is None
        assert environ == before


def test_a_profile_missing_from_the_install_is_not_pointed_to(monkeypatch, tmp_path):
    from softsnap_ros import dds_profile
    monkeypatch.setattr(dds_profile, 'NODE_PROFILE', tmp_path / 'absent.xml')
    environ = {}
    assert dds_profile.use_node_profile(environ) is None
    assert environ == {}


def test_the_profile_file_sets_the_reply_wait_and_the_announcement_period_only():
    root = ET.parse(NODE_PROFILE).getroot()
    assert root.tag == f'{FASTDDS_NS}profiles'
    assert [(p.tag, p.get('profile_name'), p.get('is_default_profile')) for p in root] == [
        (f'{FASTDDS_NS}data_writer', 'service', None),
        (f'{FASTDDS_NS}participant', 'softsnap_node', 'true')]

    def leaves(element, path=()):
        children = list(element)
        if not children:
            return [(path, element.text.strip())]
        return [leaf for child in children
                for leaf in leaves(child, path + (child.tag.removeprefix(FASTDDS_NS),))]

    values = dict(leaves(root[0]))
    prefix = ('qos', 'reliability', 'max_blocking_time')
    assert set(values) == {prefix + ('sec',), prefix + ('nanosec',)}
    wait_s = int(values[prefix + ('sec',)]) + int(values[prefix + ('nanosec',)]) * 1e-9
    assert wait_s == SERVICE_REPLY_WAIT_S
    values = dict(leaves(root[1]))
    prefix = ('rtps', 'builtin', 'discovery_config', 'leaseAnnouncement')
    assert set(values) == {prefix + ('sec',), prefix + ('nanosec',)}
    period_s = int(values[prefix + ('sec',)]) + int(values[prefix + ('nanosec',)]) * 1e-9
    assert period_s == ANNOUNCEMENT_PERIOD_S


def _node_specs(slot_port):
    from softsnap_gaits.graph import robot_graph
    from softsnap_model.scene import load_scene
    scene = load_scene('brittle_star')
    port = slot_port()   # one node runs at a time: one port is enough
    specs = robot_graph(scene, rerun=False, sim_ports={m.name: port for m in scene.modules})
    return {s.name: s for s in specs}


def _reply_wait_s(ros_node, proc, namespace: str, name: str) -> float:
    """Seconds from a call that can never be answered to the node's report of the dropped
    reply (an upper bound of the node's own wait)."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    service = f'{namespace}/{name}/get_parameters'
    # An ordinary call first: the node serves and has discovered this process.
    plain = ros_node.create_client(GetParameters, service)
    ros_node.call(plain, GetParameters.Request(names=['use_sim_time']), 60.0)
    deaf = ros_node.create_client(GetParameters, service, qos_profile=QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    ros_node.spin_until(lambda: False, 2.0)   # the node discovers the new request writer
    assert DROPPED not in proc.output()
    sent = time.monotonic()
    future = deaf.call_async(GetParameters.Request(names=['use_sim_time']))
    assert ros_node.spin_until(lambda: DROPPED in proc.output(), 30.0), proc.output()[-2000:]
    waited = time.monotonic() - sent
    assert not future.done()
    return waited


@pytest.mark.ros
@pytest.mark.parametrize('name', ['model_node', 'gait_node', 'driver_container', 'sim_yellow'])
def test_every_nodes_service_replies_wait_for_a_new_client(name, start_node, ros_node,
                                                            tmp_path, slot_port):
    spec = _node_specs(slot_port)[name]
    for variable in PROFILES_FILE_VARIABLES:
        start_node.env.pop(variable, None)   # the node's main must choose the profile itself
    proc = start_node(spec.package, spec.executable,
                      *spec.ros_args(spec.write_node_params(tmp_path)))
    waited = _reply_wait_s(ros_node, proc, spec.namespace, spec.name)
    assert waited >= SERVICE_REPLY_WAIT_S, (waited, proc.output()[-2000:])


@pytest.mark.ros
def test_a_users_own_profiles_file_decides(start_node, ros_node, tmp_path, slot_port):
    """With the user's profiles file (here one without the profile), Fast DDS's 0.1 s."""
    own = tmp_path / 'mine.xml'
    own.write_text('<?xml version="1.0" encoding="UTF-8" ?>\n'
                   '<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"/>\n')
    start_node.env[PROFILES_FILE_VARIABLES[0]] = str(own)
    spec = _node_specs(slot_port)['model_node']
    proc = start_node(spec.package, spec.executable, *spec.ros_args())
    waited = _reply_wait_s(ros_node, proc, spec.namespace, spec.name)
    assert waited < 0.9 * SERVICE_REPLY_WAIT_S, (waited, proc.output()[-2000:])


def _discovery_socket(domain_id: int) -> socket.socket:
    """A UDP socket on the discovery (metatraffic unicast) port of the highest participant
    id of ``domain_id`` that is free: participants announce themselves to ids 0-31 on
    the loopback (rmw_fastrtps with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)."""
    for participant_id in range(31, 15, -1):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(('127.0.0.1', 7400 + 250 * domain_id + 10 + 2 * participant_id))
        except OSError:
            sock.close()
            continue
        sock.settimeout(0.1)
        return sock
    raise RuntimeError(f'no free discovery port in domain {domain_id}')


@pytest.mark.ros
def test_a_node_announces_its_participant_every_announcement_period(start_node, tmp_path,
                                                                      slot_port):
    """A real node, its main choosing the profile, announces itself every
    ANNOUNCEMENT_PERIOD_S after its first burst (Fast DDS's default: every 3 s)."""
    if os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') != 'LOCALHOST':
        pytest.skip('announcements are read on the loopback')
    spec = _node_specs(slot_port)['sim_yellow']
    for variable in PROFILES_FILE_VARIABLES:
        start_node.env.pop(variable, None)   # the node's main must choose the profile itself
    sock = _discovery_socket(int(os.environ['ROS_DOMAIN_ID']))
    with sock:
        proc = start_node(spec.package, spec.executable,
                          *spec.ros_args(spec.write_node_params(tmp_path)))
        # Fast DDS's GUID prefix holds the low 16 bits of the process id in bytes 4-5: it
        # tells the node's announcements from those of other participants of the domain.
        pid = (proc.proc.pid & 0xFFFF).to_bytes(2, 'little')
        arrivals: list[float] = []
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and len(arrivals) < 14:
            try:
                data = sock.recv(65536)
            except socket.timeout:
                assert proc.alive(), proc.output()[-2000:]
                continue
            if data[:4] == b'RTPS' and data[12:14] == pid:
                arrivals.append(time.monotonic())
    gaps = [b - a for a, b in zip(arrivals, arrivals[1:])]
    # The first announcements come in a burst 0.1 s apart; the periodic ones follow.
    periodic = [gap for gap in gaps if gap > 0.5]
    assert len(periodic) >= 5, (gaps, proc.output()[-2000:])
    assert abs(statistics.median(periodic) - ANNOUNCEMENT_PERIOD_S) < 0.3, gaps
