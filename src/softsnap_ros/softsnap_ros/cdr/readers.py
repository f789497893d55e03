"""Read this project's messages straight from their serialised (CDR) bytes (no rclpy).

rclpy's own deserialisation builds a Python object for every field (12
``geometry_msgs/Point`` objects per module of a RobotShape, a Header and a Time for every
CableLength), and that was most of the CPU of the nodes that take them at 50-100 Hz.
Readers here, for messages taken raw (``take_message(..., raw=True)``):

- :func:`decode_cable_length`: the driver's commands, the model node's lengths and the
  rerun logger's lengths;
- :func:`decode_robot_shape` and :func:`decode_module_state`: the rerun logger and the
  demo's observer.

Only ``CableLength`` is read in both byte orders; anything else (XCDR2, a truncated
buffer) raises `CdrError`; :mod:`.fallback` then lets rclpy read it. The format is in
:mod:`.primitives`; ``test/ros_plumbing/test_cdr.py`` checks every field against rclpy's
deserialisation of the same bytes, over real DDS too.
"""
from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

from softsnap_ros.units import NS_PER_S, stamp_ns

from .primitives import F32 as _F32, F64 as _F64, HEADER_SIZE, STAMP as _STAMP, U32 as _U32
from .primitives import REPRESENTATION_LE, CdrError

# tension, energy (f64, f64), converged (bool as one byte); residual and solve_time follow.
_TENSION_ENERGY_CONVERGED = struct.Struct('<ddB')
_RESIDUAL_SOLVE_TIME = struct.Struct('<dd')
_F64_DTYPE = np.dtype('<f8')
_NO_VALUES = np.empty(0)
_NO_VALUES.flags.writeable = False



# Named tuples, not frozen dataclasses: they are made ~600 times a second, and a tuple is
# built in C while a frozen dataclass sets each field through object.__setattr__.
class ModuleShapeCdr(NamedTuple):
    """One ``ModuleShape`` as decoded from CDR; arrays are read-only views of the buffer."""

    stamp_ns: int
    frame_id: str
    module: str
    source: str
    cable_length: float        # m
    angles: np.ndarray         # (n,) rad
    rib_centers: np.ndarray    # (k, 3) m, k = 0 when the shape carries none
    tension: float             # rad^2/m
    energy: float              # rad^2
    converged: bool
    residual: float
    solve_time: float          # s


class RobotShapeCdr(NamedTuple):
    """One ``RobotShape`` as decoded from CDR. ``base_poses`` is (m, 7): position x y z
    (m), then orientation x y z w, one row per pose."""

    stamp_ns: int
    frame_id: str
    robot: str
    modules: tuple[ModuleShapeCdr, ...]
    base_poses: np.ndarray


# Offsets below are absolute (encapsulation header included). The header is 4 bytes, so
# 4-byte alignment of the body is `-pos % 4`; 8-byte alignment is `-(pos - 4) % 8`.

def _string(buf: bytes, pos: int, what: str) -> tuple[str, int]:
    pos += -pos % 4
    (size,) = _U32.unpack_from(buf, pos)
    pos += 4
    if size == 0:  # some writers send an empty string without its NUL
        return '', pos
    end = pos + size
    if end > len(buf):
        raise CdrError(f'message truncated: {what} needs {size} bytes at byte {pos}, '
                       f'{len(buf) - pos} left')
    if buf[end - 1] != 0:
        raise CdrError(f'{what}: string of {size} bytes at byte {pos} does not end in NUL')
    return buf[pos:end - 1].decode('utf-8'), end


def _doubles(buf: bytes, pos: int, count: int) -> tuple[np.ndarray, int]:
    """``count`` float64 at the next 8-aligned offset (no padding when count is 0)."""
    if count == 0:
        return _NO_VALUES, pos
    pos += -(pos - HEADER_SIZE) % 8
    return np.frombuffer(buf, _F64_DTYPE, count, pos), pos + 8 * count


def _module_shape(buf: bytes, pos: int) -> tuple[ModuleShapeCdr, int]:
    pos += -pos % 4
    sec, nanosec = _STAMP.unpack_from(buf, pos)
    frame_id, pos = _string(buf, pos + 8, 'header.frame_id')
    module, pos = _string(buf, pos, 'module')
    source, pos = _string(buf, pos, 'source')
    pos += -(pos - HEADER_SIZE) % 8
    (cable_length,) = _F64.unpack_from(buf, pos)
    (count,) = _U32.unpack_from(buf, pos + 8)  # 8-aligned, so 4-aligned
    angles, pos = _doubles(buf, pos + 12, count)
    pos += -pos % 4
    (count,) = _U32.unpack_from(buf, pos)
    centres, pos = _doubles(buf, pos + 4, 3 * count)
    pos += -(pos - HEADER_SIZE) % 8
    tension, energy, converged = _TENSION_ENERGY_CONVERGED.unpack_from(buf, pos)
    if converged > 1:
        raise CdrError(f'converged: a bool is 0 or 1, got {converged}')
    pos += 17
    pos += -(pos - HEADER_SIZE) % 8
    residual, solve_time = _RESIDUAL_SOLVE_TIME.unpack_from(buf, pos)
    return ModuleShapeCdr(sec * NS_PER_S + nanosec, frame_id, module, source,
                          cable_length, angles, centres.reshape(count, 3), tension, energy,
                          converged == 1, residual, solve_time), pos + 16


