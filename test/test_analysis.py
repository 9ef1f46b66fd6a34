"""The discrepancy analysis end to end: verdicts, compound verdicts, failures, CLI, data."""

import json
from pathlib import Path

import numpy as np
import pytest

from motor_id.analysis import DiscrepancyAnalysis
from motor_id.cli import main
from motor_id.data.csv_io import write_csv
from motor_id.excitation import bipolar_steps, multisine
from motor_id.model import MotorParams, Plant
from motor_id.recording import Recording
from motor_id.simulate import simulate_recording

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data'
EMPS = DATA / 'emps' / 'DATA_EMPS.mat'
DUNKER = DATA / 'dunker_gr42x25' / 'data_for_identification_without_integral.csv'
EMPS_PUBLISHED = {'J': 95.1089, 'B': 203.5034, 'coulomb_friction.T_c': 20.3935,
                  'load_torque.T_L': -3.1648}
SI_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
T = np.arange(4000) * 0.01


def _sim(effects, u, seed=1, noise=(0.005, 0.01), t=T, motor=SI_MOTOR):
    return simulate_recording(Plant(motor, 'voltage', effects), t, u, noise[0], noise[1],
                              random_state=seed)


@pytest.fixture(scope='module')
def emps_report():
    from motor_id.data.importers import load_emps
    if not EMPS.exists():
        pytest.skip(f'{EMPS} not present')
    return DiscrepancyAnalysis().fit(load_emps(EMPS)).report_


# --------------------------------------------------------------- verdicts
def test_analyze_cli_names_coulomb_friction_and_writes_json_and_plot(tmp_path, capsys):
    rec = _sim({'coulomb_friction': {'T_c': 0.05}}, bipolar_steps(T, 9.0))
    data = tmp_path / 'coulomb.csv'
    write_csv(rec, data, {'note': 'simulated'})
    out_json, out_png = tmp_path / 'report.json', tmp_path / 'report.png'
    rc = main(['analyze', str(data), '--resistance', '2.3', '--json', str(out_json),
               '--plot', str(out_png)])
    assert rc == 0
    captured = capsys.readouterr()
    assert 'verdict: coulomb_friction' in captured.out
    assert 'fitting the linear model' in captured.err
    rep = json.loads(out_json.read_text())
    assert set(rep) >= {'verdict', 'effects', 'unexplained', 'ambiguous_with', 'parameters',
                        'baseline', 'measurement', 'failed'}
    assert rep['verdict'] == 'coulomb_friction' and rep['unexplained'] is False
    best = rep['effects'][0]
    assert best['name'] == 'coulomb_friction' and best['gain'] > 0.5
    assert set(best) == {'name', 'parameters', 'gain', 'evidence'}
    for name in ('J', 'K_T', 'B', 'L_m'):
        assert rep['parameters'][name]['value'] == pytest.approx(getattr(SI_MOTOR, name),
                                                                 rel=0.02)
    assert rep['parameters']['coulomb_friction.T_c']['value'] == pytest.approx(0.05, rel=0.03)
    assert out_png.stat().st_size > 10000


def test_friction_and_load_are_ambiguous_when_the_motor_never_reverses():
    u = 6.0 + 3.0 * np.sign(np.sin(2 * np.pi * T / 8.0 + 0.1))
    rec = _sim({'coulomb_friction': {'T_c': 0.1}}, u, seed=3)
    rep = DiscrepancyAnalysis(R_m=2.3).fit(rec).report_
    named = {rep.verdict} | {a.name for a in rep.ambiguous_with}
    assert named == {'coulomb_friction', 'load_torque'}
    assert 'reverse' in rep.ambiguous_with[0].experiment


def test_encoder_grid_and_friction_are_both_reported():
    """A compound verdict: the dynamic effect plus the measurement effect with its q."""
    q = 0.4
    rec = _sim({'coulomb_friction': {'T_c': 0.05}}, bipolar_steps(T, 9.0), seed=5)
    rec.speed = q * np.round(rec.speed / q)
    rep = DiscrepancyAnalysis(R_m=2.3 * 1.03).fit(rec).report_
    assert rep.verdict == 'coulomb_friction+speed_quantization'
    assert rep.parameters['speed_quantization.q']['value'] == pytest.approx(q, rel=1e-6)
    assert rep.parameters['coulomb_friction.T_c']['value'] == pytest.approx(0.05, rel=0.1)
    entry = next(e.to_dict() for e in rep.effects if e.name == 'speed_quantization')
    assert entry['gain'] is None and entry['evidence']['kind'] == 'measurement'
    assert entry['evidence']['counts_per_revolution'] == pytest.approx(
        2 * np.pi / (q * 0.01), rel=1e-6)


