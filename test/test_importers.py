"""Tests of motor_id.data.importers: EMPS and Dunker loaders, wrong files, `motor-id import`."""

from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat, savemat

from motor_id.bag import bag_info, read_recording
from motor_id.cli import main
from motor_id.data.csv_io import write_csv
from motor_id.data.importers import DUNKER_K_T, load, load_csv, load_dunker, load_emps
from motor_id.errors import ConfigError, DataError
from motor_id.recording import Recording

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / 'shared' / 'data'
EMPS = DATA / 'emps' / 'DATA_EMPS.mat'
DUNKER_ID = DATA / 'dunker_gr42x25' / 'data_for_identification_without_integral.csv'
DUNKER_VAL = DATA / 'dunker_gr42x25' / 'validation_data.csv'

pytestmark = pytest.mark.skipif(not EMPS.is_file() or not DUNKER_ID.is_file(),
                                reason='shared measured data not present')


def dunker_columns(path):
    return np.genfromtxt(path, delimiter=';', skip_header=3)[:, :13]


@pytest.fixture(scope='module')
def emps():
    return load_emps(EMPS)


def test_emps_loads_the_benchmark(emps):
    assert len(emps) == 24841
    assert emps.input_kind == 'torque'
    assert emps.current is None
    np.testing.assert_allclose(np.diff(emps.time), 1e-3, rtol=0, atol=1e-14)
    assert emps.is_regular
    assert emps.time[-1] == pytest.approx(24.84, abs=1e-12)
    peak = np.max(np.abs(emps.input))
    assert 140.0 < peak <= 35.1507 * 4.33
    assert np.max(np.abs(emps.speed)) == pytest.approx(0.128, abs=0.002)
    assert emps.meta['reference']['M'] == 95.1089
    assert emps.meta['reference']['Fc'] == 20.3935
    assert emps.meta['closed_loop'] is True
    assert 'Janot' in emps.meta['citation']
    emps.validate()


def test_emps_force_and_speed_come_from_the_file(emps):
    mat = loadmat(EMPS)
    qm = mat['qm'].ravel()
    np.testing.assert_allclose(emps.input, mat['gtau'].item() * mat['vir'].ravel(),
                               rtol=1e-15, atol=0)
    central = (qm[2:] - qm[:-2]) / 2e-3
    np.testing.assert_allclose(emps.speed[1:-1], central, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.abs(emps.time - mat['t'].ravel()).max(), 0, atol=1e-7)
    travel = np.sum((emps.speed[1:] + emps.speed[:-1]) / 2) * 1e-3
    assert travel == pytest.approx(qm[-1] - qm[0], abs=1e-4)


def test_dunker_keeps_the_irregular_time_exactly():
    raw = dunker_columns(DUNKER_ID)
    rec = load_dunker(DUNKER_ID, motor=1)
    assert len(rec) == 2291
    np.testing.assert_allclose(rec.time * 1000, raw[:, 0], rtol=1e-15, atol=1e-12)
    assert not rec.is_regular
    dt = np.diff(rec.time)
    assert 0.0225 < dt.min() < 0.0235 and 0.038 < dt.max() < 0.0385
    assert rec.input_kind == 'torque'
    assert rec.current is None
    np.testing.assert_array_equal(rec.speed, raw[:, 7])
    rec.validate()


def test_dunker_torque_magnitude_and_sign_rule():
    raw = dunker_columns(DUNKER_VAL)
    for motor in (1, 2, 3):
        rec = load_dunker(DUNKER_VAL, motor=motor)
        setvel, vel, cur = raw[:, motor], raw[:, 6 + motor], raw[:, 9 + motor]
        np.testing.assert_allclose(np.abs(rec.input), DUNKER_K_T * cur, rtol=1e-15)
        on = cur > 0
        moving = on & (vel != 0)
        assert np.all(np.sign(rec.input[moving]) == np.sign(vel[moving]))
        starting = on & (vel == 0) & (setvel != 0)
        assert np.all(np.sign(rec.input[starting]) == np.sign(setvel[starting]))
        trailing = np.flatnonzero(on & (vel == 0) & (setvel == 0))
        assert trailing.size == rec.meta['sign_held'] > 0
        for k in trailing:
            last = vel[:k][vel[:k] != 0][-1]
            assert np.sign(rec.input[k]) == np.sign(last)
        assert rec.meta['motor'] == motor
        assert 'sign' in rec.meta['sign_rule'] and f'm{motor}vel' in rec.meta['sign_rule']
    one, two = load_dunker(DUNKER_ID, 1), load_dunker(DUNKER_ID, 2)
    assert not np.array_equal(one.input, two.input)
    with pytest.raises(ConfigError, match='motor must be 1, 2 or 3'):
        load_dunker(DUNKER_ID, motor=4)


