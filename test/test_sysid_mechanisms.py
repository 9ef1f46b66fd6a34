"""SysId routines of an arm and a flywheel on the independent physics (issue 27): kG and the
arm's offset with error bars, kS, kV, kA within the issue's targets, the mechanism taken
from a JSON log's test.

The arm: a geared motor (kV 0.6008 V s/rad, kA 0.0417 V s^2/rad, kS 0.1 V) lifting a
load of kG = 1 V whose encoder zero is 0.35 rad off horizontal; each test starts hanging
at rest (theta + offset = -pi/2), a 20 ms robot loop with jitter. The flywheel: kV 0.02025
V s/rad, kA 0.01 V s^2/rad (tau_m 0.5 s), kS 0.2 V, a 40 ms enable latency, 20 ms loop.
The elevator: the arm's motor on a 2 cm drum (kV 30.04 V s/m, kA 2.083 V s^2/m, kS 0.1 V)
lifting kG = 1 V, logged in metres: it falls whenever the input is below kG - kS, as an
elevator without a brake does between and at the start of the tests.
"""

from dataclasses import replace
import json
import math

import numpy as np
import pytest

from motor_id.cli import main
from motor_id.data.wpilog import load_wpilog
from motor_id.testing.independent_physics import Motor
from motor_id.testing.sysid_log import DEFAULT_MOTOR
from motor_id.testing.sysid_wpilog import ROUTINE, RoutineMotor, write_sysid_wpilog

ARM = Motor(J=0.05, K=0.6, R=0.5, L=1.5e-4, B=1e-3, V_supply=12.0, motor_class='arm')
OFFSET = 0.35
KG = 1.0
ARM_TESTS = {'ramp_rate': 0.5, 'ramp_duration': 4.0, 'step_voltage': 2.0,
             'step_duration': 1.0}


def arm_routine(path, seed=5, **kw):
    joint = RoutineMotor('arm', motor=ARM, kS=0.1, start=-math.pi / 2 - OFFSET,
                         effects={'arm_gravity': {'T_g': KG * ARM.K / ARM.R,
                                                  'offset': OFFSET}})
    return write_sysid_wpilog(path, seed, motors=(joint,), log_name='arm', **{**ARM_TESTS,
                                                                               **kw})


@pytest.fixture(scope='module')
def arm(tmp_path_factory):
    return arm_routine(tmp_path_factory.mktemp('arm') / 'arm.wpilog')


EL_KG = 1.0


def elevator_routine(path, seed=3):
    joint = RoutineMotor('elevator', motor=ARM, kS=0.1, start=0.0,
                         effects={'elevator_gravity': {'T_g': EL_KG * ARM.K / ARM.R}})
    return write_sysid_wpilog(path, seed, motors=(joint,), log_name='elevator',
                              units='Meter', meters_per_radian=0.02, ramp_rate=0.5,
                              ramp_duration=4.0, step_voltage=3.0, step_duration=1.0)


@pytest.fixture(scope='module')
def elevator(tmp_path_factory):
    return elevator_routine(tmp_path_factory.mktemp('elevator') / 'elevator.wpilog')


def feedforward(report):
    return {k: v for k, v in report['controller']['feedforward'].items()
            if isinstance(v, dict) and 'value' in v}


def check_arm(ff, truth):
    """The issue's targets: kG 10 %, offset 0.1 rad, kV 10 %, kS 0.1 V, kA 30 % or not
    determined; each with an error bar and a unit."""
    np.testing.assert_allclose(ff['kG']['value'], truth.kG, rtol=0.10)
    np.testing.assert_allclose(ff['offset']['value'], truth.offset, atol=0.1)
    np.testing.assert_allclose(ff['kV']['value'], truth.kV, rtol=0.10)
    np.testing.assert_allclose(ff['kS']['value'], truth.kS, atol=0.1)
    if ff['kA']['value'] is not None:
        np.testing.assert_allclose(ff['kA']['value'], truth.kA, rtol=0.30)
    for k in ('kG', 'offset', 'kV', 'kS'):
        assert ff[k]['std'] > 0
    assert (ff['kG']['unit'], ff['offset']['unit']) == ('V', 'rad')


def test_the_generated_arm_hangs_and_lifts(arm):
    rec = load_wpilog(arm.path)
    assert rec.meta['segment_names'] == list(ROUTINE)
    for a, _ in rec.segment_ranges:   # every test starts hanging at rest
        np.testing.assert_allclose(rec.position[a] + OFFSET, -math.pi / 2, atol=1e-9)
    a, b = rec.segment_ranges[0]      # the ramp lifts it to near horizontal, not over
    assert -0.5 < rec.position[b - 1] + OFFSET < 1.0
    assert arm.truth.motors['arm'].kG == pytest.approx(KG, rel=1e-12)


