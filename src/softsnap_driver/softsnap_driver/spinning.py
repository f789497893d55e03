"""Spin a node's executor until Ctrl-C, SIGTERM or an external shutdown, for every main().

rclpy's signal handler shuts the context down on SIGINT. When that happens while the
executor is between two waits, rclpy raises ``RCLError`` ("the given context is not
valid") instead of ``ExternalShutdownException``; a ``main`` catching only the latter
then dies with a traceback and exit status 1 on an ordinary Ctrl-C (seen with the rerun
logger). Here any exception raised once the context is no longer ok is that shutdown.
"""
from __future__ import annotations

from rclpy.executors import Executor, ExternalShutdownException


def spin_until_shutdown(executor: Executor) -> None:
    """``executor.spin()``; returns normally when the context was shut down."""
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if executor.context.ok():
            raise  # a real failure, not a shutdown
