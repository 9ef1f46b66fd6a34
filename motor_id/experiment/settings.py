"""What one experiment is asked to do: the joint, its topics, the limits and the plan.

The node's parameters and the CLI's flags both become one :class:`ExperimentSettings`,
checked here once, with one-line errors that say what to change.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

from motor_id.contracts import INPUT_KINDS
from motor_id.effects import MECHANISMS
from motor_id.errors import ConfigError

GRAVITY_MECHANISMS = tuple(m for m in MECHANISMS if m != 'simple')
"""Mechanisms that fall when commanded 0 (they need ``--travel``)."""
PLANS = ('sysid', 'prbs', 'multisine')
WATCHDOG = 0.25
"""The state watchdog's default [s]: the state silent, or stamped late, this long stops
the experiment."""
COMMAND_TYPES = ('multi_array', 'float64')
"""``std_msgs/Float64MultiArray`` (one value per joint of the controller) or
``std_msgs/Float64`` (the one joint)."""


@dataclass(frozen=True)
class Travel:
    """The window the joint may move in, ``[low, high]`` [rad, or m for an elevator]."""

    low: float
    high: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high)) or \
                not self.high > self.low:
            raise ConfigError(f'travel LO:HI needs finite LO < HI, got {self.low:g}:'
                              f'{self.high:g}')

    @classmethod
    def parse(cls, text: str) -> Travel:
        """``'LO:HI'`` -> Travel (``'-1.2:1.5'``)."""
        parts = str(text).split(':')
        try:
            if len(parts) != 2:
                raise ValueError
            low, high = float(parts[0]), float(parts[1])
        except ValueError:
            raise ConfigError(f'travel takes LO:HI (two numbers, e.g. -1.2:1.5), got '
                              f'{text!r}', params=('travel',)) from None
        return cls(low, high)

    @property
    def width(self) -> float:
        """HI - LO."""
        return self.high - self.low

    def text(self) -> str:
        """``'LO:HI'``."""
        return f'{self.low:g}:{self.high:g}'


@dataclass(frozen=True)
class ExperimentSettings:
    """One experiment on one joint.

    Attributes
    ----------
    joint : str
        The joint's name in ``sensor_msgs/JointState``.
    command_topic : str
        Where commands go, e.g. ``/forward_command_controller/commands``.
    max_command : float
        No command exceeds this magnitude [V, or N m / N].
    out : str
        Output folder (``recording.mcap``, ``report.json``, ``experiment.json``).
    controller_joints : tuple of str, optional
        The controller's joints in its order (``multi_array``); None: read the
        controller node's ``joints`` parameter.
    command_type : {'multi_array', 'float64'}
    state_topic : str
    input_kind : {'voltage', 'torque'}
    mechanism : {'simple', 'arm', 'elevator'}
    travel : Travel, optional
        Required for arm and elevator.
    max_speed : float, optional
        A test ends when the speed exceeds this [rad/s, or m/s].
    plan : {'sysid', 'prbs', 'multisine'}
    resistance : float, optional
        Armature resistance [Ohm] as measured (voltage plants).
    watchdog : float
        A state stream silent, or stamped late, for this long stops the experiment [s].
    time_scale : float
        Multiplies the plan's durations (1: the default plan; tests use less).
    seed : int
        Seed of the PRBS and multisine plans and of the analysis.
    identify : bool
        Analyse the recording at the end (False: record only).
    """

    joint: str
    command_topic: str
    max_command: float
    out: str
    controller_joints: tuple[str, ...] | None = None
    command_type: str = 'multi_array'
    state_topic: str = '/joint_states'
    input_kind: str = 'voltage'
    mechanism: str = 'simple'
    travel: Travel | None = None
    max_speed: float | None = None
    plan: str = 'sysid'
    resistance: float | None = None
    watchdog: float = WATCHDOG
    time_scale: float = 1.0
    seed: int = 0
    identify: bool = True

    def __post_init__(self) -> None:
        if not self.joint:
            raise ConfigError('joint: name the joint to identify (its name in JointState)')
        if not self.command_topic.strip('/'):
            raise ConfigError("command topic is empty; name the controller's topic, e.g. "
                              '/forward_command_controller/commands')
        if not (math.isfinite(self.max_command) and self.max_command > 0):
            raise ConfigError(f'max command must be a number > 0, got {self.max_command:g}')
        _choice('command type', self.command_type, COMMAND_TYPES)
        _choice('input kind', self.input_kind, INPUT_KINDS)
        _choice('mechanism', self.mechanism, MECHANISMS)
        _choice('plan', self.plan, PLANS)
        if self.mechanism in GRAVITY_MECHANISMS and self.travel is None:
            raise ConfigError(f'an {self.mechanism} falls when commanded 0: give its travel '
                              'window, travel LO:HI (it is never pushed past it)',
                              params=('travel',))
        if self.max_speed is not None and not self.max_speed > 0:
            raise ConfigError(f'max speed must be > 0, got {self.max_speed:g}')
        if self.resistance is not None and not self.resistance > 0:
            raise ConfigError(f'resistance must be > 0 Ohm, got {self.resistance:g}')
        if not 0.02 <= self.watchdog <= 5.0:
            raise ConfigError(f'watchdog must be in 0.02 .. 5 s, got {self.watchdog:g}')
        if not 0.05 <= self.time_scale <= 10.0:
            raise ConfigError(f'time scale must be in 0.05 .. 10, got {self.time_scale:g}')
        if self.controller_joints is not None:
            if self.joint not in self.controller_joints:
                raise ConfigError(f'joint {self.joint!r} is not among the controller joints '
                                  f'{", ".join(self.controller_joints) or "(none)"}')
            if len(set(self.controller_joints)) != len(self.controller_joints):
                raise ConfigError('controller joints repeat a name: '
                                  f'{", ".join(self.controller_joints)}')

    @classmethod
    def from_parameters(cls, p: Mapping[str, Any]) -> ExperimentSettings:
        """Settings from the node's parameter values (0 or '' for an unset option)."""
        travel = str(p.get('travel', '')).strip()
        return cls(
            joint=str(p['joint']), command_topic=str(p['command_topic']),
            max_command=float(p['max_command']), out=str(p['out']),
            controller_joints=parse_joints(str(p.get('controller_joints', ''))),
            command_type=str(p.get('command_type', 'multi_array')),
            state_topic=str(p.get('state_topic', '/joint_states')),
            input_kind=str(p.get('input_kind', 'voltage')),
            mechanism=str(p.get('mechanism', 'simple')),
            travel=Travel.parse(travel) if travel else None,
            max_speed=float(p['max_speed']) if p.get('max_speed') else None,
            plan=str(p.get('plan', 'sysid')),
            resistance=float(p['resistance']) if p.get('resistance') else None,
            watchdog=float(p.get('watchdog', WATCHDOG)),
            time_scale=float(p.get('time_scale', 1.0)), seed=int(p.get('seed', 0)),
            identify=bool(p.get('identify', True)))

    @property
    def linear(self) -> bool:
        """An elevator moves in m, m/s and N."""
        return self.mechanism == 'elevator'

    @property
    def controller_node(self) -> str:
        """The controller node that owns the command topic (``/arm_controller`` of
        ``/arm_controller/commands``): ros2_control runs each controller as a node named
        after it."""
        topic = '/' + self.command_topic.strip('/')
        node = topic.rsplit('/', 1)[0]
        if not node:
            raise ConfigError(f'command topic {topic} has no controller namespace: give '
                              'controller_joints, or command_type float64',
                              params=('controller_joints', 'command_type'))
        return node


def _choice(what: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ConfigError(f'{what} must be one of {", ".join(choices)}, got {value!r}')


def parse_joints(text: str) -> tuple[str, ...] | None:
    """``'a,b,c'`` -> ``('a', 'b', 'c')``; empty -> None."""
    names = tuple(n.strip() for n in str(text).split(',') if n.strip())
    return names or None
