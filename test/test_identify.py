"""Identification: recovery, identifiability verdicts, error bars, reproducibility."""

import re

import numpy as np
import pytest

from motor_id.errors import ConfigError, DataError
from motor_id.identify import Identifier, parse_bounds, parse_fixed
from motor_id.model import PAPER_MOTOR
from motor_id.recording import Recording

from conftest import paper_recording, SI_MOTOR

FIVE = ('J', 'K_T', 'K_b', 'B', 'L_m')


def rel_err(est, truth):
    return abs(est - truth) / truth


def test_paper_method_reports_three_combinations_and_varies_by_seed():
    """(a) speed only: seeds disagree along the undetermined directions; combos agree."""
    rec = paper_recording(with_current=False, speed_noise=0.005, seed=1)
    results = [Identifier(method='paper', R_m=2.3, random_state=s).fit(rec).result_
               for s in range(3)]
    for r in results:
        assert r.identifiability['rank'] == 3
        assert r.identifiability['n_free'] == 5
        for name in FIVE:
            assert r.parameters[name].determined is False
            assert r.parameters[name].value is None
        assert len(r.undetermined_directions) == 2
        assert 'not determined by this data' in r.summary()
        assert [c['name'] for c in r.identifiable_combinations] == [
            'K_T/(J*L_m)', 'R_m/L_m + B/J', '(R_m*B + K_T*K_b)/(J*L_m)']
    J = np.array([r.parameters['J'].particular_value for r in results])
    assert np.ptp(np.log(J)) > np.log(1.2)  # raw J differs by > 20 % between seeds
    truth = {'K_T/(J*L_m)': 0.66 / (0.052 * 0.0345)}
    for r in results:  # the determined combination is close for every seed
        c = r.identifiable_combinations[0]
        assert rel_err(c['value'], truth['K_T/(J*L_m)']) < 0.08


def test_zoh_recovers_all_five_with_current_and_tie():
    """(b) noise-free speed + current of an SI-consistent motor: all five within 1 %."""
    rec = paper_recording(params=SI_MOTOR)
    r = Identifier(method='zoh', R_m=2.3, random_state=0).fit(rec).result_
    assert r.identifiability['rank'] == 4 and r.identifiability['fully_determined']
    for name in FIVE:
        e = r.parameters[name]
        assert e.determined
        assert rel_err(e.value, getattr(SI_MOTOR, name)) < 0.01, name


def test_euler_biases_inductance_zoh_does_not(clean_paper):
    """(b) the paper's motor (K_T != K_b), no tie, J given: Euler's L_m is biased."""
    kw = dict(R_m=2.3, tie=False, fixed={'J': 0.052}, random_state=0)
    zoh = Identifier(method='zoh', **kw).fit(clean_paper).result_
    eul = Identifier(method='euler', **kw).fit(clean_paper).result_
    for name in ('K_T', 'K_b', 'B', 'L_m'):
        assert rel_err(zoh.parameters[name].value, getattr(PAPER_MOTOR, name)) < 0.01, name
    bias = eul.parameters['L_m'].value / PAPER_MOTOR.L_m - 1
    assert 0.15 < bias < 0.50, bias
    assert zoh.parameters['J'].assumed


def test_tie_on_the_papers_motor_scales_j_and_kt(clean_paper):
    """K_T = 0.66 != K_b = 0.64: the tie moves J and K_T along the unseen direction."""
    r = Identifier(R_m=2.3, random_state=0).fit(clean_paper).result_
    assert r.parameters['K_T'].value == pytest.approx(0.64, rel=2e-3)
    assert r.parameters['L_m'].value == pytest.approx(0.0345, rel=2e-3)
    assert r.parameters['J'].value / r.parameters['K_T'].value == pytest.approx(
        0.052 / 0.66, rel=2e-3)


def test_speed_and_current_without_tie_leave_one_direction():
    rec = paper_recording(params=SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=2)
    r = Identifier(R_m=2.3, tie=False, random_state=0).fit(rec).result_
    assert r.identifiability['rank'] == 4 and r.identifiability['n_free'] == 5
    assert r.parameters['L_m'].determined and r.parameters['K_b'].determined
    for name in ('J', 'K_T', 'B'):
        assert not r.parameters[name].determined


def test_a_known_value_determines_the_rest():
    rec = paper_recording(params=SI_MOTOR, with_current=False, speed_noise=0.002, seed=3)
    r = Identifier(R_m=2.3, tie=True, fixed={'J': 0.052}, random_state=0).fit(rec).result_
    assert r.identifiability['fully_determined']
    assert r.parameters['J'].assumed
    for name in ('K_T', 'L_m'):
        assert rel_err(r.parameters[name].value, getattr(SI_MOTOR, name)) < 0.02


