"""Fuzz: the reply parser and the simulated module's request parser never fail unexpectedly."""
import json

from hypothesis import given, settings
from hypothesis import strategies as st

from softsnap_driver.firmware import KEYWORDS, SimModule, http_reply, parse_request
from softsnap_driver.protocol import (INT32_MAX, INT32_MIN, MalformedReply, ModuleStatus,
                                      encode_set_request, parse_reply)

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
