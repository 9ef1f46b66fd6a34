"""Discrepancy analysis: diagnostics, candidate selection, JSON/CLI, EMPS and Dunker data."""

import json
from pathlib import Path

import numpy as np
import pytest

from motor_id.cli import main
from motor_id.discrepancy import (binned_means, DiscrepancyAnalysis, heldout_mask,
                                  inverse_dynamics, map_summary, noise_floor,
                                  steady_state_map)
from motor_id.excitation import bipolar_steps, multisine
from motor_id.model import MotorParams, Plant
from motor_id.recording import Recording, write_csv
from motor_id.simulate import simulate_recording

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data'
EMPS = DATA / 'emps' / 'DATA_EMPS.mat'
DUNKER = DATA / 'dunker_gr42x25' / 'data_for_identification_without_integral.csv'
EMPS_PUBLISHED = {'J': 95.1089, 'B': 203.5034, 'coulomb_friction.T_c': 20.3935,
                  'load_torque.T_L': -3.1648}
SI_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
T = np.arange(4000) * 0.01


def _bipolar(t):
    return bipolar_steps(t, 9.0)


def _sim(effects, u, seed=1, noise=(0.005, 0.01)):
    return simulate_recording(Plant(SI_MOTOR, 'voltage', effects), T, u, noise[0], noise[1],
                              random_state=seed)


@pytest.fixture(scope='module')
def emps_report():
    from motor_id.data.importers import load_emps
    if not EMPS.exists():
        pytest.skip(f'{EMPS} not present')
    return DiscrepancyAnalysis().fit(load_emps(EMPS)).report_


# ----------------------------------------------------------------- helpers
def test_heldout_mask_holds_out_every_third_block():
    mask, blocks = heldout_mask(1000)
    assert blocks == [(200, 300), (500, 600), (800, 900)]
    assert mask.sum() == 300 and mask[250] and not mask[150]


def test_noise_floor_of_a_smooth_signal_is_its_white_noise():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 10, 5000)
    y = np.sin(t) + 0.01 * rng.standard_normal(t.size)
    assert noise_floor(y) == pytest.approx(0.01, rel=0.1)
    q = np.round(5 * np.sin(t) / 0.1) * 0.1  # quantised: MAD of differences is zero
    assert 0 < noise_floor(q) < 0.1


def test_binned_means_attribute_a_sign_offset_to_the_sign():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(2000)
    r = 0.5 * np.sign(x) + 0.05 * rng.standard_normal(x.size)
    out = binned_means(r, {'x': x, 'sign(x)': x})
    assert out['sign(x)']['explained'] == pytest.approx(1.0, abs=0.02)
    assert out['sign(x)']['means'][0] == pytest.approx(-0.5, abs=0.01)


def test_steady_state_map_shows_the_friction_offset():
    rec = _sim({'coulomb_friction': {'T_c': 0.1}}, _bipolar(T), noise=(0, 0))
    points = steady_state_map(rec)
    assert len(points) >= 4
    summary = map_summary(points)
    # zero speed needs R T_c / K_T = 0.35 V on each side (plateaus settle to ~1 %)
    assert summary['positive']['zero_speed_input'] == pytest.approx(0.1 * 2.3 / 0.66, rel=0.1)
    assert summary['negative']['zero_speed_input'] == pytest.approx(-0.1 * 2.3 / 0.66,
                                                                    rel=0.1)


def test_inverse_dynamics_recovers_a_simulated_torque_plant():
    t = np.arange(20000) * 1e-3
    u = 40 * multisine(t, 1.0, 0.1, 5.0, random_state=2)
    truth = {'coulomb_friction': {'T_c': 5.0}, 'load_torque': {'T_L': -1.0}}
    rec = simulate_recording(Plant(MotorParams(J=10.0, B=20.0), 'torque', truth), t, u)
    out = inverse_dynamics(rec)
    p = {k: v['value'] for k, v in out['parameters'].items()}
    assert p['J'] == pytest.approx(10.0, rel=0.01)
    assert p['B'] == pytest.approx(20.0, rel=0.01)
    assert p['coulomb_friction.T_c'] == pytest.approx(5.0, rel=0.02)
    assert p['load_torque.T_L'] == pytest.approx(-1.0, rel=0.02)
    assert out['physical']


# --------------------------------------------------------------- analysis
def test_analyze_cli_names_coulomb_friction_and_writes_json_and_plot(tmp_path, capsys):
    rec = _sim({'coulomb_friction': {'T_c': 0.05}}, _bipolar(T))
    data = tmp_path / 'coulomb.csv'
    write_csv(rec, data, {'note': 'simulated'})
    out_json = tmp_path / 'report.json'
    out_png = tmp_path / 'report.png'
    rc = main(['analyze', str(data), '--resistance', '2.3', '--json', str(out_json),
               '--plot', str(out_png)])
    assert rc == 0
    captured = capsys.readouterr()
    assert 'verdict: coulomb_friction' in captured.out
    assert 'fitting the linear model' in captured.err
    rep = json.loads(out_json.read_text())
    assert set(rep) >= {'verdict', 'effects', 'unexplained', 'ambiguous_with', 'parameters',
                        'baseline'}
    assert rep['verdict'] == 'coulomb_friction'
    assert rep['unexplained'] is False
    best = rep['effects'][0]
    assert best['name'] == 'coulomb_friction' and best['gain'] > 0.5
    assert set(best) == {'name', 'parameters', 'gain', 'evidence'}
    rest = [e['gain'] for e in rep['effects'][1:] if not e['evidence']['significant']]
    assert rest == sorted(rest, reverse=True)
    for name in ('J', 'K_T', 'B', 'L_m'):
        assert set(rep['parameters'][name]) >= {'value', 'std', 'determined'}
        assert rep['parameters'][name]['value'] == pytest.approx(getattr(SI_MOTOR, name),
                                                                 rel=0.02)
    assert rep['parameters']['coulomb_friction.T_c']['value'] == pytest.approx(0.05, rel=0.03)
    assert set(rep['baseline']) >= {'parameters', 'fit'}
    assert out_png.stat().st_size > 10000


