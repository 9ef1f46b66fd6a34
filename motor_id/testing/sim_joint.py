"""The simulated robot's joint without ROS: mechanisms, real-time stepping, sensor timing, truth.

:mod:`motor_id.testing.sim_robot` puts this on ROS 2 topics. The physics is
:mod:`motor_id.testing.independent_physics` (never the model the fit uses). Three
mechanisms with FRC-like constants, seen at the joint (gearbox included):

========  ===================================  ==============================================
wheel     a flywheel on a small brushless      kS 0.30 V, kV 0.0200 V s/rad, kA 0.0025 V s^2/rad,
          motor; free speed ~580 rad/s         tau_m 0.125 s
arm       4 kg at 0.45 m, offset 0.35 rad,     kS 0.167 V, kG 1.18 V, kV 1.233 V s/rad,
          starts hanging; stops -2.4, 1.4 rad  kA 0.080 V s^2/rad, tau_m 0.065 s
elevator  12 kg carriage, starts on its        kS 0.15 V, kG 1.18 V, kV 6.10 V s/m,
          bottom stop; stops 0, 1.2 m          kA 0.25 V s^2/m, tau_m 0.041 s
========  ===================================  ==============================================

Time is the caller's monotonic clock [s]: :meth:`JointSim.advance` integrates the physics
up to ``now`` under the held input, taking the sensor samples at their own (jittered)
instants on the way; each sample leaves ``latency`` later (:meth:`JointSim.due`).
"""

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
import json
import math
import os
from typing import Any

import numpy as np

from motor_id.errors import ConfigError
from motor_id.testing.independent_physics import feedforward, Motor, Plant


@dataclass(frozen=True)
class Mechanism:
    """One joint's physics and names.

    Attributes
    ----------
    motor : Motor
        At the joint: J [kg m^2, or kg], K [N m/A, or N/A], R [Ohm], L [H], B.
    effects : dict
        The physics' effects (friction, gravity); hard stops come from ``stops``.
    joint : str
        The simulated joint.
    joints : tuple of str
        The controller's joints by default (the simulated one among others).
    stops : (float, float)
        Default hard stops [rad or m] (infinite: none).
    theta0 : float
        Position at rest at the start [rad or m]; a function of ``offset`` for the arm.
    linear : bool
        Position in m, torque in N.
    noise : (float, float, float)
        Sensor noise std of position, velocity, effort at ``noise = 1``.
    """

    name: str
    motor: Motor
    effects: Mapping[str, Mapping[str, float]]
    joint: str
    joints: tuple[str, ...]
    stops: tuple[float, float]
    linear: bool = False
    noise: tuple[float, float, float] = (1e-4, 0.01, 0.05)

    def theta0(self, offset: float) -> float:
        """The start: hanging (arm), on the bottom stop (elevator), at 0 (wheel)."""
        if 'arm_gravity' in self.effects:
            return -math.pi / 2.0 - offset
        if 'elevator_gravity' in self.effects:
            return self.stops[0]
        return 0.0


ARM_OFFSET = 0.35
"""The arm's default offset [rad]: horizontal at theta = -0.35, hanging at -1.92."""

MECHANISMS = {
    'wheel': Mechanism(
        'wheel', Motor(J=1e-3, K=0.02, R=0.05, L=5e-5, B=2e-5, V_supply=12.0),
        {'coulomb_friction': {'T_c': 0.12, 'T_s': 0.144}}, 'wheel_joint',
        ('intake_joint', 'wheel_joint'), (-math.inf, math.inf), noise=(1e-3, 0.5, 0.2)),
    'arm': Mechanism(
        'arm', Motor(J=1.2, K=1.2, R=0.08, L=8e-5, B=0.5, V_supply=12.0),
        {'coulomb_friction': {'T_c': 2.5, 'T_s': 3.0},
         'arm_gravity': {'T_g': 4.0 * 9.81 * 0.45, 'offset': ARM_OFFSET}}, 'arm_joint',
        ('base_joint', 'arm_joint', 'wrist_joint'), (-2.4, 1.4), noise=(2e-4, 0.01, 0.1)),
    'elevator': Mechanism(
        'elevator', Motor(J=25.0, K=6.0, R=0.06, L=6e-5, B=10.0, V_supply=12.0),
        {'coulomb_friction': {'T_c': 15.0, 'T_s': 18.0},
         'elevator_gravity': {'T_g': 12.0 * 9.81}}, 'elevator_joint',
        ('elevator_joint', 'claw_joint'), (0.0, 1.2), linear=True, noise=(1e-4, 0.002, 0.1)),
}
"""The mechanisms by name."""


