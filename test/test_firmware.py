"""The C firmware protocol (firmware/motor_card.h) against the Python protocol and card."""

import itertools
import math
from pathlib import Path
import shutil
import struct
import subprocess
import zlib

import numpy as np
import pytest

from motor_id.card import protocol as pr
from motor_id.card.stream import CommandParser
from motor_id.card.virtual_card import VirtualCard
from motor_id.errors import ConfigError, ProtocolError
from motor_id.excitation import make_excitation

FIRMWARE = Path(__file__).resolve().parents[1] / 'firmware'
HOST_MAIN = FIRMWARE / 'test' / 'host_main.c'
WARNINGS = ['-Wall', '-Wextra', '-Werror', '-pedantic']
U32 = 2 ** 32
PRINTABLE = bytes(range(0x20, 0x7F))


def _compiler(*names):
    for name in names:
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope='module')
def host(tmp_path_factory):
    """The host driver program, built with -std=c99 -Wall -Wextra -Werror."""
    cc = _compiler('cc', 'gcc', 'clang')
    if cc is None:
        pytest.skip('no C compiler on this machine')
    exe = tmp_path_factory.mktemp('firmware') / 'host_main'
    build([cc, '-std=c99', *WARNINGS, '-O2', '-o', str(exe), str(HOST_MAIN), '-lm'])
    return exe


def build(command):
    """Run a compiler; fail with its messages."""
    proc = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def run(host, lines):
    """Send request lines to a fresh driver process; return its answer lines."""
    proc = subprocess.run([str(host)], input='\n'.join(lines) + '\n', capture_output=True,
                          text=True, check=True, timeout=120)
    out = proc.stdout.splitlines()
    assert len(out) == len(lines)
    return out


def f32(x):
    """The float32 bit pattern of x (rounded) as an int."""
    return struct.unpack('<I', struct.pack('<f', x))[0]


def from_bits(bits):
    """The float32 with this bit pattern, as a Python float."""
    return struct.unpack('<f', struct.pack('<I', bits))[0]


def describe(item):
    """A decoded command or ProtocolError in the driver's DESC notation."""
    if isinstance(item, ProtocolError):
        return f'e:{item.kind}'
    if isinstance(item, pr.SetVoltage):
        return f'c:set_voltage:{f32(item.voltage):08x}'
    if isinstance(item, pr.StartProfile):
        return (f'c:start_profile:{f32(item.amplitude):08x}:{f32(item.duration):08x}:'
                f'{item.seed}:{item.name.encode("ascii").hex()}')
    if isinstance(item, pr.Stop):
        return 'c:stop'
    if isinstance(item, pr.SetPeriod):
        return f'c:set_period:{round(item.period * 1e6)}'
    return f'c:ping:{item.token}'


def python_parse(frame):
    try:
        return describe(pr.parse_command(frame))
    except ProtocolError as err:
        return f'e:{err.kind}'


def c_parse(answer):
    kind, _, rest = answer.partition(' ')
    return ('c:' if kind == 'ok' else 'e:') + rest


def reframe(ftype, payload):
    """A frame with a valid CRC around any payload (reaches the checks after the CRC)."""
    body = bytes([ftype, len(payload) & 0xFF]) + payload
    return pr.SYNC + body + struct.pack('<I', zlib.crc32(body))


def random_float_bits(rng):
    """A finite float32 bit pattern: random, a special value, or an ordinary voltage."""
    while True:
        bits = int(rng.integers(0, U32))
        special = rng.integers(0, 8)
        if special == 0:
            bits = int(rng.choice([0, 0x80000000, 1, 0x7F7FFFFF, 0xFF7FFFFF, 0x00800000]))
        elif special == 1:
            bits = f32(float(rng.uniform(-100, 100)))
        if (bits & 0x7F800000) != 0x7F800000:
            return bits


def random_command(rng):
    kind = int(rng.integers(0, 5))
    if kind == 0:
        return pr.SetVoltage(from_bits(random_float_bits(rng)))
    if kind == 1:
        n = int(rng.integers(1, pr.MAX_NAME + 1))
        name = rng.choice(['paper_steps', 'bipolar_steps', 'prbs', 'multisine',
                           rng.choice(list(PRINTABLE), n).astype(np.uint8).tobytes()
                           .decode('ascii')])
        return pr.StartProfile(str(name), from_bits(random_float_bits(rng)),
                               int(rng.integers(0, U32)), from_bits(random_float_bits(rng)))
    if kind == 2:
        return pr.Stop()
    if kind == 3:
        return pr.SetPeriod(int(rng.integers(1, U32)) / 1e6)
    return pr.Ping(int(rng.integers(0, U32)))


