"""Batch simulation: exactness, irregular sampling, effects."""

import numpy as np
import pytest
from scipy.signal import dlsim, StateSpace

from motor_id.excitation import paper_steps
from motor_id.model import continuous_matrices, PAPER_MOTOR
from motor_id.recording import Recording
from motor_id.simulate import apply_input_maps, simulate_batch

T = np.arange(2000) * 0.01
U = paper_steps(T)


def test_linear_matches_scipy_dlsim():
    p = PAPER_MOTOR.to_dict()
    out = simulate_batch(p, T, U)
    F, G = continuous_matrices({k: np.array([v]) for k, v in p.items()})
    sysd = StateSpace(F[0], G[0][:, :1], np.eye(2), np.zeros((2, 1))).to_discrete(0.01)
    _, y, _ = dlsim(sysd, U)
    np.testing.assert_allclose(out['speed'][0], y[:, 0], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(out['current'][0], y[:, 1], rtol=1e-10, atol=1e-10)


def test_batch_members_are_independent():
    p = PAPER_MOTOR.to_dict()
    batch = {k: np.array([v, v * 1.5]) for k, v in p.items()}
    out = simulate_batch(batch, T, U)
    single = simulate_batch({k: v * 1.5 for k, v in p.items()}, T, U)
    np.testing.assert_allclose(out['speed'][1], single['speed'][0], rtol=1e-12)


def test_irregular_time_is_exact():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.005, 0.015, 1500))
    u = paper_steps(t - t[0])
    out = simulate_batch(PAPER_MOTOR.to_dict(), t, u)
    # reference: a fine regular grid with the same held input (1 ms substeps)
    fine = np.arange(t[0], t[-1], 1e-4)
    uf = u[np.searchsorted(t, fine, side='right') - 1]
    ref = simulate_batch(PAPER_MOTOR.to_dict(), fine, uf)
    ref_at_t = np.interp(t, fine, ref['speed'][0])
    np.testing.assert_allclose(out['speed'][0], ref_at_t, atol=2e-3 * np.max(ref_at_t))


def test_coulomb_friction_lowers_steady_speed_by_tc_over_kt():
    p = PAPER_MOTOR.to_dict()
    base = simulate_batch(p, T, U)['speed'][0, -1]
    tc = 0.2
    fr = simulate_batch(p, T, U, effects={'coulomb_friction': {'T_c': tc}})['speed'][0, -1]
    # steady state: w = (K_T V - R T_c) / (R B + K_T K_b)
    drop = p['R_m'] * tc / (p['R_m'] * p['B'] + p['K_T'] * p['K_b'])
    assert base - fr == pytest.approx(drop, rel=1e-3)


def test_coulomb_friction_sticks_below_breakaway():
    p = PAPER_MOTOR.to_dict()
    u = np.full(T.size, 0.3)  # K_T * 0.3 / R = 0.086 N m < T_c
    out = simulate_batch(p, T, u, effects={'coulomb_friction': {'T_c': 0.1}})
    assert np.all(out['speed'][0] == 0.0)



def test_coulomb_friction_lets_a_strong_reverse_drive_carry_the_shaft_through_zero():
    # a torque plant coasting forward when a torque 100 x T_c reverses it: the shaft stops
    # within the interval and moves on backwards, it does not stall for a whole sample
    t = np.arange(3) * 0.01
    u = np.array([-100.0, -100.0, -100.0])
    out = simulate_batch({'J': 1.0, 'B': 0.0}, t, u, 'torque',
                         effects={'coulomb_friction': {'T_c': 1.0}}, x0=[0.5])
    # 0.5 - (100 - 1) x 0.01 over the first interval (the friction's direction within
    # the interval is approximated by the new one)
    assert out['speed'][0, 1] == pytest.approx(0.5 - 0.99, rel=1e-9)
    weak = simulate_batch({'J': 1.0, 'B': 0.0}, t, 0.5 * u / 100, 'torque',
                          effects={'coulomb_friction': {'T_c': 1.0}}, x0=[0.001])
    assert np.all(weak['speed'][0, 1:] == 0.0)  # a drive below T_c: it stays stopped

