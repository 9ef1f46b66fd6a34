"""Frame and command encoding, parsing, stream resynchronisation, sequence tracking."""

import math
import struct
import zlib

import numpy as np
import pytest

from motor_id.card import protocol as pr
from motor_id.card.sequence import SequenceTracker
from motor_id.card.stream import CommandParser, FrameParser
from motor_id.card.transport import open_transport, read_available, TransportError
from motor_id.errors import ConfigError, ProtocolError

SAMPLE = pr.Sample(seq=7, t_card=1.25, voltage=3.5, speed=12.25, current=0.5,
                   flags=pr.FLAG_CURRENT | pr.FLAG_PROFILE)
NO_CURRENT = pr.Sample(seq=8, t_card=1.26, voltage=-2.0, speed=0.125)


def _reframe(ftype, payload):
    """A frame with a valid CRC around an arbitrary payload (to test field checks)."""
    body = struct.pack('<BB', ftype, len(payload)) + payload
    return pr.SYNC + body + struct.pack('<I', zlib.crc32(body))


def _kind(fn, data):
    with pytest.raises(ProtocolError) as info:
        fn(data)
    return info.value.kind


def test_sample_frame_layout_is_documented():
    frame = pr.encode_sample(SAMPLE)
    assert len(frame) == 8 + 26
    assert frame[:2] == b'\xa5\x5a'
    assert frame[2] == pr.TYPE_SAMPLE and frame[3] == 26
    seq, t_us, flags, v, w, i = struct.unpack('<IQHfff', frame[4:-4])
    assert (seq, t_us, flags, v, w, i) == (7, 1250000, 3, 3.5, 12.25, 0.5)
    assert struct.unpack('<I', frame[-4:])[0] == zlib.crc32(frame[2:-4])
    assert len(pr.encode_sample(NO_CURRENT)) == 8 + 22


def test_good_frames_round_trip():
    assert pr.parse_frame(pr.encode_sample(SAMPLE)) == SAMPLE
    back = pr.parse_frame(pr.encode_sample(NO_CURRENT))
    assert math.isnan(back.current) and not back.has_current
    assert (back.seq, back.t_card, back.voltage, back.speed, back.flags) == (8, 1.26, -2.0,
                                                                         0.125, 0)
    reply = pr.Reply('start_profile', 'unknown_profile', 1234)
    assert pr.parse_frame(pr.encode_reply(reply)) == reply


def test_samples_without_current_compare_equal():
    assert pr.Sample(1, 0.0, 1.0, 2.0) == pr.Sample(1, 0.0, 1.0, 2.0, float('nan'))
    assert pr.Sample(1, 0.0, 1.0, 2.0) != pr.Sample(1, 0.0, 1.0, 2.0, 0.0)
    assert len({pr.Sample(1, 0.0, 1.0, 2.0), pr.Sample(1, 0.0, 1.0, 2.0, math.nan)}) == 1


def test_current_flag_follows_the_current_value():
    s = pr.Sample(1, 0.0, 1.0, 2.0, current=0.25, flags=0)
    assert pr.parse_frame(pr.encode_sample(s)).flags == pr.FLAG_CURRENT
    s = pr.Sample(1, 0.0, 1.0, 2.0, flags=pr.FLAG_CURRENT | pr.FLAG_STARTUP)
    assert pr.parse_frame(pr.encode_sample(s)).flags == pr.FLAG_STARTUP


def test_values_are_float32_and_microseconds():
    s = pr.Sample(1, 0.1234567, 0.1, 1 / 3, 2 / 3)
    back = pr.parse_frame(pr.encode_sample(s))
    assert back.t_card == 0.123457
    np.testing.assert_allclose([back.voltage, back.speed, back.current], [0.1, 1 / 3, 2 / 3],
                               rtol=6e-8)
    assert back.speed == float(np.float32(1 / 3))


def test_short_frames():
    frame = pr.encode_sample(SAMPLE)
    for n in (0, 1, 7, 8, 20, len(frame) - 1):
        assert _kind(pr.parse_frame, frame[:n]) == 'short'


def test_bad_sync_crc_length_type():
    frame = pr.encode_sample(SAMPLE)
    assert _kind(pr.parse_frame, b'\x00' + frame[1:]) == 'bad_sync'
    assert _kind(pr.parse_frame, frame + b'\x00') == 'bad_length'
    for i in range(2, len(frame)):  # every single-bit error after the sync is caught
        bad = bytearray(frame)
        bad[i] ^= 0x10
        assert _kind(pr.parse_frame, bytes(bad)) in ('bad_crc', 'short', 'bad_length')
    bad = bytearray(frame)
    bad[10] ^= 0x01
    assert _kind(pr.parse_frame, bytes(bad)) == 'bad_crc'
    assert _kind(pr.parse_frame, pr.encode_command(pr.Stop())) == 'bad_type'
    assert _kind(pr.parse_command, frame) == 'bad_type'
    assert _kind(pr.parse_frame, _reframe(0x7F, b'')) == 'bad_type'
    assert _kind(pr.parse_frame, _reframe(pr.TYPE_SAMPLE, bytes(23))) == 'bad_length'


