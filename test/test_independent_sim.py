"""Tests of the independent second simulator (motor_id.testing.independent_sim) against physics."""

from dataclasses import fields
import math

import numpy as np
import pytest
from scipy.linalg import expm

from motor_id.testing import independent_sim as sim

SERVO = sim.Motor(J=5e-5, K=0.08, R=1.5, L=1.5e-3, B=2e-5, V_supply=36.0,
                  motor_class='servo')
"""A fixed servo: tau_e = 1 ms, tau_m = J R / (R B + K^2) ~ 11.7 ms."""


def _exact_linear(motor, v, T):
    """Exact ZOH solution of the linear two-state motor (matrix exponential)."""
    A = np.array([[-motor.B / motor.J, motor.K / motor.J],
                  [-motor.K / motor.L, -motor.R / motor.L]])
    b = np.array([0.0, 1.0 / motor.L])
    M = np.zeros((3, 3))
    M[:2, :2] = A * T
    M[:2, 2] = b * T
    E = expm(M)
    x = np.zeros(2)
    out = np.empty((v.size, 2))
    for k, vk in enumerate(v):
        out[k] = x
        x = E[:2, :2] @ x + E[:2, 2] * vk
    return out


def test_no_load_speed_matches_closed_form():
    V = 24.0
    st = sim.integrate(SERVO, np.full(3000, V), 1e-3)
    w_nl = V * SERVO.K / (SERVO.R * SERVO.B + SERVO.K ** 2)
    np.testing.assert_allclose(st['speed'][-1], w_nl, rtol=1e-9)
    np.testing.assert_allclose(st['current'][-1], SERVO.B * w_nl / SERVO.K, rtol=1e-6)


def test_step_response_matches_matrix_exponential():
    rng = np.random.default_rng(3)
    v = np.repeat(rng.uniform(-30, 30, 40), 25)
    st = sim.integrate(SERVO, v, 1e-3, n_sub=8)
    ref = _exact_linear(SERVO, v, 1e-3)
    scale = np.max(np.abs(ref), axis=0)
    assert np.max(np.abs(st['speed'] - ref[:, 0])) < 1e-6 * scale[0]
    assert np.max(np.abs(st['current'] - ref[:, 1])) < 1e-6 * scale[1]


def test_electrical_time_constant_from_locked_rotor_step():
    # a break-away torque far above the stall torque locks the rotor: i = V/R (1 - e^-t/tau_e)
    V, T = 10.0, 1e-4
    locked = {'coulomb_friction': {'T_c': 10.0, 'T_s': 10.0}}
    st = sim.integrate(SERVO, np.full(100, V), T, locked)
    assert np.all(st['speed'] == 0.0) and np.all(st['angle'] == 0.0)
    t = np.arange(100) * T
    sel = (t > 0) & (t < 3 * SERVO.tau_e)
    tau = -t[sel] / np.log(1.0 - st['current'][sel] * SERVO.R / V)
    np.testing.assert_allclose(tau, SERVO.tau_e, rtol=1e-4)


def test_mechanical_time_constant_from_speed_step():
    # with L/R 1000 x shorter than tau_m the speed step is first order with tau_m
    m = sim.Motor(J=SERVO.J, K=SERVO.K, R=SERVO.R, L=SERVO.L / 100.0, B=SERVO.B,
                  V_supply=36.0)
    T = 1e-4
    st = sim.integrate(m, np.full(2000, 12.0), T)
    w = st['speed']
    t63 = np.interp(1.0 - math.exp(-1.0), w / m.no_load_speed(12.0), np.arange(w.size) * T)
    # the electrical lag delays the crossing by about tau_e; 1 % tolerance
    np.testing.assert_allclose(t63, m.tau_m + m.tau_e, rtol=0.01)


def test_integrator_converges_at_fourth_order():
    rng = np.random.default_rng(5)
    T = 2e-3   # 2 tau_e: one RK4 step per sample is coarse
    v = np.repeat(rng.uniform(-30, 30, 30), 20)
    ref = _exact_linear(SERVO, v, T)
    errs = []
    for n_sub in (2, 4, 8, 16):
        st = sim.integrate(SERVO, v, T, n_sub=n_sub)
        errs.append(np.max(np.abs(st['current'] - ref[:, 1])))
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all(ratios > 12.0), (errs, ratios)   # 2^4 = 16 for a fourth-order method
    assert errs[-1] < 1e-6 * np.max(np.abs(ref[:, 1]))


@pytest.mark.parametrize('effects', [{'coulomb_friction': {'T_c': 0.02, 'T_s': 0.03}},
                                     {'brush_drop': {'V_b': 1.0}}])
