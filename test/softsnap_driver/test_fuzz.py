"""Fuzz: the reply parser and the simulated module's request parser never fail unexpectedly."""
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from softsnap_driver.firmware import KEYWORDS, SimModule, http_reply, parse_request
from softsnap_driver.protocol import (INT32_MAX, INT32_MIN, MalformedReply, ModuleStatus,
                                      _parse_firmware_reply, _parse_reply, encode_set_request,
                                      parse_reply)

FUZZ = settings(max_examples=200, deadline=None)


@FUZZ
@given(st.binary(max_size=3000))
def test_reply_parser_only_raises_malformed_reply(raw):
    try:
        assert isinstance(parse_reply(raw), ModuleStatus)
    except MalformedReply:
        pass


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=10)


@FUZZ
@given(st.dictionaries(st.sampled_from(['status', 'ip', 'mac', 'm_current', 'm_power', 'm_error',
                                        'battery', 'pause', 'power', 'extra']), json_values))
def test_reply_parser_on_json_shaped_garbage(fields):
    base = json.loads(SimModule(start_time=0.0).status_json())
    base.update(fields)
    try:
        status = parse_reply(http_reply(json.dumps(base)))
    except MalformedReply:
        return
    assert INT32_MIN <= status.encoder_count <= INT32_MAX
    assert 0 <= status.motor_power <= 255


@FUZZ
@given(st.binary(max_size=3000))
def test_request_parser_never_raises_and_answers(head):
    request = parse_request(head)
    assert request.command in KEYWORDS
    if request.command == 'set':
        assert INT32_MIN <= request.target <= INT32_MAX and 0 <= request.power <= 255
    sim = SimModule(start_time=0.0)
    assert isinstance(parse_reply(sim.handle_request(head, now=0.01)), ModuleStatus)


@FUZZ
@given(st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=200))
def test_request_parser_on_printable_heads(text):
    request = parse_request(f'GET /?{text} HTTP/1.1\r\n\r\n'.encode())
    found = [word for word in KEYWORDS if word in text]
    assert request.command == (found[0] if found else 'status')


@FUZZ
@given(st.integers(INT32_MIN, INT32_MAX), st.integers(0, 255))
def test_set_round_trip_through_the_firmware_parser(target, power):
    assert parse_request(encode_set_request(target, power)) == \
        parse_request(encode_set_request(target, power))  # deterministic
    request = parse_request(encode_set_request(target, power))
    assert (request.command, request.target, request.power) == ('set', target, power)


@FUZZ
@given(st.integers(-10 ** 6, 10 ** 6), st.integers(0, 255), st.booleans(), st.integers(0, 1000))
def test_sim_status_round_trips_through_the_client_parser(count, power, paused, errors):
    sim = SimModule(start_time=0.0)
    sim.position, sim.motor_power, sim.paused, sim.encoder_errors = float(count), power, paused, errors
    status = parse_reply(sim.reply())
    assert (status.encoder_count, status.motor_power, status.paused, status.encoder_errors) == \
        (count, power, paused, errors)


# -- hostile but well-formed JSON: extreme numbers, wrong types, deep nesting, bad bytes --

FIELDS = ['status', 'ip', 'mac', 'm_current', 'm_power', 'm_error', 'battery', 'pause', 'power']


def huge_int_text(digits: int, sign: str = '') -> str:
    return sign + '1' + '0' * digits


extreme_number_texts = st.one_of(
    # Beyond float range (regression: OverflowError from math.isfinite/float), and beyond
    # sys.get_int_max_str_digits() (ValueError inside json.loads).
    st.builds(huge_int_text, st.integers(300, 6000), st.sampled_from(['', '-'])),
    st.sampled_from(['1e400', '-1e400', '1e-400', 'NaN', 'Infinity', '-Infinity', '-0',
                     '2147483648', '-2147483649', '4294967296', '1.0', '4.15e0', '9' * 40]),
    st.integers().map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(json.dumps),
)


def reply_with(field: str, value_text: str) -> bytes:
    """A firmware reply whose `field` holds `value_text` verbatim (any JSON, or not)."""
    base = json.loads(SimModule(start_time=0.0).status_json())
    base[field] = '__X__'
    return http_reply(json.dumps(base).replace('"__X__"', value_text))


def assert_parses_or_malformed(raw: bytes):
    try:
        status = parse_reply(raw)
    except MalformedReply as exc:
        assert str(exc)                  # a reason is always given
        return None
    assert isinstance(status, ModuleStatus)
    assert INT32_MIN <= status.encoder_count <= INT32_MAX
    assert 0 <= status.motor_power <= 255 and 0 <= status.encoder_errors < 2 ** 32
    assert 0.0 <= status.battery_voltage < 100.0
    assert isinstance(status.ip, str) and isinstance(status.mac, str)
    return status


@FUZZ
@given(st.sampled_from(FIELDS), extreme_number_texts)
def test_reply_parser_on_extreme_numbers(field, number):
    assert_parses_or_malformed(reply_with(field, number))


@FUZZ
@given(st.sampled_from(FIELDS), json_values)
def test_reply_parser_on_wrong_types(field, value):
    assert_parses_or_malformed(reply_with(field, json.dumps(value)))