def test_field_checks():
    base = struct.pack('<IQH', 1, 10, 0)
    nan = struct.pack('<f', float('nan'))
    one = struct.pack('<f', 1.0)
    assert _kind(pr.parse_frame, _reframe(pr.TYPE_SAMPLE, base + nan + one)) == 'bad_value'
    # current flag and payload length must agree
    flagged = struct.pack('<IQH', 1, 10, pr.FLAG_CURRENT)
    assert _kind(pr.parse_frame, _reframe(pr.TYPE_SAMPLE, flagged + one + one)) == 'bad_length'
    assert _kind(pr.parse_frame, _reframe(pr.TYPE_SAMPLE, base + one * 3)) == 'bad_length'
    assert _kind(pr.parse_frame, _reframe(pr.TYPE_REPLY, struct.pack('<BBI', 0x10, 9, 0))) \
        == 'bad_value'
    assert _kind(pr.parse_command, _reframe(pr.TYPE_SET_PERIOD, bytes(4))) == 'bad_value'
    name = struct.pack('<ffIB', 1.0, 1.0, 0, 5) + b'prbs'
    assert _kind(pr.parse_command, _reframe(pr.TYPE_START_PROFILE, name)) == 'bad_length'
    name = struct.pack('<ffIB', 1.0, 1.0, 0, 4) + b'pr\xffs'
    assert _kind(pr.parse_command, _reframe(pr.TYPE_START_PROFILE, name)) == 'bad_value'


def test_error_kinds_are_the_documented_set():
    assert set(pr.ERROR_KINDS) == {'short', 'bad_sync', 'bad_length', 'bad_crc', 'bad_type',
                                   'bad_value'}


def test_encoding_rejects_what_the_wire_cannot_carry():
    with pytest.raises(ConfigError, match='seq'):
        pr.encode_sample(pr.Sample(2 ** 32, 0.0, 0.0, 0.0))
    with pytest.raises(ConfigError, match='t_card'):
        pr.encode_sample(pr.Sample(0, -1.0, 0.0, 0.0))
    with pytest.raises(ConfigError, match='speed'):
        pr.encode_sample(pr.Sample(0, 0.0, 0.0, float('inf')))
    with pytest.raises(ConfigError, match='float32'):
        pr.encode_command(pr.SetVoltage(1e39))
    with pytest.raises(ConfigError, match='ASCII'):
        pr.encode_command(pr.StartProfile('prbs\u00e9'))
    with pytest.raises(ConfigError, match='period'):
        pr.encode_command(pr.SetPeriod(0.0))
    with pytest.raises(ConfigError, match='cannot encode'):
        pr.encode_command(SAMPLE)
    with pytest.raises(ConfigError, match='status'):
        pr.encode_reply(pr.Reply('stop', 'fine'))


def test_command_round_trip():
    commands = [pr.SetVoltage(-4.5), pr.StartProfile('multisine', 6.0, 123, 20.0),
                pr.StartProfile('paper_steps'), pr.Stop(), pr.SetPeriod(0.002),
                pr.SetPeriod(1e-6), pr.Ping(2 ** 32 - 1)]
    stream = b''.join(pr.encode_command(c) for c in commands)
    for c in commands:
        assert pr.parse_command(pr.encode_command(c)) == c
    parser = CommandParser()
    got = []
    for i in range(0, len(stream), 5):  # arrives in pieces
        got += parser.feed(stream[i:i + 5])
    assert got == commands
    assert parser.garbage_bytes == 0 and parser.buffered == 0


def test_stream_resynchronises_after_garbage():
    rng = np.random.default_rng(4)
    samples = [pr.Sample(k, k / 100, float(np.float32(k / 7)), float(k)) for k in range(50)]
    stream = bytearray()
    junk_total = 0
    for k, s in enumerate(samples):
        if k % 3 == 0:
            junk = rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8)
            junk[junk == 0xA5] = 0  # keep the garbage count exact
            stream += junk.tobytes()
            junk_total += junk.size
        stream += pr.encode_sample(s)
    stream += b'\xa5\x5a\x01'  # a torn frame at the end stays buffered
    parser = FrameParser()
    items = []
    for i in range(0, len(stream), 17):
        items += parser.feed(bytes(stream[i:i + 17]))
    assert items == samples
    assert parser.garbage_bytes == junk_total
    assert parser.frames == 50 and not parser.errors
    assert parser.buffered == 3
    tail = parser.flush()
    assert [e.kind for e in tail] == ['short'] and parser.buffered == 0


