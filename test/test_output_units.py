"""Every constant of a report carries its unit; a linear axis reads in metres (issue 27)."""

import json

import matplotlib.axes
import pytest

from motor_id.cli import main
from motor_id.contracts import linear_unit, units_of
from motor_id.data.wpilog import load_wpilog
from motor_id.identify.validation import SavedModel, validate
from motor_id.output import attach_units, expression_unit
from motor_id.testing.sysid_wpilog import ROUTINE, RoutineMotor, write_sysid_wpilog

SHORT = {'ramp_duration': 2.0, 'step_duration': 0.8, 'rest': 0.5, 'loop_period': 0.005}


def constants(node, path=''):
    """``(path, entry)`` of every dict with a value in a report."""
    if isinstance(node, dict):
        if 'value' in node:
            yield path, node
        for k, v in node.items():
            yield from constants(v, f'{path}.{k}')
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from constants(v, f'{path}[{i}]')


@pytest.mark.parametrize('rotary,linear', [
    ('V s/rad', 'V s/m'), ('V s^2/rad', 'V s^2/m'), ('N m/A', 'N/A'), ('kg m^2', 'kg'),
    ('rad/s', 'm/s'), ('N m s/rad', 'N s/m'), ('N m s^2/rad^2', 'N s^2/m^2'), ('Ohm', 'Ohm')])
def test_a_rotary_unit_on_a_linear_axis(rotary, linear):
    assert linear_unit(rotary) == linear


def test_units_of_a_linear_axis():
    units = units_of('voltage', linear=True)
    assert (units['kV'], units['kA'], units['speed'], units['K_b']) == (
        'V s/m', 'V s^2/m', 'm/s', 'V s/m')
    assert units_of('torque', linear=True)['kV'] == 'N s/m'
    assert units_of('voltage')['kV'] == 'V s/rad'


@pytest.mark.parametrize('expr,unit', [
    ('K_T/(J*L_m)', 'N m/A/(kg m^2 H)'), ('R_m/L_m + B/J', 'Ohm/H'),
    ('(R_m*B + K_T*K_b)/(J*L_m)', 'Ohm (N m s/rad)/(kg m^2 H)'), ('2*J^2', '(kg m^2)^2'),
    ('kV', 'V s/rad'), ('x/y', None), ('J +', None)])
def test_the_unit_of_a_combination(expr, unit):
    assert expression_unit(expr, units_of()) == unit


def test_attach_units_names_each_kind_of_constant():
    report = {'parameters': {'J': {'value': 1.0}, 'coulomb_friction.T_c': {'value': 0.1}},
              'effects': {'coulomb_friction': {'T_c': {'value': 0.1}}},
              'combinations': [{'name': 'kA', 'value': 1.0}, {'name': 'R_m/L_m', 'value': 2}],
              'controller': {'feedforward': {'kG': {'value': 1.0}, 'kS': {'value': 0.1},
                                             'units': {'kS': 'V'}},
                             'time_constants': {'electrical': {'value': 1e-3}},
                             'pi': {'speed': {'kp': {'value': 1.0}, 'units': {'kp': 'A s/m'}}}},
              'mystery': {'value': 3.0}, 'given': {'value': 1.0, 'unit': 'furlong'}}
    attach_units(report, 'voltage', linear=True)
    units = {path: c.get('unit') for path, c in constants(report)}
    assert units == {
        '.parameters.J': 'kg', '.parameters.coulomb_friction.T_c': 'N',
        '.effects.coulomb_friction.T_c': 'N', '.combinations[0]': 'V s^2/m',
        '.combinations[1]': 'Ohm/H', '.controller.feedforward.kG': 'V',
        '.controller.feedforward.kS': 'V', '.controller.time_constants.electrical': 's',
        '.controller.pi.speed.kp': 'A s/m', '.mystery': None, '.given': 'furlong'}


@pytest.fixture(scope='module')
def metre_log(tmp_path_factory):
    path = tmp_path_factory.mktemp('units') / 'elevator.wpilog'
    return write_sysid_wpilog(path, 11, units='Meter', motors=(RoutineMotor('lift'),),
                              **SHORT)


def test_a_metre_log_fits_and_plots_in_metres(metre_log, tmp_path, monkeypatch, capsys):
    rec = load_wpilog(metre_log.path)
    assert rec.linear
    labels = []
    real = matplotlib.axes.Axes.set_ylabel
    monkeypatch.setattr(matplotlib.axes.Axes, 'set_ylabel',
                        lambda ax, text, *a, **k: labels.append(text) or real(ax, text))
    out = tmp_path / 'fit.json'
    assert main(['fit', metre_log.path, '-R', '0.5', '-q', '--json', str(out), '--plot',
                 str(tmp_path / 'fit.png')]) == 0
    text = capsys.readouterr().out
    assert 'V s/m' in text and 'V s/rad' not in text
    assert 'speed [m/s]' in labels and not any('rad' in label for label in labels)
    report = json.loads(out.read_text())
    missing = [p for p, c in constants(report) if 'unit' not in c]
    assert not missing
    ff = report['controller']['feedforward']
    assert (ff['kV']['unit'], ff['kA']['unit'], ff['kS']['unit']) == ('V s/m', 'V s^2/m', 'V')
    assert report['parameters']['K_b']['unit'] == 'V s/m'
    assert report['data']['linear'] is True


def test_analyze_of_a_metre_log_reports_every_unit(metre_log, tmp_path, capsys):
    out = tmp_path / 'analyze.json'
    assert main(['analyze', metre_log.path, '-R', '0.5', '-q', '--candidates',
                 'coulomb_friction', '--json', str(out), '--plot',
                 str(tmp_path / 'a.png')]) == 0
    text = capsys.readouterr().out
    report = json.loads(out.read_text())
    missing = [p for p, c in constants(report) if 'unit' not in c]
    assert not missing
    ff = report['controller']['feedforward']
    assert (ff['kV']['unit'], ff['kA']['unit']) == ('V s/m', 'V s^2/m')
    # the fit % of each test by name, as motor-id validate scores the saved model
    assert [r['name'] for r in report['runs']] == list(ROUTINE)
    assert 'fit % per run' in text
    val = validate(SavedModel.from_report(report), load_wpilog(metre_log.path))
    for mine, theirs in zip(report['runs'], val.runs, strict=True):
        assert mine['channels'] == theirs.channels
        line = next(x for x in text.splitlines() if x.strip().startswith(mine['name']))
        assert f'speed {mine["channels"]["speed"]["fit_percent"]:6.2f} %' in line