# ---------------------------------------------------------------------------------------
# encoding


def test_crc_matches_zlib(host):
    rng = np.random.default_rng(1)
    data = [b'', b'123456789'] + [rng.bytes(int(rng.integers(1, 300))) for _ in range(300)]
    out = run(host, [f'crc {d.hex() or "-"}' for d in data])
    assert out[1] == 'cbf43926'       # the CRC-32 check value of zlib / IEEE 802.3
    assert [int(x, 16) for x in out] == [zlib.crc32(d) for d in data]


def test_sample_frames_match_python_encoder(host):
    rng = np.random.default_rng(2)
    cases, lines = [], []
    for k in range(3000):
        seq = int(rng.choice([0, U32 - 1, int(rng.integers(0, U32))]))
        t_us = int(rng.choice([0, U32 - 1, U32, U32 + 1, int(rng.integers(0, 2 ** 48))]))
        flags = int(rng.integers(0, 2 ** 16))
        v, w, i = (random_float_bits(rng) for _ in range(3))
        has_i = k % 2
        cases.append((seq, t_us, flags, v, w, has_i, i))
        lines.append(f'enc {seq} {t_us} {flags} {v} {w} {has_i} {i}')
    out = run(host, lines)
    for (seq, t_us, flags, v, w, has_i, i), frame_hex in zip(cases, out, strict=True):
        current = from_bits(i) if has_i else float('nan')
        sample = pr.Sample(seq, t_us / 1e6, from_bits(v), from_bits(w), current, flags)
        frame = bytes.fromhex(frame_hex)
        assert frame == pr.encode_sample(sample)
        got = pr.parse_frame(frame)
        want_flags = (flags | pr.FLAG_CURRENT) if has_i else (flags & ~pr.FLAG_CURRENT)
        assert (got.seq, round(got.t_card * 1e6), got.flags) == (seq, t_us, want_flags)
        assert (f32(got.voltage), f32(got.speed)) == (v, w)
        assert got.has_current == bool(has_i)
        if has_i:
            assert f32(got.current) == i
    assert len(out) == 3000


def test_sample_encoder_refuses_non_finite_values_like_python(host):
    nan, inf = 0x7FC00000, 0x7F800000
    cases = [(nan, 0, 0, 0), (0, inf, 0, 0), (0, 0, 1, inf), (0, 0, 1, nan), (0, 0, 0, nan)]
    out = run(host, [f'enc 1 2 0 {v} {w} {h} {i}' for v, w, h, i in cases])
    assert out[:4] == ['none'] * 4
    assert bytes.fromhex(out[4]) == pr.encode_sample(pr.Sample(1, 2e-6, 0.0, 0.0))
    for v, w, _h, i in cases[:3]:
        with pytest.raises(ConfigError):
            pr.encode_sample(pr.Sample(1, 2e-6, from_bits(v), from_bits(w), from_bits(i)))


def test_reply_frames_match_python_encoder(host):
    rng = np.random.default_rng(3)
    cases = [(kind, status, int(rng.choice([0, U32 - 1, int(rng.integers(0, U32))])))
             for kind in pr.HOST_TYPES.values() for status in pr.STATUS_NAMES
             for _ in range(20)]
    out = run(host, [f'reply {kind.code} {pr.STATUS_NAMES[s]} {v}' for kind, s, v in cases])
    for (kind, status, value), frame_hex in zip(cases, out, strict=True):
        reply = pr.Reply(kind.name, status, value)
        assert bytes.fromhex(frame_hex) == pr.encode_reply(reply)
        assert pr.parse_frame(bytes.fromhex(frame_hex)) == reply
    assert len(cases) == 5 * 5 * 20


# ---------------------------------------------------------------------------------------
# decoding


def test_command_frames_decode_like_python(host):
    rng = np.random.default_rng(4)
    frames = [pr.encode_command(random_command(rng)) for _ in range(3000)]
    out = run(host, [f'parse {f.hex()}' for f in frames])
    decoded = [c_parse(a) for a in out]
    assert decoded == [describe(pr.parse_command(f)) for f in frames]
    assert sum(d.startswith('c:start_profile') for d in decoded) > 400