def test_heating_is_told_from_a_brush_drop_by_the_electrical_equation():
    from motor_id.analysis import electrical_evidence
    u = bipolar_steps(T, 9.0)
    cases = {'resistance_drift': {'k_h': 0.01, 'tau_th': 12.0},
             'brush_drop': {'V_b': 0.4}, 'dead_zone': {'V_dz': 0.8}}
    for name, params in cases.items():
        ev = electrical_evidence(_sim({name: params}, u, seed=6))
        assert ev.favoured == name, (name, ev.explained)
    clean = electrical_evidence(_sim({}, u, seed=6))
    assert clean.favoured is None
    assert clean.R_m_base == pytest.approx(2.3, rel=0.02)


# --------------------------------------------------------------- failures
def test_a_candidate_that_raises_is_recorded_as_failed(monkeypatch, tmp_path, capsys):
    from motor_id.analysis import candidates
    real = candidates.CandidateFitter._fit

    def broken(self, name, *args):
        if name == 'brush_drop':
            raise RuntimeError('solver blew up')
        return real(self, name, *args)

    monkeypatch.setattr(candidates.CandidateFitter, '_fit', broken)
    rec = _sim({'coulomb_friction': {'T_c': 0.05}}, bipolar_steps(T, 9.0))
    data = tmp_path / 'c.csv'
    write_csv(rec, data)
    out_json = tmp_path / 'r.json'
    assert main(['analyze', str(data), '-R', '2.3', '-q', '--json', str(out_json),
                 '--candidates', 'coulomb_friction,brush_drop,load_torque']) == 0
    rep = json.loads(out_json.read_text())
    assert rep['verdict'] == 'coulomb_friction'
    assert rep['failed'] == [{'name': 'brush_drop', 'reason': 'RuntimeError: solver blew up'}]
    assert 'failed' in capsys.readouterr().out


def test_a_diverging_thermal_model_does_not_lose_the_analysis(tmp_path):
    """A hobby motor at 50 Hz: L_m / T is tiny, so any extra resistance diverges."""
    t = np.arange(4800) * 0.02
    hobby = MotorParams(J=2e-6, K_T=0.01, K_b=0.01, B=1e-6, L_m=5e-4, R_m=4.0)
    rec = _sim({}, bipolar_steps(t, 6.0), seed=8, t=t, motor=hobby)
    rep = DiscrepancyAnalysis(R_m=4.0, candidates=['resistance_drift', 'load_torque']
                              ).fit(rec).report_
    assert rep.verdict == 'none'
    drift = next(e for e in rep.effects if e.name == 'resistance_drift')
    assert drift.failed or not drift.significant
    json.dumps(rep.to_dict())


