"""Reliability under faults: the serial line (raw pty and the simulated card), the identifier.

Every case drives real node processes (driver, identifier) with a per-module
ROS_DOMAIN_ID and LOCALHOST discovery; the serial line is a real pseudo-terminal, written
either byte by byte by the test (exact fault accounting) or by ``motor-id card-sim`` with
fault injection (sustained faults, disconnects). What is checked: nothing crashes, every
bad or lost frame is counted on /diagnostics, gaps stay gaps, one log line per kind of
fault, and the identifier answers misuse with a reason and keeps serving.
"""

import os
import re
import select
import subprocess
import sys
import threading
import time
import tty

from diagnostic_msgs.msg import DiagnosticArray
from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from motor_id.card import protocol as pr
from motor_id.card.sequence import SequenceTracker
from motor_id.card.stream import FrameParser
from motor_id.errors import ProtocolError
from motor_id.excitation import make_excitation
from motor_id.model import MotorParams, Plant
from motor_id.nodes import messages
from motor_id.simulate import simulate_recording
from motor_id.testing.procs import domain_id, wait_until
from motor_id.testing.ros import (
    latest_status,
    publish_samples,
    REPO,
    ros_env,
    rows_of,
    samples_publisher,
    stop_cleanly,
)

DOMAIN = domain_id(__name__)
SI_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
LOG_LINE = re.compile(r'^\[(WARN|ERROR|FATAL)\]', re.MULTILINE)
NO_LIMITS = ('max_voltage:=1000.0', 'max_speed:=0.0', 'max_current:=0.0')
"""The raw-pty streams carry random numbers, not a motor: the safety limits are off."""


# ---------------------------------------------------------------------------------------
# helpers


def node_args(module, *params):
    args = ['-m', f'motor_id.nodes.{module}', '--ros-args']
    for p in params:
        args += ['-p', p]
    return args


def card_args(link, *extra):
    return ['-m', 'motor_id.cli', 'card-sim', '--link', str(link)] + list(extra)


def warnings_of(proc):
    """The WARN / ERROR / FATAL lines a node logged."""
    return [line for line in proc.stderr().splitlines() if LOG_LINE.match(line)]


class RawPty:
    """A pseudo-terminal whose card side the test writes byte by byte.

    The driver opens :attr:`path`; the test keeps both ends open (so the device does not
    hang up) and drains what the driver sends (its commands) in a thread.
    """

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.received = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self):
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.05)
            if r:
                try:
                    self.received += os.read(self.master, 4096)
                except OSError:
                    return

    def write(self, data, rng=None, pause=0.002):
        """Write ``data`` in chunks of random size (a UART delivers in odd pieces)."""
        rng = rng or np.random.default_rng(0)
        pos = 0
        while pos < len(data):
            n = int(rng.integers(1, 700))
            os.write(self.master, data[pos:pos + n])
            pos += n
            time.sleep(pause)

    def close(self):
        self._stop.set()
        self._thread.join(2.0)
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture
def raw_pty():
    pty = RawPty()
    yield pty
    pty.close()


def f32(x):
    return np.asarray(x, dtype=np.float32).astype(float)


def sample(seq, rng):
    """A sample whose values are float32 numbers (they cross the wire unchanged)."""
    v, w, i = f32(rng.normal(0.0, 5.0, 3))
    return pr.Sample(seq, seq * 10_000 / 1e6, float(v), float(w), float(i), pr.FLAG_CURRENT)


def junk(rng, n):
    """Random bytes without 0xA5 (so each one is exactly one garbage byte to the parser)."""
    b = rng.integers(0, 255, n)
    b[b >= 0xA5] += 1
    return b.astype(np.uint8).tobytes()