@dataclass(frozen=True)
class SimConfig:
    """What the robot's parameters set (see :mod:`motor_id.testing.sim_robot`)."""

    mechanism: str = 'wheel'
    input_kind: str = 'voltage'
    rate_hz: float = 100.0
    jitter: float = 0.05
    latency: float = 0.003
    noise: float = 1.0
    seed: int = 0
    offset: float = ARM_OFFSET
    stop_low: float | None = None
    stop_high: float | None = None

    def check(self) -> None:
        """Raise :class:`ConfigError` for an unknown mechanism or misplaced stops."""
        if self.mechanism not in MECHANISMS:
            raise ConfigError(f'mechanism {self.mechanism!r}: choose from {sorted(MECHANISMS)}')
        low, high = self.stops()
        if not low < high:
            raise ConfigError(f'stop_low ({low}) must be below stop_high ({high})')
        theta0 = MECHANISMS[self.mechanism].theta0(self.offset)
        if not low <= theta0 <= high:
            raise ConfigError(f'the {self.mechanism} starts at {theta0:.3f}, outside its '
                              f'stops [{low}, {high}]')

    def stops(self) -> tuple[float, float]:
        """The hard stops [rad or m]: the parameters, else the mechanism's."""
        low, high = MECHANISMS[self.mechanism].stops
        return (low if self.stop_low is None else self.stop_low,
                high if self.stop_high is None else self.stop_high)

    def effects(self) -> dict[str, dict[str, float]]:
        """The physics' effects: the mechanism's, the arm's offset, the stops."""
        effects = {k: dict(v) for k, v in MECHANISMS[self.mechanism].effects.items()}
        if 'arm_gravity' in effects:
            effects['arm_gravity']['offset'] = self.offset
        low, high = self.stops()
        if math.isfinite(low) or math.isfinite(high):
            effects['hard_stops'] = {'low': low, 'high': high}
        return effects


@dataclass(frozen=True)
class Sample:
    """One measurement: its instant [s, caller's clock], when it leaves, and the values."""

    t: float
    due: float
    position: float
    velocity: float
    effort: float


@dataclass(frozen=True)
class ReceivedCommand:
    """A command the robot received: when, its values, and what was applied.

    Attributes
    ----------
    time : float
        Receive time, the epoch [s].
    t : float
        Receive time from the start [s].
    values : list of float
    applied : float or None
        None: ignored.
    """

    time: float
    t: float
    values: list[float]
    applied: float | None


