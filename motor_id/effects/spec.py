"""What an effect's entry holds: its parameters, and the hooks that put it in the simulator,
the inverse dynamics, the analysis and the controller.

:class:`EffectSpec` is one entry of :data:`motor_id.effects.EFFECTS`; each effect's own
module (``motor_id/effects/<name>.py``) writes it. Other code reads an entry's attributes
(``spec.input_map``, ``spec.friction_term``, ``spec.confused_with``, a parameter's
``role``), never an effect's name: a new effect is one new module.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from motor_id.contracts import INPUT_KINDS
from motor_id.errors import ConfigError

__all__ = ['as_batch', 'Confusion', 'EffectParam', 'EffectSpec', 'ElectricalTerm',
           'FRICTION_COLUMNS', 'KernelArg', 'MechanicalTerm', 'OutputMap', 'InputMap',
           'PositionTerm', 'ROLES', 'SCALES']


SCALES = ('one', 'torque', 'input', 'speed', 'torque/speed', 'torque/speed^2', 'record',
          'sample',
          'per_record', 'per_sample', 'heating', 'max_delay', 'current', 'lag_floor')
"""Data scales an effect parameter's start grid and search range are stated in.

The analysis measures them on each recording: ``torque`` the stall torque K_T A / R_m
(the input amplitude A for a torque plant), ``input`` A, ``speed`` the top speed,
``torque/speed`` and ``torque/speed^2`` their ratios, ``record`` the record length and
``sample`` the sample period [s], ``per_record`` / ``per_sample`` their inverses [Hz], ``heating``
R_m / (i_rms^2 record) [Ohm/(A^2 s)], ``max_delay`` the longest delay tried [samples],
``current`` the current's spread [A], ``lag_floor`` the shortest sensor lag that is more
than the sampling itself (half a sample period; a whole one when the speed is counted
by an encoder, whose count difference averages over the period); ``one`` is 1.
"""

ROLES = {
    'kS': "static friction as the feedforward's kS: a dry-friction torque (times R_m / K_T "
          'on a voltage plant) or a voltage drop that opposes the motion',
    'kS_extra_negative': 'the extra dry friction of negative motion (Fc- - Fc+)',
    'kV_extra_negative': 'the extra viscous friction of negative motion (Fv- - Fv+)',
    'load': 'a constant load torque (or force offset)',
    'dead_band': 'an input dead band [input unit]',
    'static': 'the break-away (static) friction level',
    'stribeck_speed': 'the speed over which friction falls from the static level',
    'delay': 'a transport delay of the input [samples]',
    'grid': "a sensor's quantisation step (a validation simulates without it)",
    'counted': 'the speed read as a count difference (1) or at the sample (0)',
    'kG': "gravity as the feedforward's kG: the gravity torque (or force) of a joint (times "
          'R_m / K_T on a voltage plant)',
    'offset': 'the angle from the encoder zero to horizontal [rad] (an arm: its gravity is '
              'kG cos(theta + offset))',
}
"""What a parameter is to the code outside its effect (:attr:`EffectParam.role`): the
friction summary, the feedforward constants, the candidate's evidence, the validation."""

FRICTION_COLUMNS = 5
"""Columns of the simulation kernel's dry-friction table (:attr:`EffectSpec.friction_term`):
0 the Coulomb level of positive motion, 1 that of negative motion, 2 the extra viscous
friction of negative motion, 3 the static (break-away) level, 4 the Stribeck speed."""