def crafted_stream(n=400, seed=1):
    """Frames seq 0..n-1 with known faults at known places, and what a driver must see.

    Returns
    -------
    data : bytes
    expect : dict
        Exact counts (``frames_ok``, ``bad``, ``lost``, ``duplicates``, ``late``,
        ``garbage``) and ``published``: {seq: Sample} that must come out, in order.
    """
    rng = np.random.default_rng(seed)
    samples = [sample(k, rng) for k in range(n)]
    slots = rng.permutation(np.arange(10, n - 10, 3))   # never adjacent, never at the ends
    kinds = {'garbage': 8, 'bad_crc': 5, 'truncated': 4, 'drop': 5, 'duplicate': 4,
             'swap': 4}
    at, pos = {}, 0
    for kind, count in kinds.items():
        for s in slots[pos:pos + count]:
            at[int(s)] = kind
        pos += count
    out = bytearray()
    exp = dict(frames_ok=0, bad=0, lost=0, duplicates=0, late=0, garbage=0)
    published = {}
    k = 0
    while k < n:
        frame = pr.encode_sample(samples[k])
        kind = at.get(k)
        if kind == 'garbage':
            g = junk(rng, int(rng.integers(1, 40)))
            out += g + frame
            exp['garbage'] += len(g)
        elif kind == 'bad_crc':
            bad = bytearray(frame)
            bit = int(rng.integers(0, 8 * (len(frame) - pr.OVERHEAD)))
            bad[pr.HEADER.size + bit // 8] ^= 1 << (bit % 8)
            out += bad
            exp['bad'] += 1
            exp['lost'] += 1
        elif kind == 'truncated':
            cut = int(rng.integers(6, len(frame) - 2))
            out += frame[:cut]
            exp['bad'] += 1
            exp['lost'] += 1
            exp['garbage'] += cut
        elif kind == 'drop':
            exp['lost'] += 1
        elif kind == 'duplicate':
            out += frame + frame
            exp['duplicates'] += 1
        elif kind == 'swap':   # k + 1 overtakes k: k arrives late and is dropped, counted
            out += pr.encode_sample(samples[k + 1]) + frame
            published[k + 1] = samples[k + 1]
            exp['late'] += 1
            exp['frames_ok'] += 2
            k += 2
            continue
        else:
            out += frame
        if kind not in ('bad_crc', 'truncated', 'drop'):
            published[k] = samples[k]
            exp['frames_ok'] += 1 + (kind == 'duplicate')
        k += 1
    exp['published'] = published
    return bytes(out), exp


# ---------------------------------------------------------------------------------------
# the protocol: no good frame is lost next to garbage, corrupted and torn frames


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(('ok', 'garbage', 'bad_crc', 'torn')),
                          st.integers(0, 2 ** 31)), min_size=1, max_size=40),
       st.integers(1, 97))
def test_stream_parser_keeps_every_good_frame_between_faults(plan, step):
    """Arbitrary mixes of faults, cut at arbitrary points: good frames all come out."""
    rng = np.random.default_rng(len(plan) * 1000 + step)
    data, good, bad, garbage, torn_before = bytearray(), [], 0, 0, 0
    for k, (kind, seed) in enumerate(plan):
        s = sample(k, np.random.default_rng(seed))
        frame = pr.encode_sample(s)
        if kind == 'garbage':
            g = junk(rng, int(rng.integers(1, 30)))
            data += g
            garbage += len(g)
        elif kind == 'bad_crc':
            frame = bytearray(frame)
            frame[pr.HEADER.size + int(rng.integers(0, len(frame) - pr.OVERHEAD))] ^= 0x10
            data += frame
            bad += 1
            torn_before = 0
            continue
        elif kind == 'torn':
            cut = int(rng.integers(6, len(frame) - 2))
            if torn_before + cut == len(frame):
                # two torn pieces that add up to exactly one frame length, followed by a
                # sync, are one corrupted frame to any parser: keep the count unambiguous
                cut += 1 if cut < len(frame) - 3 else -1
            data += frame[:cut]
            bad += 1
            torn_before = cut
            continue
        torn_before = 0
        data += frame
        good.append(s)
    last = sample(len(plan), rng)   # a last good frame closes the stream
    data += pr.encode_sample(last)
    good.append(last)
    parser = FrameParser()
    items = []
    for i in range(0, len(data), step):
        items += parser.feed(bytes(data[i:i + step]))
    items += parser.flush()
    got = [x for x in items if isinstance(x, pr.Sample)]
    errors = [x for x in items if isinstance(x, ProtocolError)]
    assert got == good
    assert len(errors) == bad and all(e.kind == 'bad_crc' for e in errors)
    assert parser.garbage_bytes >= garbage


