"""Shape messages kept as ready-serialised CDR bytes, updated in place (no rclpy).

Why: at 100 Hz the model node publishes two ``RobotShape`` messages per tick. Built as
Python message objects (one ``ModuleShape`` and 12 ``geometry_msgs/Point`` per module)
and serialised by rclpy, a 50-module ``RobotShape`` cost 1.6 ms of CPU per publish on
the development machine, against 0.2 ms for publishing the same message as bytes. A
message's layout only changes when a module gains or loses its shape or its rib
centres, so it is laid out once (:class:`RobotShapeWire`, :class:`ModuleShapeWire`)
and each new shape is written into its place: its scalars with ``struct``, the arrays of
all new shapes together through one float64 view of the buffer.

Format: plain little-endian CDR (:mod:`.primitives`). The model node checks at start
(:func:`.fallback.check_wire`) that rclpy deserialises these bytes to the same message as
one built field by field, and uses message objects instead if it does not.

Units follow the messages (SI): lengths in m, rib centres converted from the core's
mm here; stamps in ns are split into (sec, nanosec). The readers of the same format are
in :mod:`.readers`.
"""
from __future__ import annotations

import struct

import numpy as np

from softsnap_ros.units import MM_PER_M, sec_nanosec as _split_ns

from .primitives import ENCAPSULATION_LE as CDR_LE, F64 as _F64, STAMP as _STAMP, U32 as _U32

__all__ = ['ModuleShapeWire', 'RobotShapeWire']

#: Sets of changed modules whose array indices are kept per layout (a robot's ticks
#: repeat a few: usually all modules, or one group of a gait).
INDEX_SETS_KEPT = 64

#: tension, energy (f64), converged (bool), padding to 8, residual, solve_time (f64).
_TAIL = struct.Struct('<ddB7xdd')


class _Writer:
    """Appends CDR primitives to a buffer; returns each one's byte offset in it."""

    def __init__(self):
        self.buf = bytearray(CDR_LE)

    def _align(self, size: int) -> int:
        self.buf += bytes(-(len(self.buf) - len(CDR_LE)) % size)
        return len(self.buf)

    def u32(self, value: int) -> int:
        at = self._align(4)
        self.buf += _U32.pack(value)
        return at

    def stamp(self, stamp_ns: int) -> int:
        at = self._align(4)
        self.buf += _STAMP.pack(*_split_ns(stamp_ns))
        return at

    def f64(self, count: int = 1) -> int:
        at = self._align(8)
        self.buf += bytes(8 * count)
        return at

    def boolean(self) -> int:
        at = len(self.buf)
        self.buf.append(0)
        return at

    def string(self, text: str) -> None:
        data = text.encode()
        self.u32(len(data) + 1)
        self.buf += data + b'\x00'

    def f64_sequence(self, count: int, width: int = 1) -> int:
        """A sequence of ``count`` float64, or of ``count`` structs of ``width`` float64
        each; offset of the first value (of the count if empty)."""
        at = self.u32(count)
        return self.f64(count * width) if count else at


class _ModuleFields:
    """Where one ModuleShape's values sit in a buffer, and how to write its scalars there
    (its arrays are written for all modules at once, see :meth:`_ShapeBuffer._update`)."""

    def __init__(self, writer: _Writer, frame_id: str, module: str, source: str,
                 n_angles: int, n_points: int):
        self.stamp_at = writer.stamp(0)
        writer.string(frame_id)
        writer.string(module)
        writer.string(source)
        self.cable_length_at = writer.f64()
        angles_at = writer.f64_sequence(n_angles)
        points_at = writer.f64_sequence(n_points, 3)          # geometry_msgs/Point
        self.tail_at = writer.f64(2)             # tension, energy
        writer.boolean()                         # converged
        writer.f64(2)                            # residual, solve_time
        # Indices into the buffer's float64 view (see _ShapeBuffer): the angles, and the
        # x, y of each rib centre in row order (z stays 0).
        self.angles = _f64_index(angles_at, n_angles)
        self.points = (_f64_index(points_at, 3 * n_points).reshape(n_points, 3)[:, :2].ravel()
                       if n_points else np.zeros(0, dtype=np.intp))

    def write(self, buf: bytearray, shape, stamp_ns: int) -> None:
        """Write the scalars of a :class:`~softsnap_model.predictor.ModulePrediction`
        (mm in, m out)."""
        _STAMP.pack_into(buf, self.stamp_at,
                         *_split_ns(shape.stamp_ns if shape.stamp_ns > 0 else stamp_ns))
        _F64.pack_into(buf, self.cable_length_at, shape.cable_length_mm / MM_PER_M)
        _TAIL.pack_into(buf, self.tail_at, shape.tension * MM_PER_M, shape.energy,
                        1 if shape.converged else 0, shape.residual, shape.solve_time_s)


def _f64_index(at: int, count: int) -> np.ndarray:
    """Indices in the float64 view of ``count`` float64 from byte offset ``at`` (CDR
    aligns them to 8 bytes from the end of the encapsulation header)."""
    return np.arange(count, dtype=np.intp) + (at - len(CDR_LE)) // 8


def _layout_of(shape) -> int:
    """0: no shape yet (an empty ModuleShape); 1: a shape; 2: a shape with rib centres."""
    if shape is None:
        return 0
    return 2 if shape.rib_centers_mm is not None else 1