def test_integrator_converges_through_stick_slip_and_brush_events(effects):
    # the break-away, zero-crossing and conduction events are located inside the sub-steps,
    # so the order stays near four although the right-hand side jumps
    t = np.arange(3000) * 1e-3
    v = 4.0 * np.sin(2 * np.pi * 1.0 * t) + 1.0 * np.sin(2 * np.pi * 7.0 * t)
    ref = sim.integrate(SERVO, v, 1e-3, effects, n_sub=512)
    assert np.count_nonzero(ref['speed'] == 0.0) > 10 or 'brush_drop' in effects
    errs = [np.max(np.abs(sim.integrate(SERVO, v, 1e-3, effects, n_sub=n)['speed']
                          - ref['speed'])) for n in (4, 8, 16, 32)]
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all(ratios > 10.0), (errs, ratios)
    assert errs[0] < 1e-5 * np.max(np.abs(ref['speed']))


def test_energy_balance_closes():
    # int V i dt = int (R i^2 + B w^2) dt + (L i^2 + J w^2) / 2 at the end
    T = 1e-4
    t = np.arange(20000) * T
    v = 20.0 * np.sin(2 * np.pi * 7.0 * t) + 5.0 * np.sin(2 * np.pi * 31.0 * t)
    st = sim.integrate(SERVO, v, T, n_sub=4)
    w, i = st['speed'], st['current']
    trap = 0.5 * T * (i[:-1] + i[1:])          # charge in each period (ZOH voltage)
    e_in = np.sum(v[:-1] * trap)
    loss = np.trapezoid(SERVO.R * i ** 2 + SERVO.B * w ** 2, dx=T)
    stored = 0.5 * SERVO.L * i[-1] ** 2 + 0.5 * SERVO.J * w[-1] ** 2
    np.testing.assert_allclose(e_in, loss + stored, rtol=2e-4)


def test_stick_slip_sticks_below_breakaway_and_breaks_above():
    T_c, T_s = 0.02, 0.03
    fr = {'coulomb_friction': {'T_c': T_c, 'T_s': T_s}}

    def v_for(tau):
        return tau * SERVO.R / SERVO.K   # locked-rotor voltage for a motor torque tau

    def w_ss(V):
        return (SERVO.K * V / SERVO.R - T_c) / (SERVO.B + SERVO.K ** 2 / SERVO.R)

    # from rest: 0.9 T_s (above T_c) stays stuck; then 1.2 T_s breaks away; then back to
    # 0.9 T_s keeps turning (kinetic friction is lower); then 0 V stops and sticks.
    v = np.concatenate([np.full(300, v_for(0.9 * T_s)), np.full(300, v_for(1.2 * T_s)),
                        np.full(300, v_for(0.9 * T_s)), np.zeros(600)])
    st = sim.integrate(SERVO, v, 1e-3, fr)
    w = st['speed']
    assert np.all(w[:301] == 0.0) and np.all(st['angle'][:301] == 0.0)
    assert np.all(w[305:900] > 0.0)
    # kinetic steady state: K (V - K w) / R - B w = T_c
    np.testing.assert_allclose(w[599], w_ss(v[599]), rtol=1e-6)
    np.testing.assert_allclose(w[899], w_ss(v[899]), rtol=1e-6)
    stopped = np.flatnonzero(w[900:] == 0.0)
    assert stopped.size > 0
    first = 900 + stopped[0]
    assert np.all(w[first:] == 0.0)          # stays stuck, no chattering
    assert np.all(w[900:first] >= 0.0)       # never reverses while stopping


def test_break_away_happens_when_the_drive_torque_reaches_t_s():
    # locked rotor, step from 0.9 T_s to 1.2 T_s of locked-rotor torque: the current rises
    # with tau_e, K i reaches T_s after tau_e ln(0.3 / 0.2) = 0.405 ms
    T_s, T = 0.03, 1e-4
    fr = {'coulomb_friction': {'T_c': 0.02, 'T_s': T_s}}
    V = np.concatenate([np.full(300, 0.9), np.full(100, 1.2)]) * T_s * SERVO.R / SERVO.K
    st = sim.integrate(SERVO, V, T, fr)
    t_break = SERVO.tau_e * math.log(1.5)
    moving = np.flatnonzero(st['speed'] != 0.0)
    assert moving[0] == 300 + math.ceil(t_break / T)
    assert np.all(st['speed'][moving[0]:] > 0.0)


