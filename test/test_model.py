"""Model: parameters, effects catalogue, discretisation."""

import numpy as np
import pytest
from scipy.signal import cont2discrete

from motor_id.effects import EFFECTS, parse_effect_args, validate_effects
from motor_id.errors import ConfigError
from motor_id.model import (
    continuous_matrices,
    discretize,
    MotorParams,
    PAPER_MOTOR,
    Plant,
    transfer_coefficients,
)


def test_params_reject_nonpositive_and_unknown():
    with pytest.raises(ConfigError, match='J must be > 0'):
        MotorParams(J=-1.0)
    with pytest.raises(ConfigError, match='unknown motor parameter'):
        MotorParams.from_dict({'Jm': 1.0})


def test_zoh_matches_scipy_cont2discrete():
    F, G = continuous_matrices({k: np.array([v]) for k, v in PAPER_MOTOR.to_dict().items()})
    A, Bd = discretize(F, G, [0.01], 'zoh')
    Ad, Bref, *_ = cont2discrete((F[0], G[0], np.eye(2), np.zeros((2, 2))), 0.01)
    np.testing.assert_allclose(A[0, 0], Ad, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(Bd[0, 0], Bref, rtol=1e-12, atol=1e-14)


def test_euler_is_the_papers_first_order_truncation():
    p = PAPER_MOTOR.to_dict()
    F, G = continuous_matrices({k: np.array([v]) for k, v in p.items()})
    A, Bd = discretize(F, G, [0.01], 'euler')
    T = 0.01
    expected = np.array([[1 - p['B'] * T / p['J'], p['K_T'] * T / p['J']],
                         [-p['K_b'] * T / p['L_m'], 1 - p['R_m'] * T / p['L_m']]])
    np.testing.assert_allclose(A[0, 0], expected, rtol=1e-14)
    np.testing.assert_allclose(Bd[0, 0, :, 0], [0.0, T / p['L_m']], rtol=1e-14)


def test_effects_validate_ranges_and_names():
    assert validate_effects({'coulomb_friction': {}})['coulomb_friction']['T_c'] == 0.05
    with pytest.raises(ConfigError, match='unknown effect'):
        validate_effects({'magic': {}})
    with pytest.raises(ConfigError, match='outside'):
        validate_effects({'sensor_lag': {'tau_s': -1.0}})
    with pytest.raises(ConfigError, match='does not apply'):
        Plant(input_kind='torque', effects={'brush_drop': {}})
    assert parse_effect_args(['coulomb_friction=0.2', 'resonance.f_r=3']) == {
        'coulomb_friction': {'T_c': 0.2}, 'resonance': {'f_r': 3.0}}
    assert len(EFFECTS) >= 11


def test_transfer_coefficients_are_the_speed_tf():
    p = PAPER_MOTOR.to_dict()
    c = transfer_coefficients(p, 'voltage', ('speed',))
    J, K_T, K_b, B, L, R = (p[k] for k in ('J', 'K_T', 'K_b', 'B', 'L_m', 'R_m'))
    # DC gain of w/V equals b0 / a0 = K_T / (R B + K_T K_b)
    assert c['K_T/(J*L_m)'] / c['(R_m*B + K_T*K_b)/(J*L_m)'] == pytest.approx(
        K_T / (R * B + K_T * K_b), rel=1e-12)
    assert len(c) == 3
    assert len(transfer_coefficients(p, 'voltage', ('speed', 'current'))) == 5


def test_interval_integrals_match_quadrature_of_the_current():
    from scipy.integrate import trapezoid
    from scipy.linalg import expm

    from motor_id.model import continuous_matrices, interval_integrals
    par = {'J': [3.5e-5], 'K_T': [0.098], 'K_b': [0.098], 'B': [2.4e-5], 'L_m': [1.9e-3],
           'R_m': [3.8]}
    F, G = continuous_matrices(par, 'voltage')
    dt = 5e-3
    m, Q = interval_integrals(F, G, [dt])
    d = F.shape[1] + G.shape[2]
    M = np.zeros((d, d))
    M[:2, :2], M[:2, 2:] = F[0], G[0]
    s = np.linspace(0.0, dt, 4001)
    rows = np.array([expm(M * x)[1] for x in s])  # the current's row of exp(M s)
    z0 = np.array([30.0, 0.4, 5.0, -0.01])  # speed, current, voltage, load torque
    i = rows @ z0
    assert m[0, 0] @ z0 == pytest.approx(trapezoid(i, s), rel=1e-6)
    assert z0 @ Q[0, 0] @ z0 == pytest.approx(trapezoid(i * i, s), rel=1e-6)


def test_many_interval_lengths_discretise_by_eigenvalues_as_exactly_as_expm():
    """A jittered record (one interval length per sample) takes the eigen-decomposition
    path; it matches the Pade matrix exponential to 1e-9 relative, also with the position
    state (a zero eigenvalue) and for a plant with a repeated eigenvalue (which falls back
    to the exponential)."""
    from motor_id.linalg import expm
    from motor_id.model import _held_input_matrix, SPECTRAL_MIN_INTERVALS
    from motor_id.simulate import with_position
    rng = np.random.default_rng(3)
    P = 12
    th = {'J': 10 ** rng.uniform(-6, 1, P), 'K_T': 10 ** rng.uniform(-3, 1, P),
          'K_b': 10 ** rng.uniform(-3, 1, P), 'B': 10 ** rng.uniform(-7, 0, P),
          'L_m': 10 ** rng.uniform(-5, 0, P), 'R_m': 10 ** rng.uniform(-1, 1, P)}
    dt = np.sort(rng.uniform(2.6e-3, 7.4e-3, 4 * SPECTRAL_MIN_INTERVALS))
    for kind in ('voltage', 'torque'):
        for pos in (False, True):
            F, G = continuous_matrices(th, kind)
            if pos:
                F, G = with_position(F, G)
            F[0] = np.diag(np.full(F.shape[1], -50.0))   # repeated eigenvalue: fallback
            A, Bd = discretize(F, G, dt)
            n = F.shape[1]
            E = expm(_held_input_matrix(F, G, dt))
            scale_a = np.abs(E[:, :, :n, :n]).max(axis=(1, 2, 3))[:, None, None, None]
            scale_b = np.abs(E[:, :, :n, n:]).max(axis=(1, 2, 3))[:, None, None, None]
            assert np.max(np.abs(A - E[:, :, :n, :n]) / scale_a) < 1e-9, (kind, pos)
            assert np.max(np.abs(Bd - E[:, :, :n, n:]) / scale_b) < 1e-9, (kind, pos)


def test_a_batch_with_repeated_plants_discretises_each_member_as_expm():
    """Members that share a plant (a Jacobian's initial-state columns) are discretised
    once and handed back in the batch's own order, also around a plant that falls back
    to the exponential; the decomposition cached for one run serves the next."""
    from motor_id.linalg import expm
    from motor_id.model import _held_input_matrix, SPECTRAL_MIN_INTERVALS
    rng = np.random.default_rng(5)
    P = 6
    th = {'J': 10 ** rng.uniform(-4, 0, P), 'K_T': 10 ** rng.uniform(-2, 0, P),
          'K_b': 10 ** rng.uniform(-2, 0, P), 'B': 10 ** rng.uniform(-5, -1, P),
          'L_m': 10 ** rng.uniform(-3, -1, P), 'R_m': 10 ** rng.uniform(-1, 1, P)}
    F, G = continuous_matrices(th, 'voltage')
    order = np.array([3, 0, 3, 5, 1, 0, 2, 4, 4, 5])   # repeats, not sorted
    F, G = F[order], G[order]
    F[6] = np.diag([-50.0, -50.0])                      # repeated eigenvalue: fallback
    for _ in range(2):                                  # the second from the cache
        dt = np.sort(rng.uniform(2.6e-3, 7.4e-3, 3 * SPECTRAL_MIN_INTERVALS))
        A, Bd = discretize(F, G, dt)
        E = expm(_held_input_matrix(F, G, dt))
        np.testing.assert_allclose(A, E[:, :, :2, :2], rtol=0, atol=1e-9)
        np.testing.assert_allclose(Bd / np.abs(E[:, :, :2, 2:]).max(),
                                   E[:, :, :2, 2:] / np.abs(E[:, :, :2, 2:]).max(),
                                   rtol=0, atol=1e-9)


def test_interval_integrals_over_many_interval_lengths_match_quadrature():
    """A jittered record takes the eigen-decomposition of M for the heating integrals:
    each interval's m and Q match a quadrature of the current (and its square), with the
    two-mass shaft, with the position state (left out of M: it would make M defective)
    and on a stiff plant where Van Loan's exponential of -M' loses its accuracy."""
    from scipy.linalg import expm

    from motor_id.model import interval_integrals, SPECTRAL_MIN_INTERVALS
    from motor_id.simulate import with_position
    par = {'J': [3.5e-5, 7.7e-4, 1e-5], 'K_T': [0.098, 0.91, 0.05],
           'K_b': [0.098, 0.0138, 0.05], 'B': [2.4e-5, 3.3e-3, 1e-6],
           'L_m': [1.9e-3, 0.0557, 1e-4], 'R_m': [3.8, 1.0, 2.0]}
    rng = np.random.default_rng(7)
    dt = np.sort(rng.uniform(1e-3, 8e-3, 2 * SPECTRAL_MIN_INTERVALS))
    x, w = np.polynomial.legendre.leggauss(40)
    for res, pos in ((None, False), (None, True),
                     ({'r': [1.0] * 3, 'f_r': [4.0] * 3, 'zeta': [0.05] * 3}, False)):
        F, G = continuous_matrices(par, 'voltage', res)
        if pos:
            F, G = with_position(F, G)
        m, Q = interval_integrals(F, G, dt)
        d = F.shape[1] + G.shape[2]
        for p in range(F.shape[0]):
            M = np.zeros((d, d))
            M[:F.shape[1], :F.shape[1]], M[:F.shape[1], F.shape[1]:] = F[p], G[p]
            for k in (0, dt.size - 1):
                edges = np.linspace(0.0, dt[k], 9)
                mq, Qq = np.zeros(d), np.zeros((d, d))
                for a, b in zip(edges[:-1], edges[1:], strict=True):
                    for xi, wi in zip(x, w, strict=True):
                        r = expm(M * (0.5 * (a + b) + 0.5 * (b - a) * xi))[1]
                        mq += 0.5 * (b - a) * wi * r
                        Qq += 0.5 * (b - a) * wi * np.outer(r, r)
                np.testing.assert_allclose(m[p, k], mq, rtol=0,
                                           atol=1e-9 * np.abs(mq).max())
                np.testing.assert_allclose(Q[p, k], Qq, rtol=0,
                                           atol=1e-8 * np.abs(Qq).max())
