"""The process graph of a robot: which nodes run, with which parameters (pure, no ROS).

One description serves both the demo runner (:mod:`softsnap_gaits.demo`, separate OS
processes) and the ROS 2 launch files (``launch/<scene>.launch.py``), so the graph exists
once. For a scene with modules ``m1..mN`` in namespace ``/<scene>``:

- ``sim_<m>``: a simulated module serving the firmware protocol on the module's port
  (only with ``simulate=True``; real modules are reached at the scene's host/port); with
  ``sim_modules='shared'`` one ``sim_modules`` process serves every module on
  consecutive ports instead (large robots: one DDS participant, not one per module);
- or, with ``physics=True``, one ``sim_robot``: the whole robot in MuJoCo, serving every
  module's firmware protocol on its port and publishing ``sim/base_pose`` and
  ``model/shape/simulated``;
- ``<m>_driver``: one driver per module, bridging it to ``<m>/cable_length/*`` topics.
  By default (``drivers='container'``) every driver is a node of one ``driver_container``
  process (node ``driver_container``; it shares a process's fixed cost among the modules,
  docs/driver.md); with ``drivers='separate'`` each is its own ``driver_node`` process.
  The node names, topics, services and parameters are the same in both;
- ``model_node``: forward/inverse services and the commanded/predicted shapes;
- ``robot_state``: the scene's URDF on ``/robot_description``, TF and ``/joint_states``;
- ``gait_node``: the scene's gait, publishing ``<m>/cable_length/command``;
- ``rerun_logger``: records predicted versus commanded shapes to an ``.rrd`` file;
- ``bag_recorder`` (only with ``bag=``): ``bag record`` of the robot's topics (its
  namespace and :data:`ROBOT_ABSOLUTE_TOPICS`; ``bag_all``: the whole ROS domain) to a
  rosbag2 directory (:mod:`softsnap_gaits.bag`).

With ``physics=True`` every node but ``sim_robot`` and the bag recorder gets
``use_sim_time: true`` (a container's drivers each in their own entry of its parameters
file): ``sim_robot`` publishes ``/clock``, so the gait, the drivers' stamps and stall
timing, the model and the recording follow simulated time. The bag
recorder keeps the wall clock: it stores each message's receive time from the middleware
(the system clock), as ``ros2 bag record`` does without ``--use-sim-time``, and records
``/clock`` with the rest, so a replay has the simulated time too.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

from softsnap_driver.scene_calibration import module_calibration
from softsnap_model.scene import Scene

__all__ = ['DRIVER_MODES', 'ROBOT_ABSOLUTE_TOPICS', 'SIM_MODULE_MODES', 'NodeSpec',
           'driver_parameters', 'robot_graph', 'with_driver_parameters']

#: Absolute topics the robot's nodes publish besides those under its namespace (recorded
#: in its bag): TF and the robot model (robot_state), diagnostics, sim_robot's clock, logs.
ROBOT_ABSOLUTE_TOPICS = ('/tf', '/tf_static', '/robot_description', '/joint_states',
                         '/diagnostics', '/clock', '/rosout')

#: Values of ``robot_graph(drivers=...)``: every driver in one ``driver_container``
#: process, or one ``driver_node`` process per module.
DRIVER_MODES = ('container', 'separate')
#: Values of ``robot_graph(sim_modules=...)``: one ``sim_module`` process per simulated
#: module (as a real robot has one ESP32 each), or one process serving them all.
SIM_MODULE_MODES = ('separate', 'shared')


@dataclasses.dataclass(frozen=True)
class NodeSpec:
    """One process of the graph: what ``ros2 run`` starts and its ROS parameters.

    `name` is the node the process is named after (``-r __node:=name``) and `parameters`
    are that node's own (``-p key:=value``). `node_parameters` are parameters of the
    nodes a process creates besides (the drivers of a ``driver_container``, and the
    container's ``modules``), by node name. They go in a parameters file keyed by each
    node's fully qualified name (``/<scene>/yellow_driver: ros__parameters: {...}``,
    :meth:`write_node_params`), which rcl applies to that node alone. A node-specific
    rule on the command line (``-p yellow_driver:port:=8101``) would not do: rcl matches
    its node name against the fully qualified name and accepts no ``/`` in it, so it
    never reaches a node in a namespace. The demo runner passes the file with
    ``--params-file`` (:meth:`ros_args`), the launch files as one more entry of launch_ros's
    ``parameters`` (:func:`softsnap_gaits.launching.node_action_kwargs`), which launch_ros
    also turns into ``--params-file``: a container gets the same parameters either way.
    `arguments` are the executable's own arguments, before ``--ros-args``.
    """

    package: str
    executable: str
    name: str
    namespace: str
    parameters: dict[str, Any]
    arguments: tuple[str, ...] = ()
    node_parameters: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)

    def ros_args(self, params_file: str | Path | None = None) -> list[str]:
        """Command-line arguments: ``--ros-args -r __node:=... -r __ns:=... -p k:=v ...``,
        then ``--params-file params_file`` (the file of :meth:`write_node_params`, required
        when `node_parameters` is not empty; ValueError without it)."""
        args = ['--ros-args', '-r', f'__node:={self.name}', '-r', f'__ns:={self.namespace}']
        for key, value in self.parameters.items():
            args += ['-p', f'{key}:={_param_text(value)}']
        if self.node_parameters:
            if params_file is None:
                raise ValueError(f'{self.name} needs the parameters file of its nodes '
                                 f'{sorted(self.node_parameters)} (write_node_params)')
            args += ['--params-file', str(params_file)]
        return args

    def node_params_yaml(self) -> str:
        """The parameters file of `node_parameters` (YAML text, keys fully qualified)."""
        import yaml
        ns = self.namespace.rstrip('/')
        return yaml.safe_dump({f'{ns}/{node}': {'ros__parameters': dict(params)}
                               for node, params in self.node_parameters.items()},
                              default_flow_style=False, sort_keys=False)

    def write_node_params(self, directory: str | Path) -> Path | None:
        """Write :meth:`node_params_yaml` to ``<directory>/<name>.params.yaml``; its path,
        or None when the process has no `node_parameters`."""
        if not self.node_parameters:
            return None
        path = Path(directory) / f'{self.name}.params.yaml'
        path.write_text(self.node_params_yaml())
        return path


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
                sim_robot_parameters: Mapping[str, Any] | None = None,
                drivers: str = 'container', sim_modules: str = 'separate',
                robot_state: bool = True, bag_all: bool = False) -> list[NodeSpec]:
    """Processes that run a scene's robot, in start order (modules and drivers first).

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
        Record the robot's topics (everything under ``/<scene>`` and
        :data:`ROBOT_ABSOLUTE_TOPICS`) to this rosbag2 directory, which must not exist;
        no recorder if None.
    bag_all : bool
        Record every topic of the ROS domain instead (but ``/parameter_events``).
    drivers : {'container', 'separate'}
        ``'container'``: one ``driver_container`` process drives every module (its drivers'
        parameters in a parameters file, :class:`NodeSpec`); ``'separate'``: one
        ``driver_node`` process per module. Both name module m's driver ``<m>_driver``.
    robot_state : bool
        Include ``robot_state`` (URDF on ``/robot_description``, ``/tf``, ``/tf_static``,
        ``/joint_states``; softsnap_model.robot_state_node).

    Raises
    ------
    ValueError
        `drivers` is not one of :data:`DRIVER_MODES`, `sim_modules` not one of
        :data:`SIM_MODULE_MODES`, or `physics` without `simulate`, or `sim_ports` not
        consecutive with `physics` or shared simulated modules.
    """
    if drivers not in DRIVER_MODES:
        raise ValueError(f"drivers must be one of {', '.join(DRIVER_MODES)}, got {drivers!r}")
    if sim_modules not in SIM_MODULE_MODES:
        raise ValueError(f"sim_modules must be one of {', '.join(SIM_MODULE_MODES)}, "
                         f'got {sim_modules!r}')
    ns = f'/{scene.name}'
    scene_ref = str(scene.path)
    nodes: list[NodeSpec] = []
    driver_params: dict[str, dict[str, Any]] = {}   # by driver node name, in scene order
    if physics:
        if not simulate:
            raise ValueError('physics needs simulated modules (simulate=True), not real ones')
        nodes.append(_sim_robot_spec(scene, ns, scene_ref, sim_ports, sim_robot_parameters))
    shared_sims = simulate and not physics and sim_modules == 'shared'
    if shared_sims:
        nodes.append(_shared_sims_spec(scene, ns, sim_ports))
    for module in scene.modules:
        host = '127.0.0.1' if simulate else module.host
        port = sim_ports[module.name] if simulate and sim_ports is not None else module.port
        if simulate and not physics and not shared_sims:
            nodes.append(NodeSpec('softsnap_driver', 'sim_module', f'sim_{module.name}', ns,
                                  {'host': host, 'port': port}))
        calibration = module_calibration(scene, module)
        driver_params[f'{module.name}_driver'] = {
            'module': module.name, 'host': host, 'port': port,
            'counts_per_mm': calibration.counts_per_mm,
            'straight_length_m': calibration.straight_length_m,
            'max_contraction_m': calibration.max_contraction_m,
            'poll_rate_hz': float(poll_rate_hz)}
        if physics:
            driver_params[f'{module.name}_driver']['use_sim_time'] = True
    if drivers == 'separate':
        nodes += [NodeSpec('softsnap_driver', 'driver_node', name, ns, params)
                  for name, params in driver_params.items()]
    else:
        nodes.append(_container_spec(ns, driver_params))
    nodes.append(NodeSpec('softsnap_model', 'model_node', 'model_node', ns,
                          {'scene': scene_ref, 'rate': float(model_rate_hz)}))
    if robot_state:
        nodes.append(NodeSpec('softsnap_model', 'robot_state', 'robot_state', ns,
                              {'scene': scene_ref}))
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
        # The robot's own topics: its namespace (any topic added later comes along) and the
        # absolute standard topics its nodes publish; an unrelated node on the same ROS
        # domain stays out unless bag_all asks for every topic.
        selection = ('--all',) if bag_all else ('--namespace', ns, *ROBOT_ABSOLUTE_TOPICS)
        nodes.append(NodeSpec('softsnap_gaits', 'bag', 'bag_recorder', ns, {}, arguments=(
            'record', '-o', str(bag), *selection, '--exclude', '^/parameter_events$')))
    if physics:
        on_sim_time = {'model_node', 'gait_node', 'rerun_logger', 'robot_state'}   # drivers have it already
        nodes = [dataclasses.replace(n, parameters={**n.parameters, 'use_sim_time': True})
                 if n.executable in on_sim_time else n for n in nodes]
    return nodes


def _container_spec(ns: str, driver_params: Mapping[str, Mapping[str, Any]]) -> NodeSpec:
    """One ``driver_container`` for the drivers of `driver_params` (by node name).

    The container names module m's driver ``<m>_driver`` and sets its ``module`` itself
    from ``modules``; every other parameter of a driver is in the parameters file under
    that driver's name alone (NodeSpec). Nothing is given globally, so no driver's
    parameter meets a global one of the same name."""
    modules = [params['module'] for params in driver_params.values()]
    nodes: dict[str, dict[str, Any]] = {'driver_container': {'modules': modules}}
    for name, params in driver_params.items():
        nodes[name] = {k: v for k, v in params.items() if k != 'module'}
    return NodeSpec('softsnap_driver', 'driver_container', 'driver_container', ns, {},
                    node_parameters=nodes)


def driver_parameters(nodes: list[NodeSpec]) -> dict[str, dict[str, Any]]:
    """Module name -> its driver's parameters (with ``module``), in either driver mode."""
    out: dict[str, dict[str, Any]] = {}
    for spec in nodes:
        if spec.executable == 'driver_node':
            out[spec.parameters['module']] = dict(spec.parameters)
        elif spec.executable == 'driver_container':
            for module in spec.node_parameters['driver_container']['modules']:
                out[module] = {'module': module, **spec.node_parameters[f'{module}_driver']}
    return out