def test_fit_of_an_arm_routine(arm, tmp_path, capsys):
    out = tmp_path / 'fit.json'
    assert main(['fit', arm.path, '--mechanism', 'arm', '-q', '--json', str(out)]) == 0
    capsys.readouterr()
    report = json.loads(out.read_text())
    check_arm(feedforward(report), arm.truth.motors['arm'])
    # validate simulates it with the arm's gravity at the log's measured position
    val = tmp_path / 'validate.json'
    assert main(['validate', str(out), arm.path, '--mechanism', 'arm', '--json',
                 str(val)]) == 0
    capsys.readouterr()
    scores = json.loads(val.read_text())['channels']
    assert scores['position']['fit_percent'] > 95 and scores['speed']['fit_percent'] > 90


def test_analyze_of_an_arm_routine(arm, tmp_path, capsys):
    out = tmp_path / 'analyze.json'
    assert main(['analyze', arm.path, '--mechanism', 'arm', '-q', '--json', str(out)]) == 0
    text = capsys.readouterr().out
    report = json.loads(out.read_text())
    ff, truth = feedforward(report), arm.truth.motors['arm']
    check_arm(ff, truth)
    assert [r['name'] for r in report['runs']] == list(ROUTINE)
    assert all(r['channels']['speed']['fit_percent'] > 97 for r in report['runs'])
    assert 'kG' in text and 'offset' in text
    # the gravity at each interval's midpoint (at its start: kV +1.3 %, kG -1 %), from the
    # winding the faster pole (the equation-error stage had them exchanged: kA not
    # determined, kV +3.7 %, kG -3.1 %): kV 0.6012, kA 0.0417, kG 0.9992
    for key, tol in (('kV', 0.005), ('kA', 0.03), ('kG', 0.005)):
        assert ff[key]['value'] == pytest.approx(getattr(truth, key), rel=tol), key


def json_log(rec, test):
    """A SysId JSON log (units Radians, positions in rotations) of a recording's runs."""
    log = {'sysid': True, 'test': test, 'units': 'Radians', 'unitsPerRotation': 2 * math.pi}
    names = {'quasistatic-forward': 'slow-forward', 'quasistatic-reverse': 'slow-backward',
             'dynamic-forward': 'fast-forward', 'dynamic-reverse': 'fast-backward'}
    for name, (a, b) in zip(rec.meta['segment_names'], rec.segment_ranges, strict=True):
        rows = np.column_stack([rec.time[a:b], rec.input[a:b], rec.position[a:b] / (2 * math.pi),
                                rec.speed[a:b] / (2 * math.pi)])
        log[names[name]] = rows.tolist()
    return log


def test_a_json_arm_log_fits_as_an_arm(arm, tmp_path, capsys):
    path = tmp_path / 'sysid_data.json'
    path.write_text(json.dumps(json_log(load_wpilog(arm.path), 'Arm')))
    out = tmp_path / 'fit.json'
    assert main(['fit', str(path), '-q', '--json', str(out)]) == 0
    assert "mechanism: arm (the log's test" in capsys.readouterr().err
    check_arm(feedforward(json.loads(out.read_text())), arm.truth.motors['arm'])
    val = tmp_path / 'validate.json'   # the mechanism from the log's test again
    assert main(['validate', str(out), str(path), '--json', str(val)]) == 0
    assert "mechanism: arm (the log's test" in capsys.readouterr().err
    scores = json.loads(val.read_text())['channels']
    assert scores['position']['fit_percent'] > 95 and scores['speed']['fit_percent'] > 90
    # --mechanism overrides the log: an arm fitted as a simple mechanism has no kG
    assert main(['fit', str(path), '-q', '--mechanism', 'simple', '--json', str(out)]) == 0
    assert 'kG' not in feedforward(json.loads(out.read_text()))
    capsys.readouterr()


def test_analyze_of_a_flywheel_routine(tmp_path, capsys):
    wheel = replace(DEFAULT_MOTOR, J=4e-4, motor_class='flywheel')
    log = write_sysid_wpilog(tmp_path / 'flywheel.wpilog', 9, loop_period=0.02, jitter=0.1,
                             start_latency=0.04, noise=0.003, ramp_duration=6.0,
                             step_duration=3.0,
                             motors=(RoutineMotor('flywheel', motor=wheel, kS=0.2),))
    out = tmp_path / 'analyze.json'
    assert main(['analyze', log.path, '-q', '--json', str(out)]) == 0
    capsys.readouterr()
    ff = feedforward(json.loads(out.read_text()))
    truth = log.truth.motors['flywheel']
    np.testing.assert_allclose(ff['kV']['value'], truth.kV, rtol=0.05)
    np.testing.assert_allclose(ff['kS']['value'], truth.kS, atol=0.03)
    if ff['kA']['value'] is not None:
        np.testing.assert_allclose(ff['kA']['value'], truth.kA, rtol=0.30)


