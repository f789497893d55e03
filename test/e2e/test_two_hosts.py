"""The robot graph over two hosts (issue 37): real DDS between two network namespaces.

"Robot host" A runs the simulated modules and their drivers (a laptop beside the robot);
"workstation" B runs the model, the gait and a probe. They are joined by a virtual
Ethernet link and nothing else: UDP only (no shared memory, which two computers do not
have), discovery by static peers as docs/scaling.md describes. Then the link drops for
5 s: the drivers must stop their modules (the command stream went stale), and once the
link is back, the graph must recover by itself: commands reach the drivers again and the
workstation sees new shapes predicted from measured lengths.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from softsnap_gaits.graph import robot_graph
from softsnap_model.scene import load_scene

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DROP_S = 5.0
PROBE = Path(__file__).with_name('two_host_probe.py')


def _ip(*args: str) -> None:
    subprocess.run(['ip', *args], check=True, capture_output=True, text=True, timeout=30)


@pytest.fixture
def two_hosts():
    """Two network namespaces joined by a veth pair: {'A': (name, ip, dev), 'B': ...}."""
    if os.geteuid() != 0 or shutil.which('ip') is None:
        pytest.skip('network namespaces need root and iproute2 (ip)')
    tag = f'{os.getpid() % 10000}'
    hosts = {'A': (f'ssA{tag}', '10.251.77.1', f'ssvA{tag}'),
             'B': (f'ssB{tag}', '10.251.77.2', f'ssvB{tag}')}
    made = []
    try:
        for name, _, _ in hosts.values():
            _ip('netns', 'add', name)
            made.append(name)
        (na, ipa, da), (nb, ipb, db) = hosts['A'], hosts['B']
        _ip('link', 'add', da, 'type', 'veth', 'peer', 'name', db)
        _ip('link', 'set', da, 'netns', na)
        _ip('link', 'set', db, 'netns', nb)
        for name, address, dev in hosts.values():
            _ip('-n', name, 'addr', 'add', f'{address}/24', 'dev', dev)
            _ip('-n', name, 'link', 'set', dev, 'up')
            _ip('-n', name, 'link', 'set', 'lo', 'up')
            # DDS's discovery multicast goes out on the link (as on a LAN).
            _ip('-n', name, 'route', 'add', '224.0.0.0/4', 'dev', dev)
    except subprocess.CalledProcessError as exc:
        for name in made:
            subprocess.run(['ip', 'netns', 'del', name], capture_output=True, timeout=30)
        pytest.skip(f'cannot make network namespaces here: {exc.stderr.strip()}')
    yield hosts
    for name in made:
        subprocess.run(['ip', 'netns', 'del', name], capture_output=True, timeout=30)


class Probe:
    """two_host_probe.py in a namespace; `latest` is its newest JSON line."""

    def __init__(self, argv, env, log_path):
        self.latest = None
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=open(log_path, 'wb'),
                                     stdin=subprocess.DEVNULL, env=env, text=True,
                                     start_new_session=True)
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for line in self.proc.stdout:
            try:
                self.latest = json.loads(line)['modules']
            except (ValueError, KeyError):
                pass

    def wait_for(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.latest is not None and predicate(self.latest):
                return True
            time.sleep(0.1)
        return self.latest is not None and predicate(self.latest)


def test_the_graph_spans_two_hosts_and_survives_a_5_s_link_drop(two_hosts, root_conftest,
                                                                  tmp_path):
    scene = load_scene('brittle_star')
    names = [m.name for m in scene.modules]
    first_port = 24000
    ports = {m.name: first_port + i for i, m in enumerate(scene.modules)}
    specs = {s.name: s for s in robot_graph(scene, sim_ports=ports, sim_modules='shared',
                                            rerun=False)}
    by_host = {'A': ['sim_modules', 'driver_container'], 'B': ['model_node', 'gait_node']}
    (na, ipa, da), (nb, ipb, _) = two_hosts['A'], two_hosts['B']
    base_env = dict(os.environ, PYTHONUNBUFFERED='1', ROS_HOME=str(tmp_path / 'ros_home'),
                    ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
                    # Two computers share no memory: DDS over UDP only, as between hosts.
                    FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    envs = {'A': dict(base_env, ROS_STATIC_PEERS=ipb), 'B': dict(base_env, ROS_STATIC_PEERS=ipa)}
    netns = {'A': na, 'B': nb}
    procs = []
    probe = None
    try:
        for host, nodes in by_host.items():
            for node in nodes:
                spec = specs[node]
                exe = root_conftest.executable(spec.package, spec.executable)
                argv = ['ip', 'netns', 'exec', netns[host], str(exe), *spec.arguments,
                        *spec.ros_args(spec.write_node_params(tmp_path))]
                procs.append(root_conftest.NodeProcess(argv, tmp_path / f'{host}-{node}.log',
                                                       envs[host]))
        probe = Probe(['ip', 'netns', 'exec', nb, sys.executable, str(PROBE), f'/{scene.name}',
                       ','.join(names)], envs['B'], tmp_path / 'probe.log')

        def flowing(since):
            # Every module: commands crossed B -> A (the driver's count grew since `since`),
            # its state crossed back, and new shapes predicted from measured lengths (A -> B).
            def check(seen):
                return all(seen[m]['online'] and seen[m]['commands_received'] is not None
                           and seen[m]['commands_received'] > since[m]['commands_received']
                           and seen[m]['predicted'] > since[m]['predicted'] + 5
                           and seen[m]['commanded'] > since[m]['commanded'] for m in names)
            return check

        zero = {m: {'commands_received': -1, 'predicted': 0, 'commanded': 0} for m in names}
        assert probe.wait_for(flowing(zero), 120.0), (
            f'the graph never ran across the two hosts: {probe.latest}\n' + _logs(procs))

        driver_log = next(p for p in procs if 'driver_container' in str(p.log_path))
        log_before = len(driver_log.output())
        _ip('-n', na, 'link', 'set', da, 'down')
        time.sleep(DROP_S)
        during = json.loads(json.dumps(probe.latest))
        # The robot side stopped every module itself: no command came for its timeout.
        text = driver_log.output()[log_before:]
        stopped = [m for m in names if f'{m}_driver]: stop confirmed' in text]
        assert '(stale command stream)' in text, text[-3000:]
        assert set(stopped) == set(names), f'modules not stopped on the drop: {set(names) - set(stopped)}'
        _ip('-n', na, 'link', 'set', da, 'up')
        assert probe.wait_for(flowing(during), 60.0), (
            f'the graph did not recover after the link came back: {probe.latest}\n' + _logs(procs))
        assert all(p.alive() for p in procs), _logs(procs)
    finally:
        if probe is not None:
            probe.proc.send_signal(2)
            try:
                probe.proc.wait(10)
            except subprocess.TimeoutExpired:
                probe.proc.kill()
        for p in procs:
            p.stop()


def _logs(procs) -> str:
    return '\n'.join(f'--- {p.log_path.name}\n{p.output()[-1500:]}' for p in procs)
