"""Tests of the gap-aware sample ring buffer."""

import threading

import numpy as np
import pytest

from motor_id.data.buffer import COLUMNS, SampleBuffer
from motor_id.errors import ConfigError, DataError


def make_rows(n, seq0=0, t0=0.0, dt=0.01, current=True, seed=0):
    """Rows of a varying input and a smooth response."""
    rng = np.random.default_rng(seed)
    seq = seq0 + np.arange(n)
    t = t0 + dt * np.arange(n)
    v = np.where(rng.random(n) > 0.5, 9.0, -9.0)
    w = np.cumsum(v) * 1e-3
    i = v / 2.3 if current else np.full(n, np.nan)
    return np.column_stack([seq, t, v, w, i, np.zeros(n)])


def test_contiguous_rows_have_no_gaps():
    buf = SampleBuffer(capacity=1000)
    rows = make_rows(200)
    assert buf.extend(rows[:50]) == 50
    buf.extend(rows[50:])
    snap = buf.snapshot()
    assert len(snap) == 200
    assert snap.gaps == ()
    np.testing.assert_array_equal(snap.rows, rows)
    rec = snap.recording(min_samples=20)
    np.testing.assert_allclose(rec.time, rows[:, 1], rtol=0, atol=0)
    np.testing.assert_allclose(rec.current, rows[:, 4], rtol=0, atol=0)
    assert rec.meta['seq_first'] == 0 and rec.meta['seq_last'] == 199
    assert len(COLUMNS) == 6


def test_lost_frames_are_a_gap():
    buf = SampleBuffer()
    rows = make_rows(100)
    buf.extend(np.delete(rows, [40, 41, 42], axis=0))
    snap = buf.snapshot()
    assert len(snap.gaps) == 1
    gap = snap.gaps[0]
    assert gap.kind == 'lost' and gap.seq_before == 39 and gap.seq_after == 43
    assert '3 frame(s) lost' in gap.describe()
    with pytest.raises(DataError, match='gap'):
        snap.recording()
    rec = snap.recording(allow_gaps=True)
    assert len(rec) == 57
    assert rec.meta['seq_first'] == 43


def test_latest_segment_must_hold_min_samples():
    buf = SampleBuffer()
    rows = make_rows(100)
    buf.extend(np.delete(rows, [90], axis=0))
    with pytest.raises(DataError, match='too few samples: 9'):
        buf.snapshot().recording(min_samples=20, allow_gaps=True)


def test_duplicates_are_dropped_and_counted():
    buf = SampleBuffer()
    rows = make_rows(30)
    buf.extend(np.vstack([rows[:10], rows[9:10], rows[10:]]))
    snap = buf.snapshot()
    assert len(snap) == 30 and snap.gaps == ()
    assert buf.duplicates == 1 and snap.duplicates == 1 and snap.received == 31


def test_sequence_reset_is_backwards_gap():
    buf = SampleBuffer()
    buf.extend(make_rows(50, seq0=100))
    buf.extend(make_rows(50, seq0=0, t0=5.0))
    snap = buf.snapshot()
    assert [g.kind for g in snap.gaps] == ['backwards']
    assert snap.gaps[0].index == 50


def test_time_not_increasing_is_gap():
    buf = SampleBuffer()
    rows = make_rows(40)
    rows[20:, 1] -= 0.5
    buf.extend(rows)
    assert [g.kind for g in buf.snapshot().gaps] == ['time']


def test_sequence_wraps_without_gap():
    buf = SampleBuffer(seq_modulus=256)
    rows = make_rows(100, seq0=200)
    rows[:, 0] %= 256
    buf.extend(rows)
    assert buf.snapshot().gaps == ()


def test_marked_gap_and_invalid_rows():
    buf = SampleBuffer()
    rows = make_rows(60)
    buf.extend(rows[:20])
    buf.mark_gap()
    buf.extend(rows[20:40])
    bad = rows[40:].copy()
    bad[0, 0] = np.nan
    buf.extend(bad)
    snap = buf.snapshot()
    assert [g.kind for g in snap.gaps] == ['marked', 'lost']
    assert buf.invalid == 1
    assert 'device reopened' in snap.gaps[0].describe()