@dataclass(frozen=True)
class JointTruth:
    """What the simulated joint was and did (the truth file, never in the data).

    Attributes
    ----------
    mechanism, joint, input_kind : str
    feedforward : dict
        kS, kV, kA, kG, offset of the physics, each in ``units[name]``.
    units : dict
    motor : Motor
    effects : dict
        The physics' effects (:meth:`SimConfig.effects`).
    limit : float
        The drive's saturation (``units['kG']``).
    position_start, position_min, position_max : float
        Where the joint started and how far it went [rad or m].
    position_unit : str
    stops : (float or None, float or None)
        The hard stops (None: none on that side).
    samples : int
        Measurements taken.
    duration : float
        [s]
    commands : list of ReceivedCommand
    """

    mechanism: str
    joint: str
    input_kind: str
    feedforward: dict[str, float]
    units: dict[str, str]
    motor: Motor
    effects: dict[str, dict[str, float]]
    limit: float
    position_start: float
    position_min: float
    position_max: float
    position_unit: str
    stops: tuple[float | None, float | None]
    samples: int
    duration: float
    commands: list[ReceivedCommand]

    def to_dict(self) -> dict[str, Any]:
        """The JSON of the truth file (every constant with its unit)."""
        commands = [asdict(c) for c in self.commands]
        unit = self.position_unit
        return {
            'mechanism': self.mechanism, 'joint': self.joint, 'input_kind': self.input_kind,
            'feedforward': {k: {'value': v, 'unit': self.units[k]}
                            for k, v in self.feedforward.items()},
            'physics': {'motor': self.motor.to_dict(), 'effects': self.effects,
                        'limit': {'value': self.limit, 'unit': self.units['kG']}},
            'position': {'start': self.position_start, 'min': self.position_min,
                         'max': self.position_max, 'unit': unit},
            'stops': {'low': self.stops[0], 'high': self.stops[1], 'unit': unit},
            'samples': self.samples, 'duration': {'value': self.duration, 'unit': 's'},
            'commands': commands, 'last_command': commands[-1] if commands else None,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> 'JointTruth':
        """Inverse of :meth:`to_dict` (``last_command`` is the last of ``commands``)."""
        ff = d['feedforward']
        physics, position, stops = d['physics'], d['position'], d['stops']
        units = {k: v['unit'] for k, v in ff.items()}
        units.setdefault('kG', physics['limit']['unit'])
        return cls(
            d['mechanism'], d['joint'], d['input_kind'],
            {k: v['value'] for k, v in ff.items()}, units, Motor.from_dict(physics['motor']),
            physics['effects'], physics['limit']['value'], position['start'],
            position['min'], position['max'], position['unit'], (stops['low'], stops['high']),
            d['samples'], d['duration']['value'],
            [ReceivedCommand(**c) for c in d['commands']])


@dataclass
class _Tally:
    """What the truth file reports besides the constants."""

    low: float
    high: float
    samples: int = 0
    commands: list[ReceivedCommand] = field(default_factory=list)


class JointSim:
    """The joint in real time: held input, physics, jittered samples, truth.

    Parameters
    ----------
    config : SimConfig
    start : float
        The caller's clock at the start [s] (``time.monotonic()``).
    """

    def __init__(self, config: SimConfig, start: float) -> None:
        config.check()
        self.config = config
        self.mechanism = MECHANISMS[config.mechanism]
        motor = self.mechanism.motor
        theta0 = self.mechanism.theta0(config.offset)
        self.plant = Plant(motor, config.effects(), theta0=theta0,
                           input_kind=config.input_kind)
        self.limit = (motor.V_supply if config.input_kind == 'voltage'
                      else motor.K * motor.V_supply / motor.R)
        """The drive's saturation: the supply [V], or the stall torque [N m or N]."""
        self.u = 0.0
        self.start = start
        self.now = start
        self._rng = np.random.default_rng(config.seed)
        self._period = 1.0 / config.rate_hz
        self._next = start + self._period
        self._last_due = start
        self.tally = _Tally(theta0, theta0)
        self._pending: list[Sample] = []

    @property
    def next_sample(self) -> float:
        """The instant of the next sample [s, the caller's clock]."""
        return self._next

    def command(self, now: float, value: float) -> float:
        """Hold ``value`` from ``now`` on (clipped at the drive's limit); return what is
        applied. The physics is first brought up to ``now`` under the previous input;
        the samples taken on the way are returned by the next :meth:`advance`."""
        self._pending += self._run(now)
        self.u = float(np.clip(value, -self.limit, self.limit))
        return self.u

    def advance(self, now: float) -> list[Sample]:
        """Integrate up to ``now``; return the samples taken since the last call."""
        samples = self._pending + self._run(now)
        self._pending = []
        return samples

    def _run(self, now: float) -> list[Sample]:
        samples = []
        while self._next <= now:
            self._step_to(self._next)
            samples.append(self._measure(self._next))
            spread = max(0.2, 1.0 + self.config.jitter * float(self._rng.standard_normal()))
            self._next += self._period * spread
        self._step_to(now)
        return samples

    def _step_to(self, t: float) -> None:
        if t > self.now:
            self.plant.advance(self.u, t - self.now)
            self.now = t
            pos = self.plant.position
            self.tally.low = min(self.tally.low, pos)
            self.tally.high = max(self.tally.high, pos)

    def _measure(self, t: float) -> Sample:
        s_pos, s_vel, s_eff = (self.config.noise * s for s in self.mechanism.noise)
        n = self._rng.standard_normal(3)
        effort = (self.plant.current if self.config.input_kind == 'voltage'
                  else self.plant.torque)
        latency = self.config.latency * float(self._rng.uniform(0.5, 1.5))
        due = max(self._last_due, t + latency)   # in order, as one publisher sends them
        self._last_due = due
        self.tally.samples += 1
        return Sample(t=t, due=due, position=self.plant.position + s_pos * float(n[0]),
                      velocity=self.plant.speed + s_vel * float(n[1]),
                      effort=effort + s_eff * float(n[2]))

    def record_command(self, now: float, wall: float, values: list[float],
                       applied: float | None) -> None:
        """Keep a received command: its receive time (``now`` on the caller's clock,
        ``wall`` the epoch [s]), its values, what was applied (None: ignored)."""
        self.tally.commands.append(ReceivedCommand(wall, now - self.start, list(values),
                                                   applied))

    def truth(self) -> JointTruth:
        """The truth so far (its JSON: :meth:`JointTruth.to_dict`)."""
        cfg = self.config
        mech = self.mechanism
        low, high = cfg.stops()
        return JointTruth(
            mech.name, mech.joint, cfg.input_kind,
            feedforward(mech.motor, cfg.effects(), cfg.input_kind),
            truth_units(cfg.input_kind, mech.linear), mech.motor, cfg.effects(), self.limit,
            mech.theta0(cfg.offset), self.tally.low, self.tally.high,
            'm' if mech.linear else 'rad', (_finite(low), _finite(high)), self.tally.samples,
            self.now - self.start, list(self.tally.commands))


def compile_physics(config: SimConfig) -> None:
    """Compile the integrator (seconds, once per process) on a throw-away plant, so that
    the first real step is not late."""
    mech = MECHANISMS[config.mechanism]
    Plant(mech.motor, config.effects(), mech.theta0(config.offset),
          config.input_kind).advance(0.0, 1e-3)


def truth_units(input_kind: str, linear: bool) -> dict[str, str]:
    """Units of kS, kV, kA, kG and offset for the drive and the joint."""
    length = 'm' if linear else 'rad'
    u = 'V' if input_kind == 'voltage' else ('N' if linear else 'N m')
    return {'kS': u, 'kV': f'{u} s/{length}', 'kA': f'{u} s^2/{length}', 'kG': u,
            'offset': 'rad'}


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def write_json(path: str, data: Mapping[str, Any]) -> None:
    """Write ``data`` to ``path`` atomically (a reader never sees half a file)."""
    tmp = f'{path}.tmp{os.getpid()}'
    with open(tmp, 'w', encoding='utf-8') as fh:
        json.dump(data, fh, indent=1, allow_nan=False)
    os.replace(tmp, path)


def sim_robot_args(mechanism: str = 'wheel', **params: object) -> list[str]:
    """The command line of the simulated robot, for ``launch(name, args)`` or
    :class:`motor_id.testing.procs.Process`.

    Parameters
    ----------
    mechanism : {'wheel', 'arm', 'elevator'}
    **params
        More parameters of :mod:`motor_id.testing.sim_robot` (``truth_file``, ``seed``,
        ``controller``, ``command_type``, ``input_kind``, ``rate_hz``, ``stamp``,
        ``stop_low``, ``stop_high``, ``joints`` as a list, ...).

    Examples
    --------
    >>> robot = launch('robot', sim_robot_args('arm', truth_file=str(tmp_path / 't.json')))
    >>> robot.wait_for(READY)
    """
    args = ['-m', 'motor_id.testing.sim_robot', '--ros-args', '-p', f'mechanism:={mechanism}']
    for name, value in params.items():
        if isinstance(value, bool):
            text = str(value).lower()
        elif isinstance(value, (list, tuple)):
            text = '[' + ','.join(f"'{v}'" for v in value) + ']'
        else:
            text = str(value)
        args += ['-p', f'{name}:={text}']
    return args


READY = r'sim_robot: \w+ ready'
"""Pattern of the log line printed once the robot publishes (for ``Process.wait_for``)."""


def read_truth(path: str | os.PathLike[str]) -> JointTruth:
    """The truth file's record (see :meth:`JointSim.truth`)."""
    with open(path, encoding='utf-8') as fh:
        return JointTruth.from_dict(json.load(fh))