def _corrupt(rng, frame):
    """One corruption of a valid command frame."""
    kind = int(rng.integers(0, 10))
    f = bytearray(frame)
    if kind == 0:                               # one bit flipped anywhere
        bit = int(rng.integers(0, 8 * len(f)))
        f[bit // 8] ^= 1 << (bit % 8)
    elif kind == 1:                             # torn: too short
        f = f[:int(rng.integers(0, len(f)))]
    elif kind == 2:                             # trailing bytes
        f += rng.bytes(int(rng.integers(1, 5)))
    elif kind == 3:                             # garbage before the sync marker
        f = bytearray(rng.bytes(int(rng.integers(1, 4)))) + f
    elif kind == 4:                             # length byte changed, CRC recomputed
        f = bytearray(reframe(f[2], bytes(f[4:-4])))
        f[3] = int(rng.integers(0, 256))
        f[-4:] = struct.pack('<I', zlib.crc32(bytes(f[2:-4])))
    elif kind == 5:                             # another type, valid CRC
        f = bytearray(reframe(int(rng.integers(0, 32)), bytes(f[4:-4])))
    elif kind == 6:                             # random payload of a random length
        f = bytearray(reframe(f[2], rng.bytes(int(rng.integers(0, 50)))))
    elif kind == 7:                             # one field out of its domain, valid CRC
        p = bytearray(f[4:-4])
        bad = struct.pack('<I', int(rng.choice([0x7F800000, 0xFF800000, 0x7FC00001])))
        if f[2] == pr.TYPE_SET_VOLTAGE:
            p[0:4] = bad
        elif f[2] == pr.TYPE_START_PROFILE:
            field = int(rng.integers(0, 3))             # amplitude, duration or name
            if field < 2:
                p[4 * field:4 * field + 4] = bad
            else:
                p[13 + int(rng.integers(0, len(p) - 13))] = int(
                    rng.choice([0x00, 0x1F, 0x7F, 0x80, 0xFF]))
        elif f[2] == pr.TYPE_SET_PERIOD:
            p = bytearray(4)
        f = bytearray(reframe(f[2], bytes(p)))
    elif kind == 8:                             # name length byte disagrees
        p = bytearray(f[4:-4])
        if f[2] == pr.TYPE_START_PROFILE:
            p[12] = int(rng.integers(0, 256))
        f = bytearray(reframe(f[2], bytes(p)))
    else:                                       # arbitrary bytes
        f = bytearray(pr.SYNC + rng.bytes(int(rng.integers(0, 60))))
    return bytes(f)


def test_corrupt_frames_are_rejected_where_python_rejects_them(host):
    rng = np.random.default_rng(5)
    frames = [_corrupt(rng, pr.encode_command(random_command(rng))) for _ in range(6000)]
    out = run(host, [f'parse {f.hex() or "-"}' for f in frames])
    python = [python_parse(f) for f in frames]
    mismatches = [(f.hex(), p, c_parse(a)) for f, p, a in zip(frames, python, out, strict=True)
                  if p != c_parse(a)]
    assert mismatches == []
    kinds = {p for p in python if p.startswith('e:')}
    assert kinds == {f'e:{k}' for k in pr.ERROR_KINDS}      # every kind was exercised


def _random_stream(rng):
    """Valid, corrupted and torn command frames mixed with garbage (incl. sync bytes)."""
    parts = []
    for _ in range(int(rng.integers(1, 12))):
        frame = pr.encode_command(random_command(rng))
        what = int(rng.integers(0, 6))
        if what == 0:
            parts.append(rng.bytes(int(rng.integers(1, 8))))
        elif what == 1:
            parts.append(rng.choice([0xA5, 0x5A, 0x10, 0x12, 0x00, 0x04],
                                    int(rng.integers(1, 8))).astype(np.uint8).tobytes())
        elif what == 2:
            parts.append(_corrupt(rng, frame))
        elif what == 3:
            parts.append(frame[:int(rng.integers(1, len(frame)))])
        else:
            parts.append(frame)
    return b''.join(parts)


def test_byte_stream_splits_like_python_command_parser(host):
    rng = np.random.default_rng(6)
    streams = [_random_stream(rng) for _ in range(1000)]
    lines = []
    for s in streams:
        lines += ['init 10000 100 0 1 0', f'feed {s.hex()}', 'flush']
    out = run(host, lines)
    n_items = n_errors = 0
    for k, stream in enumerate(streams):
        parser = CommandParser()
        want = [describe(x) for x in parser.feed(stream) + parser.flush()]
        fed, flushed = out[3 * k + 1].split(), out[3 * k + 2].split()
        got = fed[1:-1] + flushed[1:-1]
        assert got == want, stream.hex()
        assert flushed[-1] == f'g:{parser.garbage_bytes}', stream.hex()
        n_items += len(want)
        n_errors += sum(w.startswith('e:') for w in want)
    assert n_items > 3000 and n_errors > 500


# ---------------------------------------------------------------------------------------
# the card


def _card_script(rng, max_input, micros0, n_samples, period=0.01, watchdog=0.0):
    """Commands and ticks for the C card plus the VirtualCard's expected bytes."""
    card = VirtualCard(period=period, max_input=max_input, watchdog=watchdog, random_state=0)
    lines = [f'init {round(period * 1e6)} {max_input!r} {round(watchdog * 1e6)} 1 {micros0}']
    expected = ['ok']
    while card.seq < n_samples:
        if card.seq and rng.random() < 0.15:
            frame = pr.encode_command(_card_command(rng, max_input))
            # just after the last sample: before the next one even if the period shrinks
            t_cmd = card.t_us - card.period_us + int(rng.integers(1, 100))
            lines.append(f'rx {(micros0 + t_cmd) % U32} {frame.hex()}')
            # the simulated card, too, handles the command as decoded from the wire
            expected.append(pr.encode_reply(card.handle(pr.parse_command(frame),
                                                         t_cmd)).hex())
        t_us = card.t_us
        sample = card.step()
        if t_us:
            lines.append(f'tick {(micros0 + t_us - 1) % U32} 0 0')   # not due yet
            expected.append('none')
        lines.append(f'tick {(micros0 + t_us) % U32} {f32(sample.speed)} '
                     f'{f32(sample.current)}')
        expected.append(f'{t_us} {pr.encode_sample(sample).hex()} {f32(sample.voltage):08x}')
    return lines, expected, card


def _card_command(rng, max_input):
    kind = int(rng.integers(0, 7))
    if kind == 0:
        return pr.SetVoltage(float(rng.uniform(-1.2, 1.2) * max_input))
    if kind == 1:
        above = np.nextafter(np.float32(max_input), np.float32(np.inf))   # float32 limit
        return pr.SetVoltage(float(rng.choice([max_input, -max_input, above, -above])))
    if kind in (2, 6):
        return pr.StartProfile(str(rng.choice(['paper_steps', 'bipolar_steps', 'Paper'])),
                               float(rng.uniform(-1.1, 1.1) * max_input), 0,
                               float(rng.choice([0.0, -1.0, 0.013, 0.2, 5.0, 31.0])))
    if kind == 3:
        return pr.Stop()
    if kind == 4:
        return pr.SetPeriod(float(rng.choice([0.005, 0.01, 0.02, 5e-5, 20.0, 1e-4])))
    return pr.Ping(int(rng.integers(0, U32)))


@pytest.mark.parametrize('max_input,watchdog', [(100.0, 0.0), (12.0, 0.0), (12.0, 0.05)])
def test_card_matches_virtual_card_byte_for_byte(host, max_input, watchdog):
    """Replies and sample frames equal the simulated card's (voltage limit and watchdog
    included: with 50 ms, commands ~70 ms apart on average leave gaps that trip it)."""
    rng = np.random.default_rng(7)
    lines, expected, card = _card_script(rng, max_input, U32 - 7_000_000, 3000,
                                         watchdog=watchdog)
    out = run(host, lines + ['stat'])
    assert out[:-1] == expected
    assert int(out[-1].split()[-1]) == card.watchdog_trips
    assert (card.watchdog_trips > 20) == bool(watchdog)
    replies = [pr.parse_frame(bytes.fromhex(e)) for e, line in zip(expected, lines, strict=False)
               if line.startswith('rx')]
    statuses = {r.status for r in replies}
    assert {'ok', 'bad_value', 'unknown_profile', 'busy'} <= statuses
    assert len(replies) > 400
    limited = [r for r in replies if r.command == 'set_voltage' and r.status == 'bad_value']
    assert len(limited) > 20


def test_card_answers_unsupported_for_host_side_profiles(host):
    lines = ['init 10000 100 0 1 0', 'tick 0 0 0']
    for name in ('prbs', 'multisine'):
        lines.append(f'rx 100 {pr.encode_command(pr.StartProfile(name, 5.0, 3, 1.0)).hex()}')
    lines.append('tick 10000 0 0')
    out = run(host, lines)
    assert [pr.parse_frame(bytes.fromhex(a)) for a in out[2:4]] == [
        pr.Reply('start_profile', 'unsupported', 1)] * 2
    sample = pr.parse_frame(bytes.fromhex(out[4].split()[1]))
    assert (sample.voltage, sample.flags & pr.FLAG_PROFILE) == (0.0, 0)


def test_card_flags_an_overrun_and_skips_missed_deadlines(host):
    out = run(host, ['init 1000 100 0 0 0', 'tick 0 0 0', 'tick 3500 0 0', 'tick 3999 0 0',
                     'tick 4000 0 0'])
    first, late, early, on_time = out[1:]
    assert pr.parse_frame(bytes.fromhex(first.split()[1])).flags == pr.FLAG_STARTUP
    late_sample = pr.parse_frame(bytes.fromhex(late.split()[1]))
    assert (late_sample.seq, late_sample.t_card, late_sample.flags) == (1, 3500e-6,
                                                                         pr.FLAG_OVERRUN)
    assert early == 'none'
    assert pr.parse_frame(bytes.fromhex(on_time.split()[1])).flags == 0


# ---------------------------------------------------------------------------------------
# time base


def test_card_time_is_monotonic_across_the_micros_wrap(host):
    micros0 = U32 - 5000
    readings = list(range(U32 - 1000, U32 + 1001))
    big = [U32 + 1000 + k * (2 ** 31 - 12345) for k in range(1, 13)]   # < 2^31 apart
    lines = [f'init 10000 100 0 1 {micros0}']
    lines += [f'clock {r % U32}' for r in readings + big]
    lines.append(f'tick {(big[-1] + 1) % U32} 0 0')
    out = run(host, lines)
    times = [int(x) for x in out[1:-1]]
    assert times == [r - micros0 for r in readings + big]
    assert all(b > a for a, b in itertools.pairwise(times))
    assert times[-1] > 5 * U32                     # five more wraps, still exact
    _, frame, _ = out[-1].split()
    assert pr.parse_frame(bytes.fromhex(frame)).t_card == pytest.approx(
        (big[-1] + 1 - micros0) / 1e6, abs=0.5e-6)


def test_clock_takes_an_older_latched_reading_without_jumping(host):
    """A timer latches micros() before loop() reads it: that reading is in the past."""
    micros0 = U32 - 30
    readings = [U32 - 30, U32 - 40, U32 + 20, U32 - 10, U32 + 5, U32 + 2 ** 31 - 1, U32 + 21]
    out = run(host, [f'init 10000 100 0 1 {micros0}'] + [f'clock {r % U32}' for r in readings])
    assert [int(x) for x in out[1:]] == [0, 0, 50, 20, 35, 2 ** 31 + 29, 51]


@pytest.mark.parametrize('step_s,period_us', [(3, 100), (16, 1000), (28, 1000)])
@pytest.mark.parametrize('offset_us', [-1000, 0, 1000])
def test_paper_steps_at_the_right_instants_across_the_wrap(host, step_s, period_us,
                                                           offset_us):
    """micros() wraps within 1 ms of a step of the profile: levels and times stay exact."""
    step_us = step_s * 1_000_000
    micros0 = (U32 - step_us + offset_us) % U32       # the wrap at card time step - offset
    duration = (step_us + 2000) / 1e6
    n = math.ceil(float(np.float32(duration)) / (period_us / 1e6) - 1e-9)   # as the card
    profile = pr.StartProfile('paper_steps', 9.0, 0, duration)
    lines = [f'init {period_us} 100 0 0 {micros0}',
             f'rx {micros0} {pr.encode_command(profile).hex()}']
    lines += [f'tick {(micros0 + k * period_us) % U32} 0 0' for k in range(n + 1)]
    out = run(host, lines)
    assert pr.parse_frame(bytes.fromhex(out[1])) == pr.Reply('start_profile', 'ok', 0)
    samples = [pr.parse_frame(bytes.fromhex(a.split()[1])) for a in out[2:]]
    t_us = np.array([round(s.t_card * 1e6) for s in samples])
    np.testing.assert_array_equal(t_us, np.arange(n + 1) * period_us)
    want = np.float32(make_excitation('paper_steps', np.arange(n) * (period_us / 1e6), 9.0))
    got = np.array([s.voltage for s in samples[:n]], dtype=np.float32)
    np.testing.assert_array_equal(got, want)
    at = step_us // period_us
    assert (samples[at - 1].voltage, samples[at].voltage) == (
        np.float32({3: 0.0, 16: 3.8, 28: 7.0}[step_s]), np.float32({3: 3.8, 16: 7.0,
                                                                   28: 9.0}[step_s]))
    assert [s.flags & (pr.FLAG_PROFILE | pr.FLAG_PROFILE_END) for s in samples[-2:]] == [
        pr.FLAG_PROFILE | pr.FLAG_PROFILE_END, 0]
    assert samples[-1].voltage == 0.0
    assert all(math.isnan(s.current) for s in samples)


# ---------------------------------------------------------------------------------------
# safety


def _voltages(out):
    return [pr.parse_frame(bytes.fromhex(a.split()[1])).voltage for a in out
            if len(a.split()) == 3]


def test_watchdog_drops_to_zero_volts_without_commands(host):
    """External mode: 0 V once 50 ms pass without a command; a ping keeps it alive."""
    set5 = pr.encode_command(pr.SetVoltage(5.0)).hex()
    set6 = pr.encode_command(pr.SetVoltage(6.0)).hex()
    ping = pr.encode_command(pr.Ping(9)).hex()
    lines = ['init 10000 12 50000 0 0', 'tick 0 0 0', 'tick 10000 0 0', f'rx 10000 {set5}']
    lines += [f'tick {t} 0 0' for t in range(20000, 70000, 10000)]      # 20 .. 60 ms
    lines += [f'rx 65000 {set6}'] + [f'tick {t} 0 0' for t in (70000, 80000, 90000)]
    lines += [f'rx 95000 {ping}'] + [f'tick {t} 0 0' for t in range(100000, 170000, 10000)]
    lines.append('stat')
    out = run(host, lines)
    v = _voltages(out)
    assert v[:7] == [0.0, 0.0, 5.0, 5.0, 5.0, 5.0, 0.0]    # 60 ms - 10 ms = 50 ms: off
    assert v[7:] == [6.0] * 8 + [0.0] * 2                  # 150 ms - 95 ms >= 50 ms
    assert out[-1].split()[-1] == '2'


def test_watchdog_takes_a_sample_latched_before_the_last_command(host):
    """The timer latched t = 20 ms; a ping read at 20.05 ms is newer: no trip."""
    set5 = pr.encode_command(pr.SetVoltage(5.0)).hex()
    ping = pr.encode_command(pr.Ping(1)).hex()
    out = run(host, ['init 10000 12 50000 0 0', 'tick 0 0 0', f'rx 10 {set5}',
                     'tick 10000 0 0', f'rx 20050 {ping}', 'tick 20000 0 0', 'stat'])
    assert out[-2].split()[0] == '20000'
    assert _voltages(out) == [0.0, 5.0, 5.0]
    assert out[-1].split()[-1] == '0'


def _profile_with_pings(host, last_ping_us, watchdog_us=500_000, until_us=20_000_000):
    """paper_steps at 9 V for 40 s, a ping every 100 ms up to ``last_ping_us``, then
    silence (the driver was killed): the C card's samples and its statistics."""
    profile = pr.encode_command(pr.StartProfile('paper_steps', 9.0, 0, 40.0)).hex()
    lines = [f'init 10000 12 {watchdog_us} 0 0', 'tick 0 0 0', f'rx 1 {profile}']
    pings = range(100_000, last_ping_us + 1, 100_000)
    events = [(t, f'rx {t} {pr.encode_command(pr.Ping(t)).hex()}') for t in pings]
    events += [(t, f'tick {t} 0 0') for t in range(10_000, until_us + 1, 10_000)]
    lines += [line for _, line in sorted(events, key=lambda e: (e[0], e[1][0] == 't'))]
    out = run(host, lines + ['stat'])
    samples = [pr.parse_frame(bytes.fromhex(a.split()[1])) for a in out[:-1]
               if len(a.split()) == 3]
    return samples, out[-1].split()


def test_watchdog_stops_a_profile_when_the_host_goes_silent(host):
    """The driver dies 3.5 s into paper_steps (3.8 V): the card is at 0 V within the
    0.5 s watchdog and stays there (no 7 V at 16 s); its pings kept it running before."""
    samples, stat = _profile_with_pings(host, last_ping_us=3_500_000)
    t = np.array([s.t_card for s in samples])
    v = np.array([s.voltage for s in samples])
    zero = np.flatnonzero((t > 3.5) & (v == 0.0))[0]
    assert np.all(v[(t > 3.005) & (t < t[zero])] == np.float32(3.8))  # pinged: running
    delay = t[zero] - 3.5
    assert 0.5 - 0.010 < delay <= 0.5 + 1e-9          # within the watchdog, to a period
    assert np.all(v[zero:] == 0.0) and t[-1] >= 20.0   # never 7 V (16 s) or 9 V (28 s)
    assert not samples[zero].flags & pr.FLAG_PROFILE   # the profile is abandoned
    assert stat[-1] == '1'                             # one watchdog trip


def test_pings_keep_a_profile_running_past_the_watchdog(host):
    samples, stat = _profile_with_pings(host, last_ping_us=20_000_000)
    v = {round(s.t_card, 2): s.voltage for s in samples}   # profile time: t - 10 ms
    assert (v[3.0], v[3.01], v[16.01], v[20.0]) == (0.0, np.float32(3.8), np.float32(7.0),
                                                    np.float32(7.0))
    assert stat[-1] == '0'


def test_watchdog_can_be_switched_off(host):
    profile = pr.encode_command(pr.StartProfile('paper_steps', 9.0, 0, 4.0)).hex()
    set5 = pr.encode_command(pr.SetVoltage(5.0)).hex()
    ticks = [f'tick {k * 10000} 0 0' for k in range(1, 402)]
    off = run(host, ['init 10000 12 0 0 0', 'tick 0 0 0', f'rx 1 {profile}', *ticks, 'stat'])
    v = _voltages(off)
    assert v[301] == np.float32(3.8) and v[400] == np.float32(3.8)   # 4 s, no command
    assert v[401] == 0.0 and off[-1].split()[-1] == '0'
    off = run(host, ['init 10000 12 0 0 0', 'tick 0 0 0', f'rx 1 {set5}', *ticks, 'stat'])
    assert _voltages(off)[1:] == [5.0] * 401
    assert off[-1].split()[-1] == '0'


def test_voltage_limit_rejects_and_keeps_the_held_input(host):
    commands = [pr.SetVoltage(12.0), pr.SetVoltage(float(np.nextafter(np.float32(12.0),
                                                                      np.float32(13.0)))),
                pr.SetVoltage(-3e38), pr.StartProfile('paper_steps', 12.5, 0, 1.0),
                pr.SetVoltage(-12.0)]
    lines = ['init 10000 12 0 0 0', 'tick 0 0 0']
    for k, c in enumerate(commands):
        lines += [f'rx {k * 10000 + 1} {pr.encode_command(c).hex()}',
                  f'tick {(k + 1) * 10000} 0 0']
    out = run(host, lines)
    replies = [pr.parse_frame(bytes.fromhex(a)) for a in out[2::2]]
    assert [r.status for r in replies] == ['ok', 'bad_value', 'bad_value', 'bad_value', 'ok']
    assert _voltages(out)[1:] == [12.0, 12.0, 12.0, 12.0, -12.0]


def test_header_compiles_as_cpp_for_arduino(tmp_path):
    cxx = _compiler('c++', 'g++', 'clang++')
    if cxx is None:
        pytest.skip('no C++ compiler on this machine')
    exe = tmp_path / 'host_main_cpp'
    build([cxx, '-x', 'c++', '-std=c++11', *WARNINGS, '-o', str(exe), str(HOST_MAIN)])
    assert run(exe, ['crc 313233343536373839']) == ['cbf43926']
