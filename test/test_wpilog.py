"""WPILib DataLogs (.wpilog) of a SysId routine: the reader (runs, alignment, units, motors,
entries of other loggers, cut and corrupt files) and the commands that read them."""

from dataclasses import replace
import json
import math
import os
from pathlib import Path
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from wpiutil.log import DataLogReader

from motor_id.bag import read_recording
from motor_id.cli import main
from motor_id.data.load import load_recording
from motor_id.data.log_units import parse_unit
from motor_id.data.mapping import TopicMapping
from motor_id.data.wpilog import load_wpilog, LogEntries
from motor_id.errors import ConfigError, DataError
from motor_id.pipeline import aliased_poles
from motor_id.testing.sysid_log import DEFAULT_MOTOR
from motor_id.testing.sysid_wpilog import ROUTINE, RoutineMotor, write_sysid_wpilog

ROOT = Path(__file__).resolve().parents[1]
SHORT = {'ramp_duration': 1.5, 'step_duration': 0.6, 'rest': 0.5}
"""A short routine (about 200 loops of 20 ms) for the reader's tests."""


def raw_entries(path):
    """``{name: (metadata, [(t_us, value), ...])}`` read with wpiutil, apart from the reader."""
    out, names = {}, {}
    for record in DataLogReader(str(path)):
        if record.isStart():
            data = record.getStartData()
            names[data.entry] = (data.name, data.type)
            out[data.name] = (data.metadata, [])
        elif not record.isControl():
            name, kind = names[record.getEntry()]
            value = record.getString() if kind == 'string' else record.getDouble()
            out[name][1].append((record.getTimestamp(), value))
    return out


@pytest.fixture(scope='module')
def routine(tmp_path_factory):
    path = tmp_path_factory.mktemp('wpilog') / 'shooter.wpilog'
    log = write_sysid_wpilog(path, 1, motors=(RoutineMotor('shooter', kS=0.2),), **SHORT)
    return log, str(path)


def test_reader_splits_the_tests_and_takes_each_loops_values(routine):
    log, path = routine
    rec = load_wpilog(path)
    assert rec.meta['segment_names'] == list(ROUTINE)
    assert rec.meta['sysid']['units'] == 'Rotation' and rec.meta['sysid']['linear'] is False
    assert rec.meta['units']['speed'] == 'rad/s' and rec.meta['units']['position'] == 'rad'
    raw = raw_entries(path)
    volts = np.array(raw['voltage-shooter-shooter'][1])
    vel = np.array(raw['velocity-shooter-shooter'][1])
    pos = np.array(raw['position-shooter-shooter'][1])
    assert raw['velocity-shooter-shooter'][0] == 'Rotation per Second'
    # every loop of every test is a sample: the loop count of each test
    loops = {'quasistatic': round(SHORT['ramp_duration'] / 0.02) + 1,
             'dynamic': round(SHORT['step_duration'] / 0.02) + 1}
    assert [b - a for a, b in rec.segment_ranges] == [loops[n.split('-')[0]] for n in ROUTINE]
    # values in SI, each voltage from the velocity's own loop (30 us before it)
    np.testing.assert_allclose(rec.speed, vel[:, 1] * 2 * math.pi, rtol=1e-12)
    np.testing.assert_allclose(rec.position, pos[:, 1] * 2 * math.pi, rtol=1e-12)
    np.testing.assert_array_equal(rec.input, volts[:, 1])
    assert np.all((vel[:, 0] - volts[:, 0]) == 30)
    a, b = rec.segment_ranges[2]
    assert rec.input[a] == 0.0 and np.all(rec.input[a + 1:b] == 6.0)
    a, b = rec.segment_ranges[1]
    assert np.all(rec.input[a + 1:b] < 0) and np.all(np.diff(rec.input[a:b]) < 0)


@pytest.mark.parametrize('order', [('velocity', 'position', 'voltage'),
                                   ('position', 'voltage', 'velocity')])
def test_the_order_a_loop_logs_in_does_not_matter(routine, tmp_path, order):
    _, path = routine
    other = write_sysid_wpilog(tmp_path / 'o.wpilog', 1, order=order,
                               motors=(RoutineMotor('shooter', kS=0.2),), **SHORT).path
    a, b = load_wpilog(path), load_wpilog(other)
    assert a.segment_ranges == b.segment_ranges
    np.testing.assert_array_equal(a.input, b.input)
    np.testing.assert_array_equal(a.speed, b.speed)


