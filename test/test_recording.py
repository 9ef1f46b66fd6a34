"""Recording: validation gives one clear error per kind of unusable data."""

import numpy as np
import pytest

from motor_id.errors import DataError
from motor_id.recording import Recording
from motor_id.testing.recordings import paper_recording

T = np.arange(30) * 0.1
V = np.r_[np.zeros(10), np.ones(20)]
W = np.linspace(0.0, 2.0, 30)


def test_validate_catches_inf_and_length_mismatch():
    with pytest.raises(DataError, match="'speed' has 1 NaN/inf"):
        Recording(T, V, np.r_[W[:29], np.inf]).validate()
    with pytest.raises(DataError, match='has 29 samples but time has 30'):
        Recording(T, V, np.zeros(29)).validate()


@pytest.mark.parametrize('speed, message', [
    (np.zeros(30), r'no response: the speed is constant \(0 throughout\)'),
    (np.full(30, 3.5) + 1e-14 * np.arange(30), 'the speed is constant'),
    (np.r_[np.zeros(28), 0.1, 0.2], r'nearly constant \(0 in 28 of 30 samples\)'),
])
def test_constant_or_nearly_constant_speed_is_refused(speed, message):
    with pytest.raises(DataError, match=message) as info:
        Recording(T, V, speed).validate()
    assert '\n' not in str(info.value)


def test_a_real_speed_with_rests_passes():
    rec = paper_recording(speed_noise=0.01, seed=2)
    assert rec.validate() is rec
    rec.speed[:len(rec) // 2] = 0.0          # motor at rest for half the record
    rec.validate()


@pytest.mark.parametrize('channel', ['time', 'input', 'speed', 'current'])
def test_overflowing_magnitudes_name_the_channel_and_sample(channel):
    rec = paper_recording(seed=1)
    if channel == 'time':     # every value ~1e299, still strictly increasing
        rec.time = 1e299 * (1 + 1e-12 * np.arange(len(rec)))
    else:                     # one cell of 1e300
        getattr(rec, channel)[17] = 1e300
    k = 0 if channel == 'time' else 17
    with pytest.raises(DataError, match=rf"channel '{channel}' at sample {k}: .* is above "
                                        r"1e\+200 in magnitude \(the fit's arithmetic "
                                        'overflows\\): check the units'):
        rec.validate()


def test_a_whole_channel_near_1e299_is_refused_but_1e140_is_left_to_the_fit():
    rec = paper_recording(seed=1)
    with pytest.raises(DataError, match=r"channel 'speed' at sample 301: .* above 1e\+200"):
        Recording(rec.time, rec.input, rec.speed * 1e299).validate()
    big = Recording(rec.time, rec.input * 1e140, rec.speed * 1e140, rec.current * 1e140)
    assert big.validate() is big


def test_one_corrupt_cell_among_sane_values_is_named():
    rec = paper_recording(seed=1)
    rec.speed[1234] = 3e16
    with pytest.raises(DataError, match=r"channel 'speed' at sample 1234: 3e\+16 is .* times "
                                        r'the typical magnitude .* a corrupt value\?'):
        rec.validate()


def test_position_channel_survives_slice_concatenate_and_csv(tmp_path):
    """An optional position channel is kept by slicing, joining runs and the CSV round trip."""
    from motor_id.data.csv_io import read_csv, write_csv
    t = np.arange(100) * 0.01
    u = np.where(t > 0.2, 1.0, 0.0)
    w = np.cumsum(u) * 0.01
    pos = np.cumsum(w) * 0.01
    rec = Recording(t, u, w, position=pos)
    assert rec.channels() == ('speed',)
    assert rec.channels(True) == ('speed', 'position')
    part = rec.slice(10, 60)
    np.testing.assert_array_equal(part.position, pos[10:60])
    both = Recording.concatenate([rec, rec.slice(0, 50)])
    assert both.position.size == 150
    np.testing.assert_array_equal(both.position[100:], pos[:50])
    with pytest.raises(DataError, match='position'):
        Recording.concatenate([rec, Recording(t, u, w)])
    path = tmp_path / 'pos.csv'
    write_csv(rec, path)
    back = read_csv(path)
    np.testing.assert_allclose(back.position, pos, rtol=1e-15)
    bad = Recording(t, u, w, position=np.where(t > 0.5, np.nan, pos))
    with pytest.raises(DataError, match="'position' has 49 NaN"):
        bad.validate()
