"""Plain CDR primitives shared by the readers and writers of this package.

XCDR1 as ROS 2's rmw implementations send it (tested with rmw_fastrtps_cpp): a 4-byte
encapsulation header (representation 0x0001 little-endian, 0x0000 big-endian, then two
option bytes), then the fields in message order, each primitive aligned to its own
size counted from the end of that header; a string is a uint32 length (NUL included),
the bytes and the NUL; a sequence is a uint32 count and its elements, the first element
aligned to its type (no padding after the count of an empty sequence).
"""
from __future__ import annotations

import struct

#: The representation id of little-endian plain CDR (the first two header bytes).
REPRESENTATION_LE = b'\x00\x01'
#: The whole encapsulation header the writers emit: little-endian, options 0.
ENCAPSULATION_LE = b'\x00\x01\x00\x00'
HEADER_SIZE = 4

U32 = struct.Struct('<I')
F64 = struct.Struct('<d')
F32 = struct.Struct('<f')
STAMP = struct.Struct('<iI')  # builtin_interfaces/Time: sec, nanosec


class CdrError(ValueError):
    """The bytes are not the message in the plain CDR this package reads (the reason
    says why); :mod:`softsnap_ros.cdr.fallback` then lets rclpy read them."""


def encode_string(text: str, at: int) -> bytes:
    """A CDR string that starts at absolute offset ``at`` (header included), with the
    padding that aligns its length field to 4."""
    data = text.encode('utf-8')
    return bytes(-at % 4) + U32.pack(len(data) + 1) + data + b'\x00'
