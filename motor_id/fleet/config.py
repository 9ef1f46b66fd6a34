"""The fleet configuration: every motor of a robot's recordings mapped, with the fit settings.

A YAML file::

    motors:
      wheel_left:  {input: /left_cmd,  speed: "/joint_states:velocity",
                    current: "/joint_states:effort", joint: wheel_left,
                    effort_is: current, resistance: 1.2}
      wheel_right: {...}
    defaults: {effort_is: current}       # optional: keys every motor starts from
    fit: {seed: 0, method: zoh}          # optional: Identifier settings
    drift: {h: 7.0}                      # optional: DriftRule settings

A motor takes the keys of ``motor-id fit --profile`` (input, speed, current, joint,
effort_is, align, input_kind, shift) plus ``resistance`` [Ohm] (required for a voltage
plant), ``resistance_tolerance`` [%], ``fix`` and ``bounds`` (mappings as ``--fix`` /
``--bounds`` take them) and ``type`` (motors of one type are siblings: they share the
drift test's day-to-day scatter and are held against each other; default: the motors
of the same name on the other robots).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import hashlib
import json
import math
from typing import Any

from motor_id.data.mapping import (
    check_keys,
    mapping_settings,
    PROFILE_KEYS,
    read_yaml,
    TopicMapping,
)
from motor_id.errors import ConfigError
from motor_id.fleet.drift import DriftRule
from motor_id.identify.settings import FitSettings

MOTOR_KEYS = tuple(k for k in PROFILE_KEYS if k != 'columns') + (
    'resistance', 'resistance_tolerance', 'fix', 'bounds', 'type')
FIT_KEYS = ('method', 'seed', 'population', 'generations', 'tie')
TOP_KEYS = ('motors', 'defaults', 'fit', 'drift')


@dataclass(frozen=True)
class MotorSpec:
    """One motor of the configuration: where its channels are and what is known of it."""

    name: str
    input: str | None = None
    speed: str | None = None
    current: str | None = None
    joint: str | None = None
    effort_is: str | None = None
    align: str = 'hold'
    input_kind: str | None = None
    shift: int | None = None
    resistance: float | None = None
    resistance_tolerance: float = 10.0
    fix: dict[str, float] = field(default_factory=dict)
    bounds: dict[str, Any] = field(default_factory=dict)
    type: str | None = None

    def mapping(self) -> TopicMapping:
        """The bag mapping of :mod:`motor_id.data.rosbag`."""
        d = asdict(self)
        d.pop('type')
        return mapping_settings(d, f'motor {self.name}')[0]

    @property
    def group(self) -> str:
        """The siblings' key: ``type`` when given, else the motor's name."""
        return self.type or self.name


@dataclass(frozen=True)
class FleetFit:
    """The ``fit:`` keys shared by every task (their settings hash as written)."""

    method: str = 'zoh'
    seed: int = 0
    population: int = 20
    generations: int = 160
    tie: bool | None = None

    def settings(self, motor: MotorSpec) -> FitSettings:
        """The :class:`~motor_id.identify.FitSettings` of ``motor``'s fit (validated)."""
        fixed = dict(motor.fix) or None
        return FitSettings(method=self.method, R_m=(fixed or {}).get('R_m', motor.resistance),
                           R_m_tolerance=motor.resistance_tolerance / 100.0, tie=self.tie,
                           population=self.population, generations=self.generations,
                           random_state=self.seed, fixed=fixed,
                           bounds=dict(motor.bounds) or None)


@dataclass(frozen=True)
class FleetConfig:
    """The parsed configuration."""

    motors: tuple[MotorSpec, ...]
    fit: FleetFit
    drift: DriftRule

    def groups(self) -> dict[str, str]:
        """Motor name -> siblings' key (:attr:`MotorSpec.group`)."""
        return {m.name: m.group for m in self.motors}

    def settings_hash(self, motor: MotorSpec, analyze: bool) -> str:
        """A short hash of everything that decides a motor's result (a changed configuration
        fits the recordings again); ``type`` is left out (it decides no fit)."""
        spec = asdict(motor)
        spec.pop('type')           # siblings' key: decides no fit
        text = json.dumps({'motor': spec, 'fit': asdict(self.fit),
                           'analyze': bool(analyze)}, sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:12]


def load_fleet_config(path: str) -> FleetConfig:
    """Read and check a fleet configuration.

    Parameters
    ----------
    path : str

    Returns
    -------
    FleetConfig

    Raises
    ------
    ConfigError
        Unreadable file, bad YAML, unknown keys, bad values; the message names the file,
        the motor and the key.
    """
    return parse_fleet_config(read_yaml(path), str(path))


def parse_fleet_config(data: Any, where: str = 'fleet configuration') -> FleetConfig:
    """A :class:`FleetConfig` from the parsed YAML (see :func:`load_fleet_config`)."""
    if not isinstance(data, dict) or not isinstance(data.get('motors'), dict) \
            or not data['motors']:
        raise ConfigError(f'{where}: expected "motors:" mapping each motor name to its '
                          f'topics, e.g. motors: {{wheel_left: {{input: /left_cmd, speed: '
                          f'"/joint_states:velocity", joint: wheel_left, resistance: 1.2}}}}')
    unknown = sorted(set(map(str, data)) - set(TOP_KEYS))
    if unknown:
        raise ConfigError(f'{where}: unknown key(s) {", ".join(unknown)} (known: '
                          f'{", ".join(TOP_KEYS)})')
    defaults = _keys(data.get('defaults') or {}, f'{where}: defaults', MOTOR_KEYS)
    motors = []
    for name, entry in data['motors'].items():
        entry = _keys(entry or {}, f'{where}: motor {name}', MOTOR_KEYS)
        motors.append(_motor(str(name), {**defaults, **entry}, f'{where}: motor {name}'))
    fit = _keys(data.get('fit') or {}, f'{where}: fit', FIT_KEYS)
    try:
        drift = DriftRule.from_dict(data.get('drift'))
    except (TypeError, ConfigError) as exc:
        raise ConfigError(f'{where}: {exc}') from None
    config = FleetConfig(tuple(motors), FleetFit(**fit), drift)
    for m in config.motors:   # every motor's fit settings, checked once, here
        try:
            config.fit.settings(m)
        except ConfigError as exc:
            raise ConfigError(f'{where}: motor {m.name}: {exc}', params=exc.params) from None
    return config


_keys = check_keys


def _motor(name: str, d: dict[str, Any], where: str) -> MotorSpec:
    for key in ('resistance', 'resistance_tolerance'):
        v = d.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not math.isfinite(v) or v <= 0):
            raise ConfigError(f'{where}: {key} must be a number > 0, got {v!r}')
    if d.get('type') is not None and not (isinstance(d['type'], str) and d['type']):
        raise ConfigError(f'{where}: type must be a name (motors with the same type are '
                          f'siblings), got {d["type"]!r}')
    for key in ('fix', 'bounds'):
        if not isinstance(d.get(key) or {}, dict):
            raise ConfigError(f'{where}: {key} must be a mapping NAME: VALUE')
    mapping, _ = mapping_settings(d, where)
    d.update(mapping.to_dict())
    return MotorSpec(name=name, **{k: v for k, v in d.items() if v is not None})