def test_error_bars_cover_the_truth():
    """(c) 0.5 % speed and 1 % current noise: 2-sigma intervals hold the truth ~95 %."""
    hits = total = 0
    for seed in range(20):
        rec = paper_recording(params=SI_MOTOR, speed_noise=0.005, current_noise=0.01,
                              seed=100 + seed)
        r = Identifier(R_m=2.3, random_state=seed).fit(rec).result_
        for name in ('J', 'K_T', 'B', 'L_m'):  # K_b = K_T under the tie
            e = r.parameters[name]
            total += 1
            hits += abs(e.value - getattr(SI_MOTOR, name)) <= 2 * e.std
    coverage = hits / total
    print(f'2-sigma coverage: {hits}/{total} = {coverage:.0%}')
    assert 0.85 <= coverage <= 1.0


def test_seeded_fit_is_reproducible():
    rec = paper_recording(params=SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=5)
    a = Identifier(R_m=2.3, random_state=7).fit(rec)
    b = Identifier(R_m=2.3, random_state=7).fit(rec)
    assert a.history_ == b.history_
    assert a.params_ == b.params_


def test_progress_and_cancel():
    rec = paper_recording(params=SI_MOTOR)
    seen = []

    def progress(gen, gens, best):
        seen.append(gen)
        return gen >= 10
    r = Identifier(R_m=2.3, random_state=0).fit(rec, progress=progress).result_
    assert seen == list(range(1, 11))
    assert r.ga['generations'] == 10 and r.ga['stop'] == {'cancelled': True}


def test_json_shape():
    rec = paper_recording(params=SI_MOTOR)
    d = Identifier(R_m=2.3, random_state=0, generations=20).fit(rec).result_.to_dict()
    assert set(d['parameters']) == {'J', 'K_T', 'K_b', 'B', 'L_m', 'R_m'}
    for v in d['parameters'].values():
        assert {'value', 'std', 'determined'} <= set(v)
    assert {'generations', 'evaluations', 'seconds', 'history'} <= set(d['ga'])
    assert d['ga']['evaluations'] == 20 * 20
    assert d['method'] == 'zoh'
    assert isinstance(d['identifiable_combinations'], list)


def test_bad_requests_say_what_to_do():
    rec = paper_recording(params=SI_MOTOR)
    with pytest.raises(ConfigError, match='R_m is required'):
        Identifier().fit(rec)
    with pytest.raises(ConfigError, match='method must be one of'):
        Identifier(method='magic', R_m=2.3).fit(rec)
    with pytest.raises(ConfigError, match="channel 'current' is not in the recording"):
        Identifier(R_m=2.3, channels=('speed', 'current')).fit(rec.slice(0, 4000).__class__(
            rec.time, rec.input, rec.speed))
    flat = Recording(rec.time, np.full(rec.time.size, 3.0), rec.speed)
    with pytest.raises(DataError, match='no excitation'):
        Identifier(R_m=2.3).fit(flat)


def test_bootstrap_intervals_bracket_the_estimate():
    rec = paper_recording(params=SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=9)
    r = Identifier(R_m=2.3, random_state=0, bootstrap=20).fit(rec).result_
    for name in ('J', 'L_m'):
        lo, hi = r.parameters[name].ci95
        assert lo < r.parameters[name].value < hi
        assert (hi - lo) < 10 * r.parameters[name].std


@pytest.mark.parametrize('item, message', [
    ('J', 'takes NAME=VALUE'), ('=1', 'takes NAME=VALUE'), ('Q=1', "unknown parameter 'Q'"),
    ('J=abc', "'abc' is not a number"), ('J=-0.1', 'finite and > 0'), ('J=inf', 'finite'),
])
def test_parse_fixed_names_the_bad_item(item, message):
    with pytest.raises(ConfigError, match=re.escape(message)) as exc:
        parse_fixed([item], '--fix')
    assert str(exc.value).startswith('--fix')


@pytest.mark.parametrize('item, message', [
    ('J=1', 'takes NAME=LOW:HIGH'), ('J=a:b', 'takes NAME=LOW:HIGH'),
    ('J=1:0.1', 'LOW < HIGH'), ('B=0:1', 'LOW must be > 0'), ('J=1:nan', 'LOW < HIGH'),
])
def test_parse_bounds_names_the_bad_item(item, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_bounds([item], 'bounds')


def test_parse_fixed_and_bounds_read_good_items():
    assert parse_fixed([' J = 0.052 ', 'L_m=0.0345']) == {'J': 0.052, 'L_m': 0.0345}
    # effect parameters may span zero; the Identifier checks that they are fitted
    assert parse_bounds(['J=1e-4:1', 'load_torque.T_L=-1:1']) == {
        'J': (1e-4, 1.0), 'load_torque.T_L': (-1.0, 1.0)}
