"""Seeded WPILib DataLogs (``.wpilog``) of a SysIdRoutine on a robot, from the independent physics.

Since 2024 WPILib's SysId reads only DataLogs, written on the robot by
``SysIdRoutineLog``: a string entry ``sysid-test-state-<log name>`` that holds the test
running at each loop (``quasistatic-forward``, ``quasistatic-reverse``,
``dynamic-forward``, ``dynamic-reverse``, then ``none`` when a test ends) and, per motor,
double entries ``voltage-<motor>-<log name>``, ``position-<motor>-<log name>`` (older
releases: ``distance-...``) and ``velocity-<motor>-<log name>``, each with its unit as the
entry's metadata (``Volt``, ``Rotation``, ``Rotation per Second``, ``Meter``,
``Meter per Second``). Every record carries its own timestamp in microseconds: the entries
of one robot loop are appended one after another, a few microseconds apart.

This module writes such logs with :class:`wpiutil.DataLogWriter` as a robot loop would
(a 20 ms or 5 ms loop with jitter, the tests in the driver's order with rests between
them, other entries of the robot interleaved). The motion of each motor comes from
:func:`motor_id.testing.sysid_log.measure` on :mod:`motor_id.testing.independent_physics`
(no motor_id model code), with the same routine as the JSON logs of
:mod:`motor_id.testing.sysid_log`. The unit table here is this module's own, so that the
reader's conversion is checked against an independent one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import math
import os

import numpy as np

from motor_id.testing.independent_physics import feedforward as joint_feedforward
from motor_id.testing.independent_physics import Motor
from motor_id.testing.sysid_log import (
    DEFAULT_MOTOR,
    feedforward,
    FeedforwardTruth,
    measure,
    routine_commands,
    Timing,
)

__all__ = ['ROUTINE', 'RoutineMotor', 'SysIdWpilog', 'UNIT_PAIRS', 'WpilogTruth',
           'write_sysid_wpilog']

ROUTINE = ('quasistatic-forward', 'quasistatic-reverse', 'dynamic-forward',
           'dynamic-reverse')
"""SysIdRoutineLog's test states, in the order a driver usually runs them."""

UNIT_PAIRS = {'Rotation': ('Rotation per Second', 2.0 * math.pi),
              'Radian': ('Radian per Second', 1.0),
              'Degree': ('Degree per Second', math.pi / 180.0),
              'Meter': ('Meter per Second', 1.0),
              'Foot': ('Foot per Second', 0.3048),
              'Inch': ('Inch per Second', 0.0254)}
"""Position unit -> (velocity unit, SI value of one position unit), as WPILib names them."""

_LINEAR = ('Meter', 'Foot', 'Inch')
_OFFSETS_US = {'voltage': 20, 'position': 35, 'velocity': 50}
"""Microseconds into the loop at which the first, second and third entry is appended."""


@dataclass(frozen=True)
class RoutineMotor:
    """One motor the routine logs.

    Attributes
    ----------
    name : str
        The motor's name in the entries (``voltage-<name>-<log name>``).
    motor : Motor
        Its nameplate (independent physics).
    kS : float
        Coulomb friction as the voltage that balances it [V].
    effects : dict
        Further effects of :func:`motor_id.testing.independent_physics.integrate` (a
        joint's gravity: ``arm_gravity``, ``elevator_gravity``, ``hard_stops``).
    start : float or dict, optional
        A joint whose position matters (gravity): where each test starts at rest [rad],
        one value or ``{test: value}`` (a reverse test from the top of an elevator);
        the position is then logged as it is. None: each test continues the position
        where the last ended (a flywheel).
    """

    name: str = 'shooter'
    motor: Motor = field(default_factory=lambda: DEFAULT_MOTOR)
    kS: float = 0.0  # noqa: N815 - WPILib's symbol
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    start: float | Mapping[str, float] | None = None

    def start_of(self, test: str) -> float | None:
        """Where ``test`` starts (None: where the last one ended)."""
        if self.start is None or isinstance(self.start, (int, float)):
            return self.start
        return float(self.start[test])


@dataclass(frozen=True)
class SysIdWpilog:
    """A written log and the truth behind it (never in the data).

    Attributes
    ----------
    path : str
    truth : WpilogTruth
    """

    path: str
    truth: WpilogTruth