def as_batch(value: ArrayLike, P: int) -> np.ndarray:
    """``value`` (a scalar or a (P,) array) as a float array of shape (P,)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.full(P, float(arr))
    if arr.shape != (P,):
        raise ConfigError(f'batch parameter has shape {arr.shape}, expected ({P},)')
    return arr.astype(float)


def _at_scale(end: float | tuple[float, str], scale: str, scales: Mapping[str, float]
              ) -> float:
    """An end point ``m`` (in units of ``scale``) or ``(m, other_scale)`` as a number."""
    if isinstance(end, tuple):
        return float(end[0]) * scales[end[1]]
    return float(end) * scales[scale]


@dataclass(frozen=True)
class EffectParam:
    """One parameter of an effect: name, unit, default, allowed range, analysis grid.

    ``low`` / ``high`` are the allowed range (any motor). ``scale`` names the data scale
    of :data:`SCALES` that ``start`` (``(first, last, n)``: the analysis' start grid)
    and ``search`` (``(low, high)``: its search range) are multiples of; an end point
    may also be ``(multiple, other_scale)``. ``spacing`` is ``'log'``, ``'linear'``,
    ``'signed'`` (a log grid of both signs) or ``'integer'`` (every whole number from
    ``first`` to ``last``; the parameter is then found by the grid, never refined).
    ``role`` (a key of :data:`ROLES`, or '') says what the parameter is to other code;
    ``refined`` False: a fit with the effect asked for (``--effect``) keeps it at the
    given value (a whole number of samples, a grid step). ``fraction`` True: a number of
    samples found on the ``'integer'`` grid, which the simulation-error stage then refines
    between samples (its effect's hooks take a fraction of a sample: a latency is rarely
    a whole number of them).
    """

    name: str
    unit: str
    default: float
    low: float
    high: float
    scale: str = 'one'
    start: tuple = ()
    search: tuple = ()
    spacing: str = 'log'
    role: str = ''
    refined: bool = True
    fraction: bool = False

    def start_values(self, scales: Mapping[str, float]) -> np.ndarray:
        """The start grid on one recording's scales (``{scale: value}``), an array."""
        first, last, n = self.start
        a, b = _at_scale(first, self.scale, scales), _at_scale(last, self.scale, scales)
        if self.spacing == 'integer':
            return np.arange(max(1, int(round(a))), max(2, int(round(b))) + 1, dtype=float)
        if self.spacing == 'linear':
            return np.linspace(a, b, n)
        a = max(a, 1e-300)
        v = np.geomspace(a, max(b, a), n)
        return np.concatenate([v, -v]) if self.spacing == 'signed' else v

    def search_range(self, scales: Mapping[str, float]) -> tuple[float, float]:
        """``(low, high)`` search range on one recording's scales, inside the allowed one."""
        if not self.search:
            return (self.low, self.high)
        lo = _at_scale(self.search[0], self.scale, scales)
        hi = _at_scale(self.search[1], self.scale, scales)
        lo, hi = max(lo, self.low), min(hi, self.high)
        return (lo, hi) if hi > lo else (self.low, self.high)


Values = Mapping[str, np.ndarray]
"""An effect's parameters in a batch of P members: ``{param: (P,) array}``."""


@dataclass(frozen=True)
class InputMap:
    """The effect acts on the input before the dynamics: ``apply(u, values)`` takes the
    (P, N) input (a copy it may change in place) and returns the input the plant sees.
    Input maps apply in ``rank`` order (a delay first: it reaches back in time)."""

    rank: int
    apply: Callable[[np.ndarray, Values], np.ndarray]


@dataclass(frozen=True)
class OutputMap:
    """The effect changes what the sensor of :attr:`EffectSpec.channel` reports:
    ``apply(y, values)`` maps the (P, N) simulated channel to the reading."""

    apply: Callable[[np.ndarray, Values], np.ndarray]


@dataclass(frozen=True)
class KernelArg:
    """A parameter the simulation kernel takes as its argument ``arg`` (one value per
    member), ``absent`` where the effect is not in the model."""

    arg: str
    param: str
    absent: float = 0.0


@dataclass(frozen=True)
class MechanicalTerm:
    """The effect's regressor in the mechanical equation error ``u = J dw/dt + B w + ...``
    (inverse dynamics): the column of its parameter ``param`` from the filtered speed,
    the term as text, and whether the samples near rest are left out (dry friction is
    anything up to its level at rest)."""

    param: str
    text: str
    column: Callable[[np.ndarray], np.ndarray]
    away_from_rest: bool = False


@dataclass(frozen=True)
class ElectricalTerm:
    """The effect's regressor in the electrical equation error ``V = R_m i + L_m di/dt +
    K_b w + ...``: ``columns(t, u, i)`` gives ``[(grid value or None, column), ...]``
    (unfiltered), ``start(value, coefficient)`` the effect's parameters from the best
    column (the start of a refinement; ``{}`` for none)."""

    columns: Callable[[np.ndarray, np.ndarray, np.ndarray], list[tuple[float | None, Any]]]
    start: Callable[[float | None, float], dict[str, float]]


@dataclass(frozen=True)
class PositionTerm:
    """The effect's regressors of the measured position in the equation error ``u = kS
    sgn(w) + kV w + kA dw/dt + ...`` (a joint's gravity, in input units):
    ``columns(position)`` gives the columns, ``params(coefficients, torque_per_input)``
    the effect's parameters from their coefficients (a start for the fit)."""

    columns: Callable[[np.ndarray], list[np.ndarray]]
    params: Callable[[np.ndarray, float], dict[str, float]]


@dataclass(frozen=True)
class Confusion:
    """Another effect this one can be taken for, and the experiment that tells them apart
    (``torque_experiment`` where a torque-input plant needs another). ``one_way``: on a
    record whose speed keeps one sign the two act alike (one term)."""

    other: str
    experiment: str
    torque_experiment: str = ''
    one_way: bool = False


@dataclass(frozen=True)
class EffectSpec:
    """A named physical term that extends the linear model.

    ``category`` is ``'dynamic'`` (the term changes the motion and is found by fitting)
    or ``'measurement'`` (it changes only what a sensor reports on ``channel`` and is
    found from the measured values themselves). ``min_fraction`` maps a parameter name
    to ``(multiple, scale)``: below that the fitted term is not plausible as the named
    effect (a resistance that settles within a few samples is a wrong R_m, not heating).
    ``extends`` names the effect this one refines (asymmetric or Stribeck friction refine
    Coulomb friction): it is tried only once that effect is in the model, by the
    simulation-error stage of the analysis, never as a first explanation.
    ``simulation_only`` effects, too, only that stage tries.

    The hooks (all optional) put the effect in each part of the project:

    - simulator (:mod:`motor_id.simulate`): ``input_map``, ``friction_term`` (fills its
      columns of the kernel's dry-friction table, :data:`FRICTION_COLUMNS`, in place),
      ``kernel_args``, ``output_map``; ``plant_term`` (its values change the linear
      plant's matrices, :func:`motor_id.model.continuous_matrices`); ``heating`` (the
      kernel needs the interval integrals of the current);
    - inverse dynamics: ``mechanical_term``, ``electrical_term``;
    - analysis: ``confused_with``, ``excludes`` (never in one model with these),
      ``check`` (a plausibility rule beyond ``min_fraction``, run before them: a reason
      or ''), ``shows_offset`` (the steady-state map shows it as a zero-speed input
      offset both ways), ``named_on_offset`` (named first when it does, as good held out),
      ``stage_rule`` (when the simulation-error stage tries it: ``'always'``,
      ``'input_leaves_zero'``, ``'position_and_speed'``), ``stage_start``
      (``(drive_scale, coulomb)`` -> its start there: the largest drive torque, the
      model's Coulomb level);
    - a joint: ``mechanism`` (the gravity of that mechanism: in the base model of a record
      of it, fitted from the start, never a candidate), ``position`` (it reads the joint's
      position: the record's measured one, exogenous like the input, else the integrated
      speed), ``position_term`` (its start from the equation error);
    - controller and reports: each parameter's ``role``.
    """

    name: str
    equation: str
    params: tuple
    kinds: tuple = INPUT_KINDS
    description: str = ''
    category: str = 'dynamic'
    channel: str = ''
    min_fraction: tuple = ()
    extends: str = ''
    simulation_only: bool = False
    """Tried only by the simulation-error stage: what shows it is a whole run's response
    from its start, which one-step errors never see (a drive's enable latency)."""
    input_map: InputMap | None = None
    friction_term: Callable[[np.ndarray, Values], None] | None = None
    kernel_args: tuple[KernelArg, ...] = ()
    output_map: OutputMap | None = None
    plant_term: bool = False
    heating: bool = False
    mechanical_term: MechanicalTerm | None = None
    electrical_term: ElectricalTerm | None = None
    confused_with: tuple[Confusion, ...] = ()
    excludes: tuple[str, ...] = ()
    check: Callable[[Mapping[str, float], Mapping[str, float]], str] | None = None
    shows_offset: bool = False
    named_on_offset: bool = False
    stage_rule: str = ''
    stage_start: Callable[[float, float], dict[str, float]] | None = None
    mechanism: str = ''
    position: bool = False
    position_term: PositionTerm | None = None

    def defaults(self) -> dict[str, float]:
        """Return ``{param: default}``."""
        return {p.name: p.default for p in self.params}

    def param(self, name: str) -> EffectParam:
        """The parameter called ``name``."""
        return {p.name: p for p in self.params}[name]

    def batch(self, values: Mapping[str, ArrayLike], P: int) -> dict[str, np.ndarray]:
        """Every parameter as a (P,) array: ``values``, its default where missing."""
        return {p.name: as_batch(values.get(p.name, p.default), P) for p in self.params}

    def start_grid(self, scales: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Start points ``{param: array}`` (the Cartesian product of the param grids)."""
        axes = [p.start_values(scales) for p in self.params]
        mesh = np.meshgrid(*axes, indexing='ij')
        return {p.name: m.ravel() for p, m in zip(self.params, mesh, strict=True)}

    def implausible(self, values: Mapping[str, float], scales: Mapping[str, float]) -> str:
        """A one-line reason when fitted ``values`` are not plausible, else ``''``."""
        for name, (multiple, scale) in self.min_fraction:
            limit = multiple * scales[scale]
            if name in values and values[name] < limit:
                return (f'{self.name}.{name} = {values[name]:.4g} is below '
                        f'{multiple:g} x {scale} ({limit:.4g})')
        return ''