@pytest.mark.parametrize('units,linear,si', [('Meter', True, 1.0), ('Inch', True, 0.0254),
                                             ('Degree', False, math.pi / 180),
                                             ('Radian', False, 1.0)])
def test_units_come_from_the_metadata(tmp_path, units, linear, si):
    log = write_sysid_wpilog(tmp_path / 'u.wpilog', 2, units=units, **SHORT)
    rec = load_wpilog(log.path)
    raw = raw_entries(log.path)
    vel = np.array(raw['velocity-shooter-shooter'][1])[:, 1]
    np.testing.assert_allclose(rec.speed, vel * si, rtol=1e-12)
    assert rec.meta['sysid']['linear'] is linear
    assert rec.meta['units']['speed'] == ('m/s' if linear else 'rad/s')
    assert rec.meta['units']['position'] == ('m' if linear else 'rad')
    np.testing.assert_allclose(rec.meta['sysid']['si_to_units'], 1 / si, rtol=1e-12)


@pytest.mark.parametrize('text,expected', [
    ('Rotation', (2 * math.pi, False)), ('rotations', (2 * math.pi, False)),
    ('Meter', (1.0, True)), ('Feet', (0.3048, True)), ('in', (0.0254, True)),
    ('deg', (math.pi / 180, False))])
def test_position_units(text, expected):
    np.testing.assert_allclose(parse_unit(text), expected, rtol=1e-12)


@pytest.mark.parametrize('text,expected', [
    ('Rotation per Second', (2 * math.pi, False)), ('rps', (2 * math.pi, False)),
    ('RPM', (2 * math.pi / 60, False)), ('Meter per Second', (1.0, True)),
    ('m/s', (1.0, True)), ('Inches per Second', (0.0254, True)),
    ('Radian per Second', (1.0, False))])
def test_speed_units(text, expected):
    np.testing.assert_allclose(parse_unit(text, speed=True), expected, rtol=1e-12)
    assert parse_unit('Furlong per Fortnight', speed=True) is None
    assert parse_unit('Rotation', speed=True) is None


def test_older_distance_entries_read_as_position(routine, tmp_path):
    _, path = routine
    old = write_sysid_wpilog(tmp_path / 'old.wpilog', 1, position_name='distance',
                             motors=(RoutineMotor('shooter', kS=0.2),), **SHORT).path
    assert 'distance-shooter-shooter' in raw_entries(old)
    a, b = load_wpilog(path), load_wpilog(old)
    np.testing.assert_array_equal(a.position, b.position)
    assert b.meta['sysid']['entries']['position'] == 'distance-shooter-shooter'


def test_several_motors_are_listed_and_picked(tmp_path, capsys):
    heavy = replace(DEFAULT_MOTOR, J=2 * DEFAULT_MOTOR.J)
    motors = (RoutineMotor('drive-left'), RoutineMotor('drive-right', motor=heavy))
    path = write_sysid_wpilog(tmp_path / 'dt.wpilog', 3, motors=motors, log_name='drive',
                              **SHORT).path
    with pytest.raises(DataError, match=r'several motors: drive-left, drive-right; pick one '
                                        r'\(motor\)'):
        load_wpilog(path)
    left = load_wpilog(path, LogEntries(motor='drive-left'))
    right = load_wpilog(path, LogEntries(motor='drive-right-drive'))
    assert left.meta['sysid']['motor'] == 'drive-left (log drive)'
    # the heavier side accelerates slower under the same steps
    a, b = left.segment_ranges[2]
    assert right.speed[a + 5] < 0.8 * left.speed[a + 5]
    # --joint picks a side by the word in the motor's name, as for a JSON drivetrain log
    side = load_recording(path, mapping=TopicMapping(joint='right'))
    np.testing.assert_array_equal(side.speed, right.speed)
    with pytest.raises(DataError, match="no motor 'arm' .motors: drive-left, drive-right"):
        load_wpilog(path, LogEntries(motor='arm'))
    assert main(['import', 'sysid', path, str(tmp_path / 'x.mcap')]) == 2
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and 'drive-left, drive-right' in err
    out = tmp_path / 'left.mcap'
    assert main(['import', 'sysid', path, str(out), '--motor', 'drive-left']) == 0
    np.testing.assert_array_equal(read_recording(out).speed, left.speed)
    assert read_recording(out).meta['import_command'].endswith('--motor drive-left')