def test_friction_and_load_are_ambiguous_when_the_motor_never_reverses():
    u = 6.0 + 3.0 * np.sign(np.sin(2 * np.pi * T / 8.0 + 0.1))
    rec = _sim({'coulomb_friction': {'T_c': 0.1}}, u, seed=3)
    rep = DiscrepancyAnalysis(R_m=2.3).fit(rec).report_
    named = {rep.verdict} | {a['name'] for a in rep.ambiguous_with}
    assert named == {'coulomb_friction', 'load_torque'}
    assert 'reverse' in rep.ambiguous_with[0]['experiment']


def test_analyze_reads_an_mcap_bag(tmp_path, capsys):
    from motor_id.bag import write_recording
    t = np.arange(1500) * 0.01
    rec = simulate_recording(Plant(SI_MOTOR, 'voltage', {'load_torque': {'T_L': 0.1}}), t,
                             _bipolar(t), 0.005, 0.01, random_state=4)
    bag = tmp_path / 'load.mcap'
    write_recording(rec, bag)
    assert main(['analyze', str(bag), '-R', '2.3', '-q']) == 0
    assert 'verdict: load_torque' in capsys.readouterr().out


def test_analyze_needs_the_resistance_for_voltage_data(tmp_path, capsys):
    rec = _sim({}, _bipolar(T))
    data = tmp_path / 'clean.csv'
    write_csv(rec, data)
    assert main(['analyze', str(data)]) == 2
    assert '--resistance' in capsys.readouterr().err


# ------------------------------------------------------------ measured data
def test_emps_linear_model_fails_and_friction_with_offset_explains_it(emps_report):
    rep = emps_report
    names = rep.verdict.split('+')
    assert 'coulomb_friction' in names and 'load_torque' in names
    best = rep.effects[0]
    assert best.gain > 0.6
    lin = rep.baseline['fit']['channels']['speed']['fit_percent']
    after = rep.chosen['fit']['channels']['speed']['fit_percent']
    # output error (simulation) estimates under the chosen model
    oe = {k: rep.parameters[k]['value'] for k in EMPS_PUBLISHED}
    # equation-error (inverse dynamics) estimates: the published method
    idim = {k: v['value'] for k, v in rep.inverse_dynamics['parameters'].items()}
    print(f'\nEMPS linear model: fit {lin:.2f} %, held-out error '
          f'{rep.heldout["base_error"]:.4f}; {rep.verdict}: fit {after:.2f} %, held-out '
          f'{rep.heldout["final_error"]:.4f} (gain {100 * best.gain:.1f} %)')
    for k, ref in EMPS_PUBLISHED.items():
        print(f'  {k:<22} published {ref:10.4f}  output error {oe[k]:10.4f} '
              f'({100 * (oe[k] / ref - 1):+6.2f} %)  inverse dynamics {idim[k]:10.4f} '
              f'({100 * (idim[k] / ref - 1):+6.2f} %)')
    for k, ref in EMPS_PUBLISHED.items():
        assert idim[k] == pytest.approx(ref, rel=0.05)
    assert rep.inverse_dynamics['relative_error'] < 0.05
    for k in ('J', 'B', 'coulomb_friction.T_c'):
        assert oe[k] == pytest.approx(EMPS_PUBLISHED[k], rel=0.08)
    assert oe['load_torque.T_L'] == pytest.approx(EMPS_PUBLISHED['load_torque.T_L'], rel=0.2)


def test_dunker_shows_coulomb_friction():
    from motor_id.data.importers import load_dunker
    if not DUNKER.exists():
        pytest.skip(f'{DUNKER} not present')
    rec = load_dunker(DUNKER, motor=1)
    rep = DiscrepancyAnalysis().fit(rec).report_
    assert 'coulomb_friction' in rep.verdict.split('+')
    # the authors' fit: T0 = 0.0070 .. 0.0081 N m, b = 2.0e-5 .. 2.4e-5 N m s/rad
    assert 0.005 < rep.parameters['coulomb_friction.T_c']['value'] < 0.011
    assert 1e-5 < rep.parameters['B']['value'] < 5e-5
    ms = rep.diagnostics['steady_state']
    assert ms['positive']['zero_speed_input'] > 0.004
    assert ms['negative']['zero_speed_input'] < -0.004


def test_clean_torque_plant_gives_none():
    t = np.arange(4000) * 1e-3
    u = 40 * multisine(t, 1.0, 0.5, 20.0, random_state=5)
    rec = simulate_recording(Plant(MotorParams(J=1.0, B=20.0), 'torque'), t, u, 0.005,
                             random_state=5)
    rep = DiscrepancyAnalysis().fit(Recording(rec.time, rec.input, rec.speed, None,
                                              'torque')).report_
    assert rep.verdict == 'none' and not rep.unexplained
    assert rep.parameters['J']['value'] == pytest.approx(1.0, rel=0.02)