@pytest.mark.parametrize('effect, params', [
    ('input_delay', {'d': 5}), ('dead_zone', {'V_dz': 1.0}),
    ('voltage_saturation', {'V_max': 5.0}), ('sensor_lag', {'tau_s': 0.1}),
    ('speed_quantization', {'q': 0.5}), ('brush_drop', {'V_b': 0.7}),
    ('resistance_drift', {'k_h': 0.05, 'tau_th': 10.0}), ('resonance', {}),
    ('load_torque', {'T_L': 0.1}), ('quadratic_load', {'k_q': 1e-3}),
    ('start_latency', {'d': 5}),
])
def test_every_effect_changes_the_output(effect, params):
    p = PAPER_MOTOR.to_dict()
    base = simulate_batch(p, T, U)['speed'][0]
    out = simulate_batch(p, T, U, effects={effect: params})['speed'][0]
    assert np.all(np.isfinite(out))
    assert np.max(np.abs(out - base)) > 1e-3 * np.max(np.abs(base))


def test_input_delay_shifts_by_whole_samples():
    p = PAPER_MOTOR.to_dict()
    base = simulate_batch(p, T, U)['speed'][0]
    out = simulate_batch(p, T, U, effects={'input_delay': {'d': 7}})['speed'][0]
    np.testing.assert_allclose(out[7:], base[:-7], atol=1e-12)


def test_start_latency_holds_the_input_at_zero_after_each_start_only():
    u = np.array([0.0, 0.0, 2.0, 2.0, 2.0, 2.0, 0.0, -1.0, -1.0, -1.0, 3.0, 3.0])
    out = apply_input_maps(u, {'start_latency': {'d': np.array([0.0, 2.0, 3.0])}}, 3)
    np.testing.assert_array_equal(out[0], u)
    # each departure from zero (samples 2 and 7) waits d samples; a sign change without
    # passing zero (sample 10) is no start
    np.testing.assert_array_equal(out[1], [0, 0, 0, 0, 2, 2, 0, 0, 0, -1, 3, 3])
    np.testing.assert_array_equal(out[2], [0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 3, 3])
    # a run that starts with the drive on shows no start
    np.testing.assert_array_equal(apply_input_maps(u[2:6], {'start_latency': {'d': 2}}, 1)[0],
                                  u[2:6])


def test_a_delay_reaches_back_into_the_run_before_only_where_the_runs_follow():
    # two tests back to back: a rest, then a step at the second run's first sample
    u = np.array([0.0, 0.0, 0.0, 0.0, 5.0, 5.0, 5.0, 5.0])
    t = 0.01 * np.arange(u.size)
    rec = Recording(t, u, np.zeros(u.size), segments=[(0, 4), (4, 8)])
    assert rec.input_streams == [(0, 4), (4, 8)]   # separate tests: each from its first
    np.testing.assert_array_equal(
        apply_input_maps(u, {'input_delay': {'d': 1.5}}, 1, rec.input_streams)[0], u)
    rec.meta['runs_follow'] = [False, True]   # as motor-id experiment records its tests
    assert rec.input_streams == [(0, 8)]
    np.testing.assert_allclose(
        apply_input_maps(u, {'input_delay': {'d': 1.5}}, 1, rec.input_streams)[0],
        [0, 0, 0, 0, 0, 2.5, 5, 5])
    # a flag list that does not fit the runs (a slice, a joined record) is ignored
    rec.meta['runs_follow'] = [False, True, True]
    assert rec.input_streams == [(0, 4), (4, 8)]
    joined = Recording.concatenate([rec.slice(0, 8), rec.slice(0, 8)])
    assert 'runs_follow' not in joined.meta


@pytest.mark.parametrize('t', [T, np.cumsum(np.random.default_rng(3).uniform(0.005, 0.015,
                                                                              T.size))])
def test_linear_fast_paths_match_the_general_kernel(t):
    rng = np.random.default_rng(4)
    batch = {k: v * rng.uniform(0.5, 2.0, 5) for k, v in PAPER_MOTOR.to_dict().items()}
    x0 = rng.standard_normal((5, 2))
    fast = simulate_batch(batch, t, U, x0=x0)
    # a zero Coulomb torque routes the same model through the general kernel
    full = simulate_batch(batch, t, U, effects={'coulomb_friction': {'T_c': 0.0}}, x0=x0)
    for ch in ('speed', 'current'):
        assert fast[ch].shape == (5, T.size) and fast[ch].flags['C_CONTIGUOUS']
        np.testing.assert_allclose(fast[ch], full[ch], rtol=1e-11, atol=1e-12)
    assert fast['states'].shape == (5, T.size, 2)
    np.testing.assert_array_equal(fast['states'][..., 0], fast['speed'])
    np.testing.assert_array_equal(fast['states'][..., 1], fast['current'])
    np.testing.assert_array_equal(fast['speed'][:, 0], x0[:, 0])


