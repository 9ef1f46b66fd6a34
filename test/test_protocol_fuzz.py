"""Property tests: decoding arbitrary bytes fails only with ProtocolError; round trips."""

import math

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st

from motor_id.card import protocol as pr
from motor_id.card.stream import CommandParser, FrameParser
from motor_id.errors import ProtocolError

SETTINGS = settings(max_examples=300, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])

f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
"""Real fields travel as float32: values that are float32 numbers round-trip exactly."""
u32 = st.integers(0, 2 ** 32 - 1)


@st.composite
def samples(draw):
    current = draw(st.one_of(st.just(math.nan), f32))
    flags = draw(st.integers(0, 2 ** 16 - 1)) & ~pr.FLAG_CURRENT
    if not math.isnan(current):
        flags |= pr.FLAG_CURRENT
    t_us = draw(st.integers(0, 2 ** 53))
    return pr.Sample(draw(u32), t_us / 1e6, draw(f32), draw(f32), current, flags)


commands = st.one_of(
    st.builds(pr.SetVoltage, f32),
    st.builds(pr.StartProfile,
              st.text(st.characters(min_codepoint=32, max_codepoint=126), min_size=1,
                      max_size=pr.MAX_NAME), f32, u32, f32),
    st.just(pr.Stop()),
    st.builds(pr.SetPeriod, st.integers(1, 2 ** 32 - 1).map(lambda us: us / 1e6)),
    st.builds(pr.Ping, u32),
)

replies = st.builds(pr.Reply, st.sampled_from(sorted(pr._COMMAND_CODES)),
                    st.sampled_from(sorted(pr.STATUS_NAMES)), u32)


def _frame_like(draw_bytes):
    """Bytes that often start like a frame so the fuzzer gets past the sync check."""
    return st.one_of(draw_bytes, draw_bytes.map(lambda b: pr.SYNC + b),
                     st.tuples(st.sampled_from(sorted(pr.CARD_TYPES) + sorted(pr.HOST_TYPES)),
                               draw_bytes).map(lambda x: pr._frame(
                                   pr.CARD_TYPES.get(x[0]) or pr.HOST_TYPES[x[0]], x[1][:255])))


@st.composite
def mutated_payloads(draw):
    """A valid frame with some payload bytes overwritten and the CRC made valid again."""
    frame = draw(st.one_of(samples().map(pr.encode_sample), replies.map(pr.encode_reply),
                           commands.map(pr.encode_command)))
    ftype, payload = frame[2], bytearray(frame[pr.HEADER.size:-pr.CRC.size])
    for _ in range(draw(st.integers(0, 4)) if payload else 0):
        payload[draw(st.integers(0, len(payload) - 1))] = draw(st.integers(0, 255))
    kind = pr.CARD_TYPES.get(ftype) or pr.HOST_TYPES[ftype]
    return pr._frame(kind, bytes(payload))


@SETTINGS
@given(st.one_of(_frame_like(st.binary(max_size=80)), mutated_payloads()))
def test_parse_frame_raises_only_protocol_error(data):
    for parse in (pr.parse_frame, pr.parse_command):
        try:
            item = parse(data)
        except ProtocolError as err:
            assert err.kind in pr.ERROR_KINDS
        else:
            assert isinstance(item, (pr.Sample, pr.Reply) + pr.COMMANDS)


@SETTINGS
@given(st.lists(st.one_of(st.binary(max_size=40), samples().map(pr.encode_sample),
                          replies.map(pr.encode_reply), commands.map(pr.encode_command)),
                max_size=12),
       st.integers(1, 64))
def test_stream_parsers_raise_nothing(chunks, step):
    data = b''.join(chunks)
    for parser in (FrameParser(), CommandParser()):
        items = []
        for i in range(0, len(data), step):
            items += parser.feed(data[i:i + step])
        items += parser.flush()
        assert parser.buffered == 0
        for item in items:
            if isinstance(item, ProtocolError):
                assert item.kind in pr.ERROR_KINDS
        assert parser.frames + sum(parser.errors.values()) <= len(data) // 4 + 1


@SETTINGS
@given(samples())
def test_sample_round_trip(sample):
    frame = pr.encode_sample(sample)
    assert pr.parse_frame(frame) == sample
    assert FrameParser().feed(b'\x00' + frame + frame) == [sample, sample]


@SETTINGS
@given(commands)
def test_command_round_trip(command):
    assert pr.parse_command(pr.encode_command(command)) == command


@SETTINGS
@given(replies)
def test_reply_round_trip(reply):
    assert pr.parse_frame(pr.encode_reply(reply)) == reply


@SETTINGS
@given(samples(), st.data())
def test_any_corruption_of_a_frame_is_detected(sample, data):
    frame = bytearray(pr.encode_sample(sample))
    i = data.draw(st.integers(0, len(frame) - 1))
    frame[i] ^= data.draw(st.integers(1, 255))
    try:
        pr.parse_frame(bytes(frame))
    except ProtocolError as err:
        assert err.kind in ('bad_sync', 'bad_crc', 'short', 'bad_length')
    else:
        raise AssertionError('a corrupted frame was accepted')