def test_stream_sync_pattern_inside_garbage():
    frame = pr.encode_sample(SAMPLE)
    parser = FrameParser()
    # false syncs: unknown type, impossible length, sync + start of a frame
    data = b'\xa5\x5a\x7f\x00' + b'\xa5\x5a\x01\x05' + b'\xa5' + frame + b'\xa5\x5a' + frame
    assert parser.feed(data) == [SAMPLE, SAMPLE]
    assert parser.garbage_bytes == 4 + 4 + 1 + 2


def test_stream_reports_bad_crc_and_keeps_the_next_frame():
    good = pr.encode_sample(SAMPLE)
    bad = bytearray(good)
    bad[12] ^= 0x80
    parser = FrameParser()
    items = parser.feed(bytes(bad))
    assert items == []  # waits to see whether the next frame follows
    items = parser.feed(good + bytes(bad) + b'\x01\x02' + good)
    kinds = [i.kind if isinstance(i, ProtocolError) else 'sample' for i in items]
    assert kinds == ['bad_crc', 'sample', 'bad_crc', 'sample']
    assert parser.errors == {'bad_crc': 2}
    # the first bad frame was skipped whole, the second (followed by junk) byte by byte
    assert parser.garbage_bytes == len(good) + 2


def test_stream_recovers_a_frame_after_a_torn_one():
    good = pr.encode_sample(SAMPLE)
    parser = FrameParser()
    items = parser.feed(good[:15] + good + good)
    kinds = [i.kind if isinstance(i, ProtocolError) else 'sample' for i in items]
    assert kinds == ['bad_crc', 'sample', 'sample']


def test_replies_are_kept_aside():
    parser = FrameParser(max_replies=2)
    data = b''.join(pr.encode_reply(pr.Reply('ping', 'ok', k)) for k in range(3))
    assert parser.feed(data + pr.encode_sample(SAMPLE)) == [SAMPLE]
    assert [r.value for r in parser.replies] == [1, 2]


def test_sequence_tracker_counts_gaps_duplicates_and_late_frames():
    tr = SequenceTracker(window=8)
    kinds = [tr.update(s).kind for s in [10, 11, 13, 12, 12, 14, 18, 18, 19]]
    assert kinds == ['first', 'ok', 'gap', 'late', 'duplicate', 'ok', 'gap', 'duplicate',
                     'ok']
    assert (tr.received, tr.lost, tr.duplicates, tr.late, tr.resets) == (9, 3, 2, 1, 0)
    assert tr.update(25).lost == 5


def test_sequence_tracker_wraps_and_resets():
    tr = SequenceTracker(window=4)
    kinds = [tr.update(s).kind for s in [2 ** 32 - 2, 2 ** 32 - 1, 0, 2]]
    assert kinds == ['first', 'ok', 'ok', 'gap'] and tr.lost == 1
    assert tr.update(100, restart=True).kind == 'reset'
    assert tr.update(50).kind == 'reset'  # far back: the card restarted
    assert tr.update(51).kind == 'ok'
    assert tr.update(51 + 2 ** 20, ).kind == 'gap'
    big = SequenceTracker(max_gap=100)
    big.update(0)
    assert big.update(1000).kind == 'reset' and big.lost == 0
    with pytest.raises(ConfigError):
        tr.update(-1)


def test_transport_loop_round_trip():
    port = open_transport('loop://', timeout=0.05)
    try:
        frames = [pr.Sample(k, k / 1000, 1.0, 2.0 * k, 0.5, pr.FLAG_CURRENT) for k in range(20)]
        port.write(b'\x00\x01' + b''.join(pr.encode_sample(s) for s in frames))
        parser = FrameParser()
        got = []
        while len(got) < 20:
            data = read_available(port)
            assert data, 'loop:// returned nothing within the timeout'
            got += parser.feed(data)
        assert got == frames and parser.garbage_bytes == 2
        port.write(pr.encode_command(pr.Ping(5)))
        assert CommandParser().feed(read_available(port)) == [pr.Ping(5)]
    finally:
        port.close()


def test_transport_errors_are_domain_errors(tmp_path):
    with pytest.raises(TransportError, match='cannot open'):
        open_transport(str(tmp_path / 'no-such-tty'))
    with pytest.raises(ConfigError):
        open_transport('loop://', baudrate=0)


def test_a_frame_ending_in_a_sync_byte_does_not_depend_on_read_splitting():
    """A frame whose CRC ends in 0xA5, read to its end: the consumed byte is not kept."""
    token = next(k for k in range(10000)
                 if pr.encode_command(pr.Ping(k))[-1] == pr.SYNC[0])
    frame = pr.encode_command(pr.Ping(token))
    tail = b'\x5a\x01\x02\x03'
    whole = CommandParser()
    at_once = whole.feed(frame + tail) + whole.flush()
    split = CommandParser()
    first = split.feed(frame)
    assert split.garbage_bytes == 0
    in_two = first + split.feed(tail) + split.flush()
    assert [type(x) for x in in_two] == [type(x) for x in at_once] == [pr.Ping]
    assert in_two[0].token == token
    assert split.garbage_bytes == whole.garbage_bytes == len(tail)
