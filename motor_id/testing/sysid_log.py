"""Seeded WPILib SysId logs (``sysid_data.json``) of a known motor, from the independent physics.

The four tests a SysId log holds (voltage ramps and voltage steps, forward and backward,
each from rest) are simulated on :mod:`motor_id.testing.independent_physics` (written from
the equations, no motor_id model code) with what real logs show: an input latency (the
applied voltage lags the logged command by ``latency`` seconds), an enable latency (the
drive applies nothing for ``start_latency`` seconds after the command leaves zero), sample
times with
jitter, sensor readings that are refreshed only every ``hold`` samples (a CAN status
frame slower than the robot loop), white speed noise and optional Coulomb friction
(``kS``). The rows follow SysId's format: positions in encoder rotations and velocities
in rotations per second, which SysId converts to the log's ``units`` with
``unitsPerRotation``. The unit table here is this module's own, so that a reader's
conversion is checked against an independent one.

The motor's speed is in the SI unit of the mechanism (rad/s, or m/s for a linear
``units``); its feedforward constants (``V = kS sgn(w) + kV w + kA dw/dt``, the armature
inductance neglected) are ``kV = (K^2 + R B) / K``, ``kA = J R / K``, ``kS = T_c R / K``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import json
import math
import os
from typing import Any

import numpy as np

from motor_id.testing.independent_physics import integrate, Motor

__all__ = ['DEFAULT_MOTOR', 'feedforward', 'FeedforwardTruth', 'make_sysid_log', 'measure',
           'SysIdLog', 'SysIdTruth', 'TESTS', 'routine_commands', 'Timing',
           'UNITS_PER_ROTATION']

TESTS = ('slow-forward', 'slow-backward', 'fast-forward', 'fast-backward')

_SI_PER = {'Meters': 1.0, 'Feet': 0.3048, 'Inches': 0.0254, 'Radians': 1.0,
           'Rotations': 2.0 * math.pi, 'Degrees': math.pi / 180.0}

UNITS_PER_ROTATION = {'Radians': 2.0 * math.pi, 'Rotations': 1.0, 'Degrees': 360.0,
                      'Meters': 0.1, 'Feet': 0.1 / 0.3048, 'Inches': 0.1 / 0.0254}
"""Default ``unitsPerRotation`` per unit: one shaft turn, or a 0.1 m wheel circumference."""

DEFAULT_MOTOR = Motor(J=4.05e-5, K=0.02, R=0.5, L=1.5e-4, B=1e-5, V_supply=12.0,
                      motor_class='sysid-test')
"""A small brushed motor: tau_m 50 ms, tau_e 0.3 ms, kV 0.02025 V s/rad, kA 1.0125e-3."""


def feedforward(motor: Motor, kS: float = 0.0) -> dict[str, float]:
    """The SysId constants of ``motor`` in SI: ``{'kS' [V], 'kV' [V s/unit], 'kA'}``."""
    return {'kS': float(kS), 'kV': (motor.K ** 2 + motor.R * motor.B) / motor.K,
            'kA': motor.J * motor.R / motor.K}


@dataclass(frozen=True)
class FeedforwardTruth:
    """One motor's true feedforward constants.

    Attributes
    ----------
    kS : float
        [V]
    kV, kA : float
        SI: [V s/rad] and [V s^2/rad], or per m for linear units.
    kV_log, kA_log : float
        The same per position unit of the log.
    motor : Motor
        The nameplate behind them.
    kG : float
        A joint's gravity [V] (0: none).
    offset : float
        An arm's encoder offset [rad] (0: none).
    """

    kS: float  # noqa: N815 - kS, kV, kA, kG: WPILib's symbols
    kV: float  # noqa: N815
    kA: float  # noqa: N815
    kV_log: float  # noqa: N815
    kA_log: float  # noqa: N815
    motor: Motor
    kG: float = 0.0  # noqa: N815
    offset: float = 0.0


@dataclass(frozen=True)
class SysIdTruth:
    """The truth behind a generated SysId log (never in the data).

    Attributes
    ----------
    seed : int
    units : str
        The log's position unit.
    si_per_raw, si_per_unit : float
        SI value of one raw encoder unit and of one log unit.
    latency, start_latency : float
        [s]
    hold : int
        Loops per sensor refresh.
    jitter, sample_period : float
        Relative loop jitter, loop period [s].
    noise, speed_noise_std : float
        Speed noise as a fraction of the no-load speed, and its std [rad/s or m/s].
    feedforward : FeedforwardTruth
        The motor's constants (a drivetrain's left side).
    right : FeedforwardTruth or None
        A drivetrain's right side.
    """

    seed: int
    units: str
    si_per_raw: float
    si_per_unit: float
    latency: float
    start_latency: float
    hold: int
    jitter: float
    sample_period: float
    noise: float
    speed_noise_std: float
    feedforward: FeedforwardTruth
    right: FeedforwardTruth | None = None


@dataclass
class SysIdLog:
    """A generated log: the JSON's top level and the truth behind it (never in the data).

    Attributes
    ----------
    data : dict
        The JSON document: ``{'sysid': True, 'test', 'units', 'unitsPerRotation',
        'slow-forward', ...}``.
    truth : SysIdTruth
    """

    data: dict[str, Any]
    truth: SysIdTruth

    def write(self, path: str | os.PathLike[str]) -> str:
        """Write :attr:`data` as JSON to ``path`` and return the path."""
        with open(path, 'w', encoding='utf-8') as fh:
            json.dump(self.data, fh)
        return str(path)


@dataclass(frozen=True)
class Timing:
    """The robot loop and its sensors: period [s], jitter, integration sub-steps, input
    latency [s], readings refreshed every ``hold`` loops, enable latency [s]."""

    sample_period: float
    jitter: float
    sub: int
    latency: float
    hold: int
    start_latency: float = 0.0


def make_sysid_log(seed: int = 0, *, motor: Motor | None = None,
                   right_motor: Motor | None = None, kS: float = 0.0,
                   kS_right: float | None = None, latency: float = 0.0,
                   start_latency: float = 0.0, hold: int = 1,
                   jitter: float = 0.0, sample_period: float = 0.005, noise: float = 0.002,
                   ramp_rate: float = 1.0, ramp_duration: float = 4.0,
                   step_voltage: float = 6.0, step_duration: float = 1.5,
                   test: str = 'Simple', units: str = 'Radians',
                   units_per_rotation: float | None = None, sub: int = 10,
                   track_width: float = 0.6,
                   effects: Mapping[str, Mapping[str, float]] | None = None) -> SysIdLog:
    """Simulate the four SysId tests of a known motor and write them as SysId rows.

    Parameters
    ----------
    seed : int
        Seeds ``np.random.default_rng`` (jitter, noise, the frame phase).
    motor : Motor, optional
        The motor (left side of a Drivetrain); default :data:`DEFAULT_MOTOR`.
    right_motor : Motor, optional
        Drivetrain: the right side (default: the motor with 10 % more inertia).
    kS, kS_right : float
        Coulomb friction as the voltage that balances it [V] (right: default ``kS``).
    latency : float
        Input delay [s]: the applied voltage follows the logged command this late.
    start_latency : float
        Enable latency [s]: after the (delayed) command leaves zero, the drive applies
        nothing for this long, then follows it.
    hold : int
        The speed and position readings are refreshed every ``hold`` samples.
    jitter : float
        Sample intervals are ``sample_period (1 + jitter U(-1, 1))``.
    sample_period : float
        Nominal robot loop period [s].
    noise : float
        Speed noise std as a fraction of the no-load speed at ``step_voltage``.
    ramp_rate, ramp_duration : float
        Quasistatic tests: ``V = +-ramp_rate t`` [V/s] for ``ramp_duration`` [s].
    step_voltage, step_duration : float
        Dynamic tests: ``V = +-step_voltage`` [V] for ``step_duration`` [s].
    test : {'Simple', 'Arm', 'Elevator', 'Drivetrain'}
        The log's mechanism (no gravity is simulated for Arm or Elevator).
    units : str
        One of Meters, Feet, Inches, Radians, Rotations, Degrees.
    units_per_rotation : float, optional
        Default :data:`UNITS_PER_ROTATION` of ``units``.
    sub : int
        Integration grid steps per nominal sample (latency and jitter are whole steps).
    track_width : float
        Drivetrain: wheel separation for the gyro angle [the SI unit of ``units``].
    effects : mapping, optional
        Further effects of the physics (:func:`measure`), e.g. a two-mass ``resonance``:
        a wheel with the robot's mass behind a damped coupling.

    Returns
    -------
    SysIdLog
    """
    if units not in _SI_PER:
        raise ValueError(f'unknown units {units!r}; choose from {sorted(_SI_PER)}')
    if int(hold) < 1 or int(sub) < 1 or sample_period <= 0 or not 0 <= jitter < 1:
        raise ValueError('need hold >= 1, sub >= 1, sample_period > 0, 0 <= jitter < 1')
    rng = np.random.default_rng(seed)
    motor = motor or DEFAULT_MOTOR
    upr = float(UNITS_PER_ROTATION[units] if units_per_rotation is None
                else units_per_rotation)
    si_per_raw = upr * _SI_PER[units]
    timing = Timing(float(sample_period), float(jitter), int(sub), float(latency), int(hold),
                     float(start_latency))
    sides = [(motor, float(kS))]
    if test == 'Drivetrain':
        right = right_motor or replace(motor, J=1.1 * motor.J)
        sides.append((right, float(kS if kS_right is None else kS_right)))
    w_scale = noise * motor.no_load_speed(step_voltage)
    data: dict[str, Any] = {'sysid': True, 'test': test, 'units': units,
                            'unitsPerRotation': upr}
    t_start = 10.0
    offsets = [0.0] * len(sides)
    for name in TESTS:
        command, t = routine_commands(name, timing, rng, ramp_rate, ramp_duration, step_voltage,
                              step_duration)
        phase = int(rng.integers(timing.hold))
        cols = []
        for k, (m, ks) in enumerate(sides):
            pos, vel = measure(m, ks, command, timing, w_scale, phase, rng, effects)
            cols.append((command[1], (pos + offsets[k]) / si_per_raw, vel / si_per_raw))
            offsets[k] += float(pos[-1])
        data[name] = _rows(t_start + t, cols, test, track_width / si_per_raw)
        t_start += float(t[-1]) + 3.0
    truth = _truth(seed, sides, units, si_per_raw, timing, noise, w_scale)
    return SysIdLog(data=data, truth=truth)


def routine_commands(name: str, timing: Timing, rng: np.random.Generator, ramp_rate: float,
                     ramp_duration: float, step_voltage: float, step_duration: float
                     ) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """The commands of one test of the routine, one per robot loop.

    Parameters
    ----------
    name : str
        The test: ``slow-forward`` ... (a SysId JSON's names) or ``quasistatic-forward``
        ... (SysIdRoutineLog's); quasistatic tests ramp, dynamic tests step.
    timing : Timing
    rng : numpy.random.Generator
        Draws the loop jitter.
    ramp_rate, ramp_duration, step_voltage, step_duration : float
        As :func:`make_sysid_log`.

    Returns
    -------
    ((grid, command), t)
        The loops' indices on the integration grid, the command of each loop [V] (0 at
        the first), and the loop times from 0 [s].
    """
    slow = name.startswith(('slow', 'quasistatic'))
    duration = ramp_duration if slow else step_duration
    n = int(round(duration / timing.sample_period)) + 1
    steps = timing.sample_period * (1.0 + timing.jitter * rng.uniform(-1.0, 1.0, n - 1))
    h = timing.sample_period / timing.sub
    grid = np.concatenate([[0], np.cumsum(np.maximum(1, np.rint(steps / h)).astype(int))])
    t = grid * h
    sign = 1.0 if name.endswith('forward') else -1.0
    u = sign * (ramp_rate * t if slow else np.full(n, step_voltage))
    u[0] = 0.0
    return (grid, u), t


def measure(motor: Motor, kS: float, command: tuple[np.ndarray, np.ndarray],
            timing: Timing, w_noise: float, phase: int, rng: np.random.Generator,
            effects: Mapping[str, Mapping[str, float]] | None = None, theta0: float = 0.0,
            read_after: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Position [rad] and speed [rad/s] readings of one motor at the loops of one test.

    The command is delayed by ``timing.latency``, blanked for ``timing.start_latency``
    after it leaves zero, integrated from rest on the independent physics (with Coulomb
    friction ``kS`` [V] and any further ``effects`` of
    :func:`motor_id.testing.independent_physics.integrate`); the speed gets white noise of
    std ``w_noise`` and both readings are refreshed every ``timing.hold`` loops from loop
    ``phase``. The joint starts at rest at ``theta0`` [rad, or m for an elevator]. Each
    loop's readings are taken ``read_after`` integration steps after its command.
    """
    grid, u = command
    h = timing.sample_period / timing.sub
    delay = int(round(timing.latency / h))
    j = np.arange(int(grid[-1]) + 1 + read_after)
    k = np.searchsorted(grid, j - delay, side='right') - 1
    v = np.where(k >= 0, u[np.maximum(k, 0)], 0.0)
    off = int(round(timing.start_latency / h))
    for on in np.flatnonzero((v[1:] != 0.0) & (v[:-1] == 0.0)) + 1:
        v[on:on + off] = 0.0   # the drive arms on its first non-zero command
    hidden: dict[str, Mapping[str, float]] = dict(effects or {})
    if kS > 0:
        T_c = kS * motor.K / motor.R
        hidden['coulomb_friction'] = {'T_c': T_c, 'T_s': T_c}
    states = integrate(motor, v, h, hidden, theta0=theta0)
    speed = states['speed'][grid + read_after] + w_noise * rng.standard_normal(grid.size)
    angle = states['angle'][grid + read_after]
    n = grid.size
    held = np.maximum((np.arange(n) - phase) // timing.hold * timing.hold + phase, 0)
    return angle[held], speed[held]


def _rows(t: np.ndarray, cols: list[tuple[np.ndarray, np.ndarray, np.ndarray]], test: str,
          track_raw: float) -> list[list[float]]:
    """SysId rows: ``[t, V, pos, vel]`` or the nine Drivetrain columns."""
    t = np.round(t, 6)
    if test != 'Drivetrain':
        u, pos, vel = cols[0]
        return np.column_stack([t, u, pos, vel]).tolist()
    (u, pl, vl), (_, pr, vr) = cols
    angle = (pr - pl) / track_raw
    rate = np.gradient(angle, t) if t.size > 1 else np.zeros_like(angle)
    return np.column_stack([t, u, u, pl, pr, vl, vr, angle, rate]).tolist()


def _truth(seed: int, sides: list[tuple[Motor, float]], units: str, si_per_raw: float,
           timing: Timing, noise: float, w_noise: float) -> SysIdTruth:
    """The constants behind the log, in SI and in the log's units."""
    si_per_unit = _SI_PER[units]

    def side(m: Motor, ks: float) -> FeedforwardTruth:
        ff = feedforward(m, ks)
        return FeedforwardTruth(ff['kS'], ff['kV'], ff['kA'], ff['kV'] * si_per_unit,
                                ff['kA'] * si_per_unit, m)
    return SysIdTruth(int(seed), units, si_per_raw, si_per_unit, timing.latency,
                      timing.start_latency, timing.hold, timing.jitter,
                      timing.sample_period, noise, w_noise, side(*sides[0]),
                      side(*sides[1]) if len(sides) > 1 else None)
