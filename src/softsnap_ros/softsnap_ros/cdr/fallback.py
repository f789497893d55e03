"""Our messages from their bytes with rclpy as the fallback, and the start-up self-check.

The readers of :mod:`.readers` take plain little-endian CDR only; bytes in another
encoding (big-endian, XCDR2) are then read by rclpy's ``deserialize_message``: slower,
never wrong. Bytes rclpy refuses too raise (a ``CdrError`` or rclpy's own error): one
unreadable message is the caller's to log and skip.

:func:`check_wire` is what a node runs once at start before it publishes ready-made
bytes: if rclpy does not read them back as the message built field by field (another
middleware's encoding), the node publishes message objects instead: CPU, not
correctness.
"""
from __future__ import annotations

from typing import Callable, Iterable

from softsnap_ros.units import stamp_ns

from .primitives import CdrError
from .readers import (RobotShapeCdr, decode_cable_length, decode_module_state,
                      decode_robot_shape, from_message)

__all__ = ['WireMismatch', 'check_wire', 'read_cable_length', 'read_module_state',
           'read_robot_shape']

#: Told the message type each time rclpy had to read bytes our readers refused.
OnFallback = Callable[[type], None] | None


class WireMismatch(ValueError):
    """Our wire format and this middleware's disagree (the message says where)."""


def _rclpy_reads(data: bytes, msg_type, on_fallback: OnFallback):
    from rclpy.serialization import deserialize_message
    if on_fallback is not None:
        on_fallback(msg_type)
    return deserialize_message(data, msg_type)


def read_cable_length(data: bytes, on_fallback: OnFallback = None) -> tuple[int, float]:
    """(header stamp in ns, cable_length in m) of a serialised ``CableLength``."""
    try:
        return decode_cable_length(data)
    except CdrError:
        from softsnap_interfaces.msg import CableLength
        msg = _rclpy_reads(data, CableLength, on_fallback)
        return stamp_ns(msg.header.stamp), msg.cable_length


def read_robot_shape(data: bytes, on_fallback: OnFallback = None) -> RobotShapeCdr:
    """A serialised ``RobotShape`` as :class:`RobotShapeCdr` (whichever path read it)."""
    try:
        return decode_robot_shape(data)
    except CdrError:
        from softsnap_interfaces.msg import RobotShape
        return from_message(_rclpy_reads(data, RobotShape, on_fallback))


def read_module_state(data: bytes, on_fallback: OnFallback = None) -> tuple[int, str, float]:
    """(header stamp in ns, module, battery_voltage in V) of a serialised ``ModuleState``."""
    try:
        return decode_module_state(data)
    except CdrError:
        from softsnap_interfaces.msg import ModuleState
        msg = _rclpy_reads(data, ModuleState, on_fallback)
        return stamp_ns(msg.header.stamp), msg.module, msg.battery_voltage


def check_wire(written: Iterable[tuple[bytes, object]] = (),
               read: Iterable[tuple[Callable[[bytes], object], object, object]] = ()) -> None:
    """Raise `WireMismatch` unless rclpy and our codec agree on these samples.

    ``written``: (our bytes, the message built field by field): rclpy must read the bytes
    back as that message. ``read``: (our decoder, a message, what the decoder must return
    for rclpy's bytes of that message).
    """
    from rclpy.serialization import deserialize_message, serialize_message
    for data, want in written:
        got = deserialize_message(data, type(want))
        if got != want:
            raise WireMismatch(f'{type(want).__name__} read back as {got}')
    for decode, msg, expected in read:
        got = decode(serialize_message(msg))
        if got != expected:
            raise WireMismatch(f'{type(msg).__name__} decoded as {got}, expected {expected}')