def decode_robot_shape(buf: bytes) -> RobotShapeCdr:
    """A ``RobotShape`` from its serialised bytes (what a raw subscription delivers).

    Raises `CdrError` (a ValueError) for bytes this reader does not handle; every field
    equals what rclpy's ``deserialize_message`` gives for the same bytes. Bytes after
    the last field (rmw leaves up to 8) are ignored.
    """
    buf = bytes(buf)
    _check_header(buf)
    where = 'header'
    pos = HEADER_SIZE
    try:
        sec, nanosec = _STAMP.unpack_from(buf, pos)
        frame_id, pos = _string(buf, pos + 8, 'header.frame_id')
        where = 'robot'
        robot, pos = _string(buf, pos, 'robot')
        pos += -pos % 4
        (count,) = _U32.unpack_from(buf, pos)
        pos += 4
        modules = []
        for i in range(count):
            where = i
            module, pos = _module_shape(buf, pos)
            modules.append(module)
        where = 'base_poses'
        pos += -pos % 4
        (count,) = _U32.unpack_from(buf, pos)
        poses, pos = _doubles(buf, pos + 4, 7 * count)
    except CdrError as exc:  # name the module; a top-level field names itself
        if isinstance(where, int):
            raise CdrError(f'{_where(where)}.{exc}') from None
        raise
    except (struct.error, ValueError) as exc:  # ValueError: numpy's short buffer, bad UTF-8
        raise CdrError(f'{_where(where)}: message truncated or malformed at byte {pos}: '
                       f'{exc}') from None
    return RobotShapeCdr(sec * NS_PER_S + nanosec, frame_id, robot, tuple(modules),
                         poses.reshape(count, 7))


# CableLength: header (stamp, frame_id), cable_length (f64, m).
# ModuleState: header, module (string), online, paused (bool), measured_cable_length,
# target_cable_length (f64), encoder_count, encoder_target (i32), motor_power (u8),
# battery_voltage (f32, V), then fields the logger does not read.


def _check_header(buf: bytes) -> None:
    if len(buf) < HEADER_SIZE:
        raise CdrError(f'a CDR message needs a {HEADER_SIZE}-byte header, got {len(buf)} bytes')
    if buf[:2] != REPRESENTATION_LE:
        raise CdrError('only little-endian plain CDR (representation 0x0001) is read, '
                       f'got representation 0x{buf[:2].hex()}')


#: XCDR1 encapsulation ids (the first two bytes) by byte order, for CableLength.
_CABLE_LENGTH_LAYOUT = {
    b'\x00\x01': (struct.Struct('<iII'), struct.Struct('<d')),   # little-endian
    b'\x00\x00': (struct.Struct('>iII'), struct.Struct('>d')),   # big-endian
}


def decode_cable_length(buf: bytes) -> tuple[int, float]:
    """(header stamp in ns, cable_length in m) of a serialised ``CableLength``.

    Layout: int32 ``sec``, uint32 ``nanosec``, uint32 length of ``frame_id`` with its
    NUL, its bytes, padding to a multiple of 8, float64 ``cable_length``. The frame id is
    skipped, not decoded: this runs for every command and length message.
    """
    layout = _CABLE_LENGTH_LAYOUT.get(bytes(buf[:2]))
    if layout is None:
        raise CdrError('only plain CDR (representation 0x0001 or 0x0000) is read, '
                       f'got representation 0x{bytes(buf[:2]).hex()}')
    header, value = layout
    if len(buf) < HEADER_SIZE + 12:
        raise CdrError(f'CableLength truncated: {len(buf)} bytes')
    sec, nanosec, text = header.unpack_from(buf, HEADER_SIZE)
    at = HEADER_SIZE + ((12 + text + 7) & ~7)
    if text < 1 or at + 8 > len(buf):
        raise CdrError(f'CableLength truncated or malformed: a frame_id of {text} bytes '
                       f'in {len(buf)} bytes')
    return sec * NS_PER_S + nanosec, value.unpack_from(buf, at)[0]


def decode_module_state(buf: bytes) -> tuple[int, str, float]:
    """(header stamp in ns, module, battery_voltage in V) of a serialised ``ModuleState``:
    the fields the logger records; the rest of the message is not read."""
    _check_header(buf)
    try:
        sec, nanosec = _STAMP.unpack_from(buf, HEADER_SIZE)
        _, pos = _string(buf, HEADER_SIZE + 8, 'header.frame_id')
        module, pos = _string(buf, pos, 'module')
        pos += 2  # online, paused: one byte each
        pos += -(pos - HEADER_SIZE) % 8
        # two f64 (16 bytes), two i32 (8), one u8 padded to 4: the f32 is 28 bytes on.
        (battery,) = _F32.unpack_from(buf, pos + 28)
    except (struct.error, ValueError) as exc:  # ValueError: bad UTF-8
        raise CdrError(f'ModuleState truncated or malformed: {exc}') from None
    return sec * NS_PER_S + nanosec, module, battery


def _where(where) -> str:
    return f'modules[{where}]' if isinstance(where, int) else where

def from_message(msg) -> RobotShapeCdr:
    """The same structure from a deserialised RobotShape (the fallback for bytes
    `decode_robot_shape` refuses), so callers handle one kind of shape."""
    def stamp_of(header) -> int:
        return stamp_ns(header.stamp)

    modules = tuple(
        ModuleShapeCdr(stamp_of(s.header), s.header.frame_id, s.module, s.source,
                       s.cable_length, np.asarray(s.angles, dtype=float),
                       np.array([(p.x, p.y, p.z) for p in s.rib_centers],
                                dtype=float).reshape(-1, 3),
                       s.tension, s.energy, s.converged, s.residual, s.solve_time)
        for s in msg.modules)
    poses = np.array([(p.position.x, p.position.y, p.position.z, p.orientation.x,
                       p.orientation.y, p.orientation.z, p.orientation.w)
                      for p in msg.base_poses], dtype=float).reshape(-1, 7)
    return RobotShapeCdr(stamp_of(msg.header), msg.header.frame_id, msg.robot, modules, poses)