def test_crafted_stream_expectations_hold_for_the_parser():
    """The expectations of :func:`crafted_stream` are right (checked without ROS)."""
    data, exp = crafted_stream()
    parser, tracker = FrameParser(), SequenceTracker()
    published = []
    for i in range(0, len(data), 37):
        for item in parser.feed(data[i:i + 37]):
            if isinstance(item, pr.Sample) and \
                    tracker.update(item.seq).kind not in ('duplicate', 'late'):
                published.append(item)
    assert parser.frames == exp['frames_ok']
    assert sum(parser.errors.values()) == parser.errors['bad_crc'] == exp['bad']
    assert parser.garbage_bytes == exp['garbage']
    assert (tracker.lost, tracker.duplicates, tracker.late) == \
        (exp['lost'], exp['duplicates'], exp['late'])
    assert published == list(exp['published'].values())


# ---------------------------------------------------------------------------------------
# the driver on a raw pty


def test_driver_counts_every_fault_on_a_raw_pty(client, launch, raw_pty):
    """Garbage, bad CRCs, torn frames, drops, duplicates and reordering, all counted."""
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    drv = launch('driver', node_args('driver', f'device:={raw_pty.path}',
                                     'excitation:=external', 'publish_channels:=false',
                                     *NO_LIMITS))
    drv.wait_for('device .* open')
    assert wait_until(lambda: client.node.count_subscribers('/samples') >= 1 and
                      client.node.count_publishers('/samples') >= 1, 20.0)
    time.sleep(0.5)
    data, exp = crafted_stream()
    raw_pty.write(data, np.random.default_rng(2))

    def counted():
        st_ = latest_status(diags, 'motor_id: driver')
        return int(st_.get('frames_ok', 0)) >= exp['frames_ok'] and \
            int(st_.get('samples_published', 0)) >= len(exp['published'])
    assert wait_until(counted, 15.0), (latest_status(diags, 'motor_id: driver'),
                                       drv.output())
    time.sleep(1.2)   # one more diagnostics period: the counts must not move on
    st_ = latest_status(diags, 'motor_id: driver')
    assert int(st_['frames_ok']) == exp['frames_ok']
    assert int(st_['frames_bad']) == int(st_['frame_bad_crc']) == exp['bad']
    assert int(st_['garbage_bytes']) == exp['garbage']
    assert (int(st_['lost']), int(st_['duplicates']), int(st_['late'])) == \
        (exp['lost'], exp['duplicates'], exp['late'])
    assert int(st_['samples_published']) == len(exp['published'])
    assert st_['link'] == 'stalled'   # the test stopped writing more than a second ago
    # gaps stay gaps: exactly the good frames come out, in order, values untouched
    rows = rows_of(samples)
    want = np.array([[s.seq, s.t_card, s.voltage, s.speed, s.current, s.flags]
                     for s in exp['published'].values()])
    np.testing.assert_array_equal(rows, want)
    # one log line per kind of fault, not one per fault
    text = drv.stderr()
    for pattern in ('bad frame from the card', r'frame\(s\) lost before',
                    'duplicate frame seq', 'late frame seq'):
        assert len(re.findall(pattern, text)) == 1, (pattern, text)
    assert len(warnings_of(drv)) == 4, text
    assert raw_pty.received   # the driver did talk to the "card" (set period)
    stop_cleanly(drv)


