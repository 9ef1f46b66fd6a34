"""Hidden effects simulated by the independent simulator: the rates the analysis achieves.

The cases come from :mod:`motor_id.testing.independent_sim`, which shares no model
code with motor_id, through the case plan of :mod:`motor_id.testing.discrepancy`
(seeded; R_m told off by 2-5 % of either sign). The default test runs one round at
0.5 % noise (every effect once and four clean cases, at most 4,000 samples each); the
slow test runs the benchmark's independent cases at 0.5 and 2 % noise. Both assert the
issue's targets for false alarms (0), spurious second effects (<= 1 per 20 cases), the
encoder grid (100 %) and the named rate (95 %).
"""

import os

import pytest

from motor_id.testing import discrepancy as dr
from motor_id.testing import independent_sim

ROUND_SEED = 7100
"""Seed of the first case of the default round."""

MIN_NAMED = 12
"""Effects named (verdict or ambiguous) in the default round of 12: all of them, as the
issue's 95 % asks of 12 cases. Measured 12/12 at 22:45 UTC on 2026-11-23 (10/12 at 20:00,
12/12 at 20:47 with a 92 % floor)."""
MAX_SPURIOUS = 0
"""Compound verdicts allowed in the default round of 12 effect cases (the issue's <= 1 per
20 cases allows none here; measured 0)."""
MAGNITUDE_TOLERANCE = {'coulomb_friction': 0.1, 'load_torque': 0.05, 'quadratic_load': 0.3,
                       'brush_drop': 0.1, 'dead_zone': 0.05, 'voltage_saturation': 0.05,
                       'input_delay': 0.0, 'sensor_lag': 0.1, 'speed_quantization': 0.01,
                       'current_quantization': 0.01, 'resistance_drift': 0.1,
                       'resonance': 0.05}
"""Largest |found / true - 1| of a named effect's magnitude (dr.MAGNITUDE), per effect.
Measured in the default round at 22:45 UTC: T_c -0.3 %, T_L 0 %, k_q -0.1 %, V_b +2.6 %,
V_dz 0 %, V_max 0 %, d exact, tau_s -0.8 % (+32 % before the lag filtered the continuous
speed), q and q_i exact, k_h -0.5 % (-12 % before the heating used the interval's mean
i^2 R), f_r 0 %."""

SWEEP_MIN_NAMED = 0.95
"""Named rate of the slow sweep (24 effect cases), the issue's target. Measured 24/24 at
22:41 UTC (22/24 at 20:46, 17/24 at 20:29); the misses, if any, are listed by
benchmarks/discrepancy_rates.py --failures."""


@pytest.fixture(scope='module')
def round_rows():
    """One seeded round at 0.5 % noise: every effect once and four clean cases.

    Analysed in two worker processes where the machine has two cores (the cases are
    seeded: the rows are the same as in one process, in half the wall time).
    """
    specs = dr.plan('independent', 0.005, len(independent_sim.EFFECTS) + dr.CLEAN_PER_ROUND,
                    ROUND_SEED, max_samples=4000)
    return dr.run_cases(specs, jobs=min(2, os.cpu_count() or 1))


def _describe(rows):
    return '\n'.join(dr.failure_lines(rows))


def test_plan_is_seeded_and_covers_every_effect():
    a = dr.plan('independent', 0.02, 40, 11, max_samples=4000)
    b = dr.plan('independent', 0.02, 40, 11, max_samples=4000)
    assert a == b
    effects = [s.effect for s in a[:16]]
    assert sorted(e for e in effects if e != 'none') == sorted(independent_sim.EFFECTS)
    assert effects.count('none') == dr.CLEAN_PER_ROUND
    assert {s.motor_class for s in a} == set(independent_sim.MOTOR_CLASSES)
    errors = [s.r_m_error for s in a]
    assert all(0.02 <= abs(e) <= 0.05 for e in errors)
    assert min(errors) < 0 < max(errors)
    assert all(2000 <= s.n_samples <= 4000 for s in a)
    assert dr.plan('independent', 0.02, 4, 11, exact_rm=True)[0].r_m_error == 0.0


def test_recording_tells_the_resistance_off_by_the_planned_error():
    spec = dr.plan('independent', 0.005, 1, 3, max_samples=2500)[0]
    rec, truth, r_known = dr.make_recording(spec)
    assert len(rec) == truth.n_samples == spec.n_samples
    assert r_known / truth.R_m - 1.0 == pytest.approx(spec.r_m_error, abs=1e-12)
    assert truth.effect == spec.effect


def test_independent_round_names_hidden_effects(round_rows):
    eff = [r for r in round_rows if r.effect != 'none']
    assert len(eff) == len(independent_sim.EFFECTS)
    assert not [r for r in round_rows if r.error], _describe(round_rows)
    named = sum(r.named for r in eff)
    assert named >= MIN_NAMED, _describe(round_rows)


def test_independent_round_raises_no_false_alarm(round_rows):
    clean = [r for r in round_rows if r.effect == 'none']
    assert len(clean) == dr.CLEAN_PER_ROUND
    assert not any(r.false_alarm for r in clean), _describe(clean)


def test_independent_round_adds_no_spurious_second_effect(round_rows):
    spurious = [r for r in round_rows if r.spurious]
    assert len(spurious) <= MAX_SPURIOUS, _describe(spurious)


def test_independent_round_names_the_encoder_grid(round_rows):
    grid = [r for r in round_rows if r.effect == 'speed_quantization']
    assert len(grid) == 1 and grid[0].named, _describe(grid)


def test_independent_round_finds_effect_magnitudes(round_rows):
    checked = 0
    for r in round_rows:
        tol = MAGNITUDE_TOLERANCE.get(r.effect)
        if tol is None or not r.named:
            continue
        assert r.param_error is not None, _describe([r])
        assert abs(r.param_error) <= tol, \
            (r.effect, r.param, r.param_found, r.param_true)
        checked += 1
    assert checked >= MIN_NAMED - 2


@pytest.mark.slow
def test_independent_sweep_rates():
    """The benchmark's independent cases at 0.5 and 2 % noise (32 analyses, to 25,000 samples)."""
    specs = dr.build_plan(generators=('independent',), levels=dr.TARGET_NOISE)
    rows = dr.run_cases(specs)
    rates = dr.rates(rows)
    assert rates.errors[0] == 0, _describe(rows)
    assert rates.rate('named') >= SWEEP_MIN_NAMED, _describe(rows)
    assert rates.rate('false_alarm') == 0.0, _describe(rows)
    assert rates.rate('spurious') <= 0.05, _describe(rows)
    assert rates.rate('grid_named') == 1.0, _describe(rows)
