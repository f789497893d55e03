"""Decode a serialised ``softsnap_interfaces/RobotShape`` straight from its CDR bytes.

The rerun logger takes the shape topics raw (``create_subscription(..., raw=True)``)
because rclpy's own deserialisation builds a Python object for every field, with 12
``geometry_msgs/Point`` objects per module, and that was most of the logger's CPU. This
module reads exactly the RobotShape / ModuleShape layout with ``struct`` and numpy views
of the buffer instead; it imports no rclpy.

The wire format is plain CDR (XCDR1, what rmw_fastrtps and rmw_cyclonedds send for ROS
types), little-endian: a 4-byte encapsulation header (representation 0x0001), then the
fields in message order, each primitive aligned to its own size counted from the end of
that header; a string is a uint32 length (NUL included), the bytes and the NUL; a
sequence is a uint32 count and its elements, the first element aligned to its type (no
padding for an empty sequence). Anything else (big-endian, XCDR2, a truncated buffer)
raises `CdrError` so the caller can fall back to rclpy's ``deserialize_message``.
``test/gaits/test_shape_cdr.py`` checks every field against rclpy's deserialisation of
the same bytes, over real DDS too.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

#: Encapsulation header of little-endian plain CDR (representation id 0x0001, options 0).
CDR_LE = b'\x00\x01'
HEADER_SIZE = 4

_U32 = struct.Struct('<I')
_STAMP = struct.Struct('<iI')  # builtin_interfaces/Time: sec, nanosec
_F64 = struct.Struct('<d')
# tension, energy (f64, f64), converged (bool as one byte); residual and solve_time follow.
_TENSION_ENERGY_CONVERGED = struct.Struct('<ddB')
_RESIDUAL_SOLVE_TIME = struct.Struct('<dd')
_F64_DTYPE = np.dtype('<f8')


class CdrError(ValueError):
    """The bytes are not a RobotShape in little-endian plain CDR (the reason says why)."""


@dataclass(frozen=True)
class ModuleShapeCdr:
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


@dataclass(frozen=True)
class RobotShapeCdr:
    """One ``RobotShape`` as decoded from CDR. ``base_poses`` is (m, 7): position x y z
    (m), then orientation x y z w, one row per pose."""

    stamp_ns: int
    frame_id: str
    robot: str
    modules: tuple[ModuleShapeCdr, ...]
    base_poses: np.ndarray


class _Reader:
    """A cursor over one CDR body; offsets count from the end of the encapsulation header."""

    __slots__ = ('buf', 'pos', 'end')

    def __init__(self, buf: bytes):
        if len(buf) < HEADER_SIZE:
            raise CdrError(f'a CDR message needs a {HEADER_SIZE}-byte header, got {len(buf)} bytes')
        if buf[:2] != CDR_LE:
            raise CdrError(f'only little-endian plain CDR (representation 0x0001) is read, '
                           f'got representation 0x{buf[:2].hex()}')
        self.buf = buf
        self.pos = HEADER_SIZE
        self.end = len(buf)

    def _need(self, size: int, what: str) -> int:
        start = self.pos
        if start + size > self.end:
            raise CdrError(f'message truncated: {what} needs {size} bytes at offset '
                           f'{start - HEADER_SIZE}, {self.end - start} left')
        self.pos = start + size
        return start

    def align(self, size: int) -> None:
        self.pos += -(self.pos - HEADER_SIZE) % size

    def u32(self, what: str) -> int:
        self.align(4)
        return _U32.unpack_from(self.buf, self._need(4, what))[0]

    def stamp_ns(self) -> int:
        self.align(4)
        sec, nanosec = _STAMP.unpack_from(self.buf, self._need(8, 'a stamp'))
        return sec * 1_000_000_000 + nanosec

    def string(self, what: str) -> str:
        size = self.u32(what)
        if size == 0:  # some writers send an empty string without its NUL
            return ''
        start = self._need(size, what)
        if self.buf[start + size - 1] != 0:
            raise CdrError(f'{what}: string of {size} bytes at offset {start - HEADER_SIZE} '
                           'does not end in NUL')
        return self.buf[start:start + size - 1].decode('utf-8')

    def f64(self, what: str) -> float:
        self.align(8)
        return _F64.unpack_from(self.buf, self._need(8, what))[0]

    def f64_array(self, count: int, what: str) -> np.ndarray:
        """``count`` float64 at the next 8-aligned offset (no padding when count is 0)."""
        if count == 0:
            return np.empty(0)
        self.align(8)
        start = self._need(8 * count, what)
        return np.frombuffer(self.buf, _F64_DTYPE, count, start)


def decode_robot_shape(buf: bytes) -> RobotShapeCdr:
    """A ``RobotShape`` from its serialised bytes (what a raw subscription delivers).

    Raises `CdrError` (a ValueError) for bytes this reader does not handle; every field
    equals what rclpy's ``deserialize_message`` gives for the same bytes.
    """
    reader = _Reader(bytes(buf))
    stamp = reader.stamp_ns()
    frame_id = reader.string('header.frame_id')
    robot = reader.string('robot')
    modules = tuple(_module_shape(reader, i) for i in range(reader.u32('modules count')))
    n_poses = reader.u32('base_poses count')
    poses = reader.f64_array(7 * n_poses, 'base_poses').reshape(n_poses, 7)
    return RobotShapeCdr(stamp, frame_id, robot, modules, poses)


def _module_shape(reader: _Reader, index: int) -> ModuleShapeCdr:
    what = f'modules[{index}]'
    stamp = reader.stamp_ns()
    frame_id = reader.string(f'{what}.header.frame_id')
    module = reader.string(f'{what}.module')
    source = reader.string(f'{what}.source')
    cable_length = reader.f64(f'{what}.cable_length')
    angles = reader.f64_array(reader.u32(f'{what}.angles count'), f'{what}.angles')
    n_centres = reader.u32(f'{what}.rib_centers count')
    centres = reader.f64_array(3 * n_centres, f'{what}.rib_centers').reshape(n_centres, 3)
    reader.align(8)
    tension, energy, converged = _TENSION_ENERGY_CONVERGED.unpack_from(
        reader.buf, reader._need(17, f'{what}.tension'))
    if converged > 1:
        raise CdrError(f'{what}.converged: a bool is 0 or 1, got {converged}')
    reader.align(8)
    residual, solve_time = _RESIDUAL_SOLVE_TIME.unpack_from(
        reader.buf, reader._need(16, f'{what}.residual'))
    return ModuleShapeCdr(stamp, frame_id, module, source, cable_length, angles, centres,
                          tension, energy, bool(converged), residual, solve_time)


def from_message(msg) -> RobotShapeCdr:
    """The same structure from a deserialised RobotShape (the fallback for bytes
    `decode_robot_shape` refuses), so callers handle one kind of shape."""
    def stamp_of(header) -> int:
        return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec

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
