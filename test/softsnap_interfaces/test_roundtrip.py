"""Two separate processes exchange a custom message and a custom service over Fast DDS."""
import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from softsnap_ros.processes import stop_process_group

pytestmark = pytest.mark.ros

PEER = Path(__file__).with_name('echo_peer.py')


@pytest.fixture
def peer(tmp_path):
    log = open(tmp_path / 'peer.log', 'wb')
    proc = subprocess.Popen([sys.executable, str(PEER)], stdout=log, stderr=subprocess.STDOUT,
                            env=dict(os.environ, ROS_HOME=str(tmp_path)), start_new_session=True)
    yield proc
    if stop_process_group(proc, 10.0) == -signal.SIGKILL:
        # The peer is this test's helper, not a product node (their SIGINT exit is tested in
        # test/e2e/test_sigint.py); once in a full CI run it hung silently in rclpy's
        # shutdown. It was killed so no process outlives the test: say so.
        warnings.warn(f'echo_peer ignored SIGINT for 10 s and was killed; log: '
                      f'{(tmp_path / "peer.log").read_bytes()[-500:]!r}')
    log.close()


def test_custom_message_and_service_cross_process(peer, ros_node):
    from softsnap_interfaces.msg import CableLength
    from softsnap_interfaces.srv import SetGait

    assert os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp') == 'rmw_fastrtps_cpp'
    received = []
    ros_node.create_subscription(CableLength, 'echo/out', received.append, 10)
    pub = ros_node.create_publisher(CableLength, 'echo/in', 10)
    assert ros_node.spin_until(lambda: pub.get_subscription_count() > 0, 15.0), 'peer not matched'

    sent = [0.1, 0.125, 0.15]
    for value in sent:
        msg = CableLength()
        msg.header.frame_id = 'm1'
        msg.cable_length = value
        pub.publish(msg)
    assert ros_node.spin_until(lambda: len(received) >= len(sent), 10.0)
    assert [m.cable_length for m in received] == pytest.approx([2 * v for v in sent])
    assert all(m.header.frame_id == 'm1' for m in received)

    client = ros_node.create_client(SetGait, 'echo/set_gait')
    response = ros_node.call(client, SetGait.Request(gait='walk', period=1.1), 15.0)
    assert response.success and response.message == 'echo:walk:1.100'
    response = ros_node.call(client, SetGait.Request(gait='bad', period=0.0))
    assert not response.success
    assert peer.poll() is None
