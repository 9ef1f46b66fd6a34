"""Analysis helpers: held-out split, noise floor, binned means, steady-state map, IDIM, grids."""

import numpy as np
import pytest

from motor_id.analysis import (
    binned_means,
    heldout_mask,
    inverse_dynamics,
    map_summary,
    noise_floor,
    steady_state_map,
)
from motor_id.analysis.candidates import _spread, CandidateFitter
from motor_id.analysis.heldout import HeldOutSplit
from motor_id.effects import EFFECTS, SCALES
from motor_id.excitation import bipolar_steps, multisine
from motor_id.identify.estimator import WIDEN
from motor_id.model import MotorParams, Plant
from motor_id.simulate import simulate_recording

SI_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
T = np.arange(4000) * 0.01


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
    assert out['sign(x)'].explained == pytest.approx(1.0, abs=0.02)
    assert out['sign(x)'].means[0] == pytest.approx(-0.5, abs=0.01)


def test_steady_state_map_shows_the_friction_offset():
    rec = simulate_recording(Plant(SI_MOTOR, 'voltage', {'coulomb_friction': {'T_c': 0.1}}),
                             T, bipolar_steps(T, 9.0))
    summary = map_summary(steady_state_map(rec))
    # zero speed needs R T_c / K_T = 0.35 V on each side (plateaus settle to ~1 %)
    assert summary.positive.zero_speed_input == pytest.approx(0.1 * 2.3 / 0.66, rel=0.1)
    assert summary.negative.zero_speed_input == pytest.approx(-0.1 * 2.3 / 0.66, rel=0.1)


def test_inverse_dynamics_recovers_a_simulated_torque_plant():
    t = np.arange(20000) * 1e-3
    u = 40 * multisine(t, 1.0, 0.1, 5.0, random_state=2)
    truth = {'coulomb_friction': {'T_c': 5.0}, 'load_torque': {'T_L': -1.0}}
    rec = simulate_recording(Plant(MotorParams(J=10.0, B=20.0), 'torque', truth), t, u)
    out = inverse_dynamics(rec)
    p = {k: v.value for k, v in out.parameters.items()}
    assert p['J'] == pytest.approx(10.0, rel=0.01)
    assert p['B'] == pytest.approx(20.0, rel=0.01)
    assert p['coulomb_friction.T_c'] == pytest.approx(5.0, rel=0.02)
    assert p['load_torque.T_L'] == pytest.approx(-1.0, rel=0.02)
    assert out.physical


def test_every_dynamic_effect_has_a_start_grid_and_search_range_on_the_data_scale():
    scales = dict.fromkeys(SCALES, 1.0)
    scales.update(torque=3.0, input=12.0, speed=200.0, record=40.0, sample=0.01,
                  per_record=1 / 40, per_sample=100.0, max_delay=40.0)
    scales['torque/speed^2'] = 3.0 / 200.0 ** 2
    for name, spec in EFFECTS.items():
        if spec.category != 'dynamic':
            assert spec.channel in ('speed', 'current')
            continue
        grid = spec.start_grid(scales)
        assert set(grid) == {p.name for p in spec.params}
        for p in spec.params:
            lo, hi = p.search_range(scales)
            assert p.low <= lo < hi <= p.high
            assert np.all((grid[p.name] >= lo) & (grid[p.name] <= hi)), (name, p.name)
    assert EFFECTS['coulomb_friction'].start_grid(scales)['T_c'].max() == pytest.approx(1.5)
    assert EFFECTS['input_delay'].start_grid(scales)['d'].tolist() == list(range(1, 41))
    assert EFFECTS['resistance_drift'].implausible({'tau_th': 0.5}, scales)
    assert not EFFECTS['resistance_drift'].implausible({'tau_th': 10.0}, scales)


