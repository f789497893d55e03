"""Service replies wait for a client that has just started (softsnap_driver.dds_profile).

Fast DDS drops a service reply when, by the time the server sends it, the server has not
discovered the calling client's reply reader; it waits its reply writer's
max_blocking_time for it (0.1 s by default). On the loaded CI machine an action goal sent
by a client that had just started never got its goal response that way. Every node's main
loads a profile that makes the wait SERVICE_REPLY_WAIT_S, unless the user chose a
profiles file of their own.

The wait is observed from outside, in real node processes: a client whose reply reader
can never match (it asks for transient-local replies, the server offers volatile ones)
calls a node's parameter service, and the node reports the dropped reply only after the
whole wait.
"""
from __future__ import annotations

import time
import xml.etree.ElementTree as ET

import pytest

from softsnap_driver.dds_profile import (PROFILES_FILE_VARIABLES, SERVICE_REPLY_PROFILE,
                                         SERVICE_REPLY_WAIT_S, use_service_reply_profile)

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
    returned = use_service_reply_profile(environ)
    if chosen:
        assert returned == SERVICE_REPLY_PROFILE
        assert environ == {**before, **dict.fromkeys(PROFILES_FILE_VARIABLES,
                                                     str(SERVICE_REPLY_PROFILE))}
    else:
        assert returned is None
        assert environ == before


def test_a_profile_missing_from_the_install_is_not_pointed_to(monkeypatch, tmp_path):
    from softsnap_driver import dds_profile
    monkeypatch.setattr(dds_profile, 'SERVICE_REPLY_PROFILE', tmp_path / 'absent.xml')
    environ = {}
    assert dds_profile.use_service_reply_profile(environ) is None
    assert environ == {}


def test_the_profile_file_sets_the_reply_wait_and_nothing_else():
    root = ET.parse(SERVICE_REPLY_PROFILE).getroot()
    assert root.tag == f'{FASTDDS_NS}profiles'
    assert [(p.tag, p.get('profile_name')) for p in root] == [(f'{FASTDDS_NS}data_writer',
                                                               'service')]

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
