"""The catalogue of named effects: each physical term beyond the linear DC-motor model.

Each effect lives in one module of this package (``motor_id/effects/<name>.py``), whose
:class:`EffectSpec` entry holds everything about it: its equation and parameters
(:class:`EffectParam`: unit, default, allowed range, and the analysis' start grid and
search range in units of a data scale of :data:`SCALES`), and its hooks into the
simulator, the inverse dynamics, the analysis and the controller (see
:class:`EffectSpec`). The simulator, the fitter and the discrepancy analysis all read this
one catalogue, :data:`EFFECTS`, by the entries' attributes and the parameters' roles
(:data:`ROLES`), never by an effect's name; :mod:`motor_id.model` holds the linear plant
they extend.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
import math
from typing import Any

from motor_id.effects import (
    arm_gravity,
    asymmetric_friction,
    brush_drop,
    coulomb_friction,
    current_quantization,
    dead_zone,
    elevator_gravity,
    input_delay,
    load_torque,
    quadratic_load,
    resistance_drift,
    resonance,
    sensor_lag,
    speed_quantization,
    start_latency,
    stiction,
    stribeck_friction,
    voltage_saturation,
)
from motor_id.effects.signals import interval_mean, on_grid
from motor_id.effects.spec import (
    as_batch,
    Confusion,
    EffectParam,
    EffectSpec,
    ElectricalTerm,
    FRICTION_COLUMNS,
    InputMap,
    KernelArg,
    MechanicalTerm,
    OutputMap,
    PositionTerm,
    ROLES,
    SCALES,
)
from motor_id.errors import ConfigError

__all__ = ['as_batch', 'Confusion', 'count_reading', 'EFFECTS', 'EffectParam', 'EffectSpec',
           'ElectricalTerm', 'FRICTION_COLUMNS', 'InputMap', 'interval_mean', 'KernelArg',
           'MECHANISMS', 'mechanism_effect', 'MechanicalTerm', 'on_grid', 'OutputMap',
           'parse_effect_args', 'PositionTerm', 'role_keys', 'role_params', 'role_value',
           'ROLES', 'SCALES', 'validate_effects']

EFFECTS = {m.SPEC.name: m.SPEC for m in (
    coulomb_friction, asymmetric_friction, stribeck_friction, stiction, load_torque,
    quadratic_load, brush_drop, dead_zone, input_delay, voltage_saturation, sensor_lag,
    speed_quantization, current_quantization, resistance_drift, resonance, start_latency,
    elevator_gravity, arm_gravity,
)}
"""The catalogue of named effects, in the order the analysis names them when two explain a
record equally well (the more common first); parameter ranges are the allowed ranges."""


MECHANISMS = ('simple',) + tuple(s.mechanism for s in EFFECTS.values() if s.mechanism)
"""What a joint moves: ``'simple'`` (a shaft or wheel, no gravity) or a mechanism whose
gravity is an effect (:attr:`EffectSpec.mechanism`): ``'elevator'``, ``'arm'``."""


def mechanism_effect(mechanism: str) -> str:
    """The effect that is ``mechanism``'s gravity ('' for ``'simple'``).

    Raises
    ------
    ConfigError
        An unknown mechanism.
    """
    if mechanism not in MECHANISMS:
        raise ConfigError(f'unknown mechanism {mechanism!r}; choose from {list(MECHANISMS)}',
                          params=('mechanism',))
    return next((n for n, s in EFFECTS.items() if s.mechanism == mechanism), '')


def role_params(role: str, scale: str | None = None) -> Iterator[tuple[EffectSpec, EffectParam]]:
    """``(spec, param)`` of every parameter with ``role`` (and data ``scale``, when given),
    in catalogue order."""
    for spec in EFFECTS.values():
        for p in spec.params:
            if p.role == role and (scale is None or p.scale == scale):
                yield spec, p


def role_keys(effects: Mapping[str, Any], role: str, scale: str | None = None) -> list[str]:
    """``['effect.param', ...]`` of the parameters with ``role`` among ``effects``."""
    return [f'{spec.name}.{p.name}' for spec, p in role_params(role, scale)
            if spec.name in effects]


def role_value(effects: Mapping[str, Mapping[str, Any]], role: str, default: Any = 0.0,
               scale: str | None = None) -> Any:
    """The value of the parameter with ``role`` among ``effects`` (the sum where several
    effects have one), ``default`` where none has it."""
    found = [effects[spec.name][p.name] for spec, p in role_params(role, scale)
             if p.name in (effects.get(spec.name) or {})]
    if not found:
        return default
    total = found[0]
    for v in found[1:]:
        total = total + v
    return total


def count_reading() -> dict[str, dict[str, float]]:
    """The speed read as an encoder's count difference (the mean over each sample period)
    without its grid: ``{effect: {param: value}}`` of the effect with a ``'counted'``
    parameter, its grid step 0."""
    return {spec.name: {q.name: (1.0 if q.role == 'counted' else 0.0) for q in spec.params}
            for spec, _ in role_params('counted')}


def validate_effects(effects: Mapping[str, Mapping[str, float] | None] | None,
                     input_kind: str = 'voltage') -> dict[str, dict[str, float]]:
    """Check an ``{effect: {param: value}}`` mapping against :data:`EFFECTS`.

    Missing parameters take their defaults. Returns a new, complete dict.
    """
    out: dict[str, dict[str, float]] = {}
    for name, values in (effects or {}).items():
        if name not in EFFECTS:
            raise ConfigError(f'unknown effect {name!r}; known effects: {sorted(EFFECTS)}')
        spec = EFFECTS[name]
        if input_kind not in spec.kinds:
            raise ConfigError(f'effect {name!r} does not apply to a {input_kind}-input plant')
        values = dict(values or {})
        unknown = set(values) - {p.name for p in spec.params}
        if unknown:
            raise ConfigError(f'effect {name!r} has no parameter(s) {sorted(unknown)}; '
                              f'it takes {[p.name for p in spec.params]}')
        full: dict[str, float] = {}
        for p in spec.params:
            v = float(values.get(p.name, p.default))
            if not (math.isfinite(v) and p.low <= v <= p.high):
                raise ConfigError(f'effect {name}.{p.name} = {v} is outside '
                                  f'[{p.low}, {p.high}] {p.unit}')
            full[p.name] = v
        out[name] = full
    return out


def parse_effect_args(items: Iterable[str] | None) -> dict[str, dict[str, float]]:
    """Parse CLI items ``NAME`` or ``NAME=VALUE`` or ``NAME.PARAM=VALUE`` into effects.

    ``NAME=VALUE`` sets the effect's first parameter.
    """
    effects: dict[str, dict[str, float]] = {}
    for item in items or ():
        key, _, value = item.partition('=')
        name, _, pname = key.partition('.')
        if name not in EFFECTS:
            raise ConfigError(f'unknown effect {name!r}; known effects: {sorted(EFFECTS)}')
        entry = effects.setdefault(name, {})
        if value:
            pname = pname or EFFECTS[name].params[0].name
            try:
                entry[pname] = float(value)
            except ValueError:
                raise ConfigError(f'effect value {item!r} is not a number') from None
    return effects
