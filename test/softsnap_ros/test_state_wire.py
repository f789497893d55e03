"""The driver's ModuleState and CableLength bytes (state_wire) read back by rclpy as the
message-object path's messages, for any field values (NaN, extremes, any text)."""
import math
import struct

from hypothesis import example, given, settings
from hypothesis import strategies as st

from softsnap_ros.cdr import (CableLengthWire, ModuleStateFields, ModuleStateWire,
                              fill_module_state)

FUZZ = settings(max_examples=300, deadline=None)
NAMES = st.text(st.characters(min_codepoint=0x30, max_codepoint=0x7a), min_size=1, max_size=13)
F64 = st.floats(allow_nan=True, allow_infinity=True)
F32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
U32 = st.integers(0, 2**32 - 1)
TIME = st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 10**9 - 1))
FIELDS = st.builds(
    ModuleStateFields, st.booleans(), st.booleans(), F64, F64, st.integers(-2**31, 2**31 - 1),
    st.integers(-2**31, 2**31 - 1), st.integers(0, 255), F32, F32, U32, U32, U32, U32, TIME,
    U32, U32, U32, U32, U32, U32, U32,
    st.text(st.characters(blacklist_categories=('Cs',), blacklist_characters='\x00'),
            max_size=40),
    TIME)


def same(a, b) -> bool:
    """Field-by-field equality of two messages, NaN equal to NaN (bit for bit)."""
    if hasattr(a, 'get_fields_and_field_types'):
        return all(same(getattr(a, name), getattr(b, name))
                   for name in a.get_fields_and_field_types())
    if isinstance(a, float):
        return struct.pack('<d', a) == struct.pack('<d', b) or (math.isnan(a) and math.isnan(b))
    return type(a) is type(b) and a == b


@FUZZ
@given(frame_id=NAMES, module=NAMES, stamp=TIME, fields=st.lists(FIELDS, min_size=1, max_size=3))
def test_module_state_bytes_read_back_as_the_message_object(frame_id, module, stamp, fields):
    from rclpy.serialization import deserialize_message, serialize_message
    from softsnap_interfaces.msg import ModuleState
    wire = ModuleStateWire(frame_id, module)
    for values in fields:   # one wire, several states: the cached error text changes
        want = ModuleState(module=module)
        want.header.frame_id = frame_id
        want.header.stamp.sec, want.header.stamp.nanosec = stamp
        fill_module_state(want, values)
        got = deserialize_message(wire.serialize(stamp, values), ModuleState)
        assert same(got, deserialize_message(serialize_message(want), ModuleState)), (got, want)
        assert got.last_error == values.last_error and got.module == module


@FUZZ
@given(frame_id=st.text(max_size=20).filter(lambda t: '\x00' not in t), stamp=TIME, length=F64)
def test_cable_length_bytes_read_back_as_the_message_object(frame_id, stamp, length):
    from rclpy.serialization import deserialize_message
    from softsnap_interfaces.msg import CableLength
    from softsnap_ros.cdr import decode_cable_length
    raw = CableLengthWire(frame_id).serialize(stamp, length)
    got = deserialize_message(raw, CableLength)
    assert got.header.frame_id == frame_id
    assert (got.header.stamp.sec, got.header.stamp.nanosec) == stamp
    assert struct.pack('<d', got.cable_length) == struct.pack('<d', length)
    # The project's own reader (model node, logger) reads it too.
    stamp_ns, value = decode_cable_length(raw)
    assert stamp_ns == stamp[0] * 10**9 + stamp[1]
    assert struct.pack('<d', value) == struct.pack('<d', length)


@FUZZ
@given(sec=st.integers(-2**31, 2**31 - 1), nanosec=U32)
@example(sec=2**31 - 1, nanosec=2**32 - 1)
@example(sec=-2**31, nanosec=0)
def test_any_command_header_stamp_echoes_as_a_time_rclpy_accepts(sec, nanosec):
    """A command's header (int32 sec, uint32 nanosec, possibly >= 1e9) is echoed in
    ModuleState.last_command_stamp: normalised, and held at the latest representable
    time when it would overflow int32 seconds (it used to make every state publish fail)."""
    from builtin_interfaces.msg import Time
    from softsnap_ros.units import TIME_SEC_MAX, sec_nanosec
    stamp_ns = sec * 10**9 + nanosec
    got = sec_nanosec(stamp_ns)
    Time(sec=got[0], nanosec=got[1])   # raises if either is out of its type's range
    assert 0 <= got[1] < 10**9
    if stamp_ns <= TIME_SEC_MAX * 10**9 + 999_999_999:
        assert got[0] * 10**9 + got[1] == stamp_ns
    else:
        assert got == (TIME_SEC_MAX, 999_999_999)
