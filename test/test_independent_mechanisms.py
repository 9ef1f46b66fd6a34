"""The independent physics' joints: gravity (elevator, arm), hard stops, stick-slip with
gravity, the torque drive and the real-time Plant, against closed-form results."""

import math

import numpy as np
import pytest

from motor_id.testing.independent_physics import (
    feedforward,
    integrate,
    Motor,
    Plant,
    simulate,
)

# an FRC-like motor through a gearbox, seen at the joint
JOINT = Motor(J=0.05, K=0.2, R=0.1, L=1e-4, B=0.002, V_supply=12.0)


def test_pendulum_small_oscillation_period_is_two_pi_sqrt_j_over_t_g():
    # no winding torque (K -> 0, no back-EMF braking) and no damping: J phi'' = -T_g sin phi
    # about the hanging rest; the small-amplitude period is 2 pi sqrt(J / T_g) (amplitude
    # 0.05 rad: the large-amplitude correction is 1.6e-4)
    motor = Motor(J=0.02, K=1e-9, R=1.0, L=1e-3, B=0.0, V_supply=12.0)
    T_g, offset = 3.0, 0.4
    rest = -math.pi / 2.0 - offset
    T = 1e-3
    states = integrate(motor, np.zeros(20000), T, {'arm_gravity': {'T_g': T_g,
                                                                  'offset': offset}},
                       theta0=rest + 0.05)
    phi = states['angle'] - rest
    up = np.flatnonzero((phi[:-1] < 0.0) & (phi[1:] >= 0.0))
    crossings = up + phi[up] / (phi[up] - phi[up + 1])   # sub-sample zero crossings
    period = float(np.mean(np.diff(crossings))) * T
    assert period == pytest.approx(2.0 * math.pi * math.sqrt(0.02 / T_g), rel=1e-3)
    # energy is kept: the swing's amplitude does not decay
    assert np.max(phi[-2000:]) == pytest.approx(0.05, rel=1e-3)


def test_elevator_falls_at_the_back_emf_terminal_speed_at_zero_volts():
    # V = 0: K i = -K^2 w / R brakes the fall; steady w = -T_g / (B + K^2 / R)
    T_g = 20.0
    states = integrate(JOINT, np.zeros(4000), 1e-3, {'elevator_gravity': {'T_g': T_g}},
                       theta0=1.0)
    terminal = -T_g / (JOINT.B + JOINT.K ** 2 / JOINT.R)
    assert states['speed'][-1] == pytest.approx(terminal, rel=1e-6)
    assert states['current'][-1] == pytest.approx(-JOINT.K * terminal / JOINT.R, rel=1e-6)


def test_arm_settles_where_the_motor_torque_balances_gravity():
    # constant V, friction-free: at rest K V / R = T_g cos(theta + offset), on the stable
    # branch between hanging and horizontal
    T_g, offset, V = 5.0, -0.3, 1.5
    rest = -math.pi / 2.0 - offset
    states = integrate(JOINT, np.full(6000, V), 1e-3,
                       {'arm_gravity': {'T_g': T_g, 'offset': offset}}, theta0=rest)
    expected = -math.acos(JOINT.K * V / (JOINT.R * T_g)) - offset
    assert states['angle'][-1] == pytest.approx(expected, abs=1e-6)
    assert abs(states['speed'][-1]) < 1e-6


def test_a_stuck_elevator_breaks_away_only_when_the_drive_beats_gravity_and_t_s():
    # a slow ramp from 0 V: stuck while |K i - T_g| <= T_s, i.e. until
    # V = R (T_g + T_s) / K (i = V / R at rest); T_s > T_g, so at 0 V it does not fall
    T_g, T_s = 4.0, 6.0
    effects = {'elevator_gravity': {'T_g': T_g}, 'coulomb_friction': {'T_c': 3.0, 'T_s': T_s}}
    T = 1e-3
    ramp = np.linspace(0.0, 8.0, 8001)      # 1 V/s
    states = integrate(JOINT, ramp, T, effects, theta0=0.5)
    moved = np.flatnonzero(states['speed'] != 0.0)
    v_break = JOINT.R * (T_g + T_s) / JOINT.K
    assert ramp[moved[0] - 1] == pytest.approx(v_break, abs=2e-3)
    assert np.all(states['angle'][:moved[0]] == 0.5)
    # gravity larger than T_s: held at 0 V no more, it slides down
    slide = integrate(JOINT, np.zeros(500), T, {'elevator_gravity': {'T_g': 8.0},
                                                'coulomb_friction': {'T_c': 3.0, 'T_s': 6.0}},
                      theta0=0.5)
    assert slide['angle'][-1] < 0.5 - 1e-3


