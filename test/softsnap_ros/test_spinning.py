"""spin_until_shutdown: an exception racing with a shutdown is the shutdown; others are not;
a Ctrl-C returns only once rclpy's signal thread has shut the context down.

rclpy shuts the context down from its signal thread; a callback's take failing in
between ended model_node with exit status 1 on an ordinary SIGINT (CI). Real rclpy
contexts and executors; the failing callback stands for the failed take, the timer
that shuts the context down for rclpy's signal thread.
"""
from __future__ import annotations

import threading
import time

import pytest

from softsnap_ros.spinning import SHUTDOWN_GRACE_S, spin_until_shutdown


def _executor_raising(exception: BaseException):
    """Yields (executor, context) of a node whose timer raises ``exception`` on its first
    call, then closes them (both fixtures' body)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('spinning_probe', context=context, start_parameter_services=False)

    def fail():
        raise exception

    node.create_timer(0.05, fail)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield executor, context
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)


@pytest.fixture
def failing_executor():
    """(executor, context): a node whose timer raises RuntimeError on its first call."""
    yield from _executor_raising(
        RuntimeError('Unable to convert call argument (stand-in for a failed take)'))


@pytest.fixture
def interrupted_executor():
    """(executor, context): a node whose timer raises KeyboardInterrupt (a Ctrl-C) on its
    first call; rclpy's signal handlers are put back as they were afterwards."""
    from rclpy.signals import (get_current_signal_handlers_options, install_signal_handlers,
                               uninstall_signal_handlers)

    before = get_current_signal_handlers_options()
    yield from _executor_raising(KeyboardInterrupt())
    uninstall_signal_handlers()     # installing only adds handlers
    install_signal_handlers(before)


def test_a_ctrl_c_returns_once_the_signal_thread_has_shut_the_context_down(interrupted_executor):
    """Regression: the executor's signal guard condition was destroyed while rclpy's
    signal thread could still be triggering it (driver_container SIGSEGV on SIGINT, CI)."""
    from rclpy.signals import SignalHandlerOptions, install_signal_handlers

    executor, context = interrupted_executor
    install_signal_handlers(SignalHandlerOptions.SIGINT)
    threading.Timer(0.3, context.shutdown).start()
    started = time.monotonic()
    spin_until_shutdown(executor)           # KeyboardInterrupt: no exception
    assert time.monotonic() - started >= 0.25
    assert not context.ok()


def test_a_ctrl_c_without_rclpy_handlers_returns_at_once(interrupted_executor):
    """With rclpy's SIGINT handler not installed no shutdown follows: nothing to wait for."""
    from rclpy.signals import uninstall_signal_handlers

    executor, context = interrupted_executor
    uninstall_signal_handlers()
    started = time.monotonic()
    spin_until_shutdown(executor)
    assert time.monotonic() - started < SHUTDOWN_GRACE_S
    assert context.ok()


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