def uart_receive(data, ratio, rng, idle=3):
    """What a UART receiver set to the wrong baud rate makes of ``data``.

    The sender puts each byte on the line as 8N1 (start bit 0, 8 data bits LSB first,
    stop bit 1) with up to ``idle`` idle (1) bit times between bytes. The receiver waits
    for a falling edge, samples the middle of each of its own bit times, which are
    ``ratio`` sender bit times long, and delivers the byte whether or not the stop bit
    is right (framing errors are not reported in raw mode).

    Parameters
    ----------
    data : bytes
    ratio : float
        Sender baud / receiver baud (e.g. 0.5: card at 57600, host at 115200).
    rng : numpy.random.Generator
    idle : int

    Returns
    -------
    bytes
    """
    byte = np.frombuffer(data, dtype=np.uint8)
    bits = ((byte[:, None] >> np.arange(8)) & 1).astype(np.uint8)
    gaps = rng.integers(0, idle + 1, byte.size)
    line = []
    for b, g in zip(bits, gaps, strict=True):
        line.append(np.concatenate(([0], b, [1], np.ones(g, dtype=np.uint8))))
    line = np.concatenate([np.ones(4, dtype=np.uint8)] + line + [np.ones(20, np.uint8)])
    out = bytearray()
    t = 1
    n = line.size
    while True:
        falls = np.flatnonzero((line[t:-1] == 1) & (line[t + 1:] == 0))
        if falls.size == 0:
            break
        edge = t + 1 + int(falls[0])
        points = edge + ratio * (1.5 + np.arange(8))
        if points[-1] >= n:
            break
        value = int(np.sum(line[points.astype(int)] << np.arange(8)))
        out.append(value)
        t = int(edge + ratio * 9.5)
        if t >= n - 2:
            break
    return bytes(out)


def test_driver_warns_once_on_a_baud_rate_mismatch_and_recovers(client, launch, raw_pty):
    """A wrong line rate: garbage counted, one warning naming the baud rate, no crash."""
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    drv = launch('driver', node_args('driver', f'device:={raw_pty.path}',
                                     'excitation:=external', 'publish_channels:=false',
                                     *NO_LIMITS))
    drv.wait_for('device .* open')
    assert wait_until(lambda: client.node.count_publishers('/samples') >= 1, 20.0)
    time.sleep(0.5)
    rng = np.random.default_rng(7)
    frames = b''.join(pr.encode_sample(sample(k, rng)) for k in range(2000))
    garbled = [uart_receive(frames[:24000], 0.5, rng),    # host twice as fast as the card
               uart_receive(frames[24000:], 2.0, rng)]    # host twice as slow
    assert sum(map(len, garbled)) > 40000
    good = [pr.encode_sample(sample(k, rng)) for k in range(3000, 3100)]
    raw_pty.write(b''.join(good[:50]), rng)
    seen_garbled = []
    for g in garbled:   # two episodes, ~2 s each, a little good data between them
        end = time.monotonic() + 2.5
        for k in range(0, len(g), 1000):
            raw_pty.write(g[k:k + 1000], rng, pause=0.0)
            time.sleep(max(0.0, (end - time.monotonic()) / ((len(g) - k) / 1000 + 1)))
            seen_garbled.append(latest_status(diags, 'motor_id: driver').get('link'))
        mark = len(diags)   # statuses from here on follow the garbled episode
        raw_pty.write(b''.join(good[50:75] if g is garbled[0] else good[75:]), rng)
    assert wait_until(lambda: int(latest_status(diags, 'motor_id: driver')
                                  .get('samples_published', 0)) >= 100, 10.0)
    st_ = latest_status(diags, 'motor_id: driver')
    assert drv.proc.poll() is None
    assert 'garbled' in seen_garbled, seen_garbled   # /diagnostics said so meanwhile
    # and recovered with good frames (a second after the last of them it may be stalled)
    links = [{kv.key: kv.value for kv in s.values}.get('link')
             for d in list(diags)[mark:] for s in d.status if s.name == 'motor_id: driver']
    assert 'connected' in links, links
    assert int(st_['garbage_bytes']) >= 0.9 * sum(map(len, garbled))
    assert int(st_['frames_ok']) == 100
    rows = rows_of(samples)
    np.testing.assert_array_equal(rows[:, 0], np.arange(3000, 3100))
    text = drv.stderr()
    found = re.findall(r'no valid frame in \d+ bytes: check the baud rate', text)
    assert len(found) == 1, text
    assert len(warnings_of(drv)) <= 3, text
    stop_cleanly(drv)


# ---------------------------------------------------------------------------------------
# the driver with the simulated card: sustained faults, disconnects, missing device