@pytest.mark.parametrize('input_kind', ['voltage', 'torque'])
def test_hard_stop_halts_the_joint_and_holds_it_while_pushed(input_kind):
    # pushed up into the high stop it stays there at speed 0; pulled back (the input
    # reversed) it leaves; the low stop holds an elevator resting on it at 0 input
    effects = {'elevator_gravity': {'T_g': 10.0}, 'hard_stops': {'low': 0.0, 'high': 0.3}}
    u_up = 6.0 if input_kind == 'voltage' else 25.0
    u = np.concatenate([np.full(2000, u_up), np.zeros(3000)])
    states = integrate(JOINT, u, 1e-3, effects, theta0=0.0, input_kind=input_kind)
    pos = states['angle']
    hit = int(np.argmax(pos >= 0.3))
    assert hit > 0
    assert np.all(pos[hit:2000] == 0.3)
    assert np.all(states['speed'][hit + 1:2000] == 0.0)
    assert np.all(pos <= 0.3) and np.all(pos >= 0.0)
    assert np.all(pos[-500:] == 0.0)        # fell back and rests on the low stop
    assert np.all(states['speed'][-500:] == 0.0)
    rest = integrate(JOINT, np.zeros(500), 1e-3, effects, theta0=0.0)
    assert np.all(rest['angle'] == 0.0) and np.all(rest['speed'] == 0.0)


def test_torque_drive_reaches_the_speed_where_torque_meets_friction_and_damping():
    effects = {'coulomb_friction': {'T_c': 0.3}}
    # J / B = 25 s: 12 time constants, exp(-12) = 6e-6 left
    states = integrate(JOINT, np.full(3000, 1.0), 0.1, effects, input_kind='torque')
    assert states['speed'][-1] == pytest.approx((1.0 - 0.3) / JOINT.B, rel=2e-5)
    assert states['current'][-1] == pytest.approx(1.0 / JOINT.K, rel=1e-9)


def test_plant_stepped_in_uneven_chunks_follows_the_sample_grid():
    # the real-time robot advances by whatever wall time passed: the result must not
    # depend on the chunks (events and stops included)
    effects = {'arm_gravity': {'T_g': 5.0, 'offset': 0.2}, 'hard_stops': {'low': -3.0,
                                                                          'high': 0.5},
               'coulomb_friction': {'T_c': 0.2, 'T_s': 0.3}}
    rest = -math.pi / 2.0 - 0.2
    u = np.concatenate([np.full(1500, 4.0), np.full(1500, -1.0)])
    T = 1e-3
    ref = integrate(JOINT, u, T, effects, theta0=rest, n_sub=4)
    plant = Plant(JOINT, effects, theta0=rest)
    rng = np.random.default_rng(3)
    for segment in (u[:1500], u[1500:]):
        left = segment.size
        while left:
            n = min(int(rng.integers(1, 40)), left)
            plant.advance(segment[0], n * T)
            left -= n
    assert plant.position == pytest.approx(float(ref['angle'][-1]), abs=1e-6)
    assert plant.speed == pytest.approx(float(ref['speed'][-1]), abs=1e-4)
    assert plant.time == pytest.approx(u.size * T, rel=1e-12)
    assert float(np.max(ref['angle'])) == pytest.approx(0.5, abs=1e-12)  # hit the stop


def test_feedforward_truth_of_voltage_and_torque_drives():
    effects = {'coulomb_friction': {'T_c': 0.5}, 'arm_gravity': {'T_g': 6.0, 'offset': 0.3}}
    ff = feedforward(JOINT, effects)
    g = JOINT.R / JOINT.K
    assert ff == pytest.approx({'kS': g * 0.5, 'kV': JOINT.K + g * JOINT.B, 'kA': g * JOINT.J,
                                'kG': g * 6.0, 'offset': 0.3}, rel=1e-12)
    assert feedforward(JOINT, effects, 'torque') == pytest.approx(
        {'kS': 0.5, 'kV': JOINT.B, 'kA': JOINT.J, 'kG': 6.0, 'offset': 0.3}, rel=1e-12)
    # the voltage feedforward holds the arm (below horizontal, where the rest is stable):
    # kG cos(theta + offset) at rest is the voltage
    theta = -0.8
    v = ff['kG'] * math.cos(theta + 0.3)
    states = integrate(JOINT, np.full(3000, v), 1e-3,
                       {'arm_gravity': {'T_g': 6.0, 'offset': 0.3}}, theta0=theta)
    assert states['angle'][-1] == pytest.approx(theta, abs=1e-6)


def test_simulate_takes_a_position_dependent_case_and_rejects_bad_ones():
    speed, current, states = simulate(JOINT, np.zeros(100), 1e-3,
                                      {'elevator_gravity': {'T_g': 5.0},
                                       'hard_stops': {'low': 0.0, 'high': 1.0}},
                                      rng=1, theta0=0.0)
    assert np.all(states['angle'] == 0.0)
    assert speed.shape == current.shape == (100,)
    with pytest.raises(ValueError, match='outside the hard stops'):
        integrate(JOINT, np.zeros(3), 1e-3, {'hard_stops': {'low': 0.0}}, theta0=-1.0)
    with pytest.raises(ValueError, match='one of elevator_gravity and arm_gravity'):
        integrate(JOINT, np.zeros(3), 1e-3, {'elevator_gravity': {'T_g': 1.0},
                                             'arm_gravity': {'T_g': 1.0}})
    with pytest.raises(ValueError, match='rigid joint'):
        integrate(JOINT, np.zeros(3), 1e-3, {'hard_stops': {'low': 0.0},
                                             'resonance': {'r': 1.0, 'f_r': 5.0, 'zeta': 0.1}})
    with pytest.raises(ValueError, match='input_kind'):
        integrate(JOINT, np.zeros(3), 1e-3, input_kind='current')
