"""The driver's outgoing ``ModuleState`` and ``CableLength`` as ready CDR bytes (no rclpy).

Why: a driver publishes one ``ModuleState`` (28 fields) and one measured ``CableLength``
per poll. Filling a message object sets every field through rclpy's checking property
setters, and ``publish`` then converts each field back to C before serialising; the
bytes written here by ``struct`` cost a fraction of that (docs/benchmarks.md, "Driver,
fourth pass"). rclpy publishes ``bytes`` as they are. The node checks at start that
rclpy reads these bytes back as the message built field by field
(:func:`fill_module_state` fills one) and publishes message objects if it does not.

Format: plain little-endian CDR (:mod:`.primitives`). The frame id and module name never change for a
driver, so everything up to the first float64 is laid out once.
"""
from __future__ import annotations

import struct
from typing import NamedTuple

from .primitives import ENCAPSULATION_LE as _ENCAPSULATION, F64 as _F64, HEADER_SIZE as _HEADER
from .primitives import STAMP as _STAMP, encode_string as _string

__all__ = ['CableLengthWire', 'ModuleStateFields', 'ModuleStateWire', 'fill_module_state']

# From measured_cable_length (8-aligned) to stops_unconfirmed: f64 f64 i32 i32 u8, 3 bytes
# of padding, f32 f32, four u32, a Time, seven u32. Every field sits at its natural
# alignment once the first float64 does, so the layout is one Struct.
_BODY = struct.Struct('<ddiiB3xffIIIIiIIIIIIII')


class ModuleStateFields(NamedTuple):
    """The fields of one ``ModuleState`` after header and module, in message order.

    Times are (sec, nanosec) pairs; units as in ModuleState.msg (m, counts, V, W).
    """

    online: bool
    paused: bool
    measured_cable_length: float
    target_cable_length: float
    encoder_count: int
    encoder_target: int
    motor_power: int
    battery_voltage: float
    power: float
    encoder_errors: int
    request_failures: int
    commands_received: int
    targets_sent: int
    last_command_stamp: tuple[int, int]
    commands_clamped: int
    commands_refused: int
    reboots_detected: int
    stale_stops: int
    stalls_detected: int
    internal_errors: int
    stops_unconfirmed: int
    last_error: str
    last_error_time: tuple[int, int]


_TIME_FIELDS = ('last_command_stamp', 'last_error_time')


class _Prefix:
    """Encapsulation, stamp slot and frame id, ending where the next field starts."""

    def __init__(self, frame_id: str):
        self.tail = _string(frame_id, _HEADER + 8)
        self.end = _HEADER + 8 + len(self.tail)


class ModuleStateWire:
    """``softsnap_interfaces/ModuleState`` of one module as CDR bytes.

    Parameters
    ----------
    frame_id, module : str
        ``header.frame_id`` and ``module``: fixed for a driver.
    """

    def __init__(self, frame_id: str, module: str):
        prefix = _Prefix(frame_id)
        fixed = prefix.tail + _string(module, prefix.end)
        at = _HEADER + 8 + len(fixed) + 2                      # online, paused: a byte each
        self._middle = fixed                                   # after the stamp
        self._pad = bytes(-(at - _HEADER) % 8)                 # to measured_cable_length
        self._body_end = at + len(self._pad) + _BODY.size
        self._error = ('', _string('', self._body_end))       # last_error, its bytes

    def serialize(self, stamp: tuple[int, int], fields: ModuleStateFields) -> bytes:
        """CDR bytes of the state with ``header.stamp`` ``stamp`` (sec, nanosec)."""
        f = fields
        if f.last_error != self._error[0]:   # an error text changes rarely: encode once
            self._error = (f.last_error, _string(f.last_error, self._body_end))
        command_sec, command_nanosec = f.last_command_stamp
        return b''.join((
            _ENCAPSULATION, _STAMP.pack(*stamp), self._middle,
            b'\x01' if f.online else b'\x00', b'\x01' if f.paused else b'\x00', self._pad,
            _BODY.pack(f.measured_cable_length, f.target_cable_length, f.encoder_count,
                       f.encoder_target, f.motor_power, f.battery_voltage, f.power,
                       f.encoder_errors, f.request_failures, f.commands_received,
                       f.targets_sent, command_sec, command_nanosec, f.commands_clamped,
                       f.commands_refused, f.reboots_detected, f.stale_stops,
                       f.stalls_detected, f.internal_errors, f.stops_unconfirmed),
            self._error[1],
            # last_error_time: the string ends anywhere; a Time is 4-aligned.
            bytes(-(self._body_end + len(self._error[1])) % 4),
            _STAMP.pack(*f.last_error_time)))


class CableLengthWire:
    """``softsnap_interfaces/CableLength`` with a fixed ``header.frame_id`` as CDR bytes."""

    def __init__(self, frame_id: str):
        prefix = _Prefix(frame_id)
        self._middle = prefix.tail + bytes(-(prefix.end - _HEADER) % 8)

    def serialize(self, stamp: tuple[int, int], cable_length_m: float) -> bytes:
        """CDR bytes of a length (m) with ``header.stamp`` ``stamp`` (sec, nanosec)."""
        return b''.join((_ENCAPSULATION, _STAMP.pack(*stamp), self._middle,
                         _F64.pack(cable_length_m)))


def fill_module_state(msg, fields: ModuleStateFields):
    """Set ``msg``'s fields (a ModuleState message object) from ``fields``; returns it.

    The message-object path (the fallback, and the reference the bytes are checked
    against); the header and module are the caller's.
    """
    for name, value in zip(ModuleStateFields._fields, fields):
        if name in _TIME_FIELDS:
            time = getattr(msg, name)
            time.sec, time.nanosec = value
        else:
            setattr(msg, name, value)
    return msg