def test_wrong_files_raise_data_error(tmp_path):
    with pytest.raises(DataError, match='not a MATLAB'):
        load_emps(DUNKER_ID)
    with pytest.raises(DataError, match='no such file'):
        load_emps(tmp_path / 'missing.mat')
    other = tmp_path / 'other.mat'
    savemat(other, {'t': np.arange(5.0), 'y': np.ones(5)})
    with pytest.raises(DataError, match='not the EMPS data set: .*qm.*found t, y'):
        load_emps(other)
    with pytest.raises(DataError, match='not a text file'):
        load_dunker(EMPS)
    csv = tmp_path / 'plain.csv'
    csv.write_text('a;b;c\ns;s;s\nx;y;z\n1;2;3\n')
    with pytest.raises(DataError, match='not a Dunker GR 42x25 log.*missing t, m1setvel'):
        load_dunker(csv)
    lines = DUNKER_ID.read_text().splitlines()
    bad = tmp_path / 'bad.csv'
    bad.write_text('\n'.join(lines[:10] + [lines[10].replace(';', ';x', 1)] + lines[11:20]))
    with pytest.raises(DataError, match=r'bad\.csv:11: column .* non-numeric'):
        load_dunker(bad)
    back = tmp_path / 'back.csv'
    back.write_text('\n'.join(lines[:10] + [lines[8]] + lines[11:20]))
    with pytest.raises(DataError, match='time does not increase'):
        load_dunker(back)


def test_import_cli_writes_a_bag_that_reads_back(tmp_path, capsys):
    out = tmp_path / 'd2.mcap'
    assert main(['import', 'dunker', str(DUNKER_VAL), str(out), '--motor', '2']) == 0
    assert '1238 samples' in capsys.readouterr().out
    rec, back = load_dunker(DUNKER_VAL, 2), read_recording(out)
    for name in ('time', 'input', 'speed'):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name))
    assert back.input_kind == 'torque' and back.current is None
    assert back.meta['sign_rule'] == rec.meta['sign_rule']
    assert back.meta['import_command'].endswith('--motor 2')
    assert main(['import', 'dunker', str(DUNKER_VAL), str(out)]) == 2
    assert 'exists; pass --force' in capsys.readouterr().err
    src = tmp_path / 'rec.csv'
    rng = np.random.default_rng(7)
    write_csv(Recording(np.arange(50) * 0.01, rng.normal(size=50), rng.normal(size=50),
                        rng.normal(size=50)), src)
    out = tmp_path / 'csv.mcap'
    assert main(['import', 'csv', str(src), str(out)]) == 0
    csv_back = read_recording(out)
    np.testing.assert_array_equal(csv_back.current, load_csv(src).current)
    assert main(['import', 'emps', str(DUNKER_VAL), str(tmp_path / 'x.mcap')]) == 2
    assert 'not a MATLAB' in capsys.readouterr().err


def test_committed_bags_hold_the_converted_data(emps):
    back = read_recording(ROOT / 'bags' / 'emps.mcap')
    for name in ('time', 'input', 'speed'):
        np.testing.assert_array_equal(getattr(back, name), getattr(emps, name))
    assert back.meta['reference'] == emps.meta['reference']
    for kind, src in (('ident', DUNKER_ID), ('valid', DUNKER_VAL)):
        for motor in (1, 2, 3):
            path = ROOT / 'bags' / f'dunker_{kind}_m{motor}.mcap'
            back, rec = read_recording(path), load_dunker(src, motor)
            np.testing.assert_array_equal(back.input, rec.input)
            np.testing.assert_array_equal(back.time, rec.time)
            assert bag_info(path).topics[1].count == -(-len(rec) // 50)


def test_dunker_as_a_torque_csv_imports_by_column_name(tmp_path, capsys):
    """A measured set written as users write it: ``time,torque,speed`` with a BOM."""
    rec = load_dunker(DUNKER_VAL, 1)
    src = tmp_path / 'dunker.csv'
    src.write_text('time,torque,speed\n' + ''.join(
        f'{t!r},{u!r},{w!r}\n' for t, u, w in zip(rec.time.tolist(), rec.input.tolist(),
                                                   rec.speed.tolist(), strict=True)),
        encoding='utf-8-sig')
    back = load_csv(src)
    assert back.input_kind == 'torque'
    np.testing.assert_array_equal(back.input, rec.input)
    out = tmp_path / 'd.mcap'
    assert main(['import', 'csv', str(src), str(out)]) == 0
    assert '(torque input)' in capsys.readouterr().out
    again = load('bag', out)
    np.testing.assert_array_equal(again.speed, rec.speed)
    assert again.input_kind == 'torque'


def test_measured_sets_pass_validation_and_show_no_false_shift(emps):
    """Closed-loop measured data: valid, and the shift check stays silent (rss ratios)."""
    from motor_id.data.shift import detect_shift
    recs = [emps] + [load_dunker(src, m) for src in (DUNKER_ID, DUNKER_VAL) for m in (1, 2, 3)]
    for rec in recs:
        rec.validate()
        check = detect_shift(rec)
        assert check.samples == 0 and check.channel == 'speed', rec.meta['source']
        assert min(check.relative_rss.values()) > 0.8