def test_entries_of_another_logger_are_named(tmp_path):
    names = {'voltage': 'TalonFX-10/MotorVoltage', 'position': 'TalonFX-10/Position',
             'velocity': 'TalonFX-10/Velocity', 'state': 'SysIdTestState'}
    path = write_sysid_wpilog(tmp_path / 'ctre.wpilog', 4, entry_names=names,
                              metadata=False, **SHORT).path
    with pytest.raises(DataError, match='no SysIdRoutineLog motor.*TalonFX-10/Velocity'):
        load_wpilog(path)
    named = LogEntries(voltage='MotorVoltage', velocity='TalonFX-10/Velocity',
                       position='Position', state='SysIdTestState')
    with pytest.raises(DataError, match=r'no unit in its metadata; give the position unit '
                                        r'\(units: '):
        load_wpilog(path, named)
    rec = load_wpilog(path, LogEntries(**{**named.__dict__, 'units': 'Rotation'}))
    ref = write_sysid_wpilog(tmp_path / 'ref.wpilog', 4, **SHORT).path
    np.testing.assert_array_equal(rec.speed, load_wpilog(ref).speed)
    with pytest.raises(DataError, match=r'need voltage and velocity \(missing: voltage\)'):
        load_wpilog(path, LogEntries(velocity='Velocity'))
    with pytest.raises(DataError, match="no velocity entry 'Speed'"):
        load_wpilog(path, LogEntries(voltage='MotorVoltage', velocity='Speed', units='Meter'))


def test_a_cut_log_keeps_the_tests_before_the_cut(routine, tmp_path):
    _, path = routine
    whole = load_wpilog(path)
    data = Path(path).read_bytes()
    raw = raw_entries(path)
    # cut in the middle of the third test (dynamic-forward)
    t_cut = raw['velocity-shooter-shooter'][1][whole.segment_ranges[2][0] + 12][0]
    cut = tmp_path / 'cut.wpilog'
    cut.write_bytes(data[:_offset_of(path, t_cut)])
    rec = load_wpilog(cut)
    assert rec.meta['segment_names'] == list(ROUTINE[:3])
    assert any('ends during dynamic-forward' in w for w in rec.meta['warnings'])
    n = whole.segment_ranges[2][0] + 11
    np.testing.assert_array_equal(rec.speed[:n], whole.speed[:n])
    head = tmp_path / 'head.wpilog'
    head.write_bytes(data[:10])
    with pytest.raises(DataError, match='not a WPILib DataLog'):
        load_wpilog(head)


def _offset_of(path, t_us):
    """Byte offset in the file of the first record at or after ``t_us`` (a record starts
    with its header byte: the length of its entry, size and timestamp fields)."""
    data = Path(path).read_bytes()
    pos = 12 + int.from_bytes(data[8:12], 'little')
    while pos < len(data):
        h = data[pos]
        ne, ns, nt = (h & 3) + 1, ((h >> 2) & 3) + 1, ((h >> 4) & 7) + 1
        size = int.from_bytes(data[pos + 1 + ne:pos + 1 + ne + ns], 'little')
        t = int.from_bytes(data[pos + 1 + ne + ns:pos + 1 + ne + ns + nt], 'little')
        if t >= t_us:
            return pos
        pos += 1 + ne + ns + nt + size
    return len(data)


