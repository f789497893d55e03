"""The one ``--ros-args`` hand-over of executables that also run without ROS.

``sim_module`` and ``sim_robot`` are plain programs (no rclpy import, so a simulator runs
where ROS is not installed); ``ros2 run`` and ``launch_ros`` start them with
``--ros-args``, and then their node module runs instead, with rclpy imported only then.
This module imports nothing of ROS.
"""
from __future__ import annotations

import importlib
import sys


def run_node_if_ros_args(argv: list[str], node_module: str) -> int | None:
    """If ``argv`` (without the program name) holds ``--ros-args``, run
    ``node_module.main`` with the full command line and return its exit status; else None
    (the caller goes on as a plain program)."""
    if '--ros-args' not in argv:
        return None
    return importlib.import_module(node_module).main([sys.argv[0], *argv])
