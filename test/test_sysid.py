"""WPILib SysId logs: the reader (units, runs, errors), `motor-id import|fit|validate|analyze`
on generated logs, SysId's own fit re-implemented, and the real log when it is present."""

import argparse
import copy
import io
import json
import math
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from motor_id.bag import BagWriter, read_recording, write_recording
from motor_id.cli import main
from motor_id.cli.data_args import add_data_arguments, load_runs
from motor_id.data.load import load_recording
from motor_id.data.mapping import TopicMapping
from motor_id.data.sysid import load_sysid, MIN_TEST_ROWS, TESTS
from motor_id.errors import BagError, ConfigError, DataError
from motor_id.identify.validation import SavedModel, validate
from motor_id.testing.sysid_log import make_sysid_log, UNITS_PER_ROTATION
from motor_id.testing.sysid_ols import (
    fit_acceleration,
    fit_discrete,
    noise_floor,
    prepare,
    simulate_feedforward,
)

ROOT = Path(__file__).resolve().parents[1]
REAL_LOG = ROOT.parent / 'shared' / 'data' / 'sysid' / 'sysid_data.json'
SHORT = {'ramp_duration': 1.0, 'step_duration': 0.4}
"""A short log (about 500 rows) for the reader's tests."""


def motor_id(*args, check=True):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH',
                                                                                 ''))
    proc = subprocess.run([sys.executable, '-m', 'motor_id.cli', *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f'exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}')
    return proc


def first_order_gains(model):
    """kS, kV, kA of a saved model: ``T_c R/K_T``, ``(R B + K_T K_b)/K_T``,
    ``(R J + B L)/K_T`` (the speed-only record determines these, not the parameters)."""
    p = model.parameters
    kS = abs(model.effects.get('coulomb_friction', {}).get('T_c', 0.0)) * p['R_m'] / p['K_T']
    return (kS, (p['R_m'] * p['B'] + p['K_T'] * p['K_b']) / p['K_T'],
            (p['R_m'] * p['J'] + p['B'] * p['L_m']) / p['K_T'])


@pytest.fixture(scope='module')
def clean_log(tmp_path_factory):
    """Coulomb friction and jitter, no latency, fresh readings."""
    log = make_sysid_log(1, kS=0.2, jitter=0.3)
    return log, log.write(tmp_path_factory.mktemp('sysid') / 'clean.json')


@pytest.fixture(scope='module')
def real_like_log(tmp_path_factory):
    """As the real log: 20 ms latency, readings held 4 samples, strong jitter."""
    log = make_sysid_log(2, kS=0.2, latency=0.02, hold=4, jitter=0.4)
    return log, log.write(tmp_path_factory.mktemp('sysid') / 'real_like.json')


# ------------------------------------------------------------------------------ reader

@pytest.mark.parametrize('units', sorted(UNITS_PER_ROTATION))
def test_reader_converts_rotations_to_si_and_keeps_the_four_runs(tmp_path, units):
    log = make_sysid_log(3, units=units, **SHORT)
    rec = load_sysid(log.write(tmp_path / 'log.json'))
    rows = {name: np.array(log.data[name]) for name in TESTS}
    assert rec.meta['segment_names'] == list(TESTS)
    assert [b - a for a, b in rec.segment_ranges] == [rows[n].shape[0] for n in TESTS]
    si_per_raw = log.truth.si_per_raw   # the generator's own unit table
    for name, (a, b) in zip(TESTS, rec.segment_ranges, strict=True):
        r = rows[name]
        np.testing.assert_array_equal(rec.input[a:b], r[:, 1])
        np.testing.assert_allclose(rec.speed[a:b], r[:, 3] * si_per_raw, rtol=1e-12, atol=0)
        np.testing.assert_allclose(rec.position[a:b], r[:, 2] * si_per_raw, rtol=1e-12,
                                   atol=0)
        np.testing.assert_allclose(np.diff(rec.time[a:b]), np.diff(r[:, 0]), rtol=0,
                                   atol=1e-9)
    assert np.all(np.diff(rec.time) > 0) and rec.current is None
    info = rec.meta['sysid']
    assert info['units'] == units and info['test'] == 'Simple' and info['joint'] is None
    assert info['unitsPerRotation'] == pytest.approx(UNITS_PER_ROTATION[units], rel=1e-15)
    # a gain per SI unit of speed, in the log's units
    side = log.truth.feedforward
    assert side.kV / info['si_to_units'] == pytest.approx(side.kV_log, rel=1e-12)
    linear = units in ('Meters', 'Feet', 'Inches')
    assert rec.meta['units']['speed'] == ('m/s' if linear else 'rad/s')


def test_reader_reads_each_side_of_a_drivetrain_log(tmp_path):
    log = make_sysid_log(4, test='Drivetrain', units='Meters', kS=0.1, kS_right=0.3,
                         **SHORT)
    path = log.write(tmp_path / 'dt.json')
    scale = log.truth.si_per_raw
    left, right = load_sysid(path, 'left'), load_sysid(path, joint='RIGHT')
    for rec, iv, ip, iw in ((left, 1, 3, 5), (right, 2, 4, 6)):
        r = np.concatenate([np.array(log.data[n]) for n in TESTS])
        np.testing.assert_array_equal(rec.input, r[:, iv])
        np.testing.assert_allclose(rec.position, r[:, ip] * scale, rtol=1e-12, atol=0)
        np.testing.assert_allclose(rec.speed, r[:, iw] * scale, rtol=1e-12, atol=0)
    assert left.meta['sysid']['joint'] == 'left' and right.meta['sysid']['joint'] == 'right'
    # the right side has more inertia and friction: it is slower
    assert np.max(right.speed) < 0.99 * np.max(left.speed)
    rec = load_recording(path, mapping=TopicMapping(joint='right'))
    np.testing.assert_array_equal(rec.speed, right.speed)


def test_generated_logs_repeat_with_the_seed():
    a = make_sysid_log(7, kS=0.1, latency=0.01, hold=3, jitter=0.3, **SHORT)
    b = make_sysid_log(7, kS=0.1, latency=0.01, hold=3, jitter=0.3, **SHORT)
    c = make_sysid_log(8, kS=0.1, latency=0.01, hold=3, jitter=0.3, **SHORT)
    assert a.data == b.data and a.data != c.data
    vel = np.array(a.data['fast-forward'])[:, 3]
    runs = np.flatnonzero(np.diff(vel) != 0)
    assert np.all(np.diff(runs) % 3 == 0)   # a reading changes every third sample


def _base(tmp_path, **kw):
    log = make_sysid_log(5, **{**SHORT, **kw})
    return copy.deepcopy(log.data), tmp_path / 'bad.json'


def _write(path, data):
    path.write_text(json.dumps(data))
    return str(path)


def _fails(path, match, joint=None):
    with pytest.raises(DataError, match=match) as info:
        load_sysid(path, joint)
    assert str(path) in str(info.value)   # every error names the file
    return info.value


def test_reader_errors_name_the_file_and_the_problem(tmp_path):
    data, path = _base(tmp_path)
    path.write_text('{"sysid": true, "test": ')
    _fails(path, r'not JSON \(Expecting value at line 1')
    _fails(_write(path, [1, 2]), 'the top level is a list')
    for sysid, shown in ((False, 'False'), ('yes', "'yes'")):
        _fails(_write(path, {**data, 'sysid': sysid}), rf'"sysid" is {shown}, not true')
    _fails(_write(path, {k: v for k, v in data.items() if k != 'sysid'}),
           '"sysid" is missing')
    _fails(_write(path, {k: v for k, v in data.items() if k != 'fast-backward'}),
           r"test 'fast-backward' missing \(found slow-forward, slow-backward, fast-forward\)")
    _fails(_write(path, {**data, 'units': 'Furlongs'}), "unknown units 'Furlongs'")
    _fails(_write(path, {**data, 'test': 'Drivetrain (Angular)'}),
           "unsupported SysId test 'Drivetrain \\(Angular\\)'")
    _fails(_write(path, {**data, 'unitsPerRotation': 0}), 'unitsPerRotation.*> 0, got 0')
    _fails(_write(path, data), 'leave joint out', joint='left')
    assert not (tmp_path / 'missing.json').exists()
    _fails(tmp_path / 'missing.json', 'no such file')


def test_reader_errors_point_at_the_row(tmp_path):
    data, path = _base(tmp_path)
    bad = copy.deepcopy(data)
    bad['slow-backward'][5] = bad['slow-backward'][5][:3]
    _fails(_write(path, bad), r"test 'slow-backward' row 5: 3 values, a Simple row has 4 "
                              r'\(t, V, position, velocity\)')
    bad = copy.deepcopy(data)
    bad['fast-forward'][2][3] = 'fast'
    _fails(_write(path, bad), r"test 'fast-forward' row 2: velocity is 'fast', not a number")
    bad = copy.deepcopy(data)
    bad['fast-forward'][7][2] = math.nan   # json writes NaN, a non-standard token
    _fails(_write(path, bad), r"test 'fast-forward' row 7: position is nan \(1 non-finite")
    bad = copy.deepcopy(data)
    bad['slow-forward'][9][0] = bad['slow-forward'][8][0]
    _fails(_write(path, bad), r"test 'slow-forward': time is not increasing at row 9")


def test_drivetrain_log_needs_a_known_side(tmp_path):
    log = make_sysid_log(6, test='Drivetrain', **SHORT)
    path = log.write(tmp_path / 'dt.json')
    _fails(path, "give joint 'left' or 'right'")
    _fails(path, "unknown joint 'middle'", joint='middle')
    bad = copy.deepcopy(log.data)
    bad['slow-forward'][0] = bad['slow-forward'][0][:4]
    _fails(_write(tmp_path / 'short_row.json', bad), 'row 0: 4 values, a Drivetrain row '
                                                     'has 9', joint='left')


def test_a_test_with_too_few_rows_is_dropped_with_a_warning(tmp_path):
    data, path = _base(tmp_path)
    data['fast-backward'] = data['fast-backward'][:MIN_TEST_ROWS - 1]
    rec = load_sysid(_write(path, data))
    assert rec.meta['segment_names'] == list(TESTS[:3]) and len(rec.segment_ranges) == 3
    assert rec.meta['warnings'] == [f"test 'fast-backward' dropped: {MIN_TEST_ROWS - 1} "
                                    f'row(s), fewer than {MIN_TEST_ROWS}']
    for name in TESTS:
        data[name] = data[name][:3]
    _fails(_write(path, data), f'no test has at least {MIN_TEST_ROWS} rows')


def test_bag_and_csv_options_do_not_apply_to_a_sysid_log(clean_log):
    _, path = clean_log
    with pytest.raises(ConfigError, match='fixed columns'):
        load_recording(path, columns={'time': 't'})
    with pytest.raises(ConfigError, match='voltage input, not torque'):
        load_recording(path, input_kind='torque')
    with pytest.raises(ConfigError, match="takes only the mapping's joint"):
        load_recording(path, mapping=TopicMapping(speed='/joint_states:velocity'))


# --------------------------------------------------------------------------------- CLI

def test_several_logs_keep_every_test_as_a_run(clean_log, tmp_path):
    _, path = clean_log
    other = make_sysid_log(10, **SHORT).write(tmp_path / 'other.json')
    parser = argparse.ArgumentParser()
    parser.add_argument('data', nargs='+')
    add_data_arguments(parser)
    rec = load_runs(parser.parse_args([path, other]), stream=io.StringIO())
    first, second = load_sysid(path), load_sysid(other)
    assert len(rec) == len(first) + len(second)
    sizes = [b - a for a, b in first.segment_ranges + second.segment_ranges]
    assert [b - a for a, b in rec.segment_ranges] == sizes
    assert rec.meta['segment_names'] == ([f'clean.json:{n}' for n in TESTS]
                                         + [f'other.json:{n}' for n in TESTS])
    np.testing.assert_array_equal(rec.speed, np.concatenate([first.speed, second.speed]))


def test_import_writes_the_log_as_a_bag(clean_log, tmp_path, capsys):
    _, path = clean_log
    rec = load_sysid(path)
    out = tmp_path / 'log.mcap'
    assert main(['import', 'sysid', path, str(out)]) == 0
    captured = capsys.readouterr()
    assert f'{len(rec)} samples' in captured.out and '(voltage input)' in captured.out
    assert 'slow-forward, slow-backward, fast-forward, fast-backward' in captured.err
    back = read_recording(out)
    np.testing.assert_allclose(back.time - back.time[0], rec.time - rec.time[0], rtol=0,
                               atol=1e-9)
    np.testing.assert_array_equal(back.input, rec.input)
    np.testing.assert_array_equal(back.speed, rec.speed)
    assert back.meta['segment_names'] == list(TESTS)
    assert back.meta['import_command'] == f'motor-id import sysid clean.json {out.name}'
    # the four tests stay four runs: a fit of the bag never simulates across a boundary
    assert back.segment_ranges == rec.segment_ranges and len(back.segment_ranges) == 4
    assert 'runs' not in back.meta


def test_bag_runs_survive_lost_samples_and_a_bad_layout_is_named(clean_log, tmp_path):
    _, path = clean_log
    rec = load_sysid(path)
    out = tmp_path / 'log.mcap'
    write_recording(rec, out)
    # a bag whose first run lost its first 5 samples and whose second run lost all but
    # its last (a recorder that dropped messages): the runs are kept by sequence number
    (a0, b0), (a1, b1) = rec.segment_ranges[:2]
    keep = np.ones(len(rec), dtype=bool)
    keep[a0:a0 + 5] = False
    keep[a1:b1 - 1] = False
    rows = rec.sample_rows()[keep]
    lossy = tmp_path / 'lossy.mcap'
    with BagWriter(lossy) as bag:
        bag.write_meta({'input_kind': 'voltage', 'runs': [list(r) for r in rec.segments]})
        bag.write_samples(rows, 0)
    back = read_recording(lossy)
    sizes = [b - a for a, b in back.segment_ranges]
    assert sizes == [b0 - a0 - 5, 1] + [b - a for a, b in rec.segment_ranges[2:]]
    bad = tmp_path / 'bad.mcap'
    with BagWriter(bad) as bag:
        bag.write_meta({'input_kind': 'voltage', 'runs': [[0, 10], [5, 20]]})
        bag.write_samples(rec.sample_rows()[:20], 0)
    with pytest.raises(BagError, match=r'runs \[\(0, 10\), \(5, 20\)\] are not increasing'):
        read_recording(bad)


def test_import_of_a_drivetrain_side_and_a_bad_log(tmp_path, capsys):
    log = make_sysid_log(9, test='Drivetrain', **SHORT)
    path = log.write(tmp_path / 'dt.json')
    out = tmp_path / 'right.mcap'
    assert main(['import', 'sysid', path, str(out), '--joint', 'right']) == 0
    back = read_recording(out)
    np.testing.assert_array_equal(back.speed, load_sysid(path, 'right').speed)
    assert back.meta['import_command'].endswith('--joint right')
    capsys.readouterr()
    assert main(['import', 'sysid', path, str(tmp_path / 'x.mcap')]) == 2
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and err.endswith("give joint 'left' or 'right' (command line: --joint)")


def test_fit_recovers_the_feedforward_constants(clean_log, tmp_path):
    log, path = clean_log
    js = tmp_path / 'fit.json'
    proc = motor_id('fit', path, '-R', '0.5', '--effect', 'coulomb_friction', '--json', js,
                    '-q')
    assert 'fit speed:' in proc.stdout
    assert 'responds' not in proc.stderr   # no shift claimed across the runs' boundaries
    report = json.loads(js.read_text())
    assert report['data']['runs'] == 4 and report['data']['source'] == 'clean.json'
    # the report's feedforward block: kV and kA are determined by a speed-only record
    # (ratios of its identifiable combinations) though J, K_T, K_b, B, L_m are not
    ff = report['controller']['feedforward']
    kV, kA = ff['kV']['value'], ff['kA']['value']
    t = log.truth
    assert kV == pytest.approx(t.feedforward.kV, rel=0.01) and ff['kV']['std'] < 0.01 * kV
    assert kA == pytest.approx(t.feedforward.kA, rel=0.03) and ff['kA']['std'] < 0.03 * kA
    kS, kV_model, kA_model = first_order_gains(SavedModel.from_report(report))
    assert (kV_model, kA_model) == pytest.approx((kV, kA), rel=1e-6)
    # kS = T_c R_m / K_T is determined too (T_c / K_T is), from the saved model
    assert kS == pytest.approx(t.feedforward.kS, rel=0.05)
    # the model explains each test when simulated from the input alone
    val = tmp_path / 'val.json'
    motor_id('validate', js, path, '--json', val)
    assert json.loads(val.read_text())['channels']['speed']['fit_percent'] > 98.0


def test_fit_on_a_log_with_latency_and_held_readings(real_like_log, tmp_path):
    log, path = real_like_log
    js = tmp_path / 'fit.json'
    motor_id('fit', path, '-R', '0.5', '--effect', 'coulomb_friction', '--json', js, '-q')
    kS, kV, kA = first_order_gains(SavedModel.from_report(json.loads(js.read_text())))
    t = log.truth
    assert kV == pytest.approx(t.feedforward.kV, rel=0.02)    # the steady state is unaffected
    assert kS == pytest.approx(t.feedforward.kS, rel=0.15)
    # without a delay term the model takes the latency and the held readings into its
    # dynamics; their low-frequency equivalent adds at most kV x (delay + hold period)
    lag = t.latency + t.hold * t.sample_period
    assert 0.95 * t.feedforward.kA <= kA <= t.feedforward.kA + 1.1 * t.feedforward.kV * lag


@pytest.mark.slow   # the discrepancy analysis: about 20 s
def test_analyze_reads_a_sysid_log_and_its_model_validates(clean_log, tmp_path):
    _, path = clean_log
    js = tmp_path / 'analyze.json'
    motor_id('analyze', path, '-R', '0.5', '--json', js, '-q')
    report = json.loads(js.read_text())
    assert report['data']['runs'] == 4
    # speed-only voltage data: R_m does not enter, the given 0.5 Ohm is echoed, not used
    assert report['verdict'] and report['parameters']['R_m']['value'] is None
    assert '0.5 Ohm is not used' in report['resistance']['note']
    # its saved model runs on the log (each test from its own first samples); how good
    # the chosen model is belongs to the analysis' tests (here it simulates the speed
    # worse than the plain fit, which reaches 99 %: reported in issue 19)
    val = tmp_path / 'val.json'
    motor_id('validate', js, path, '--json', val)
    scores = json.loads(val.read_text())
    assert scores['segments'] == 4 and scores['channels']['speed']['fit_percent'] > 80.0


# --------------------------------------------------------------- SysId's own method

def test_sysid_ols_recovers_a_clean_motor(clean_log):
    log, path = clean_log
    prep = prepare(load_sysid(path))
    t = log.truth
    acc = fit_acceleration(prep)
    true = (t.feedforward.kS, t.feedforward.kV, t.feedforward.kA)
    assert (acc.kS, acc.kV, acc.kA) == pytest.approx(true, rel=0.02)
    disc = fit_discrete(prep)
    assert (disc.kS, disc.kV, disc.kA) == pytest.approx(true, rel=0.03)
    assert acc.r_squared > 0.9 and disc.r_squared > 0.99   # a differentiated speed is noisy
    rows = prep.rows()
    assert set(rows) == set(TESTS) and all(n > 100 for n in rows.values())
    assert 0 < prep.step_test_duration <= prep.max_step_time


def test_sysid_simulation_is_the_exact_first_order_response():
    t = np.cumsum(np.r_[0.0, np.random.default_rng(0).uniform(0.002, 0.008, 400)])
    v = simulate_feedforward(0.3, 0.02, 1e-3, t, np.full(t.size, 6.0), 0.0)
    tau, v_end = 1e-3 / 0.02, (6.0 - 0.3) / 0.02
    # sgn(0) = 0 on the first interval, then the friction acts
    expected = v_end * (1 - np.exp(-(t - t[1]) / tau)) + v[1] * np.exp(-(t - t[1]) / tau)
    np.testing.assert_allclose(v[1:], expected[1:], rtol=1e-9, atol=1e-9)
    assert np.all(np.isnan(simulate_feedforward(0.0, -1.0, 1e-3, t, t, 0.0)))


def test_noise_floor_is_sysids_causal_moving_mean():
    x = np.random.default_rng(1).normal(size=200)
    mean = np.array([x[max(0, k - 8):k + 1].sum() / 9 for k in range(200)])
    expected = math.sqrt(np.sum((x[:196] - mean[4:]) ** 2) / 196)
    assert noise_floor(x) == pytest.approx(expected, rel=1e-12)
    # the filter starts from zeros, as WPILib's LinearFilter does: a constant is not
    # noise-free at the start
    assert noise_floor(np.zeros(50)) == 0.0
    assert noise_floor(np.full(50, 3.0)) > 0.1


# ------------------------------------------------------------------- the real log

real_log = pytest.mark.skipif(not REAL_LOG.is_file(),
                              reason=f'{REAL_LOG} not present (not redistributable)')


@real_log
def test_real_log_reads_as_four_runs():
    rec = load_sysid(REAL_LOG)
    assert rec.meta['segment_names'] == list(TESTS)
    assert rec.meta['sysid']['test'] == 'Simple' and rec.meta['sysid']['units'] == 'Radians'
    assert rec.sample_period == pytest.approx(0.005, abs=2e-4) and not rec.is_regular
    assert rec.has_position and rec.current is None
    for name, (a, b) in zip(TESTS, rec.segment_ranges, strict=True):
        sign = 1.0 if name.endswith('forward') else -1.0
        assert sign * rec.speed[b - 1] > 0 and sign * (rec.position[b - 1] - rec.position[a]) > 0
    prep = prepare(rec)
    fit = fit_acceleration(prep)
    assert fit.kV > 0 and fit.kA > 0 and fit.kS > 0


@real_log
@pytest.mark.slow   # a fit of about 10,000 jittered samples: tens of seconds
def test_real_log_fit_agrees_with_sysid_on_kv(tmp_path):
    js = tmp_path / 'fit.json'
    motor_id('fit', REAL_LOG, '-R', '1', '--effect', 'coulomb_friction', '--json', js, '-q')
    report = json.loads(js.read_text())
    _, kV, _ = first_order_gains(SavedModel.from_report(report))
    sysid = fit_acceleration(prepare(load_sysid(REAL_LOG)))
    assert kV == pytest.approx(sysid.kV, rel=0.05)
    assert report['fit']['channels']['speed']['fit_percent'] > 95.0


def test_a_position_that_disagrees_with_the_velocity_is_left_out(tmp_path, capsys):
    """A drivetrain log whose positions took the units per rotation twice (as a public
    swerve log does: their rate is 0.233 x the velocity): the position is left out with a
    warning, the speed kept; an arm, which reads the position, is then refused."""
    log = make_sysid_log(4, test='Drivetrain', units='Meters', **SHORT)
    good = load_sysid(log.write(tmp_path / 'good.json'), 'left')
    assert good.has_position and 'warnings' not in good.meta
    factor = UNITS_PER_ROTATION['Meters']   # 0.1 m per rotation, applied twice
    data = copy.deepcopy(log.data)
    for name in TESTS:
        for row in data[name]:
            row[3] *= factor
    path = tmp_path / 'bad.json'
    path.write_text(json.dumps(data))
    rec = load_sysid(path, 'left')
    assert not rec.has_position
    np.testing.assert_array_equal(rec.speed, good.speed)
    [warning] = rec.meta['warnings']
    assert 'the logged position does not follow the logged velocity: its rate is' in warning
    ratio = float(warning.split('its rate is ')[1].split(' x')[0])
    np.testing.assert_allclose(ratio, factor, rtol=0.02)
    # a speed-only voltage record is simulated from its first samples (the current by
    # least squares over a grid of starts: one batch member per start)
    model = tmp_path / 'fit.json'
    assert main(['fit', str(path), '--joint', 'left', '-q', '--json', str(model)]) == 0
    scores = validate(SavedModel.from_report(json.loads(model.read_text())), rec).runs
    assert [r.name for r in scores] == list(TESTS)
    assert all(r.channels['speed']['fit_percent'] > 90 for r in scores)
    capsys.readouterr()
    right = load_sysid(path, 'right')   # the other side's position is as logged
    assert right.has_position and 'warnings' not in right.meta
    assert main(['fit', str(path), '--joint', 'left', '--mechanism', 'arm', '-q']) == 2
    assert 'needs the measured position' in capsys.readouterr().err


@pytest.mark.slow
def test_analyze_without_a_usable_position_gives_the_constants(tmp_path, capsys):
    """A SysId log whose position is left out (here scaled by 0.25) is analysed by
    simulation error on the speed alone: kS, kV and kA with their error bars (before, every
    constant was 'not determined')."""
    log = make_sysid_log(11, kS=0.2, jitter=0.2)
    data = copy.deepcopy(log.data)
    for name in TESTS:
        for row in data[name]:
            row[2] *= 0.25
    path = tmp_path / 'nopos.json'
    path.write_text(json.dumps(data))
    out = tmp_path / 'analyze.json'
    assert main(['analyze', str(path), '-q', '--json', str(out)]) == 0
    assert 'the position is left out' in capsys.readouterr().err
    ff = json.loads(out.read_text())['controller']['feedforward']
    truth = log.truth.feedforward
    np.testing.assert_allclose(ff['kS']['value'], truth.kS, atol=0.03)
    np.testing.assert_allclose(ff['kV']['value'], truth.kV, rtol=0.05)
    if ff['kA']['value'] is not None:
        np.testing.assert_allclose(ff['kA']['value'], truth.kA, rtol=0.30)
    assert ff['kS']['std'] > 0 and ff['kV']['std'] > 0