def _heated_rk4(par, t, u, k_h, tau_th, n_sub=50):
    """The continuous heating model integrated by RK4 with fine sub-steps (the reference)."""
    J, K, B, L, R0 = (par[k] for k in ('J', 'K_T', 'B', 'L_m', 'R_m'))
    h = (t[1] - t[0]) / n_sub

    def f(x, v):
        w, i, dR = x
        return np.array([(K * i - B * w) / J, (v - (R0 + dR) * i - K * w) / L,
                         k_h * i * i * (1.0 + dR / R0) - dR / tau_th])

    x = np.zeros(3)
    out = np.zeros((t.size, 3))
    for k in range(t.size):
        out[k] = x
        for _ in range(n_sub):
            k1 = f(x, u[k])
            k2 = f(x + 0.5 * h * k1, u[k])
            k3 = f(x + 0.5 * h * k2, u[k])
            k4 = f(x + h * k3, u[k])
            x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def test_heating_on_a_drive_whose_current_settles_within_a_sample_matches_the_physics():
    # a servo with L/R = 0.5 ms sampled at 5 ms: the current settles ten times within each
    # interval. The heating integrates i^2 R over the interval (Van Loan integrals) and
    # the drop is dR times the interval's mean current. Against fine RK4: speed 0.08 %,
    # current 3.3 % of their std (the drop taken at the start current, as before: 4.2 %
    # and 20 %, as bad as no heating at all)
    par = {'J': 3.5e-5, 'K_T': 0.098, 'K_b': 0.098, 'B': 2.4e-5, 'L_m': 1.9e-3, 'R_m': 3.8}
    rng = np.random.default_rng(3)
    t = np.arange(3000) * 5e-3
    u = np.repeat(rng.uniform(-6.0, 6.0, 120), 25)
    ref = _heated_rk4(par, t, u, 4.0, 5.0)
    out = simulate_batch(par, t, u, 'voltage', 'zoh',
                         {'resistance_drift': {'k_h': 4.0, 'tau_th': 5.0}})
    cold = simulate_batch(par, t, u, 'voltage', 'zoh')
    for c, j, tol in (('speed', 0, 0.01), ('current', 1, 0.05)):
        scale = np.std(ref[:, j])
        err = np.sqrt(np.mean((out[c][0] - ref[:, j]) ** 2)) / scale
        effect = np.sqrt(np.mean((cold[c][0] - ref[:, j]) ** 2)) / scale
        assert err < tol, (c, err)
        assert effect > 3 * tol, (c, effect)  # the heating itself is much larger


def test_interval_mean_of_a_ramp_is_its_value_at_mid_interval():
    from motor_id.effects import interval_mean
    y = 3.0 * np.arange(6.0) - 1.0
    np.testing.assert_allclose(interval_mean(y)[1:], y[1:] - 1.5)
    assert interval_mean(y)[0] == y[0]


def test_a_count_difference_reads_the_interval_mean_a_sampled_sensor_the_sample():
    t = np.arange(2000) * 0.01
    u = paper_steps(t)
    par = PAPER_MOTOR.to_dict()
    plain = simulate_batch(par, t, u)['speed'][0]
    q = 0.05
    counted = simulate_batch(par, t, u, effects={
        'speed_quantization': {'q': q, 'counted': 1.0}})['speed'][0]
    sampled = simulate_batch(par, t, u, effects={
        'speed_quantization': {'q': q, 'counted': 0.0}})['speed'][0]
    np.testing.assert_allclose(sampled, q * np.round(plain / q))
    mid = 0.5 * (plain[1:] + plain[:-1])
    np.testing.assert_allclose(counted[1:], q * np.round(mid / q))
    assert np.any(counted != sampled)


