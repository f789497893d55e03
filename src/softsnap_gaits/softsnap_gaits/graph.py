"""The process graph of a robot: which nodes run, with which parameters (pure, no ROS).

One description serves both the demo runner (:mod:`softsnap_gaits.demo`, separate OS
processes) and the ROS 2 launch files (``launch/<scene>.launch.py``), so the graph exists
once. For a scene with modules ``m1..mN`` in namespace ``/<scene>``:

- ``sim_<m>``: a simulated module serving the firmware protocol on the module's port
  (only with ``simulate=True``; real modules are reached at the scene's host/port);
- or, with ``physics=True``, one ``sim_robot``: the whole robot in MuJoCo, serving every
  module's firmware protocol on its port and publishing ``sim/base_pose`` and
  ``model/shape/simulated``;
- ``driver_<m>``: one driver per module, bridging it to ``<m>/cable_length/*`` topics;
- ``model_node``: forward/inverse services and the commanded/predicted shapes;
- ``gait_node``: the scene's gait, publishing ``<m>/cable_length/command``;
- ``rerun_logger``: records predicted versus commanded shapes to an ``.rrd`` file;
- ``bag_recorder`` (only with ``bag=``): ``bag record --all`` of the robot's ROS domain
  to a rosbag2 directory (:mod:`softsnap_gaits.bag`).

With ``physics=True`` every node but ``sim_robot`` and the bag recorder gets
``use_sim_time: true``: ``sim_robot`` publishes ``/clock``, so the gait, the drivers'
stamps and stall timing, the model and the recording follow simulated time. The bag
recorder keeps the wall clock: it stores each message's receive time from the middleware
(the system clock), as ``ros2 bag record`` does without ``--use-sim-time``, and records
``/clock`` with the rest, so a replay has the simulated time too.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

from softsnap_model.forward import reachable_range
from softsnap_model.scene import Scene

__all__ = ['NodeSpec', 'robot_graph']


@dataclasses.dataclass(frozen=True)
class NodeSpec:
    """One node of the graph: what ``ros2 run`` starts and its ROS parameters.

    `arguments` are the executable's own arguments, before ``--ros-args``.
    """

    package: str
    executable: str
    name: str
    namespace: str
    parameters: dict[str, Any]
    arguments: tuple[str, ...] = ()

    def ros_args(self) -> list[str]:
        """Command-line arguments: ``--ros-args -r __node:=... -r __ns:=... -p k:=v ...``."""
        args = ['--ros-args', '-r', f'__node:={self.name}', '-r', f'__ns:={self.namespace}']
        for key, value in self.parameters.items():
            args += ['-p', f'{key}:={_param_text(value)}']
        return args


def _param_text(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(_param_text(v) for v in value) + ']'
    if isinstance(value, str):
        # Quote strings that YAML would read as another type.
        return value if value and not value.replace('.', '', 1).isdigit() else f"'{value}'"
    return repr(value)


def robot_graph(scene: Scene, *, simulate: bool = True, gait: str | None = None,
                gait_rate_hz: float = 50.0, model_rate_hz: float = 100.0,
                poll_rate_hz: float = 20.0, recording: str | Path | None = None,
                rerun_rate_hz: float = 30.0, rerun: bool = True,
                autostart: bool = True,
                sim_ports: Mapping[str, int] | None = None,
                bag: str | Path | None = None, physics: bool = False,
                sim_robot_parameters: Mapping[str, Any] | None = None) -> list[NodeSpec]:
    """Nodes that run a scene's robot, in start order (modules and drivers first).

    Parameters
    ----------
    scene : Scene
        The robot (modules, threadings, driver addresses, gaits).
    simulate : bool
        Start one simulated module per module on its scene port (loopback).
    gait : str, optional
        Gait name; the scene's default gait if None.
    gait_rate_hz, model_rate_hz, poll_rate_hz, rerun_rate_hz : float
        Command, prediction, status-poll and logging rates, Hz.
    recording : path, optional
        Where the rerun logger writes its ``.rrd`` (its default under runs/ if None).
    rerun : bool
        Include the rerun logger.
    autostart : bool
        Start the gait as soon as the gait node is up.
    sim_ports : mapping, optional
        Loopback port per module name for the simulated modules (and their drivers);
        the scene's ports if None. Ignored with ``simulate=False``. With ``physics``
        they must be consecutive in scene order (``sim_robot`` takes a first port).
    physics : bool
        Simulate the whole robot in MuJoCo with one ``sim_robot`` instead of one
        ``sim_module`` per module (needs ``simulate``); the other nodes (but the bag
        recorder) then run on its ``/clock`` (``use_sim_time: true``).
    sim_robot_parameters : mapping, optional
        Extra ``sim_robot`` parameters (payload, time_factor, ...).
    bag : path, optional
        Record every topic of the ROS domain (but ``/parameter_events``) to this rosbag2
        directory, which must not exist; no recorder if None.
    """
    ns = f'/{scene.name}'
    scene_ref = str(scene.path)
    nodes: list[NodeSpec] = []
    if physics:
        if not simulate:
            raise ValueError('physics needs simulated modules (simulate=True), not real ones')
        nodes.append(_sim_robot_spec(scene, ns, scene_ref, sim_ports, sim_robot_parameters))
    for module in scene.modules:
        host = '127.0.0.1' if simulate else module.host
        port = sim_ports[module.name] if simulate and sim_ports is not None else module.port
        if simulate and not physics:
            nodes.append(NodeSpec('softsnap_driver', 'sim_module', f'sim_{module.name}', ns,
                                  {'host': host, 'port': port}))
        low_mm, straight_mm = reachable_range(scene.skeleton, module.threading_mm)
        # The driver never commands beyond what the model can reach or the scene allows.
        max_contraction_mm = min(module.max_contraction_mm, straight_mm - low_mm)
        nodes.append(NodeSpec('softsnap_driver', 'driver_node', f'driver_{module.name}', ns, {
            'module': module.name, 'host': host, 'port': port,
            'counts_per_mm': float(module.counts_per_mm),
            'straight_length_m': straight_mm / 1000.0,
            'max_contraction_m': max_contraction_mm / 1000.0,
            'poll_rate_hz': float(poll_rate_hz)}))
    nodes.append(NodeSpec('softsnap_model', 'model_node', 'model_node', ns,
                          {'scene': scene_ref, 'rate': float(model_rate_hz)}))
    nodes.append(NodeSpec('softsnap_gaits', 'gait_node', 'gait_node', ns, {
        'scene': scene_ref, 'gait': gait or scene.default_gait, 'rate': float(gait_rate_hz),
        'autostart': bool(autostart)}))
    if rerun:
        params: dict[str, Any] = {'scene': scene_ref, 'rate': float(rerun_rate_hz)}
        if recording is not None:
            params['output'] = str(recording)
        if physics:
            params['world_view'] = True   # the robot moves in the world (sim/base_pose)
        nodes.append(NodeSpec('softsnap_gaits', 'rerun_logger', 'rerun_logger', ns, params))
    if bag is not None:
        # Every topic, not a list: standard topics (markers, joint states, /diagnostics)
        # and any added later are recorded without naming them here.
        nodes.append(NodeSpec('softsnap_gaits', 'bag', 'bag_recorder', ns, {}, arguments=(
            'record', '-o', str(bag), '--all', '--exclude', '^/parameter_events$')))
    if physics:
        on_sim_time = {'driver_node', 'model_node', 'gait_node', 'rerun_logger'}
        nodes = [dataclasses.replace(n, parameters={**n.parameters, 'use_sim_time': True})
                 if n.executable in on_sim_time else n for n in nodes]
    return nodes


def _sim_robot_spec(scene: Scene, ns: str, scene_ref: str, sim_ports: Mapping[str, int] | None,
                    extra: Mapping[str, Any] | None) -> NodeSpec:
    """The one ``sim_robot`` node serving every module of `scene` (consecutive ports)."""
    params: dict[str, Any] = {'scene': scene_ref, 'host': '127.0.0.1', 'port_base': 0}
    if sim_ports is not None:
        ports = [sim_ports[m.name] for m in scene.modules]
        if ports != list(range(ports[0], ports[0] + len(ports))):
            raise ValueError(f'sim_robot serves consecutive ports in scene order, got {ports}')
        params['port_base'] = ports[0]
    params.update(extra or {})
    return NodeSpec('softsnap_driver', 'sim_robot', 'sim_robot', ns, params)