def test_stick_slip_reversal_without_chattering():
    fr = {'coulomb_friction': {'T_c': 0.02, 'T_s': 0.03}}
    t = np.arange(4000) * 1e-3
    v = 4.0 * np.sin(2 * np.pi * 1.0 * t)
    st = sim.integrate(SERVO, v, 1e-3, fr)
    w = st['speed']
    s = np.sign(w[w != 0.0])
    assert np.count_nonzero(np.diff(s)) <= 2 * 4 + 1     # one reversal per half period
    assert np.count_nonzero(w == 0.0) > 20               # it dwells at zero at each reversal
    # stuck samples have drive torque below the break-away torque
    zero = np.flatnonzero(w[1:] == 0.0) + 1
    assert np.all(np.abs(SERVO.K * st['current'][zero]) <= 0.03 + 1e-12)


def test_brush_drop_blocks_current_below_the_drop():
    st = sim.integrate(SERVO, np.full(200, 0.5), 1e-3, {'brush_drop': {'V_b': 0.6}})
    assert np.all(st['current'] == 0.0) and np.all(st['speed'] == 0.0)
    st = sim.integrate(SERVO, np.full(3000, 10.0), 1e-3, {'brush_drop': {'V_b': 0.6}})
    np.testing.assert_allclose(st['speed'][-1], SERVO.no_load_speed(10.0 - 0.6), rtol=1e-9)


@pytest.mark.parametrize('seed', range(6))
def test_encoder_speed_lies_on_its_grid(seed):
    data, truth = sim.make_case(seed, effect='speed_quantization', noise=0.05)
    q = truth.effect_params['q']
    np.testing.assert_allclose(q, 2 * np.pi / (truth.effect_params['cpr']
                                               * truth.sample_period), rtol=1e-15)
    counts = np.round(data.speed / q)
    np.testing.assert_array_equal(data.speed, counts * q)   # bit for bit on the grid
    np.testing.assert_allclose(data.speed / q, counts, rtol=0, atol=1e-9)
    assert np.unique(counts).size > 5


@pytest.mark.parametrize('seed', range(6))
def test_heating_raises_resistance_by_the_drawn_fraction(seed):
    data, truth = sim.make_case(seed, effect='resistance_drift')
    p = truth.effect_params
    assert 0.10 <= p['rise_target'] <= 0.40
    np.testing.assert_allclose(p['rise'], p['rise_target'], rtol=0.02)
    motor = sim.Motor.from_dict(truth.motor)
    v = sim.amplifier(data.input, truth.sim_effects)
    st = sim.integrate(motor, v, truth.sample_period, truth.sim_effects, truth.n_sub)
    np.testing.assert_allclose(st['resistance'][-1] / motor.R - 1.0, p['rise'], rtol=1e-12)
    assert np.all(st['temperature_rise'] >= 0.0) and st['temperature_rise'][0] == 0.0


def test_heating_reaches_the_thermal_steady_state():
    # locked rotor at constant V: dT = R_th V^2 / (R0 (1 + alpha dT)), solve the quadratic
    V, R_th, C_th, a = 5.0, 2.0, 0.2, sim.ALPHA_COPPER
    eff = {'coulomb_friction': {'T_c': 10.0, 'T_s': 10.0},
           'resistance_drift': {'alpha': a, 'R_th': R_th, 'C_th': C_th}}
    st = sim.integrate(SERVO, np.full(10000, V), 1e-3, eff)
    P0 = V ** 2 / SERVO.R
    dT = (-1.0 + math.sqrt(1.0 + 4.0 * a * R_th * P0)) / (2.0 * a)
    np.testing.assert_allclose(st['temperature_rise'][-1], dT, rtol=1e-6)
    np.testing.assert_allclose(st['current'][-1], V / (SERVO.R * (1 + a * dT)), rtol=1e-6)


def test_amplifier_clips_before_the_dead_zone():
    eff = {'voltage_saturation': {'V_max': 10.0}, 'dead_zone': {'V_dz': 3.0}}
    v = sim.amplifier([20.0, -20.0, 2.0, 5.0, -12.0], eff)
    np.testing.assert_array_equal(v, [7.0, -7.0, 0.0, 2.0, -7.0])   # not 17 V
    speed, _, st = sim.simulate(SERVO, np.full(3000, 20.0), 1e-3, eff, noise=(0.0, 0.0))
    np.testing.assert_allclose(speed[-1], SERVO.no_load_speed(7.0), rtol=1e-9)


def test_input_delay_shifts_whole_samples():
    v = sim.amplifier(np.arange(1.0, 6.0), {'input_delay': {'d': 2}})
    np.testing.assert_array_equal(v, [0.0, 0.0, 1.0, 2.0, 3.0])