def test_driver_accounts_for_every_frame_under_sustained_faults(client, launch, tmp_path):
    """Heavy faults plus disconnects for seconds: exact accounting and a quiet log."""
    link = tmp_path / 'card'
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    drv = launch('driver', node_args('driver', f'device:={link}', 'reopen_backoff_max:=0.2',
                                     'excitation:=prbs', 'duration:=1000.0',
                                     'publish_channels:=false'))
    drv.wait_for('cannot open')
    # the client must be matched before the card starts: it compares its rows with
    # what the driver published (discovery takes up to ~3.5 s on a loaded machine)
    assert wait_until(lambda: client.node.count_publishers('/samples') >= 1, 20.0)
    time.sleep(1.5)   # the device is missing: retried with backoff, logged once
    assert drv.stderr().count('cannot open') == 1, drv.stderr()
    card = launch('card', card_args(link, '--speedup', '5', '--seed', '4',
                                    '--fault', 'garbage=0.2', '--fault', 'bad_crc=0.05',
                                    '--fault', 'drop=0.05', '--fault', 'duplicate=0.05',
                                    '--fault', 'reorder=0.05', '--fault', 'disconnect=2:0.4'))

    def enough():
        st_ = latest_status(diags, 'motor_id: driver')
        return int(st_.get('device_lost', 0)) >= 3 and int(st_.get('frames_bad', 0)) > 100
    assert wait_until(enough, 30.0), (latest_status(diags, 'motor_id: driver'),
                                      drv.output())
    stop_cleanly(card)
    assert wait_until(lambda: latest_status(diags, 'motor_id: driver').get('link') ==
                      'disconnected', 10.0)
    published = lambda: int(latest_status(diags, 'motor_id: driver')   # noqa: E731
                            .get('samples_published', -1))
    assert wait_until(lambda: rows_of(samples).shape[0] == published(), 10.0)
    st_ = latest_status(diags, 'motor_id: driver')
    rows = rows_of(samples)
    seq = rows[:, 0].astype(np.int64)
    assert np.all(np.diff(seq) >= 1)               # no duplicate, nothing out of order
    assert np.all(np.diff(rows[:, 1]) > 0)
    missing = int(seq[-1] - seq[0] + 1 - seq.size)  # gaps in what was published...
    # every late frame is dropped; one older than the first published frame (the card
    # swapped it with that one) is late but was never missing from the published range
    accounted = int(st_['lost']) + int(st_['late'])
    assert accounted - 1 <= missing <= accounted, (missing, accounted, seq[:5], drv.stderr())
    assert int(st_['lost']) > 100 and int(st_['duplicates']) > 20
    assert int(st_['garbage_bytes']) > 1000
    assert int(st_['opens']) == int(st_['device_lost'])   # the last loss: the card stopped
    assert drv.proc.poll() is None
    # the log: a line per outage (lost, reopened, cannot open) and one per fault kind
    outages = int(st_['device_lost'])
    kinds = [k for k in st_ if k.startswith('frame_')] + ['lost', 'duplicate', 'late']
    warnings = warnings_of(drv)
    assert len(warnings) <= len(kinds) + 2 * outages + 2, '\n'.join(warnings)
    assert drv.stderr().count('bad frame from the card') <= len(kinds)
    stop_cleanly(drv)


# ---------------------------------------------------------------------------------------
# the identifier under misuse


def prbs_rows(n, period=0.01, seed=0):
    """Rows seq, t, voltage, speed, current, flags of a PRBS experiment on the SI motor."""
    t = np.arange(n) * period
    u = make_excitation('prbs', t, 9.0, seed)
    rec = simulate_recording(Plant(SI_MOTOR), t, u)
    return np.column_stack([np.arange(n), t, rec.input, rec.speed, rec.current,
                            np.zeros(n)])


def publish(client, rows, batch=100):
    publish_samples(client, rows, batch)


def identify(client):
    return client.call(Trigger, '/identifier/identify', timeout=120.0)