def with_driver_parameters(nodes: list[NodeSpec], **parameters: Any) -> list[NodeSpec]:
    """`nodes` with `parameters` added to every driver's, in either driver mode (e.g.
    ``command_timeout_s=0.0`` for a test that sends single commands)."""
    out = []
    for spec in nodes:
        if spec.executable == 'driver_node':
            spec = dataclasses.replace(spec, parameters={**spec.parameters, **parameters})
        elif spec.executable == 'driver_container':
            spec = dataclasses.replace(spec, node_parameters={
                node: params if node == 'driver_container' else {**params, **parameters}
                for node, params in spec.node_parameters.items()})
        out.append(spec)
    return out


def _consecutive_ports(scene: Scene, sim_ports: Mapping[str, int] | None, who: str) -> int:
    """The first of the modules' ports, which `who` serves consecutively in scene order."""
    ports = [sim_ports[m.name] if sim_ports is not None else m.port for m in scene.modules]
    if ports != list(range(ports[0], ports[0] + len(ports))):
        raise ValueError(f'{who} serves consecutive ports in scene order, got {ports}')
    return ports[0]


def _shared_sims_spec(scene: Scene, ns: str, sim_ports: Mapping[str, int] | None) -> NodeSpec:
    """One ``sim_module`` process (node ``sim_modules``) serving every module of `scene`."""
    first = _consecutive_ports(scene, sim_ports, 'a shared sim_module')
    return NodeSpec('softsnap_driver', 'sim_module', 'sim_modules', ns,
                    {'host': '127.0.0.1', 'port': first, 'count': len(scene.modules)})


def _sim_robot_spec(scene: Scene, ns: str, scene_ref: str, sim_ports: Mapping[str, int] | None,
                    extra: Mapping[str, Any] | None) -> NodeSpec:
    """The one ``sim_robot`` node serving every module of `scene` (consecutive ports)."""
    params: dict[str, Any] = {'scene': scene_ref, 'host': '127.0.0.1', 'port_base': 0}
    if sim_ports is not None:
        params['port_base'] = _consecutive_ports(scene, sim_ports, 'sim_robot')
    params.update(extra or {})
    return NodeSpec('softsnap_driver', 'sim_robot', 'sim_robot', ns, params)