@dataclass(frozen=True)
class WpilogTruth:
    """The truth behind a generated DataLog (never in the data).

    Attributes
    ----------
    seed : int
    log_name, units : str
        The routine's log name and the entries' position unit.
    si_per_unit : float
        SI value of one position unit.
    linear : bool
        A linear unit (the constants are per m).
    loop_period, jitter, latency, start_latency : float
    hold : int
    noise, speed_noise_std : float
        As :class:`motor_id.testing.sysid_log.SysIdTruth`.
    motors : dict
        ``{name: FeedforwardTruth}``.
    """

    seed: int
    log_name: str
    units: str
    si_per_unit: float
    linear: bool
    loop_period: float
    jitter: float
    latency: float
    start_latency: float
    hold: int
    noise: float
    speed_noise_std: float
    motors: dict[str, FeedforwardTruth]


def write_sysid_wpilog(path: str | os.PathLike[str], seed: int = 0, *,
                       motors: Sequence[RoutineMotor] = (RoutineMotor(),),
                       log_name: str = 'shooter', loop_period: float = 0.02,
                       jitter: float = 0.05, latency: float = 0.0,
                       start_latency: float = 0.0, hold: int = 1, noise: float = 0.002,
                       ramp_rate: float = 1.0, ramp_duration: float = 4.0,
                       step_voltage: float = 6.0, step_duration: float = 1.5,
                       units: str = 'Rotation', meters_per_radian: float = 0.05 / math.pi,
                       position_name: str = 'position',
                       order: Sequence[str] = ('voltage', 'position', 'velocity'),
                       tests: Sequence[str] = ROUTINE, rest: float = 2.0,
                       others: bool = True, sub: int = 10,
                       entry_names: Mapping[str, str] | None = None,
                       metadata: bool = True, frame_delay: float = 0.0) -> SysIdWpilog:
    """Run the routine on the robot and write its DataLog as SysIdRoutineLog does.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.wpilog`` to write.
    seed : int
        Seeds ``np.random.default_rng`` (loop jitter, noise, the frame phase).
    motors : sequence of RoutineMotor
        The motors the routine logs (each gets the same commands).
    log_name : str
        The routine's log name.
    loop_period : float
        The robot loop [s] (0.02 or 0.005 on a roboRIO).
    jitter : float
        Loop intervals are ``loop_period (1 + jitter U(-1, 1))``.
    latency, start_latency, hold, noise : float, float, int, float
        As :func:`motor_id.testing.sysid_log.make_sysid_log`.
    ramp_rate, ramp_duration, step_voltage, step_duration : float
        The routine's quasistatic ramp [V/s] and dynamic step [V], and how long each runs.
    units : str
        The position unit of the entries: a key of :data:`UNIT_PAIRS`.
    meters_per_radian : float
        Linear units: the travel per motor radian [m] (default a 0.1 m circumference).
    position_name : {'position', 'distance'}
        The position entry's prefix (older SysIdRoutineLog releases: ``distance``).
    order : sequence of str
        The order in which each loop appends voltage, position and velocity.
    tests : sequence of str
        The states run, in order (a name may repeat: the test run again).
    rest : float
        Seconds between tests (state ``none``; the robot loop goes on).
    others : bool
        Also log entries a robot logs besides the routine (battery voltage, a
        NetworkTables value, console messages).
    sub : int
        Integration grid steps per loop.
    entry_names : dict, optional
        Another logger's names instead of SysIdRoutineLog's: ``{'voltage', 'position',
        'velocity', 'state': name}`` (one motor).
    metadata : bool
        Write each entry's unit as its metadata (False: no metadata, as some loggers).
    frame_delay : float
        A vendor logger's readings (REV's URCL, CTRE's SignalLogger: the motor
        controller's status frames): each loop logs the position and velocity the
        controller measured this long [s] after the loop's command, and a test's log
        opens with its first applied command (the loop before it, command 0, is not
        logged), so the first velocity of a step test already moves. 0: SysIdRoutineLog's
        own entries, read in the loop.

    Returns
    -------
    SysIdWpilog
    """
    import wpiutil
    from wpiutil.log import DoubleLogEntry, IntegerLogEntry, StringLogEntry

    if units not in UNIT_PAIRS:
        raise ValueError(f'unknown units {units!r}; choose from {sorted(UNIT_PAIRS)}')
    if sorted(order) != sorted(_OFFSETS_US):
        raise ValueError(f'order must be a permutation of {sorted(_OFFSETS_US)}')
    rng = np.random.default_rng(seed)
    timing = Timing(float(loop_period), float(jitter), int(sub), float(latency), int(hold),
                    float(start_latency))
    vel_unit, si_per_unit = UNIT_PAIRS[units]
    raw_per_rad = (meters_per_radian if units in _LINEAR else 1.0) / si_per_unit
    w_scale = noise * motors[0].motor.no_load_speed(step_voltage)
    read_after = int(round(frame_delay / (timing.sample_period / timing.sub)))
    log = wpiutil.DataLogWriter(str(path))
    t_us = 3_000_000   # the robot has been up 3 s when the first test starts
    state = None
    entries: dict[str, DoubleLogEntry] = {}
    battery = IntegerLogEntry(log, 'systemTime', '', t_us) if others else None
    volts = DoubleLogEntry(log, 'NT:/SmartDashboard/battery', '', t_us) if others else None
    console = StringLogEntry(log, 'messages', '', t_us) if others else None
    angles = [0.0] * len(motors)
    for test in tests:
        (grid, u), t = routine_commands(test, timing, rng, ramp_rate, ramp_duration,
                                        step_voltage, step_duration)
        stamps = t_us + np.rint(t * 1e6).astype(np.int64)
        phase = int(rng.integers(timing.hold))
        readings = []
        for k, m in enumerate(motors):
            start = m.start_of(test)
            angle, speed = measure(m.motor, m.kS, (grid, u), timing, w_scale, phase, rng,
                                   m.effects, 0.0 if start is None else start, read_after)
            if start is None:
                angle = angles[k] + angle
                angles[k] = float(angle[-1])
            readings.append((angle * raw_per_rad, speed * raw_per_rad))
        if console is not None:
            console.append(f'starting {test}', int(stamps[0]) - 400)
        for i, stamp in enumerate(stamps):
            if frame_delay > 0 and i == 0:
                continue   # the loop before the first applied command
            at = int(stamp) + int(rng.integers(0, 8))
            for k, m in enumerate(motors):
                pos, vel = readings[k]
                values = {'voltage': u[i], 'position': pos[i], 'velocity': vel[i]}
                for j, what in enumerate(order):
                    name = position_name if what == 'position' else what
                    key = (entry_names or {}).get(what) or f'{name}-{m.name}-{log_name}'
                    unit = {'voltage': 'Volt', 'position': units, 'velocity': vel_unit}[what]
                    if key not in entries:
                        entries[key] = DoubleLogEntry(log, key, unit if metadata else '',
                                                      at)
                    entries[key].append(float(values[what]),
                                        at + _OFFSETS_US[order[j]] + 60 * k)
            if state is None:
                state = StringLogEntry(log, (entry_names or {}).get(
                    'state', f'sysid-test-state-{log_name}'), '', at)
            state.append(test, at + 70 + 60 * len(motors))
            if battery is not None and volts is not None:
                battery.append(1_700_000_000_000_000 + at, at + 400)
                volts.append(12.5 - 0.1 * abs(u[i]), at + 410)
        t_end = int(stamps[-1]) + int(round(loop_period * 1e6))
        if state is not None:
            state.append('none', t_end + 70)
        t_us = t_end + int(round(rest * 1e6))
    log.flush()
    log.stop()
    return SysIdWpilog(path=str(path), truth=_truth(
        seed, motors, log_name, units, si_per_unit, meters_per_radian, timing, noise,
        w_scale))


def _truth(seed: int, motors: Sequence[RoutineMotor], log_name: str, units: str,
           si_per_unit: float, meters_per_radian: float, timing: Timing, noise: float,
           w_noise: float) -> WpilogTruth:
    """The constants behind the log: SI (per rad, or per m for linear units) and per unit."""
    per_si = meters_per_radian if units in _LINEAR else 1.0   # metres (or rad) per motor rad
    out: dict[str, FeedforwardTruth] = {}
    for m in motors:
        ff = feedforward(m.motor, m.kS)
        joint = joint_feedforward(m.motor, m.effects)
        kV, kA = ff['kV'] / per_si, ff['kA'] / per_si
        out[m.name] = FeedforwardTruth(ff['kS'], kV, kA, kV * si_per_unit, kA * si_per_unit,
                                       m.motor, joint['kG'], joint['offset'])
    return WpilogTruth(int(seed), log_name, units, si_per_unit, units in _LINEAR,
                       timing.sample_period, timing.jitter, timing.latency,
                       timing.start_latency, timing.hold, noise, w_noise, out)