def test_identifier_refuses_misuse_with_reasons_and_keeps_serving(client, launch):
    """Empty, too few, inf, a gap: each refused with its reason; then a good fit."""
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    proc = launch('identifier', node_args('identifier', 'generations:=20',
                                          'window_s:=25.0'))
    rows = prbs_rows(6000)
    resp = identify(client)
    assert not resp.success and 'buffer is empty' in resp.message
    publish(client, rows[:50])
    assert wait_until(lambda: 'too few samples: 50' in identify(client).message, 10.0)
    bad = rows[50:1000].copy()
    bad[650, 3] = np.inf                       # seq 700
    publish(client, bad)
    assert wait_until(lambda: 'NaN/inf' in identify(client).message, 10.0)
    resp = identify(client)
    assert not resp.success and "channel 'speed' has 1 NaN/inf" in resp.message
    publish(client, np.delete(rows[1000:2000], np.arange(500, 510), axis=0))
    assert wait_until(lambda: 'gap' in identify(client).message, 10.0)
    resp = identify(client)
    assert not resp.success and '10 frame(s) lost' in resp.message
    publish(client, rows[2000:])   # 40 s more: the last 25 s hold neither the inf nor gap
    assert wait_until(lambda: int(latest_status(diags, 'motor_id: identifier')
                                  .get('received', 0)) == 5990, 10.0)
    resp = identify(client)
    assert resp.success, resp.message
    assert 'identified from 2501 samples' in resp.message
    st_ = latest_status(diags, 'motor_id: identifier')
    assert wait_until(lambda: latest_status(diags, 'motor_id: identifier')
                      .get('fits_ok') == '1', 5.0)
    assert int(latest_status(diags, 'motor_id: identifier')['fits_failed']) >= 4, st_
    stop_cleanly(proc)


def test_identifier_loses_no_sample_while_fitting_at_1khz(client, launch):
    """A fit of several seconds while samples stream at 1 kHz: every one is received."""
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    proc = launch('identifier', node_args('identifier', 'generations:=3000',
                                          'window_s:=3.0', 'max_samples:=20000'))
    rows = prbs_rows(40000, period=0.001, seed=3)
    pub = samples_publisher(client)
    sent = [0]
    stop = threading.Event()

    def stream():   # 1 kHz in real time, one row per message (the driver's worst case)
        t0 = time.monotonic()
        while not stop.is_set() and sent[0] < rows.shape[0]:
            due = min(int((time.monotonic() - t0) * 1000.0) + 1, rows.shape[0])
            for k in range(sent[0], due):
                pub.publish(messages.rows_to_msg(rows[k:k + 1]))
            sent[0] = due
            time.sleep(0.001)
    thread = threading.Thread(target=stream, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: sent[0] >= 4000, 20.0)
        fut = client.call_async(Trigger, '/identifier/identify')
        proc.wait_for(r'fitting 300[01] samples', 20.0)   # t = seq * 1 ms: float edge
        fit_start = sent[0]
        assert wait_until(fut.done, 120.0)
        fit_rows = sent[0] - fit_start
        time.sleep(1.0)
    finally:
        stop.set()
        thread.join(5.0)
    resp = fut.result()
    assert resp.success, resp.message
    assert fit_rows >= 1000, f'the fit overlapped only {fit_rows} samples'
    total = sent[0]

    def all_in():
        st_ = latest_status(diags, 'motor_id: identifier')
        return st_.get('received') == str(total)
    assert wait_until(all_in, 20.0), (total, latest_status(diags, 'motor_id: identifier'))
    st_ = latest_status(diags, 'motor_id: identifier')
    assert st_['gaps'] == '0' and st_['duplicates'] == '0'
    stop_cleanly(proc)


def test_identifier_inverted_sample_limits_stop_with_the_parameter_name(launch):
    proc = launch('identifier', node_args('identifier', 'min_samples:=5000',
                                          'max_samples:=1000'))
    code = proc.wait(20.0)
    err = proc.stderr()
    assert code != 0
    assert 'parameter min_samples' in err and 'max_samples' in err, err
    assert 'Traceback' not in err, err


# ---------------------------------------------------------------------------------------
# the soak benchmark, briefly


@pytest.mark.slow
def test_soak_smoke(tmp_path):
    """``benchmarks/soak.py --minutes 0.3`` runs the faulty pipeline and prints PASS."""
    out = tmp_path / 'soak.json'
    proc = subprocess.run([sys.executable, os.path.join(REPO, 'benchmarks', 'soak.py'),
                           '--minutes', '0.3', '--sample-every', '2', '--json', str(out)],
                          env=ros_env(DOMAIN), capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert 'RESULT: PASS' in proc.stdout, proc.stdout
    assert 'Traceback' not in proc.stdout + proc.stderr
    assert out.exists()
