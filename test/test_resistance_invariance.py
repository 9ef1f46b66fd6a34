"""R_m where speed-only voltage data cannot see it (issue 27): never needed, never used.

Every output of fit and analyze is the same, to the bit, whatever ``-R`` says (0.05, 1, 20
Ohm or none): the verdict, kS, kV, kA, their error bars and intervals. Only the
``resistance`` block (which echoes the given value) and the timings differ.
"""

import json

import pytest

from motor_id.cli import main
from motor_id.data.csv_io import write_csv
from motor_id.identify.space import resistance_enters
from motor_id.testing.recordings import paper_recording
from motor_id.testing.sysid_wpilog import RoutineMotor, write_sysid_wpilog

GIVEN = ('0.05', '1', '20', None)


def comparable(report):
    """The report without its timings and its ``resistance`` block."""
    if isinstance(report, dict):
        return {k: comparable(v) for k, v in report.items()
                if k not in ('seconds', 'resistance')}
    if isinstance(report, list):
        return [comparable(v) for v in report]
    return report


@pytest.mark.parametrize('kind,current,fixed,enters', [
    ('voltage', False, None, False), ('voltage', False, {'R_m': 2.0}, False),
    ('voltage', True, None, True), ('voltage', False, {'J': 1e-4}, True),
    ('torque', False, None, False)])
def test_when_the_resistance_enters(kind, current, fixed, enters):
    assert resistance_enters(kind, current, fixed) is enters


@pytest.fixture(scope='module')
def routine(tmp_path_factory):
    path = tmp_path_factory.mktemp('r') / 'routine.wpilog'
    return write_sysid_wpilog(path, 21, loop_period=0.005, ramp_duration=2.0,
                              step_duration=0.8, rest=0.5, start_latency=0.02,
                              motors=(RoutineMotor('arm', kS=0.15),)).path


def run_all(command, path, tmp_path, capsys, *extra):
    """``{given: (report, printed text)}`` of one command over every -R."""
    out = {}
    for r in GIVEN:
        js = tmp_path / f'{command}_{r}.json'
        args = [command, path, '-q', '--json', str(js), *extra] + (['-R', r] if r else [])
        assert main(args) == 0, capsys.readouterr().err
        out[r] = (json.loads(js.read_text()), capsys.readouterr().out)
    return out


def test_fit_is_the_same_whatever_r_says(routine, tmp_path, capsys):
    runs = run_all('fit', routine, tmp_path, capsys)
    reference = comparable(runs['1'][0])
    for r, (report, text) in runs.items():
        assert comparable(report) == reference, r
        res = report['resistance']
        assert res['enters'] is False and res['internal'] == 1.0
        assert res['given'] == (None if r is None else float(r))
        assert report['parameters']['R_m']['value'] is None
        assert 'R_m does not enter' in text
        assert 'r_m_sensitivity' not in report
    ff = runs[None][0]['controller']['feedforward']
    assert all(ff[k]['value'] is not None for k in ('kS', 'kV', 'kA'))
    # the printed constants are the same lines too
    tables = {r: [x for x in text.splitlines() if x.startswith(('kS ', 'kV ', 'kA '))]
              for r, (_, text) in runs.items()}
    assert len(tables['1']) == 3 and all(t == tables['1'] for t in tables.values())


def test_analyze_is_the_same_whatever_r_says(routine, tmp_path, capsys):
    runs = run_all('analyze', routine, tmp_path, capsys, '--candidates',
                   'coulomb_friction,resistance_drift,input_delay,dead_zone')
    reference = comparable(runs['1'][0])
    assert reference['controller']['feedforward']['kS']['value'] is not None
    for r, (report, text) in runs.items():
        assert comparable(report) == reference, r
        assert report['resistance']['enters'] is False
        assert ('not used' in report['resistance']['note']) is (r is not None)
        assert 'R_m: R_m does not enter' in text


@pytest.mark.slow
def test_analyze_with_every_candidate_is_the_same_whatever_r_says(routine, tmp_path,
                                                                   capsys):
    runs = run_all('analyze', routine, tmp_path, capsys)
    reference = comparable(runs['1'][0])
    assert all(comparable(report) == reference for report, _ in runs.values())


def test_a_measured_current_still_needs_r(tmp_path, capsys):
    rec = paper_recording(speed_noise=0.01, current_noise=0.01, seed=2)
    write_csv(rec, tmp_path / 'c.csv')
    for command in ('fit', 'analyze'):
        assert main([command, str(tmp_path / 'c.csv'), '-q']) == 2
        err = capsys.readouterr().err
        assert 'with a measured current' in err and 'is required' in err


def test_a_fixed_parameter_ties_the_others_to_r(routine, capsys):
    assert main(['fit', routine, '-q', '--fix', 'J=1e-4']) == 2
    err = capsys.readouterr().err   # the library names parameters, the command line its flags
    assert 'a fixed parameter other than R_m' in err
    assert '(command line: -R/--resistance, --fix)' in err
