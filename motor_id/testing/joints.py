"""Records of a joint under gravity (an arm, an elevator) from the independent physics,
driven by the experiment's own plan and guard offline (no ROS): what ``motor-id
experiment`` records on a robot, for the gravity tests of the analysis."""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np

from motor_id.experiment.guard import StateSample
from motor_id.experiment.session import ExperimentSession
from motor_id.experiment.settings import ExperimentSettings, Travel
from motor_id.recording import Recording
from motor_id.testing.independent_physics import feedforward, Motor, Plant

ARM_MOTOR = Motor(J=0.1, K=1.0, R=1.0, L=1e-3, B=0.05, V_supply=12.0)
"""An arm joint through its gearbox: kV = 1.05 V s/rad, kA = 0.1 V s^2/rad."""
ELEVATOR_MOTOR = Motor(J=0.5, K=1.0, R=1.0, L=1e-3, B=9.0, V_supply=12.0)
"""An elevator seen at its carriage (per metre): kV = 10 V s/m, kA = 0.5 V s^2/m."""


@dataclass
class JointCase:
    """A generated joint record and its truth."""

    recording: Recording
    truth: dict[str, float]
    """The true feedforward constants (kS, kV, kA, kG, offset) of the physics."""
    effects: dict[str, dict[str, float]]


def joint_case(mechanism: str, out: str | Path, seed: int = 0, *, T_g: float = 3.0,
               offset: float = 0.3, T_c: float = 0.2, motor: Motor | None = None,
               travel: tuple[float, float] | None = None, max_command: float = 12.0,
               period: float = 0.01, noise: tuple[float, float] = (2e-4, 0.01),
               time_scale: float = 0.5, t_max: float = 300.0) -> JointCase:
    """Run the experiment's SysId plan on an arm or an elevator of the independent physics.

    Parameters
    ----------
    mechanism : {'arm', 'elevator'}
    out : path
        The experiment's output folder (its bag and log are written there).
    seed : int
        Seeds the measurement noise.
    T_g, offset, T_c : float
        Gravity [N m or N], the arm's encoder offset [rad] (horizontal at theta + offset
        = 0), Coulomb friction (static at the same level).
    motor : Motor, optional
        Default :data:`ARM_MOTOR` or :data:`ELEVATOR_MOTOR`.
    travel : (float, float), optional
        The travel window relative to the rest position (default arm: -1.2 .. 1.2 rad;
        elevator: 0 .. 1.2 m from its bottom stop).
    max_command : float
        [V]
    period : float
        Sample period [s]; each command is held from its sample on.
    noise : (float, float)
        Standard deviations of the position [rad or m] and speed [rad/s or m/s] noise.
    time_scale : float
        The plan's durations multiplied by this.
    """
    rng = np.random.default_rng(seed)
    gravity = {'T_g': T_g, 'offset': offset} if mechanism == 'arm' else {'T_g': T_g}
    if mechanism == 'arm':
        motor = motor or ARM_MOTOR
        rest = -math.pi / 2.0 - offset
        lo, hi = travel or (-1.2, 1.2)
        effects: dict[str, dict[str, float]] = {'arm_gravity': gravity,
                                   'hard_stops': {'low': rest + lo - 0.2,
                                                  'high': rest + hi + 0.2}}
        window = Travel(rest + lo, rest + hi)
    else:
        motor = motor or ELEVATOR_MOTOR
        rest = 0.0
        lo, hi = travel or (0.0, 1.2)
        effects = {'elevator_gravity': gravity, 'hard_stops': {'low': 0.0, 'high': hi + 0.1}}
        window = Travel(lo, hi)
    if T_c > 0:
        effects['coulomb_friction'] = {'T_c': T_c, 'T_s': T_c}
    plant = Plant(motor, effects, theta0=rest)
    settings = ExperimentSettings('joint', '/ctrl/commands', max_command, str(out),
                                  controller_joints=('joint',), mechanism=mechanism,
                                  travel=window, time_scale=time_scale, seed=seed)
    sess = ExperimentSession(settings)
    sess.open()
    sess.start(0.0)
    t, u = 0.0, 0.0
    while not sess.guard.finished and t < t_max:
        s = StateSample(t, t, plant.position + noise[0] * rng.standard_normal(),
                        plant.speed + noise[1] * rng.standard_normal(), lag=0.0)
        cmd = sess.on_state(s)
        if cmd is not None:
            u = cmd
        plant.advance(u, period)
        t += period
    rec = sess.close()
    if rec is None:
        raise RuntimeError('the experiment recorded too few samples')
    truth = feedforward(motor, effects)
    return JointCase(rec, truth, effects)


def elevator_open_loop(seed: int = 0, *, T_g: float = 3.0, T_c: float = 0.2,
                       motor: Motor | None = None, period: float = 0.01,
                       noise: tuple[float, float] = (2e-4, 0.005), start: float = 0.5
                       ) -> JointCase:
    """An elevator driven open loop about its holding voltage, never on a stop: slow ramps
    and steps up and down, each from rest (a linear axis: position in m).

    The experiment's own runs (:func:`joint_case`) rest the carriage on its bottom stop
    between tests, which the model does not describe (no stops); this record keeps to
    what it does describe.
    """
    from motor_id.contracts import channel_units

    rng = np.random.default_rng(seed)
    motor = motor or ELEVATOR_MOTOR
    effects: dict[str, dict[str, float]] = {'elevator_gravity': {'T_g': T_g}}
    if T_c > 0:
        effects['coulomb_friction'] = {'T_c': T_c, 'T_s': T_c}
    hold = motor.R * T_g / motor.K
    parts = []
    for kind, size, seconds in (('rest', 0.0, 1.0), ('ramp', 3.0, 3.0), ('rest', 0.0, 1.0),
                                ('ramp', -3.0, 3.0), ('rest', 0.0, 1.0), ('step', 4.0, 0.8),
                                ('rest', 0.0, 1.0), ('step', -4.0, 0.8), ('rest', 0.0, 1.0)):
        n = int(round(seconds / period))
        parts.append(np.linspace(0.0, size, n) if kind == 'ramp' else np.full(n, size))
    u = hold + np.concatenate(parts)
    plant = Plant(motor, effects, theta0=start)
    pos, speed = np.empty(u.size), np.empty(u.size)
    for k, v in enumerate(u):
        pos[k], speed[k] = plant.position, plant.speed
        plant.advance(float(v), period)
    t = np.arange(u.size) * period
    rec = Recording(t, u, speed + noise[1] * rng.standard_normal(u.size),
                    input_kind='voltage',
                    meta={'source': 'motor_id.testing.joints', 'mechanism': 'elevator',
                          'units': channel_units('voltage', True, position=True)},
                    position=pos + noise[0] * rng.standard_normal(u.size))
    return JointCase(rec, feedforward(motor, effects), effects)