def test_sensor_lag_of_a_speed_ramp_is_the_continuous_filter_output():
    # a constant torque on a frictionless inertia: w = (tau / J) t. The sensor's lag acts
    # on the continuous speed, so its reading must be the exact filter output, not the
    # filter of the held samples (which ran about half a period long)
    J, torque, tau_s, T = 0.01, 0.02, 0.015, 0.01
    t = np.arange(200) * T
    out = simulate_batch({'J': J, 'B': 0.0}, t, np.full(t.size, torque), 'torque', 'zoh',
                         {'sensor_lag': {'tau_s': tau_s}})
    slope = torque / J
    exact = slope * (t - tau_s * (1.0 - np.exp(-t / tau_s)))
    np.testing.assert_allclose(out['speed'][0], exact, rtol=1e-9, atol=1e-12)


def test_runs_simulate_members_that_differ_only_elsewhere_once_and_exactly():
    """A Jacobian's initial-state columns change one run each: on the other runs those
    members are simulated once, and every member's output is bit for bit its own
    simulation (jittered runs, a friction effect, a member with other parameters)."""
    from motor_id.simulate import simulate_runs
    rng = np.random.default_rng(4)
    t = np.concatenate([np.cumsum(rng.uniform(4e-3, 6e-3, n)) + 10.0 * k
                        for k, n in enumerate((120, 90, 60))])
    segments = [(0, 120), (120, 210), (210, 270)]
    u = np.where(np.sin(3.0 * t) > 0, 6.0, -6.0)
    p = PAPER_MOTOR.to_dict()
    x0 = np.zeros((5, 6))
    x0[1, 0], x0[2, 3], x0[3, 5] = 1.0, -2.0, 0.1        # each moves one run's start
    theta = {k: np.full(5, v) for k, v in p.items()}
    theta['J'][4] *= 1.1                                  # and one other plant
    effects = {'coulomb_friction': {'T_c': np.full(5, 0.05)}}
    out = simulate_runs(theta, t, u, effects=effects, x0=x0, segments=segments)
    for m in range(5):
        one = simulate_runs({k: v[m] for k, v in theta.items()}, t, u,
                            effects={'coulomb_friction': {'T_c': 0.05}}, x0=x0[m],
                            segments=segments)
        np.testing.assert_array_equal(out['speed'][m], one['speed'][0])
        np.testing.assert_array_equal(out['current'][m], one['current'][0])


@pytest.mark.parametrize('shape', ['ramp', 'sine', 'steps'])
def test_brush_drop_blocks_current_below_it_as_the_independent_physics_does(shape):
    # the brushes conduct only while |V - K w| beats V_b. Against the independent RK4
    # integrator (motor_id.testing.independent_physics, events for the current's zero
    # crossings): within 0.5 % of the speed's RMS on three motors, where the drop taken
    # from the start current's sign alone chattered around zero current and let a shaft
    # creep under any voltage (2.6 % to 107 % off; 16 rad/s on a ramp still below V_b)
    from motor_id.testing.independent_physics import integrate, Motor
    for J, K, R, L, B, dt in ((0.0017, 0.12, 1.0, 0.05, 0.0017, 0.005),
                              (0.052, 0.66, 2.3, 0.0345, 0.002, 0.01),
                              (1e-5, 0.05, 6.0, 0.009, 2e-5, 0.002)):
        t = np.arange(0.0, 8.0, dt)
        u = {'ramp': 0.25 * t, 'sine': 2.0 * np.sin(2 * np.pi * 0.4 * t),
             'steps': np.where(t % 2 < 1, 1.5, -0.3)}[shape]
        eff = {'brush_drop': {'V_b': 0.7}}
        ref = integrate(Motor(J=J, K=K, R=R, L=L, B=B, V_supply=24.0), u, dt, eff)['speed']
        out = simulate_batch({'J': J, 'K_T': K, 'K_b': K, 'B': B, 'L_m': L, 'R_m': R}, t,
                             u, 'voltage', 'zoh', eff, np.zeros(2))['speed'][0]
        rms = np.sqrt(np.mean(ref[:t.size] ** 2))
        assert np.sqrt(np.mean((out - ref[:t.size]) ** 2)) < 5e-3 * rms, (J, shape)
        below = u < 0.7 if shape == 'ramp' else np.zeros(t.size, bool)
        assert np.all(np.abs(out[below]) < 1e-12 * rms)   # at rest until V beats the drop