def test_a_corrupt_log_is_read_to_the_damage_or_refused(routine, tmp_path):
    _, path = routine
    whole = load_wpilog(path)
    raw = raw_entries(path)
    t_bad = raw['velocity-shooter-shooter'][1][whole.segment_ranges[3][0] + 3][0]
    data = bytearray(Path(path).read_bytes())
    at = _offset_of(path, t_bad)
    data[at:at + 40] = np.random.default_rng(5).integers(0, 256, 40, dtype=np.uint8).tobytes()
    bad = tmp_path / 'bad.wpilog'
    bad.write_bytes(bytes(data))
    rec = load_wpilog(bad)
    assert rec.meta['segment_names'][:3] == list(ROUTINE[:3])
    # wpiutil's reader stops at a record whose size runs off the file: the test that the
    # damage falls in ends there, as in a cut file
    assert any('ends during dynamic-reverse (no "none" after it: the file was cut, or is '
               'corrupt from there)' in w for w in rec.meta['warnings'])
    n = whole.segment_ranges[3][0]
    np.testing.assert_array_equal(rec.speed[:n], whole.speed[:n])
    # a record of an entry that was never started: the reading stops there, with a warning
    data = bytearray(Path(path).read_bytes())
    assert data[at] & 3 == 0   # a one-byte entry id follows the header byte
    data[at + 1] = 200
    stray = tmp_path / 'stray.wpilog'
    stray.write_bytes(bytes(data))
    rec = load_wpilog(stray)
    assert any('corrupt after record' in w and 'entry 200, which was never started' in w
               for w in rec.meta['warnings'])
    np.testing.assert_array_equal(rec.speed[:n], whole.speed[:n])
    junk = tmp_path / 'junk.wpilog'
    junk.write_bytes(b'this is no data log at all' * 10)
    with pytest.raises(DataError, match='junk.wpilog: not a WPILib DataLog'):
        load_wpilog(junk)
    with pytest.raises(DataError, match='nothing.wpilog: no such file'):
        load_wpilog(tmp_path / 'nothing.wpilog')


def test_repeated_and_unknown_states_and_short_tests(tmp_path):
    tests = ('quasistatic-forward', 'quasistatic-forward', 'dynamic-forward')
    path = write_sysid_wpilog(tmp_path / 'rep.wpilog', 6, tests=tests, **SHORT).path
    rec = load_wpilog(path)
    assert rec.meta['segment_names'] == ['quasistatic-forward', 'quasistatic-forward#2',
                                         'dynamic-forward']
    short = write_sysid_wpilog(tmp_path / 's.wpilog', 6, step_duration=0.1,
                               ramp_duration=1.0, rest=0.5).path
    rec = load_wpilog(short)
    assert rec.meta['segment_names'] == ['quasistatic-forward', 'quasistatic-reverse']
    assert sum('dropped: 6 sample(s), fewer than 10' in w for w in rec.meta['warnings']) == 2