def test_linear_fit_widens_a_bound_the_inertia_sits_on():
    # a hobby motor: J = 3e-7 kg m^2 is below the Identifier's default box (1e-6)
    motor = MotorParams(J=3e-7, K_T=0.008, K_b=0.008, B=1.6e-7, L_m=2e-3, R_m=5.5)
    t = np.arange(4000) * 2e-3
    rec = simulate_recording(Plant(motor, 'voltage'), t, bipolar_steps(t, 5.0, period=0.4),
                             speed_noise=0.005, current_noise=0.005, random_state=3)
    split = HeldOutSplit(rec)
    fitter = CandidateFitter(rec, split, R_m=5.5)
    base = fitter.fit_linear(60)
    assert fitter.physical_bounds['J'][0] == pytest.approx(1e-6 / WIDEN)
    assert base.physical['J'] == pytest.approx(3e-7, rel=0.05)
    assert base.heldout_error < 2 * split.floor


def test_spread_starts_walk_the_finest_axis_of_a_flat_grid():
    grid = EFFECTS['resonance'].start_grid({'one': 1.0, 'per_sample': 100.0,
                                                 'per_record': 0.1})
    cost = np.ones(next(iter(grid.values())).size)
    best = int(np.argmax(grid['f_r']))
    rows = _spread(grid, best, cost)
    assert len(rows) == 3
    assert len({grid['f_r'][k] for k in rows}) == 3
    assert all(grid['r'][k] == grid['r'][best] and grid['zeta'][k] == grid['zeta'][best]
               for k in rows)
    assert _spread({'x': np.array([1.0, 2.0])}, 0, np.ones(2)) == []


def test_further_starts_run_only_while_no_refinement_has_found_the_effect():
    """The best grid points, then (a grid that cannot rank its points) the spread starts
    are refined in turn until one cuts the reference's squared training error to FOUND,
    or (a one-parameter effect) the best points' refinements agree to SETTLED; the best
    of those refined wins."""
    from motor_id.analysis import candidates
    from motor_id.analysis.report import ModelScore

    def fitter_with(errors):
        fitted = []

        class Stub(CandidateFitter):
            def grid_best(self, ref, name, grid, fixed_effects=None, top=1):
                return [{'T_c': 1.0}, {'T_c': 2.0}], [{'T_c': 3.0}, {'T_c': 4.0}]

            def fit_model(self, effects, free, start, weight=True):
                fitted.append(effects['coulomb_friction']['T_c'])
                return effects

            def score(self, name, est, n_extra, t0):
                return ModelScore(name=name, effects=est,
                                  train_error=errors[est['coulomb_friction']['T_c']])

        stub = Stub.__new__(Stub)
        stub.scales, stub.extra_starts, stub.starts = {'torque': 1.0}, {}, 2
        return stub, fitted

    ref = ModelScore(name='linear', effects={}, train_error=1.0)
    found = np.sqrt(candidates.FOUND)
    stub, fitted = fitter_with({1.0: 0.99 * found, 2.0: 0.1, 3.0: 0.1, 4.0: 0.1})
    assert stub.fit('coulomb_friction', ref).train_error == pytest.approx(0.99 * found)
    assert fitted == [1.0]
    stub, fitted = fitter_with({1.0: 1.01 * found, 2.0: 0.5, 3.0: 0.1, 4.0: 0.1})
    assert stub.fit('coulomb_friction', ref).train_error == pytest.approx(0.5)
    assert fitted == [1.0, 2.0]
    stub, fitted = fitter_with({1.0: 1.01 * found, 2.0: 1.0, 3.0: 0.95, 4.0: 0.1})
    assert stub.fit('coulomb_friction', ref).train_error == pytest.approx(0.1)
    assert fitted == [1.0, 2.0, 3.0, 4.0]
    # a one-parameter effect whose two best points end at one minimum: no spread starts
    stub, fitted = fitter_with({1.0: 0.95, 2.0: 0.95 * (1 + candidates.SETTLED / 2),
                                3.0: 0.1, 4.0: 0.1})
    assert stub.fit('coulomb_friction', ref).train_error == pytest.approx(0.95)
    assert fitted == [1.0, 2.0]


