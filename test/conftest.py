"""Shared fixtures: isolated ROS 2 environment, node processes, an in-test rclpy node, and
a private rerun configuration with an .rrd reader.

Every test session gets its own ROS domain id and localhost-only discovery, so parallel
runs on one machine (or a developer's other nodes) never see each other's topics.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)

# A slot of our own (softsnap_gaits.isolation): a ROS domain id and a block of loopback
# ports that no other test session or demo on this machine uses while this one runs.
# Set before rclpy is imported anywhere in this process or its children.
from softsnap_gaits.isolation import claim_slot  # noqa: E402  (no ROS imports)

from softsnap_ros.processes import ChildProcess  # noqa: E402  (no ROS imports)

SLOT, _slot_warning = claim_slot()
if _slot_warning:
    print(f'conftest: warning: {_slot_warning}', file=sys.stderr)
os.environ['ROS_DOMAIN_ID'] = str(SLOT.domain_id)
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')
# MuJoCo picks its OpenGL backend once, when first imported: offscreen EGL for the
# simulated camera's tests (nothing else here renders).
os.environ.setdefault('MUJOCO_GL', 'egl')
# The nodes' Fast DDS profile (service replies wait for a client that has just started,
# participants announced every second), in this process and every process it starts, as
# in every node's main (init_ros).
from softsnap_ros.dds_profile import use_node_profile  # noqa: E402  (no ROS imports)

use_node_profile()


def executable(package: str, name: str) -> Path:
    """Path of a node executable where `ros2 run <package> <name>` finds it."""
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix(package)) / 'lib' / package / name
    assert path.exists(), f'{path} missing: run scripts/bootstrap.sh'
    return path


#: A node started as its own OS process, stopped with SIGINT like Ctrl-C; stop() also stops
#: whatever it started, in its process group or not (by a tag every descendant inherits).
NodeProcess = ChildProcess


_ROOT_CONFTEST = sys.modules[__name__]   # later conftest files take the module name


@pytest.fixture(scope='session')
def root_conftest():
    """This module (NodeProcess, executable, the session's SLOT): several conftest files
    share the module name, so `import conftest` may find another one."""
    return _ROOT_CONFTEST


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

    start.env = env   # the processes' environment: a test may change it before starting
    yield start
    for proc in started:
        proc.stop()


@pytest.fixture
def slot_port():
    """Factory: a loopback TCP port of this session's slot that nothing listens on."""
    return SLOT.free_port


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

    def call(client, request, timeout: float = 30.0):
        """Wait for the service, call it and return the response (fails the test on timeout;
        30 s by default: a node on a machine with both cores busy answers late, not never)."""
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


# ---------------------------------------------------------------- rerun recordings
RERUN_CLI = Path(sys.prefix) / 'bin' / 'rerun'


@pytest.fixture(scope='session', autouse=True)
def rerun_config(tmp_path_factory):
    """Keep rerun's config and data out of ~ (also for child processes) and analytics off."""
    base = tmp_path_factory.mktemp('rerun_home')
    saved = {k: os.environ.get(k) for k in ('XDG_CONFIG_HOME', 'XDG_DATA_HOME')}
    os.environ['XDG_CONFIG_HOME'] = str(base / 'config')
    os.environ['XDG_DATA_HOME'] = str(base / 'data')
    # 0.41 has no environment switch for analytics; its config file is the switch.
    subprocess.run([str(RERUN_CLI), 'analytics', 'disable'], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60)
    yield base
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


class Recording:
    """Rows of an .rrd file by entity path (without the leading '/').

    ``rows[path]`` is a list of dicts, one per logged row, sorted by the temporal index,
    with timeline values as int (ns for timestamps) and components by their column name
    (e.g. ``'LineStrips3D:strips'``) as Python lists. ``static`` holds static rows.
    """

    def __init__(self, path: Path):
        import pyarrow as pa
        from rerun.chunk import RrdReader

        self.path = path
        reader = RrdReader(str(path))
        self.blueprints = reader.blueprints()
        self.recordings = reader.recordings()
        # store() needs the footer/manifest a closed file sink writes: this is how the
        # tests check that a recording was closed properly.
        self.store = reader.store()
        self.rows: dict[str, list[dict]] = defaultdict(list)
        self.static: dict[str, dict] = {}
        for chunk in reader.stream().to_chunks():
            entity = chunk.entity_path.lstrip('/')
            batch = chunk.to_record_batch()
            columns = {}
            for name, column in zip(batch.schema.names, batch.columns):
                if name == 'rerun.controls.RowId':
                    continue
                if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
                    column = column.cast(pa.int64())
                columns[name] = column.to_pylist()
            for i in range(batch.num_rows):
                row = {name: values[i] for name, values in columns.items()}
                if chunk.is_static:
                    self.static.setdefault(entity, {}).update(
                        {k: v for k, v in row.items() if v is not None})
                else:
                    self.rows[entity].append(row)
        for rows in self.rows.values():
            rows.sort(key=lambda r: (r.get('ros_time') or r.get('step') or 0,
                                     r.get('log_time') or 0))

    @property
    def entities(self) -> set[str]:
        return set(self.rows) | set(self.static)

    def values(self, entity: str, component: str) -> list:
        """The non-null values of one component of one entity, in time order."""
        return [r[component] for r in self.rows.get(entity, []) if r.get(component) is not None]

    def scalars(self, entity: str) -> list[float]:
        return [v[0] for v in self.values(entity, 'Scalars:scalars')]

    def times(self, entity: str, timeline: str = 'ros_time') -> list[int]:
        return [r[timeline] for r in self.rows.get(entity, [])]


@pytest.fixture
def read_rrd():
    """read_rrd(path) -> Recording."""
    return Recording