def check_elevator(ff, truth):
    """The issue's targets for an elevator: kG 10 %, kS 0.1 V, kV 10 %, kA 30 % or not
    determined; per metre."""
    np.testing.assert_allclose(ff['kG']['value'], truth.kG, rtol=0.10)
    np.testing.assert_allclose(ff['kS']['value'], truth.kS, atol=0.1)
    np.testing.assert_allclose(ff['kV']['value'], truth.kV, rtol=0.10)
    if ff['kA']['value'] is not None:
        np.testing.assert_allclose(ff['kA']['value'], truth.kA, rtol=0.30)
    assert (ff['kG']['unit'], ff['kV']['unit'], ff['kA']['unit']) == ('V', 'V s/m', 'V s^2/m')
    assert ff['kG']['std'] > 0 and ff['kS']['std'] > 0


def test_the_generated_elevator_falls_when_undriven(elevator):
    rec = load_wpilog(elevator.path)
    assert rec.meta['segment_names'] == list(ROUTINE)
    a, b = rec.segment_ranges[0]   # the ramp starts below kG - kS: the carriage falls first
    assert rec.speed[a + 10] < -0.01 and rec.speed[b - 1] > 0.01
    assert elevator.truth.motors['elevator'].kG == pytest.approx(EL_KG, rel=1e-12)


def test_fit_of_an_elevator_routine(elevator, tmp_path, capsys):
    """The fit starts from SysId's whole equation-error model as well: started from the
    plant fitted without gravity alone, it ended at kS 1.6 +- 14 V and kG 2.5 +- 22 V (61 %
    of the speed); now kS 0.0998, kV 30.043, kA 2.080, kG 1.0001 (99.6 %)."""
    out = tmp_path / 'fit.json'
    assert main(['fit', elevator.path, '--mechanism', 'elevator', '-q', '--json',
                 str(out)]) == 0
    capsys.readouterr()
    report = json.loads(out.read_text())
    check_elevator(feedforward(report), elevator.truth.motors['elevator'])
    assert report['fit']['channels']['speed']['fit_percent'] > 95


@pytest.mark.slow
def test_analyze_of_an_elevator_routine(elevator, tmp_path, capsys):
    """analyze: kS 0.0993, kV 30.046, kA 2.079, kG 0.9997; each test 97.8-99.0 %."""
    out = tmp_path / 'analyze.json'
    assert main(['analyze', elevator.path, '--mechanism', 'elevator', '-q', '--json',
                 str(out)]) == 0
    capsys.readouterr()
    report = json.loads(out.read_text())
    check_elevator(feedforward(report), elevator.truth.motors['elevator'])
    assert all(r['channels']['speed']['fit_percent'] > 90 for r in report['runs'])


@pytest.mark.parametrize('r, f_r, zeta', [(50.0, 1.0, 0.75), (20.0, 2.0, 0.6)])
def test_a_wheel_with_the_robot_behind_a_damped_coupling_is_found(tmp_path, r, f_r, zeta):
    """A SysId JSON log (5 ms, kS 0.4 V) of a motor and wheel with 98 % (95 %) of the
    inertia behind a damped coupling, as a drivetrain whose tyres slip while the robot
    catches up (independent physics, two masses). Without the coupling the analysis
    simulated the steps at 10 % (38 %) and put kA 33 % low; the simulation stage now tries
    the two-mass model on every record and finds it."""
    from motor_id.analysis import DiscrepancyAnalysis
    from motor_id.data.sysid import load_sysid
    from motor_id.testing.sysid_log import DEFAULT_MOTOR, make_sysid_log
    log = make_sysid_log(0, motor=DEFAULT_MOTOR, sample_period=0.005, kS=0.4, noise=0.004,
                         effects={'resonance': {'r': r, 'f_r': f_r, 'zeta': zeta}})
    rec = load_sysid(log.write(tmp_path / 'twomass.json'))
    ana = DiscrepancyAnalysis(random_state=0).fit(rec)
    report = ana.report_.to_dict()
    stage = ana.report_.simulation
    assert 'resonance' in stage.model.effects, stage.chosen
    assert stage.model.effects['resonance']['f_r'] == pytest.approx(f_r, rel=0.05)
    assert stage.model.effects['resonance']['zeta'] == pytest.approx(zeta, rel=0.1)
    ff = {c.name: c for c in stage.estimates.combinations}
    truth = log.truth.feedforward
    for key, tol in (('kS', 0.02), ('kV', 0.01), ('kA', 0.02)):
        assert ff[key].value == pytest.approx(getattr(truth, key), rel=tol), key
    steps = {run['name']: run['channels']['speed']['fit_percent'] for run in report['runs']}
    assert min(steps['fast-forward'], steps['fast-backward']) > 90.0, steps
    # the equation-error model, without the coupling, explains too little of the speed
    # (-49 %); the report is judged on the two masses it presents (99 % held out)
    assert stage.heldout_fit['speed'] > 90.0
    assert report['adequate'], report['warnings']
    assert 'the equation-error model explains (held out)' in report['warnings'][0]
    assert 'simulation-error model (coulomb_friction+resonance)' in report['warnings'][0]
