"""The command thread (CommandInbox) in the test process, over real DDS.

Between commands it sleeps in rcl_wait for up to COMMAND_IDLE_WAIT_S; a stop, a route
added and rclpy.shutdown() wake it at once through its guard condition. Here the idle
wait is made a minute long, so a thread that was not woken would outlive the generous
joins.
"""
from __future__ import annotations

import contextlib
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from softsnap_interfaces.msg import CableLength  # noqa: E402

from softsnap_driver import driver_node  # noqa: E402
from softsnap_driver.driver_node import CommandInbox  # noqa: E402
from softsnap_ros.spinning import inbox_node  # noqa: E402

NS = '/inbox_test'


def _inbox_delivering(context, name: str):
    """An inbox on a node of its own in ``context``, one route, and a publisher on that
    route's topic; returns (inbox node, inbox, publisher node, publisher, delivered)."""
    node = inbox_node(f'{name}_inbox', NS, context)
    inbox = CommandInbox(node)
    delivered = []
    inbox.subscribe('m1/cable_length/command', 10,
                    lambda length_m, stamp_ns: delivered.append((length_m, stamp_ns)),
                    node.get_logger())
    sender = rclpy.create_node(f'{name}_sender', namespace=NS, context=context)
    publisher = sender.create_publisher(CableLength, 'm1/cable_length/command', 10)
    return node, inbox, sender, publisher, delivered


def _deliver_one(publisher, delivered, length_m: float, timeout_s: float = 30.0) -> None:
    """Publish ``length_m`` until the inbox has delivered it (discovery takes a while)."""
    msg = CableLength(cable_length=length_m)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 7, 8
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not delivered:
        publisher.publish(msg)
        time.sleep(0.1)
    assert delivered, f'no command delivered within {timeout_s:g} s'
    assert delivered[0] == (pytest.approx(length_m), 7_000_000_008)


@contextlib.contextmanager
def _asleep_after_a_command(monkeypatch, name: str, length_m: float):
    """An inbox in a context of its own whose command thread has delivered one command
    and is asleep again in a minute-long wait; yields (context, inbox node, inbox,
    sender node). Nodes and context are closed after (if the test has not)."""
    monkeypatch.setattr(driver_node, 'COMMAND_IDLE_WAIT_S', 60.0)
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node, inbox, sender, publisher, delivered = _inbox_delivering(context, name)
        _deliver_one(publisher, delivered, length_m)
        time.sleep(0.2)                 # asleep again in its (minute-long) wait
        yield context, node, inbox, sender
        if context.ok():
            sender.destroy_node()
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_a_stop_wakes_the_sleeping_command_thread_at_once(monkeypatch):
    with _asleep_after_a_command(monkeypatch, 'stop', 0.1875) as (_, _, inbox, _):
        inbox.stop(20.0)
        assert not inbox._thread.is_alive(), 'the stop did not wake the command thread'


def test_the_context_shutdown_wakes_and_ends_the_command_thread(monkeypatch):
    with _asleep_after_a_command(monkeypatch, 'shutdown', 0.125) as (context, _, inbox, _):
        rclpy.shutdown(context=context)     # an explicit shutdown, before any stop
        inbox._thread.join(20.0)
        assert not inbox._thread.is_alive(), 'the shutdown did not wake the command thread'


def test_a_route_added_while_the_thread_sleeps_gets_its_commands_at_once(monkeypatch):
    # driver_container subscribes its modules one by one: the thread is already asleep
    # on the first module's route when the others are added.
    with _asleep_after_a_command(monkeypatch, 'added', 0.15) as (_, node, inbox, sender):
        second = []
        inbox.subscribe('m2/cable_length/command', 10,
                        lambda length_m, stamp_ns: second.append((length_m, stamp_ns)),
                        node.get_logger())
        publisher = sender.create_publisher(CableLength, 'm2/cable_length/command', 10)
        _deliver_one(publisher, second, 0.0625, timeout_s=20.0)
        inbox.stop(20.0)
        assert not inbox._thread.is_alive()