@FUZZ
@given(st.sampled_from(FIELDS + ['extra']), st.integers(1, 8000), st.sampled_from('[{'))
def test_reply_parser_on_deep_nesting(field, depth, bracket):
    close = ']' if bracket == '[' else '}'
    inner = '[' * depth + ']' * depth if bracket == '[' else '{"a":' * depth + '1' + close * depth
    assert_parses_or_malformed(reply_with(field, inner))


@FUZZ
@given(st.binary(min_size=1, max_size=8), st.integers(0, 10 ** 6))
def test_reply_parser_on_non_utf8_bytes(noise, where):
    good = SimModule(start_time=0.0).reply()
    at = where % len(good)
    assert_parses_or_malformed(good[:at] + noise + good[at:])


def test_regression_battery_beyond_float_range_is_malformed():
    # Found against an independent firmware emulator: OverflowError killed the I/O thread.
    with pytest.raises(MalformedReply, match="'battery' out of range"):
        parse_reply(reply_with('battery', huge_int_text(400)))


@pytest.mark.parametrize('field, text, reason', [
    ('m_current', huge_int_text(5000), 'not JSON'),       # beyond int max str digits
    ('extra', '[' * 5000 + ']' * 5000, 'not JSON|nest'),  # RecursionError in json
    ('ip', '12', "'ip' must be a string"),
    ('mac', '["02:53"]', "'mac' must be a string"),
    ('status', '["ok"]', 'reply status'),
])
def test_hostile_values_give_the_reason(field, text, reason):
    with pytest.raises(MalformedReply, match=reason):
        parse_reply(reply_with(field, text))


def test_non_utf8_reply_is_malformed_with_the_reason():
    with pytest.raises(MalformedReply, match='not UTF-8'):
        parse_reply(SimModule(start_time=0.0).reply().replace(b'"ok"', b'"\xff\xfe"'))


# -- the firmware-framing fast path agrees with the general parser ----------------------

FIRMWARE_HEAD = b'HTTP/1.1 200 OK\r\nContent-type:application/json\r\nConnection: close\r\n\r\n'

number_texts = st.one_of(
    st.integers(0, 99).map(str),            # valid in every field: the fast path's cases
    st.integers(-2 ** 33, 2 ** 33).map(str),
    st.sampled_from(['0', '-0', '00', '007', '-01', '255', '256', '2147483647', '2147483648',
                     '-2147483648', '-2147483649', '4294967295', '4294967296', '1e3', '4.15',
                     '99.999999', '100', '4.', '.5', '4.1234567', '1' * 11]),
    st.floats(0, 120).map(lambda v: f'{v:.{abs(hash(v)) % 8}f}'))
string_texts = st.text(st.characters(max_codepoint=0x7f), max_size=70) | st.text('0123456789.:AB"\\', max_size=20)


@FUZZ
@given(st.fixed_dictionaries({
    'ip': string_texts, 'mac': string_texts, 'm_current': number_texts, 'm_power': number_texts,
    'm_error': number_texts, 'battery': number_texts,
    'pause': st.sampled_from(['true', 'false', '1', 'null', '"false"']),
    'power': st.text('0123456789ABCDEFabcdef', max_size=1024) | st.text('0123456789ABCDEFg', max_size=1030)}),
    st.sampled_from(['', '\r\n\r\n', '\n', ' ', '\r\n\r\nx', '\t\r\n', ' ' * 16000]))
def test_fast_path_agrees_with_the_general_parser(fields, tail):
    body = ('{"status":"ok","ip":"%(ip)s","mac":"%(mac)s","m_current":%(m_current)s,'
            '"m_power":%(m_power)s,"m_error":%(m_error)s,"battery":%(battery)s,'
            '"pause":%(pause)s,"power":"%(power)s"}' % fields)
    raw = FIRMWARE_HEAD + body.encode() + tail.encode()
    fast = _parse_firmware_reply(raw)
    try:
        general = _parse_reply(raw)
    except MalformedReply:
        assert fast is None, 'the fast path accepted a reply the general parser refuses'
        return
    if fast is not None:
        assert fast == general
        assert (fast.battery_voltage, fast.ip, fast.mac, tuple(fast.power_history_w)) == \
            (general.battery_voltage, general.ip, general.mac, tuple(general.power_history_w))


@FUZZ
@given(st.integers(-10 ** 6, 10 ** 6), st.integers(0, 255), st.booleans(), st.integers(0, 1000),
       st.floats(0.0, 50.0))
def test_simulated_replies_take_the_fast_path(count, power, paused, errors, seconds):
    # The firmware's (and the simulator's) framing must not silently fall back to the
    # slow parser: that is where the driver's CPU per request goes.
    sim = SimModule(start_time=0.0)
    sim.advance_to(seconds)
    sim.position, sim.motor_power, sim.paused, sim.encoder_errors = float(count), power, paused, errors
    raw = sim.reply()
    fast = _parse_firmware_reply(raw)
    assert fast is not None
    assert fast == _parse_reply(raw)
    assert (fast.encoder_count, fast.motor_power, fast.paused, fast.encoder_errors) == \
        (count, power, paused, errors)