def test_sensor_lag_is_a_first_order_filter():
    tau_s = 0.02
    st = sim.integrate(SERVO, np.full(4000, 12.0), 1e-3, {'sensor_lag': {'tau_s': tau_s}})
    # steady state equal; a lag of tau_s on the ramp-like part
    np.testing.assert_allclose(st['sensor'][-1], st['speed'][-1], rtol=1e-9)
    assert np.all(st['sensor'][1:200] < st['speed'][1:200])


def test_make_case_is_reproducible_bit_for_bit():
    a, ta = sim.make_case(11)
    b, tb = sim.make_case(11)
    for k in ('time', 'input', 'speed', 'current'):
        assert np.array_equal(getattr(a, k), getattr(b, k))
    assert ta.to_dict() == tb.to_dict()
    c, _ = sim.make_case(12)
    assert not (a.speed.size == c.speed.size and np.array_equal(a.speed, c.speed))


def test_truth_is_never_in_the_data():
    data, truth = sim.make_case(4, effect='load_torque', r_m_error=0.05)
    assert {f.name for f in fields(data)} == {'time', 'input', 'speed', 'current',
                                              'input_kind', 'known'}
    assert data.input_kind == 'voltage'
    assert set(data.known) == {'R_m'}
    np.testing.assert_allclose(data.known['R_m'], truth.motor['R'] * 1.05, rtol=1e-15)
    for k in ('time', 'input', 'speed', 'current'):
        assert isinstance(getattr(data, k), np.ndarray)
    assert 'load_torque' not in repr(data) and 'T_L' not in repr(data)
    rec = sim.to_recording(data)
    assert 'load_torque' not in repr(rec.meta) and len(rec) == truth.n_samples


@pytest.mark.parametrize('motor_class', sim.MOTOR_CLASSES)
@pytest.mark.parametrize('effect', ('none',) + sim.EFFECTS)
def test_every_class_and_effect_gives_finite_detectable_data(motor_class, effect):
    data, truth = sim.make_case(21, effect=effect, motor_class=motor_class, n_samples=3000)
    assert truth.motor_class == motor_class and truth.effect == effect
    assert 1e-3 <= truth.sample_period <= 0.02
    for k in ('input', 'speed', 'current'):
        assert getattr(data, k).shape == (3000,) and np.all(np.isfinite(getattr(data, k)))
    assert np.std(data.speed) > 0 and np.std(data.current) > 0
    assert truth.excitation not in sim.NOT_REVEALED_BY.get(effect, ())
    if effect == 'none':
        return
    motor = sim.Motor.from_dict(truth.motor)
    T = truth.sample_period
    s1, c1, _ = sim.simulate(motor, data.input, T, truth.sim_effects, (0.0, 0.0), 0,
                             truth.n_sub)
    s0, c0, _ = sim.simulate(motor, data.input, T, {}, (0.0, 0.0), 0, truth.n_sub)
    noise = truth.noise['speed']
    change = max(np.sqrt(np.mean((s1 - s0) ** 2)) / (noise * np.std(s0)),
                 np.sqrt(np.mean((c1 - c0) ** 2)) / (noise * np.std(c0)))
    assert change > 3.0, change


def test_draws_cover_the_stated_ranges():
    classes, periods, lengths = set(), [], []
    for seed in range(40):
        _, t = sim.make_case(seed, effect='none')
        classes.add(t.motor_class)
        periods.append(t.sample_period)
        lengths.append(t.n_samples)
        m = t.motor
        assert m['K_T'] == m['K_b']
        lo_hi = {'industrial': (1e-2, 1e-1), 'servo': (1e-5, 1e-4), 'hobby': (1e-7, 1e-6)}
        assert lo_hi[t.motor_class][0] <= m['J'] <= lo_hi[t.motor_class][1]
    assert classes == set(sim.MOTOR_CLASSES)
    assert 1e-3 <= min(periods) and max(periods) <= 0.02
    assert 2000 <= min(lengths) and max(lengths) <= 25000


def test_effects_an_excitation_cannot_reveal_are_refused():
    with pytest.raises(ValueError, match='cannot reveal'):
        sim.make_case(0, effect='dead_zone', excitation='prbs')
    with pytest.raises(ValueError, match='unknown effect'):
        sim.make_case(0, effect='gearbox')
    seen = {sim.make_case(s, effect='brush_drop', n_samples=2000)[1].excitation
            for s in range(12)}
    assert 'staircase' not in seen and len(seen) >= 2
