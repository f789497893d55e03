"""spin_until_shutdown: an exception racing with a shutdown is the shutdown; others are not.

rclpy shuts the context down from its signal thread; a callback's take failing in
between ended model_node with exit status 1 on an ordinary SIGINT (CI). Real rclpy
contexts and executors; the failing callback stands for the failed take.
"""
from __future__ import annotations

import threading
import time

import pytest

from softsnap_driver.spinning import SHUTDOWN_GRACE_S, spin_until_shutdown


@pytest.fixture
def failing_executor():
    """(executor, context): a node whose timer raises RuntimeError on its first call."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('spinning_probe', context=context, start_parameter_services=False)

    def fail():
        raise RuntimeError('Unable to convert call argument (stand-in for a failed take)')

    node.create_timer(0.05, fail)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield executor, context
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_an_exception_followed_by_the_shutdown_is_the_shutdown(failing_executor):
    executor, context = failing_executor
    # The shutdown lands after the failure (as from rclpy's signal thread), within the grace.
    threading.Timer(0.3, context.shutdown).start()
    started = time.monotonic()
    spin_until_shutdown(executor)          # returns: no exception
    assert not context.ok()
    assert time.monotonic() - started < SHUTDOWN_GRACE_S + 5.0


def test_an_exception_without_a_shutdown_is_raised_after_the_grace(failing_executor):
    executor, context = failing_executor
    started = time.monotonic()
    with pytest.raises(RuntimeError, match='stand-in'):
        spin_until_shutdown(executor)
    assert time.monotonic() - started >= SHUTDOWN_GRACE_S
    assert context.ok()