def test_capacity_keeps_the_latest_rows():
    buf = SampleBuffer(capacity=64)
    rows = make_rows(1000)
    for k in range(0, 1000, 37):
        buf.extend(rows[k:k + 37])
    snap = buf.snapshot()
    assert len(snap) == 64 and len(buf) == 64
    np.testing.assert_array_equal(snap.rows, rows[-64:])


def test_window_in_seconds():
    buf = SampleBuffer(capacity=10000, window_s=1.0)
    buf.extend(make_rows(500, dt=0.01))
    snap = buf.snapshot()
    assert len(snap) == 101
    assert snap.span == pytest.approx(1.0, rel=0, abs=1e-9)


def test_recording_reasons():
    buf = SampleBuffer()
    with pytest.raises(DataError, match='empty'):
        buf.snapshot().recording()
    buf.extend(make_rows(10))
    with pytest.raises(DataError, match='too few samples: 10'):
        buf.snapshot().recording(min_samples=20)
    buf.clear()
    rows = make_rows(100)
    rows[:, 2] = 3.0
    buf.extend(rows)
    with pytest.raises(DataError, match='no excitation'):
        buf.snapshot().recording()
    buf.clear()
    rows = make_rows(100, seq0=1000)
    rows[50, 3] = np.inf
    buf.extend(rows)
    with pytest.raises(DataError, match='NaN/inf'):
        buf.snapshot().recording()


def test_no_current_channel_becomes_none():
    buf = SampleBuffer()
    buf.extend(make_rows(50, current=False))
    rec = buf.snapshot().recording()
    assert rec.current is None and rec.channels() == ('speed',)


def test_bad_shapes_and_settings():
    buf = SampleBuffer()
    with pytest.raises(DataError, match='shape'):
        buf.extend(np.zeros((3, 5)))
    assert buf.extend(np.zeros((0, 6))) == 0
    with pytest.raises(ConfigError, match='capacity'):
        SampleBuffer(capacity=1)
    with pytest.raises(ConfigError, match='window_s'):
        SampleBuffer(window_s=-1.0)


def test_concurrent_writes_and_snapshots():
    buf = SampleBuffer(capacity=5000)
    rows = make_rows(20000)
    errors = []

    def writer():
        for k in range(0, rows.shape[0], 10):
            buf.extend(rows[k:k + 10])

    def reader():
        for _ in range(200):
            snap = buf.snapshot()
            if snap.gaps or (len(snap) > 1 and np.any(np.diff(snap.rows[:, 0]) != 1)):
                errors.append(snap)

    threads = [threading.Thread(target=writer), threading.Thread(target=reader)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors
    np.testing.assert_array_equal(buf.snapshot().rows, rows[-5000:])


def test_profile_segment_is_the_latest_complete_profile():
    buf = SampleBuffer()
    rows = make_rows(300)
    rows[50:150, 5] = 2
    rows[149, 5] = 6          # end of the first run
    rows[200:280, 5] = 2
    rows[279, 5] = 6          # end of the second run
    buf.extend(rows[:290])
    seg = buf.snapshot().profile_segment()
    np.testing.assert_array_equal(seg.rows, rows[200:280])
    buf.extend(rows[290:])
    buf.clear()
    buf.extend(rows[:260])
    seg = buf.snapshot().profile_segment()
    np.testing.assert_array_equal(seg.rows, rows[50:150])


def test_profile_segment_reasons_and_gaps():
    buf = SampleBuffer()
    rows = make_rows(200)
    rows[20:120, 5] = 2
    buf.extend(rows[:100])
    with pytest.raises(DataError, match='no complete excitation profile'):
        buf.snapshot().profile_segment()
    rows[119, 5] = 6
    buf.clear()
    buf.extend(np.delete(rows, [60], axis=0))
    seg = buf.snapshot().profile_segment()
    assert len(seg) == 99 and [g.index for g in seg.gaps] == [40]
    with pytest.raises(DataError, match='gap'):
        seg.recording()
    small = SampleBuffer(capacity=50)
    small.extend(rows[:150])
    with pytest.raises(DataError, match='started before the window'):
        small.snapshot().profile_segment()