class _ShapeBuffer:
    """Shared logic of the robot and module wires: one layout, rebuilt when a module's
    layout (:func:`_layout_of`) changes, and the shapes last written, by identity."""

    def __init__(self, robot: str, source: str, modules: list[str], n_segments: int,
                 n_ribs: int):
        self.robot, self.source, self.modules = robot, source, list(modules)
        self.n_segments, self.n_ribs = n_segments, n_ribs
        self._layouts: tuple | None = None
        self._written: list = [None] * len(self.modules)
        self.buf = bytearray()
        self._fields: list[_ModuleFields] = []

    def _module(self, writer: _Writer, name: str, layout: int) -> _ModuleFields:
        if layout == 0:  # what the node sends for a module not solved yet
            return _ModuleFields(writer, '', name, self.source, 0, 0)
        return _ModuleFields(writer, f'{self.robot}/{name}', name, self.source,
                             self.n_segments, self.n_ribs if layout == 2 else 0)

    def _bind(self, buf: bytearray) -> None:
        """Adopt a newly laid out buffer: its float64 view, and no array indices yet."""
        self.buf = buf
        # The whole message after the encapsulation header as float64: every float64
        # field is aligned to 8 from there, so one view reaches all of them.
        self._f64 = np.frombuffer(buf, '<f8', (len(buf) - len(CDR_LE)) // 8, len(CDR_LE))
        self._indices: dict[tuple, tuple] = {}

    def _update(self, shapes, stamp_ns: int) -> None:
        layouts = tuple(_layout_of(shape) for shape in shapes)
        if layouts != self._layouts:
            self._build(layouts)
            self._layouts = layouts
            self._written = [None] * len(shapes)
        buf, written, fields = self.buf, self._written, self._fields
        changed = [i for i, shape in enumerate(shapes)
                   if shape is not None and shape is not written[i]]
        if not changed:
            return
        for i in changed:
            fields[i].write(buf, shapes[i], stamp_ns)
        # The arrays of every changed module in two assignments: numpy's per-call cost,
        # not the copying, is what a module's arrays cost (two calls per module before).
        key = tuple(changed)
        indices = self._indices.get(key)
        if indices is None:
            if len(self._indices) >= INDEX_SETS_KEPT:
                self._indices.clear()
            indices = self._indices[key] = (
                np.concatenate([fields[i].angles for i in changed]),
                np.concatenate([fields[i].points for i in changed]),
                [i for i in changed if fields[i].points.size])
        angles_at, points_at, with_points = indices
        self._f64[angles_at] = np.concatenate([shapes[i].angles for i in changed])
        if with_points:
            self._f64[points_at] = np.concatenate(
                [shapes[i].rib_centers_mm for i in with_points]).ravel() / MM_PER_M
        # Marked only once every field is in: after a write that raised, the next
        # message writes these modules again instead of keeping stale arrays.
        for i in changed:
            written[i] = shapes[i]


class RobotShapeWire(_ShapeBuffer):
    """A ``softsnap_interfaces/RobotShape`` of one source as CDR bytes.

    ``header.frame_id`` and ``robot`` are the robot's name, ``modules`` one entry per
    module in scene order, each a ``ModuleShape`` with ``header.frame_id``
    ``<robot>/<module>`` (empty, with everything else zero, for a module without a
    shape yet), ``base_poses`` one Pose per module.

    Parameters
    ----------
    robot : str
        Scene name.
    source : str
        "commanded" or "predicted".
    modules : list of str
        Module names in scene order.
    n_segments, n_ribs : int
        Angles and rib centres per shape.
    """

    def _build(self, layouts) -> None:
        writer = _Writer()
        self._stamp_at = writer.stamp(0)
        writer.string(self.robot)
        writer.string(self.robot)
        writer.u32(len(self.modules))
        self._fields = [self._module(writer, name, layout)
                        for name, layout in zip(self.modules, layouts)]
        n = len(self.modules)
        poses_at = writer.f64_sequence(n, 7)      # geometry_msgs/Pose
        self._bind(writer.buf)
        self._poses = (np.frombuffer(self.buf, '<f8', 7 * n, poses_at).reshape(n, 7)
                       if n else np.zeros((0, 7)))
        self._poses_written: list = [None] * n

    def serialize(self, shapes, base_poses, stamp_ns: int) -> bytes:
        """CDR bytes of the robot message.

        Parameters
        ----------
        shapes : list of ModulePrediction or None
            Current shape per module (scene order); only shapes not written before are
            written.
        base_poses : list of ((x, y, z) m, (x, y, z, w))
            Base pose per module in the robot frame.
        stamp_ns : int
            ``header.stamp`` of the robot message, and of module shapes whose length
            had no stamp, ns.
        """
        self._update(shapes, stamp_ns)
        _STAMP.pack_into(self.buf, self._stamp_at, *_split_ns(stamp_ns))
        written = self._poses_written
        for i, pose in enumerate(base_poses):
            if pose is not written[i]:   # fixed bases are the same tuples every tick
                self._poses[i, :3] = pose[0]
                self._poses[i, 3:] = pose[1]
                written[i] = pose
        return bytes(self.buf)


class ModuleShapeWire(_ShapeBuffer):
    """A ``softsnap_interfaces/ModuleShape`` of one module and source as CDR bytes
    (the same fields as in :class:`RobotShapeWire`)."""

    def __init__(self, robot: str, source: str, module: str, n_segments: int, n_ribs: int):
        super().__init__(robot, source, [module], n_segments, n_ribs)

    def _build(self, layouts) -> None:
        writer = _Writer()
        self._fields = [self._module(writer, self.modules[0], layouts[0])]
        self._bind(writer.buf)

    def serialize(self, shape, stamp_ns: int) -> bytes:
        """CDR bytes of one module's shape (``stamp_ns`` if its length had no stamp)."""
        self._update([shape], stamp_ns)
        return bytes(self.buf)
