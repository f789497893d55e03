"""ROS 2 launch support: the launch files turn :func:`robot_graph` into launch actions.

``ros2 launch softsnap_gaits <scene>.launch.py [simulate:=true] [physics:=true] [gait:=...] [recording:=...] [drivers:=container|separate] [rviz:=true]``
starts the same graph as the demo runner (:mod:`softsnap_gaits.demo`): there is one
description of the graph, in :mod:`softsnap_gaits.graph`. The ``launch`` packages are
imported only when a launch file runs (they are not on PyPI; a ROS 2 install has them).
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from softsnap_model.scene import load_scene

from .graph import DRIVER_MODES, NodeSpec, robot_graph

#: Launch arguments and their defaults (strings, as ros2 launch passes them).
LAUNCH_ARGUMENTS = {
    'simulate': ('true', 'start one simulated module per module (false: real modules)'),
    'physics': ('false', 'simulate the whole robot in MuJoCo with one sim_robot (needs simulate)'),
    'gait': ('', "gait name ('' = the scene's default)"),
    'gait_rate': ('50.0', 'command rate, Hz'),
    'model_rate': ('100.0', 'prediction rate, Hz'),
    'recording': ('', ".rrd path ('' = runs/<robot>-<UTC time>.rrd)"),
    'rerun': ('true', 'start the rerun logger'),
    'drivers': ('container', "container: every driver in one driver_container process; "
                             "separate: one driver_node process per module"),
    'rviz': ('false', 'open RViz 2 on the robot (rviz/<scene>.rviz: RobotModel, TF, markers)'),
    'sim_port_base': ('0', "simulated modules (and their drivers) on consecutive loopback ports "
                           "from this one; 0 = the scene's ports"),
}


def _flag(text: str) -> bool:
    if text.lower() not in ('true', 'false', '1', '0'):
        raise ValueError(f'expected true or false, got {text!r}')
    return text.lower() in ('true', '1')


def graph_from_arguments(scene_name: str, arguments: dict[str, str]) -> list[NodeSpec]:
    """The robot graph for launch-argument strings (defaults from LAUNCH_ARGUMENTS)."""
    args = {key: arguments.get(key, default) for key, (default, _) in LAUNCH_ARGUMENTS.items()}
    scene = load_scene(scene_name)
    base = int(args['sim_port_base'])
    if not (base == 0 or 1024 <= base <= 65535 - len(scene.modules)):
        raise ValueError(f'sim_port_base must be 0 or a port from 1024 to '
                         f'{65535 - len(scene.modules)}, got {base}')
    sim_ports = {m.name: base + i for i, m in enumerate(scene.modules)} if base else None
    if args['drivers'] not in DRIVER_MODES:
        raise ValueError(f"launch argument drivers must be one of {', '.join(DRIVER_MODES)}, "
                         f"got {args['drivers']!r}")
    return robot_graph(scene, simulate=_flag(args['simulate']),
                       gait=args['gait'] or None, gait_rate_hz=float(args['gait_rate']),
                       model_rate_hz=float(args['model_rate']),
                       recording=args['recording'] or None, rerun=_flag(args['rerun']),
                       sim_ports=sim_ports, physics=_flag(args['physics']),
                       drivers=args['drivers'])


def node_action_kwargs(spec: NodeSpec, params_dir: str | Path | None = None) -> dict[str, Any]:
    """Keyword arguments of ``launch_ros.actions.Node`` for one process of the graph.

    `spec.parameters` (the named node's own) are one dict, which launch_ros writes to a
    parameters file keyed by that node's fully qualified name. A process with
    `spec.node_parameters` (a ``driver_container``'s drivers) gets its
    :meth:`~softsnap_gaits.graph.NodeSpec.write_node_params` file as a second entry, a
    ``pathlib.Path`` that launch_ros passes on as ``--params-file`` unchanged: the same
    file the demo runner passes. It is written to `params_dir` (a new temporary
    directory if None, as launch_ros does for dicts).
    """
    parameters: list[Any] = [dict(spec.parameters)]
    if spec.node_parameters:
        directory = params_dir if params_dir is not None else tempfile.mkdtemp(
            prefix='softsnap_launch_params_')
        parameters.append(spec.write_node_params(directory))
    kwargs = {'package': spec.package, 'executable': spec.executable, 'name': spec.name,
              'namespace': spec.namespace, 'parameters': parameters,
              'output': 'screen', 'emulate_tty': True}
    if spec.arguments:
        kwargs['arguments'] = list(spec.arguments)
    return kwargs


def rviz_action_kwargs(scene_name: str) -> dict[str, Any]:
    """``launch_ros.actions.Node`` keyword arguments of RViz 2 with the scene's shipped
    configuration (rviz2 comes with a ROS 2 desktop install, not with the pip wheels)."""
    from ament_index_python.packages import get_package_share_directory
    config = Path(get_package_share_directory('softsnap_gaits')) / 'rviz' / f'{scene_name}.rviz'
    return {'package': 'rviz2', 'executable': 'rviz2', 'name': 'rviz2',
            'arguments': ['-d', str(config)], 'output': 'screen'}


def generate_robot_launch_description(scene_name: str):
    """A LaunchDescription starting the scene's graph (used by launch/<scene>.launch.py)."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch_ros.actions import Node

    def nodes(context):
        arguments = {key: context.launch_configurations.get(key, default)
                     for key, (default, _) in LAUNCH_ARGUMENTS.items()}
        actions = [Node(**node_action_kwargs(spec))
                   for spec in graph_from_arguments(scene_name, arguments)]
        if _flag(arguments['rviz']):
            actions.append(Node(**rviz_action_kwargs(scene_name)))
        return actions

    declared = [DeclareLaunchArgument(key, default_value=default, description=text)
                for key, (default, text) in LAUNCH_ARGUMENTS.items()]
    return LaunchDescription([*declared, OpaqueFunction(function=nodes)])
