"""Shared fixtures: isolated ROS 2 environment, node processes and an in-test rclpy node.

Every test session gets its own ROS domain id and localhost-only discovery, so parallel
runs on one machine (or a developer's other nodes) never see each other's topics.
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)

# Set before rclpy is imported anywhere in this process or its children.
os.environ.setdefault('ROS_DOMAIN_ID', str(random.Random(os.getpid()).randint(1, 100)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')


def executable(package: str, name: str) -> Path:
    """Path of a node executable where `ros2 run <package> <name>` finds it."""
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix(package)) / 'lib' / package / name
    assert path.exists(), f'{path} missing: run scripts/bootstrap.sh'
    return path


class NodeProcess:
    """A node started as its own OS process, stopped with SIGINT like Ctrl-C."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str]):
        self.argv = argv
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, env=env, start_new_session=True)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors='replace')

    def stop(self, timeout: float = 10.0) -> int:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


@pytest.fixture
def start_node(tmp_path):
    """Factory: start_node('softsnap_model', 'model_node', '--ros-args', '-p', 'x:=1')."""
    started: list[NodeProcess] = []
    env = dict(os.environ, ROS_HOME=str(tmp_path / 'ros_home'), PYTHONUNBUFFERED='1')

    def start(package: str, name: str, *args: str) -> NodeProcess:
        log = tmp_path / f'{package}.{name}.{len(started)}.log'
        proc = NodeProcess([str(executable(package, name)), *args], log, env)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        proc.stop()


@pytest.fixture
def ros_node():
    """An rclpy node in the test process, with spin_until(predicate, timeout) attached."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(f'test_client_{os.getpid()}', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin_until(predicate, timeout: float = 10.0) -> bool:
        """Spin until predicate() is true; False if timeout (s) passes first."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            executor.spin_once(timeout_sec=0.02)
        return bool(predicate())

    def call(client, request, timeout: float = 10.0):
        """Wait for the service, call it and return the response (fails the test on timeout)."""
        assert spin_until(client.service_is_ready, timeout), f'{client.srv_name} not available'
        future = client.call_async(request)
        assert spin_until(future.done, timeout), f'{client.srv_name} did not answer'
        return future.result()

    node.spin_until = spin_until
    node.call = call
    node.executor_ = executor
    yield node
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=context)