def test_a_huge_cell_is_a_one_line_error_not_a_traceback(tmp_path, capsys):
    rec = _sim({}, bipolar_steps(T, 9.0))
    rec.speed[100] = 1e300
    data = tmp_path / 'bad.csv'
    write_csv(rec, data)
    assert main(['analyze', str(data), '-R', '2.3', '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and '1e+300' in err[0] and 'Traceback' not in err[0]
    # the same value handed over in memory (not through a reader)
    from motor_id.errors import DataError
    with pytest.raises(DataError, match='sample 100'):
        DiscrepancyAnalysis(R_m=2.3).fit(rec)


# --------------------------------------------------------------- CLI
def test_analyze_candidates_restricts_the_search(tmp_path, capsys):
    rec = _sim({'load_torque': {'T_L': 0.1}}, bipolar_steps(T, 9.0), seed=4)
    data = tmp_path / 'load.csv'
    write_csv(rec, data)
    out_json = tmp_path / 'r.json'
    assert main(['analyze', str(data), '-R', '2.3', '-q', '--json', str(out_json),
                 '--candidates', 'load_torque, sensor_lag']) == 0
    rep = json.loads(out_json.read_text())
    assert rep['verdict'] == 'load_torque'
    assert {e['name'] for e in rep['effects'] if '+' not in e['name']} == {
        'load_torque', 'sensor_lag'}
    assert rep['parameters']['load_torque.T_L']['value'] == pytest.approx(0.1, rel=0.05)


def test_analyze_candidates_without_the_true_effect_names_none_or_flags_structure(
        tmp_path):
    rec = _sim({'load_torque': {'T_L': 0.1}}, bipolar_steps(T, 9.0), seed=4)
    data = tmp_path / 'load.csv'
    write_csv(rec, data)
    out_json = tmp_path / 'r.json'
    assert main(['analyze', str(data), '-R', '2.3', '-q', '--json', str(out_json),
                 '--candidates', 'sensor_lag']) == 0
    rep = json.loads(out_json.read_text())
    assert rep['verdict'] in ('none', 'sensor_lag')
    assert rep['unexplained'] is True


def test_analyze_unknown_candidate_is_exit_2(tmp_path, capsys):
    rec = _sim({}, bipolar_steps(T, 9.0))
    data = tmp_path / 'clean.csv'
    write_csv(rec, data)
    assert main(['analyze', str(data), '-R', '2.3', '--candidates', 'coulomb,load']) == 2
    err = capsys.readouterr().err
    assert "unknown candidate effect 'coulomb'" in err and 'Traceback' not in err


def test_analyze_reads_an_mcap_bag(tmp_path, capsys):
    from motor_id.bag import write_recording
    t = np.arange(1500) * 0.01
    rec = _sim({'load_torque': {'T_L': 0.1}}, bipolar_steps(t, 9.0), seed=4, t=t)
    bag = tmp_path / 'load.mcap'
    write_recording(rec, bag)
    assert main(['analyze', str(bag), '-R', '2.3', '-q']) == 0
    assert 'verdict: load_torque' in capsys.readouterr().out


def test_analyze_needs_the_resistance_for_voltage_data(tmp_path, capsys):
    rec = _sim({}, bipolar_steps(T, 9.0))
    data = tmp_path / 'clean.csv'
    write_csv(rec, data)
    assert main(['analyze', str(data)]) == 2
    assert '--resistance' in capsys.readouterr().err


# ------------------------------------------------------------ measured data
@pytest.mark.slow
def test_emps_friction_with_offset_and_published_parameters(emps_report):
    rep = emps_report
    names = rep.verdict.split('+')
    assert 'coulomb_friction' in names and 'load_torque' in names
    assert 'speed_quantization' not in names  # a 2.5e-5 m/s grid: a resolution
    combo = next(e for e in rep.effects if e.name == rep.chosen.search.name)
    assert combo.gain > 0.6
    assert all(c['marginal'] > 0.05 for c in combo.components.values())
    idim = {k: v.value for k, v in rep.inverse_dynamics.parameters.items()}
    oe = {k: v['value'] for k, v in rep.chosen.search.output_error_parameters.items()}
    head = {k: rep.parameters[k]['value'] for k in EMPS_PUBLISHED}
    print(f'\nEMPS {rep.verdict}: gain {100 * combo.gain:.1f} %; estimator '
          f'{rep.chosen.search.estimator}')
    for k, ref in EMPS_PUBLISHED.items():
        print(f'  {k:<22} published {ref:10.4f}  headline {head[k]:10.4f} '
              f'({100 * (head[k] / ref - 1):+6.2f} %)  output error {oe[k]:10.4f} '
              f'({100 * (oe[k] / ref - 1):+6.2f} %)')
    assert 'inverse dynamics' in rep.chosen.search.estimator
    for k in ('J', 'B', 'coulomb_friction.T_c'):
        assert head[k] == pytest.approx(EMPS_PUBLISHED[k], rel=0.05)
    assert head['load_torque.T_L'] == pytest.approx(EMPS_PUBLISHED['load_torque.T_L'],
                                                    rel=0.1)
    assert idim == {k: head[k] for k in idim}
    assert rep.inverse_dynamics.relative_error < 0.05


def test_dunker_shows_coulomb_friction_and_its_speed_grid():
    from motor_id.data.importers import load_dunker
    if not DUNKER.exists():
        pytest.skip(f'{DUNKER} not present')
    rep = DiscrepancyAnalysis().fit(load_dunker(DUNKER, motor=1)).report_
    assert 'coulomb_friction' in rep.verdict.split('+')
    # the authors' fit: T0 = 0.0070 .. 0.0081 N m, b = 2.0e-5 .. 2.4e-5 N m s/rad
    assert 0.005 < rep.parameters['coulomb_friction.T_c']['value'] < 0.011
    assert 1e-5 < rep.parameters['B']['value'] < 5e-5
    assert rep.measurement['input'].found  # the current (the input) on a 25.6 mA grid
    ms = rep.diagnostics.steady_state
    assert ms.positive.zero_speed_input > 0.004
    assert ms.negative.zero_speed_input < -0.004


def test_clean_torque_plant_gives_none():
    t = np.arange(4000) * 1e-3
    u = 40 * multisine(t, 1.0, 0.5, 20.0, random_state=5)
    rec = simulate_recording(Plant(MotorParams(J=1.0, B=20.0), 'torque'), t, u, 0.005,
                             random_state=5)
    rep = DiscrepancyAnalysis().fit(Recording(rec.time, rec.input, rec.speed, None,
                                              'torque')).report_
    assert rep.verdict == 'none' and not rep.unexplained
    assert rep.parameters['J']['value'] == pytest.approx(1.0, rel=0.02)
