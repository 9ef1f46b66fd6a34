"""CSV reading: good data, and one clear error per kind of bad data."""

import numpy as np
import pytest

from motor_id.errors import DataError
from motor_id.recording import read_csv, Recording, write_csv

from conftest import paper_recording

HEADER = 'time,voltage,speed,current\n'


def write(tmp_path, text, name='d.csv'):
    p = tmp_path / name
    p.write_text(text)
    return p


def rows(n=50, start=0):
    return ''.join(f'{0.01 * k},{1.0 + (k > 10)},{0.1 * k},{0.01 * k}\n'
                   for k in range(start, start + n))


def test_round_trip_is_exact(tmp_path):
    rec = paper_recording(speed_noise=0.01, current_noise=0.01, seed=1)
    write_csv(rec, tmp_path / 'r.csv', {'note': 'x'})
    back = read_csv(tmp_path / 'r.csv')
    for ch in ('time', 'input', 'speed', 'current'):
        np.testing.assert_array_equal(getattr(back, ch), getattr(rec, ch))
    assert back.meta['note'] == 'x'


def test_optional_current_and_extra_columns(tmp_path):
    p = write(tmp_path, 'time,speed,voltage,temp\n' + ''.join(
        f'{0.01 * k},{0.1 * k},{1.0 + (k > 3)},20\n' for k in range(30)))
    rec = read_csv(p)
    assert not rec.has_current and rec.channels() == ('speed',)
    assert rec.input[5] == 2.0


@pytest.mark.parametrize('text, message', [
    ('time,voltage\n' + '0,1\n' * 30, r'd\.csv:1: missing column\(s\) speed'),
    ('time;voltage;speed\n0;1;2\n', 'delimited by something other than commas'),
    ('0,1,2,3\n' + rows(), 'the header is missing'),
    (HEADER + rows(5) + '0.05,abc,0.5,0.05\n' + rows(30, 6),
     r"d\.csv:7: column 'voltage' has non-numeric value 'abc'"),
    (HEADER + rows(5) + '0.05,1,nan,0.05\n' + rows(30, 6), r"d\.csv:7: column 'speed' is nan"),
    (HEADER + rows(5) + rows(30, 4), r'd\.csv:7: duplicate time stamp'),
    (HEADER + rows(5) + '0.01,1,1,1\n' + rows(30, 6), r'd\.csv:7: time goes backwards'),
    (HEADER + rows(5), 'too few samples: 5'),
    (HEADER + ''.join(f'{0.01 * k},2.0,{0.1 * k},0\n' for k in range(40)), 'no excitation'),
    ('', 'empty file'),
    (HEADER + '0,1,2\n', r'd\.csv:2: 3 cell\(s\), header has 4'),
])
def test_bad_files_get_one_specific_line(tmp_path, text, message):
    with pytest.raises(DataError, match=message) as info:
        read_csv(write(tmp_path, text))
    assert '\n' not in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match='cannot read'):
        read_csv(tmp_path / 'nope.csv')


def test_validate_catches_inf_and_length_mismatch():
    t = np.arange(30) * 0.1
    v = np.r_[np.zeros(10), np.ones(20)]
    with pytest.raises(DataError, match="'speed' has 1 NaN/inf"):
        Recording(t, v, np.r_[np.zeros(29), np.inf]).validate()
    with pytest.raises(DataError, match='has 29 samples but time has 30'):
        Recording(t, v, np.zeros(29)).validate()