def test_datalog_options_are_refused_for_other_files(tmp_path):
    csv = tmp_path / 'x.csv'
    csv.write_text('time,voltage,speed\n' + ''.join(f'{k * 0.01},{1.0},{k}\n'
                                                   for k in range(30)))
    with pytest.raises(ConfigError, match='pick the entries of a WPILib DataLog'):
        load_recording(csv, log_entries=LogEntries(motor='m'))
    with pytest.raises(ConfigError, match="takes only the mapping's joint"):
        load_recording(tmp_path / 'y.wpilog', mapping=TopicMapping(speed='/js'))


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH',
                                                                                 ''))
    return subprocess.run([sys.executable, '-m', 'motor_id.cli', *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=600, check=False)


def test_fit_reads_a_wpilog_and_recovers_kv_ka(tmp_path):
    log = write_sysid_wpilog(tmp_path / 'fw.wpilog', 7, loop_period=0.005, units='Meter',
                             motors=(RoutineMotor('flywheel', kS=0.0),))
    out = tmp_path / 'fit.json'
    proc = _cli('fit', log.path, '-R', '0.5', '--json', out, '-q')
    assert proc.returncode == 0, proc.stderr
    ff = json.loads(out.read_text())['controller']['feedforward']
    truth = log.truth.motors['flywheel']
    np.testing.assert_allclose(ff['kV']['value'], truth.kV, rtol=0.02)
    np.testing.assert_allclose(ff['kA']['value'], truth.kA, rtol=0.1)


def test_validate_scores_each_test_by_name(tmp_path):
    log = write_sysid_wpilog(tmp_path / 'v.wpilog', 8, loop_period=0.005,
                             motors=(RoutineMotor('flywheel', kS=0.0),), **SHORT)
    model = tmp_path / 'fit.json'
    assert _cli('fit', log.path, '-R', '0.5', '--json', model, '-q').returncode == 0
    out = tmp_path / 'val.json'
    proc = _cli('validate', model, log.path, '--json', out)
    assert proc.returncode == 0, proc.stderr
    val = json.loads(out.read_text())
    assert [r['name'] for r in val['runs']] == list(ROUTINE)
    assert all(set(r['channels']) == set(val['channels']) for r in val['runs'])
    assert all(set(r['channels']['speed']) == set(val['channels']['speed'])
               for r in val['runs'])
    for name in ROUTINE:
        line = next(x for x in proc.stdout.splitlines() if x.strip().startswith(name))
        fit = next(r for r in val['runs'] if r['name'] == name)['channels']['speed']
        assert f'speed {fit["fit_percent"]:6.2f} %' in line
    # each run's score is the fit % of that test alone, after its first two samples
    rec = load_wpilog(log.path)
    sim = np.loadtxt(_csv(tmp_path, model, log.path), delimiter=',', skiprows=1)
    for r, (a, b) in zip(val['runs'], rec.segment_ranges, strict=True):
        y, yh = sim[a + 2:b, 2], sim[a + 2:b, 3]
        expected = 100 * (1 - np.linalg.norm(y - yh) / np.linalg.norm(y - y.mean()))
        np.testing.assert_allclose(r['channels']['speed']['fit_percent'], expected,
                                   rtol=1e-9)
        assert r['channels']['speed']['samples'] == b - a - 2
    samples = sum(r['channels']['speed']['samples'] for r in val['runs'])
    assert samples == val['channels']['speed']['samples']


def _csv(tmp_path, model, data):
    out = tmp_path / 'val.csv'
    proc = _cli('validate', model, data, '--csv', out)
    assert proc.returncode == 0, proc.stderr
    header = out.read_text().splitlines()[0].split(',')
    assert header[:4] == ['time', 'segment', 'position_measured', 'position_simulated']
    rows = np.loadtxt(out, delimiter=',', skiprows=1)
    keep = tmp_path / 'speed.csv'
    np.savetxt(keep, rows[:, [0, 1, 4, 5]], delimiter=',', header='t,seg,y,yh')
    return keep


@pytest.fixture(scope='module')
def friction_logs(tmp_path_factory):
    """A metre routine with static friction at a 5 ms and at a 20 ms robot loop."""
    root = tmp_path_factory.mktemp('friction')
    return {period: write_sysid_wpilog(root / f'f{int(period * 1000)}.wpilog', 3,
                                       units='Meter', loop_period=period,
                                       motors=(RoutineMotor('lift', kS=0.1),))
            for period in (0.005, 0.02)}


@pytest.mark.parametrize('period', [0.005, 0.02])
def test_fit_of_a_sysid_log_reports_ks(friction_logs, tmp_path, period):
    log = friction_logs[period]
    out = tmp_path / 'fit.json'
    proc = _cli('fit', log.path, '-R', '0.5', '--json', out)
    assert proc.returncode == 0, proc.stderr
    assert 'model: linear + coulomb_friction (a SysId log' in proc.stderr
    assert 'overflow' not in proc.stderr
    report = json.loads(out.read_text())
    assert report['adequate'] and 'coulomb_friction' in report['effects']
    truth = log.truth.motors['lift']
    ff = report['controller']['feedforward']
    np.testing.assert_allclose(ff['kS']['value'], truth.kS, atol=0.01)
    np.testing.assert_allclose(ff['kV']['value'], truth.kV, rtol=0.01)
    np.testing.assert_allclose(ff['kA']['value'], truth.kA, rtol=0.05)
    assert ff['kS']['std'] > 0 and ff['kS']['unit'] == 'V'
    if 'alias_guard' in report:   # a first fit aliased a pole pair onto the 50 ms lag
        assert report['alias_guard']['kept'] == 'refit'


def test_a_pole_pair_above_nyquist_is_an_alias():
    # a 20 ms loop: the 50 Hz pair of a fit that took the mechanical lag for an alias,
    # and the motor itself (real poles at 20 /s and 3300 /s)
    aliased = {'J': 5.2262e-05, 'K_T': 0.15999, 'K_b': 1.2671, 'B': 0.0015603,
               'L_m': 0.038953, 'R_m': 0.5}
    motor = {**aliased, 'J': 0.16, 'K_T': 1.2566, 'K_b': 1.2566, 'B': 0.0395, 'L_m': 1.5e-4}
    result = SimpleNamespace(input_kind='voltage', channels=('speed',))
    result.values = lambda: aliased
    np.testing.assert_allclose(aliased_poles(result, 0.02), 50.2, rtol=0.01)
    assert aliased_poles(result, 0.005) is None    # below the Nyquist frequency of 5 ms
    result.values = lambda: motor
    assert aliased_poles(result, 0.02) is None
    result.channels = ('speed', 'current')
    result.values = lambda: aliased
    assert aliased_poles(result, 0.02) is None      # the current sees the electrical pole


def test_fit_with_an_effect_searches_on_the_records_scale(friction_logs, tmp_path):
    log = friction_logs[0.005]
    out = tmp_path / 'fit.json'
    proc = _cli('fit', log.path, '-R', '0.5', '--effect', 'coulomb_friction', '-q', '--json',
                out)
    assert proc.returncode == 0 and 'overflow' not in proc.stderr, proc.stderr
    report = json.loads(out.read_text())
    assert report['adequate'] and report['effect_search']['K_T_held'] is True
    t_c = report['effect_search']['ranges']['coulomb_friction.T_c']
    assert t_c[0] == 0.0 and 0 < t_c[1] < 100
    np.testing.assert_allclose(report['controller']['feedforward']['kS']['value'], 0.1,
                               atol=0.01)
    # the linear model alone on request: no kS, and the notes say so
    proc = _cli('fit', log.path, '-R', '0.5', '--effect', 'none', '-q', '--json', out)
    report = json.loads(out.read_text())
    assert report['effects'] == {} and report['controller']['feedforward']['kS']['value'] == 0
    assert any(n.startswith('kS = 0') for n in report['controller']['notes'])


AK = '{"source":"AdvantageKit"}'
ENUM_NAMES = {'quasistatic-forward': 'kQuasistaticForward',
              'quasistatic-reverse': 'kQuasistaticReverse', 'dynamic-forward': 'kDynamicForward',
              'dynamic-reverse': 'kDynamicReverse', 'none': 'kNone'}


def advantagekit_copy(src, dst, late_loops=(0, 0)):
    """The routine ``src`` as an AdvantageKit robot logs it: the state as the Java enum's
    name under ``/RealOutputs/Shooter/SysIdState``, the voltage a double with the unit in
    JSON metadata, velocity and position elements of arrays (double[] and float[], no
    unit); the velocity entry starts ``late_loops[0]`` loops into the first test, the
    voltage ``late_loops[1]`` loops after that."""
    import wpiutil
    from wpiutil.log import (
        DoubleArrayLogEntry,
        DoubleLogEntry,
        FloatArrayLogEntry,
        StringLogEntry,
    )

    raw = raw_entries(src)
    state = raw['sysid-test-state-shooter'][1]
    volts, pos, vel = (raw[f'{c}-shooter-shooter'][1] for c in ('voltage', 'position',
                                                                  'velocity'))
    t_vel = vel[late_loops[0]][0] if late_loops[0] else 0
    t_volt = volts[sum(late_loops)][0] if sum(late_loops) else 0
    log = wpiutil.DataLogWriter(str(dst))
    st = StringLogEntry(log, '/RealOutputs/Shooter/SysIdState', AK, state[0][0] - 5)
    entries = {}
    for t, value in sorted(state + [(t, ('V', v)) for t, v in volts]
                           + [(t, ('P', v)) for t, v in pos] + [(t, ('W', v)) for t, v in vel],
                           key=lambda tv: tv[0]):
        if isinstance(value, str):
            st.append(ENUM_NAMES[value], t)
            continue
        kind, v = value
        if kind == 'V' and t >= t_volt:
            if 'V' not in entries:
                entries['V'] = DoubleLogEntry(log, '/Shooter/AppliedVolts',
                                              '{"source":"AdvantageKit","unit":"Volt"}', t)
            entries['V'].append(v, t)
        elif kind == 'P':
            if 'P' not in entries:
                entries['P'] = FloatArrayLogEntry(log, '/Shooter/Positions', AK, t)
            entries['P'].append([v, 0.0, 0.0], t)
        elif kind == 'W' and t >= t_vel:
            if 'W' not in entries:
                entries['W'] = DoubleArrayLogEntry(log, '/Shooter/Velocities', AK, t)
            entries['W'].append([v, -v], t)
    log.flush()
    log.stop()
    return str(dst)


def test_an_advantagekit_log_maps_its_arrays_and_enum_states(routine, tmp_path):
    _, path = routine
    ref = load_wpilog(path)
    ak = advantagekit_copy(path, tmp_path / 'akit.wpilog')
    with pytest.raises(DataError, match=r'no SysIdRoutineLog motor .* \(numeric entries: '
                                        r'/Shooter/AppliedVolts, /Shooter/Positions, '
                                        r'/Shooter/Velocities\)'):
        load_wpilog(ak)
    named = LogEntries(voltage='AppliedVolts', velocity='Shooter/Velocities',
                       units='Rotation')
    with pytest.raises(DataError, match=r"velocity entry '/Shooter/Velocities' holds "
                                        r'double\[\] \(arrays of 2\); name one element: '
                                        r'/Shooter/Velocities\[0\] .. /Shooter/Velocities\[1\]'):
        load_wpilog(ak, named)
    with pytest.raises(DataError, match=r'has no element 5 \(its arrays hold 2\)'):
        load_wpilog(ak, replace(named, velocity='Velocities[5]'))
    with pytest.raises(DataError, match='no unit in its metadata'):   # JSON without a unit
        load_wpilog(ak, replace(named, velocity='Velocities[0]', units=None))
    # the state entry is found by its name (sysid) and its values, the enum names read
    rec = load_wpilog(ak, replace(named, velocity='Velocities[0]', position='Positions[0]'))
    assert rec.meta['segment_names'] == list(ROUTINE)
    assert rec.meta['sysid']['entries'] == {
        'voltage': '/Shooter/AppliedVolts', 'velocity': '/Shooter/Velocities[0]',
        'position': '/Shooter/Positions[0]', 'state': '/RealOutputs/Shooter/SysIdState'}
    np.testing.assert_array_equal(rec.speed, ref.speed)
    np.testing.assert_array_equal(rec.input, ref.input)
    np.testing.assert_allclose(rec.position, ref.position, rtol=1e-6)   # float[]
    other = load_wpilog(ak, replace(named, velocity='/Shooter/Velocities[1]'))
    np.testing.assert_array_equal(other.speed, -ref.speed)


def test_entries_that_start_mid_log(routine, tmp_path):
    """A velocity entry started 5 loops into the first test, the voltage 3 loops later: the
    first test is read from the first loop that has both, and a warning counts the loops
    without a voltage."""
    _, path = routine
    ref = load_wpilog(path)
    ak = advantagekit_copy(path, tmp_path / 'late.wpilog', late_loops=(5, 3))
    rec = load_wpilog(ak, LogEntries(voltage='AppliedVolts', velocity='Velocities[0]',
                                     state='SysIdState', units='Rotation'))
    assert rec.meta['segment_names'] == list(ROUTINE)
    (a0, b0), (a1, _) = ref.segment_ranges[:2]
    assert rec.segment_ranges[0] == (0, b0 - a0 - 8)
    np.testing.assert_array_equal(rec.speed[:b0 - a0 - 8], ref.speed[a0 + 8:b0])
    np.testing.assert_array_equal(rec.speed[b0 - a0 - 8:], ref.speed[a1:])
    assert any("test 'quasistatic-forward': 3 sample(s) without a finite voltage" in w
               for w in rec.meta['warnings'])


def test_two_routines_in_one_log(tmp_path, capsys):
    """Two SysIdRoutineLogs (log names a and b, one motor each, the second routine after
    the first): the error lists both, a motor or a state entry picks one."""
    import wpiutil
    from wpiutil.log import DoubleLogEntry, StringLogEntry

    src = write_sysid_wpilog(tmp_path / 'one.wpilog', 8, **SHORT).path
    raw = raw_entries(src)
    log = wpiutil.DataLogWriter(str(tmp_path / 'two.wpilog'))
    shift = {'a': 0, 'b': raw['sysid-test-state-shooter'][1][-1][0] + 1_000_000}
    for name, (meta, records) in raw.items():
        if not name.endswith('-shooter') or not records:
            continue
        for log_name, dt in shift.items():
            new = name[:-len('shooter')].replace('-shooter-', '-arm-') + log_name
            kind = StringLogEntry if name.startswith('sysid') else DoubleLogEntry
            entry = kind(log, new, meta, records[0][0] + dt)
            for t, v in records:
                entry.append(v, t + dt)
    log.flush()
    log.stop()
    path = str(tmp_path / 'two.wpilog')
    with pytest.raises(DataError, match=r'several motors: arm-a, arm-b; pick one'):
        load_wpilog(path)
    ref = load_wpilog(src)
    for sel in (LogEntries(motor='arm-b'), LogEntries(state='sysid-test-state-b')):
        rec = load_wpilog(path, sel)
        assert rec.meta['sysid']['motor'] == 'arm (log b)'
        np.testing.assert_array_equal(rec.speed, ref.speed)
        np.testing.assert_allclose(rec.time - rec.time[0], ref.time - ref.time[0], atol=1e-9)
    assert main(['fit', path, '--motor', 'arm-a', '-q', '--json',
                 str(tmp_path / 'a.json')]) == 0
    capsys.readouterr()


def test_the_sysid_benchmark_reads_another_loggers_entries(tmp_path):
    # benchmarks/sysid.py passes --voltage ... --units to the reader and to motor-id, as
    # for the real URCL export (docs/sysid.md); --fit-only keeps it to seconds
    names = {'voltage': 'URCL/SparkMax-11/AppliedOutputVoltage',
             'position': 'URCL/SparkMax-11/MotorPositionRotations',
             'velocity': 'URCL/SparkMax-11/MotorVelocityRPM',
             'state': 'sysid-test-state-DriveSubsystem'}
    log = write_sysid_wpilog(tmp_path / 'urcl.wpilog', 4, entry_names=names, metadata=False,
                             units='Meter', **SHORT)
    out = tmp_path / 'bench.json'
    repo = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(repo) + os.pathsep + os.environ.get('PYTHONPATH',
                                                                                ''))
    proc = subprocess.run(
        [sys.executable, str(repo / 'benchmarks' / 'sysid.py'), '--log', log.path,
         '--json', str(out), '--fit-only', '--units', 'Meter', '--voltage',
         names['voltage'], '--position', names['position'], '--velocity',
         names['velocity'], '--state', names['state']],
        cwd=str(tmp_path), env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = json.loads(out.read_text())
    ours = result['models']['motor_id fit']
    assert '--voltage URCL/SparkMax-11/AppliedOutputVoltage' in ours['command']
    assert '--units Meter' in ours['command']
    assert set(ours['fit_percent']) == set(ROUTINE)
    assert all(f > 90.0 for f in ours['fit_percent'].values()), ours['fit_percent']
    truth = log.truth.motors['shooter']
    np.testing.assert_allclose(ours['gains']['kV'], truth.kV, rtol=0.05)   # V s/m


def test_a_frictionless_routine_is_not_said_to_hide_friction(tmp_path):
    """A flywheel without friction (kS 0): its quasistatic ramps lag by kA / kV times the
    ramp rate, which the steady-state map takes for a static offset both ways (about
    +-0.07 V). The analysis' model lags as much, so the report does not warn of friction
    its verdict does not name (it had, on every such routine); an offset the model does
    not reproduce still gets the warning."""
    from motor_id.analysis.assembly import _offset_unexplained
    from motor_id.analysis.diagnostics import SteadyPoint
    log = write_sysid_wpilog(tmp_path / 'fw.wpilog', 1,
                             motors=(RoutineMotor('flywheel', kS=0.0),))
    out = tmp_path / 'an.json'
    assert main(['analyze', log.path, '-q', '--json', str(out)]) == 0
    report = json.loads(out.read_text())
    ss = report['diagnostics']['steady_state']
    assert ss['positive']['zero_speed_input'] > 0.04
    assert ss['negative']['zero_speed_input'] < -0.04
    assert not any('static offset' in w for w in report['warnings']), report['warnings']
    ff = report['controller']['feedforward']
    assert abs(ff['kS']['value'] or 0.0) < 0.03
    np.testing.assert_allclose(ff['kV']['value'], log.truth.motors['flywheel'].kV, rtol=0.05)
    # a model through zero: the record's offset is not its own
    u = np.array([1.0, 2.0, 3.0, -1.0, -2.0, -3.0])
    pts = [SteadyPoint(start=0, stop=1, input=x, speed=50 * (x - 0.1 * np.sign(x)),
                       speed_linear=50 * x) for x in u]
    assert _offset_unexplained((0.1, -0.1), pts)
    pts = [replace(p, speed_linear=p.speed) for p in pts]
    assert not _offset_unexplained((0.1, -0.1), pts)
