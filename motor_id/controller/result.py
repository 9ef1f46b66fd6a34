"""What a controller design produced: feedforward constants, time constants and PI loops,
each number with its error bar, with the design's JSON and table."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from motor_id.errors import ConfigError
from motor_id.records import optional, Record


@dataclass(frozen=True)
class Quantity(Record):
    """A designed number: value and std (None: the parameters it needs are unknown, or no
    covariance was given), and its unit where the entry states one."""

    value: float | None
    std: float | None
    unit: str | None = optional()


@dataclass(frozen=True)
class Feedforward(Record):
    """WPILib SysId's constants (``kG`` and an arm's ``offset`` with a joint's gravity)."""

    kS: Quantity  # noqa: N815 - WPILib's symbols
    kV: Quantity  # noqa: N815
    kA: Quantity  # noqa: N815
    units: dict[str, str]
    convention: str
    kG: Quantity | None = optional()  # noqa: N815
    offset: Quantity | None = optional()


@dataclass(frozen=True)
class TimeConstants(Record):
    """The electrical and mechanical time constants [s]."""

    electrical: Quantity
    mechanical: Quantity


@dataclass(frozen=True)
class LoopDesign(Record):
    """One PI loop: its gains, designed bandwidth and its check on the full model."""

    kp: Quantity
    ki: Quantity
    bandwidth_hz: float | None
    phase_margin_deg: float | None
    crossover_hz: float | None
    gain_margin_db: float | None
    closed_loop_bandwidth_hz: float | None
    closed_loop_stable: bool | None
    units: dict[str, str]
    design: str
    form: str = 'u = kp e + ki integral(e dt)'


@dataclass(frozen=True)
class PiLoops(Record):
    """The cascade's loops (None: the plant has no such loop)."""

    current: LoopDesign | None
    speed: LoopDesign | None


@dataclass
class ControllerDesign:
    """Feedforward constants, time constants and cascaded PI gains, each with an error bar
    (a :class:`Quantity`)."""

    input_kind: str
    feedforward: Feedforward
    time_constants: TimeConstants
    pi: PiLoops
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: keys ``feedforward, time_constants, pi, notes`` (the contract)."""
        return {'feedforward': self.feedforward.to_dict(),
                'time_constants': self.time_constants.to_dict(),
                'pi': self.pi.to_dict(), 'notes': list(self.notes)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], input_kind: str = 'voltage'
                  ) -> ControllerDesign:
        """The design of a ``to_dict()`` (ConfigError for another shape)."""
        if not isinstance(d, dict) or set(d) != {'feedforward', 'time_constants', 'pi',
                                                  'notes'}:
            raise ConfigError('design must be a ControllerDesign or its to_dict()')
        try:
            return cls(input_kind=input_kind,
                       feedforward=Feedforward.from_dict(d['feedforward']),
                       time_constants=TimeConstants.from_dict(d['time_constants']),
                       pi=PiLoops.from_dict(d['pi']), notes=list(d['notes']))
        except (KeyError, TypeError, AttributeError) as exc:
            raise ConfigError(f'design must be a ControllerDesign or its to_dict(): '
                              f'{exc}') from exc

    def summary(self) -> str:
        """Return a plain-text table for people (one string, lines separated by newlines)."""
        ff, tc = self.feedforward, self.time_constants
        lines = [f'controller design ({self.input_kind} plant; {ff.convention})',
                 f'{"quantity":<14}{"value":>13}{"std":>12}  units']
        for k, q in (('kS', ff.kS), ('kV', ff.kV), ('kA', ff.kA)):
            lines.append(_row(k, q, ff.units[k]))
        for k, g in (('kG', ff.kG), ('offset', ff.offset)):   # a joint's gravity
            if g is not None:   # kG in input units, as kS
                lines.append(_row(k, g, g.unit or ff.units.get(k, ff.units['kS'])))
        lines.append(_row('tau_e', tc.electrical, 's'))
        lines.append(_row('tau_m', tc.mechanical, 's'))
        for loop, d in (('current', self.pi.current), ('speed', self.pi.speed)):
            if d is None:
                lines.append(f'{loop + " PI":<14}{"-":>13}{"-":>12}  (no {loop} loop)')
                continue
            lines.append(_row(f'{loop} kp', d.kp, d.units['kp']))
            lines.append(_row(f'{loop} ki', d.ki, d.units['ki']))
            lines.append(f'{"":<14}designed {format_number(d.bandwidth_hz)} Hz; checked: '
                         f'crossover {format_number(d.crossover_hz)} Hz, phase margin '
                         f'{format_number(d.phase_margin_deg)} deg')
        lines.append('notes:')
        lines.extend(f'- {n}' for n in self.notes)
        return '\n'.join(lines)


def format_number(x: float | None) -> str:
    """A number for the table ("-" for None)."""
    return '-' if x is None else f'{x:.4g}'


def _row(name: str, entry: Quantity, unit: str) -> str:
    return f'{name:<14}{format_number(entry.value):>13}{format_number(entry.std):>12}  {unit}'