def test_sign_test_of_held_out_sub_blocks():
    from motor_id.analysis.selection import sign_test
    assert sign_test(12, 12) == pytest.approx(2.0 ** -12)
    assert sign_test(11, 12) == pytest.approx(13 / 4096)
    assert sign_test(0, 12) == pytest.approx(1.0)


@pytest.mark.parametrize('gain, wins, significant', [
    (0.06, 7, True),    # the plain rule: 5 % and at least half of the sub-blocks
    (0.06, 5, False),
    (0.03, 12, True),   # a small cut everywhere (p = 2.4e-4): an effect under much noise
    (0.03, 11, False),  # p = 3.2e-3: chance is not ruled out
    (0.015, 12, False),  # below 0.4 x min_gain
])
def test_a_small_held_out_gain_counts_only_when_every_sub_block_agrees(gain, wins,
                                                                       significant):
    from motor_id.analysis.report import ModelScore
    from motor_id.analysis.selection import judge
    from motor_id.recording import Recording
    rng = np.random.default_rng(0)
    n = 1000
    rec = Recording(np.arange(n) * 0.01, rng.standard_normal(n), rng.standard_normal(n),
                    None, 'voltage', {})
    split = HeldOutSplit(rec)
    m = len(split.subblocks)
    ref_sub = np.ones(m)
    sub = np.where(np.arange(m) < wins, 0.9, 1.1)
    preds = [rec.speed]
    ref = ModelScore(name='linear', effects={}, heldout_error=1.0, train_error=1.0,
                     prediction={'preds': preds, 'sub': ref_sub})
    s = ModelScore(name='load_torque', effects={'load_torque': {'T_L': 0.1}},
                   heldout_error=1.0 - gain, train_error=0.9, n_extra=1,
                   prediction={'preds': preds, 'sub': sub})
    judge(s, ref, split, 0.05, {})
    assert s.significant is significant


@pytest.mark.parametrize('name, steady, significant', [
    ('coulomb_friction', (0.4, -0.39), True),   # the steady states show the offset
    ('coulomb_friction', None, False),          # they do not: the sub-block rule stands
    ('dead_zone', (0.4, -0.39), True),
    ('input_delay', (0.4, -0.39), False),       # not a friction-like effect
])
def test_a_static_offset_in_the_steady_states_lets_friction_count_on_few_sub_blocks(
        name, steady, significant):
    from types import SimpleNamespace

    from motor_id.analysis.report import ModelScore
    from motor_id.analysis.search import CandidateSearch
    from motor_id.analysis.selection import judge
    from motor_id.recording import Recording
    rng = np.random.default_rng(1)
    n = 1000
    rec = Recording(np.arange(n) * 0.01, rng.standard_normal(n), rng.standard_normal(n),
                    None, 'voltage', {})
    split = HeldOutSplit(rec)
    m = len(split.subblocks)
    # a real drivetrain's log: 61 % off the held-out error, 5 of 12 sub-blocks better
    sub = np.where(np.arange(m) < round(5 * m / 12), 0.2, 1.02)
    ref = ModelScore(name='linear', effects={}, heldout_error=1.0, train_error=1.0,
                     prediction={'preds': [rec.speed], 'sub': np.ones(m)})
    s = ModelScore(name=name, effects={name: {}}, heldout_error=0.39, train_error=0.9,
                   n_extra=1, prediction={'preds': [rec.speed], 'sub': sub})
    judge(s, ref, split, 0.05, {})
    assert s.gain == pytest.approx(0.61) and s.block_wins < 0.5 and s.delta_bic < 0
    assert not s.significant
    search = CandidateSearch(SimpleNamespace(steady=steady), None, (), (), print,
                             min_gain=0.05, ambiguity=0.05, max_effects=2,
                             structure_ratio=2.0, pool_size=3)
    search._offset_evidence(s)
    assert s.significant is significant
