"""The DC motor model: parameters, named effect terms, continuous dynamics, discretisation.

Units are SI throughout: J [kg m^2], K_T [N m/A], K_b [V s/rad], B [N m s/rad],
L_m [H], R_m [Ohm], speed [rad/s], current [A], voltage [V], torque [N m].

Two plant kinds share this module:

* ``'voltage'``: the armature-voltage-driven motor, x = [speed, current],
  ``J dw/dt = K_T i - B w + tau_extra``, ``L_m di/dt = V - R_m i - K_b w``.
* ``'torque'``: a current- or torque-controlled drive seen from its mechanical side,
  x = [speed], ``J dw/dt = u - B w + tau_extra`` with u the applied torque (or force:
  then J is a mass and B a viscous coefficient in N s/m).

Every non-linear or extra physical term is a named *effect* in :data:`EFFECTS`; the
simulator (card), the fitter and the discrepancy analysis all use this one catalogue.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
import functools
import json
import math
import os
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from motor_id.contracts import INPUT_KINDS, UNITS
from motor_id.errors import ConfigError
from motor_id.linalg import expm

PARAM_NAMES = ('J', 'K_T', 'K_b', 'B', 'L_m', 'R_m')
PARAM_UNITS = {name: UNITS[name] for name in PARAM_NAMES}
MECHANICAL_PARAMS = ('J', 'B')
DISCRETISATIONS = ('zoh', 'euler')
"""How the continuous model becomes a discrete one (the fit's methods add 'paper')."""


@dataclass(frozen=True)
class MotorParams:
    """Physical parameters of a permanent-magnet DC motor (SI units)."""

    J: float = 0.052
    K_T: float = 0.66
    K_b: float = 0.64
    B: float = 0.002
    L_m: float = 0.0345
    R_m: float = 2.3

    def __post_init__(self) -> None:
        for name in PARAM_NAMES:
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value)):
                raise ConfigError(f'parameter {name} must be a finite number, got {value!r}')
            if value <= 0:
                raise ConfigError(f'parameter {name} must be > 0, got {value}')

    def to_dict(self) -> dict[str, float]:
        """Return the parameters as a plain ``{name: float}`` dict."""
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: Mapping[str, float]) -> MotorParams:
        """Build from a dict; unknown keys raise :class:`ConfigError`."""
        unknown = set(values) - set(PARAM_NAMES)
        if unknown:
            raise ConfigError(
                f'unknown motor parameter(s) {sorted(unknown)}; expected {list(PARAM_NAMES)}')
        return cls(**{k: float(v) for k, v in values.items()})


PAPER_MOTOR = MotorParams()
"""The motor of the paper: R_m 2.3, L_m 34.5 mH, J 0.052, K_T 0.66, K_b 0.64, B 0.002."""


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

    def defaults(self) -> dict[str, float]:
        """Return ``{param: default}``."""
        return {p.name: p.default for p in self.params}

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


EFFECTS = {e.name: e for e in (
    EffectSpec('coulomb_friction', 'tau -= T_c sgn(w); stuck (w = 0) while |drive| <= T_c',
               (EffectParam('T_c', 'N m', 0.05, 0.0, 1e3, 'torque', (1e-4, 0.5, 16),
                            (0.0, 2.0)),),
               description='dry friction with stiction at zero speed'),
    EffectSpec('asymmetric_friction', 'Coulomb level T_c + dT_c and viscous B + dB when '
               'the motion is negative (w < 0); T_c and B when positive',
               (EffectParam('dT_c', 'N m', 0.0, -1e3, 1e3, 'torque', (1e-3, 0.2, 4),
                            (-2.0, 2.0), 'signed'),
                EffectParam('dB', 'N m s/rad', 0.0, -1e5, 1e5, 'torque/speed', (1e-3, 0.3, 4),
                            (-2.0, 2.0), 'signed')),
               description='direction-dependent dry and viscous friction (Fc+/Fc-, Fv+/Fv-)',
               extends='coulomb_friction'),
    EffectSpec('stribeck_friction', 'dry friction T_c + (T_s - T_c) exp(-(w / v_s)^2); '
               'break-away at T_s',
               (EffectParam('T_s', 'N m', 0.08, 0.0, 1e3, 'torque', (0.01, 0.6, 6), (0.0, 2.0)),
                EffectParam('v_s', 'rad/s', 0.05, 0.0, 1e4, 'speed', (0.003, 0.3, 6),
                            (0.0, 1.0))),
               description='friction falling from a static level to the Coulomb level as '
               'the speed rises (Stribeck curve)', extends='coulomb_friction'),
    EffectSpec('stiction', 'stuck (w = 0) while |drive| <= T_s; moving: Coulomb T_c',
               (EffectParam('T_s', 'N m', 0.08, 0.0, 1e3, 'torque', (0.01, 0.6, 8),
                            (0.0, 2.0)),),
               description='break-away torque above the Coulomb level at zero speed',
               extends='coulomb_friction'),
    EffectSpec('load_torque', 'tau -= T_L',
               (EffectParam('T_L', 'N m', 0.05, -1e3, 1e3, 'torque', (1e-4, 0.5, 12),
                            (-2.0, 2.0), 'signed'),),
               description='constant load torque (or force offset)'),
    EffectSpec('quadratic_load', 'tau -= k_q w |w|',
               (EffectParam('k_q', 'N m s^2/rad^2', 2e-4, 0.0, 1e3, 'torque/speed^2',
                            (1e-4, 1.0, 16), (0.0, 2.0)),),
               description='fan or pump load growing with the square of speed'),
    EffectSpec('brush_drop', 'V -= V_b sgn(i)',
               (EffectParam('V_b', 'V', 0.6, 0.0, 100.0, 'input', (1e-3, 0.3, 14),
                            (0.0, 1.0)),), kinds=('voltage',),
               description='constant voltage drop across the brushes'),
    EffectSpec('dead_zone', 'V_eff = 0 if |V| <= V_dz else V - V_dz sgn(V)',
               (EffectParam('V_dz', 'V (input unit)', 0.8, 0.0, 1e3, 'input',
                            (5e-3, 0.6, 14), (0.0, 1.0)),),
               description='the driver passes nothing below V_dz'),
    EffectSpec('input_delay', 'V_eff(k) = V(k - d)',
               (EffectParam('d', 'samples', 3, 0, 500, 'one', (1, (1.0, 'max_delay'), 0),
                            (), 'integer'),),
               description='transport delay of whole samples'),
    EffectSpec('voltage_saturation', 'V_eff = clip(V, -V_max, V_max)',
               (EffectParam('V_max', 'V (input unit)', 6.0, 0.0, 1e4, 'input',
                            (0.15, 0.98, 16), (0.01, 2.0), 'linear'),),
               description='the amplifier clips the input'),
    EffectSpec('sensor_lag', 'tau_s dy/dt = w - y (speed sensor first-order filter)',
               (EffectParam('tau_s', 's', 0.05, 0.0, 10.0, 'sample', (0.5, (0.1, 'record'), 16),
                            (0.0, (0.2, 'record'))),),
               description='first-order lag of the speed measurement',
               min_fraction=(('tau_s', (1.0, 'lag_floor')),)),
    EffectSpec('speed_quantization', 'y = q round(w_m / q); w_m = the mean of w over '
               '(t[k-1], t[k]] if counted else w(t[k])',
               (EffectParam('q', 'rad/s per count', 0.3, 0.0, 1e3, 'speed'),
                EffectParam('counted', '-', 1.0, 0.0, 1.0, 'one')),
               description='encoder counts per sample period: the speed sits on a grid; '
               'a count difference is the mean speed over the sample period (counted = 1), '
               'a quantised speed sensor reads it at the sample (counted = 0)',
               category='measurement', channel='speed'),
    EffectSpec('current_quantization', 'y_i = q_i round(i / q_i)',
               (EffectParam('q_i', 'A per count', 0.01, 0.0, 1e3, 'current'),),
               kinds=('voltage',),
               description='current ADC resolution: the current sits on a grid',
               category='measurement', channel='current'),
    EffectSpec('resistance_drift', 'R = R_m + dR, d(dR)/dt = k_h i^2 (1 + dR / R_m) - '
               'dR / tau_th (copper loss i^2 R, averaged over each interval)',
               (EffectParam('k_h', 'Ohm/(A^2 s)', 0.02, 0.0, 1e3, 'heating', (0.03, 10.0, 5),
                            (0.0, 1000.0)),
                EffectParam('tau_th', 's', 20.0, 0.1, 1e5, 'record', (0.05, 0.8, 3),
                            ((1.0, 'sample'), 10.0))), kinds=('voltage',),
               description='armature heating raises the resistance',
               min_fraction=(('tau_th', (0.03, 'record')),)),
    EffectSpec('resonance', 'two-mass shaft: J_m = J/(1+r), J_l = J r/(1+r), '
               'k_s = J_l (2 pi f_r)^2, c_s = 2 zeta sqrt(k_s J_l)',
               (EffectParam('r', '-', 1.0, 0.01, 100.0, 'one', (0.25, 4.0, 3)),
                EffectParam('f_r', 'Hz', 4.0, 0.01, 1e3, 'per_sample',
                            ((3.0, 'per_record'), 0.2, 10), ((3.0, 'per_record'), 0.5)),
                EffectParam('zeta', '-', 0.05, 0.0, 5.0, 'one', (0.03, 0.15, 2))),
               description='a compliant shaft between motor and load'),
)}
"""The catalogue of named effects; parameter ranges are the allowed ranges."""


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


@dataclass
class Plant:
    """A complete model: physical parameters, plant kind and the named effects it has."""

    params: MotorParams = field(default_factory=MotorParams)
    input_kind: str = 'voltage'
    effects: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.input_kind not in INPUT_KINDS:
            raise ConfigError(f'input_kind must be one of {INPUT_KINDS}, got {self.input_kind!r}')
        self.effects = validate_effects(self.effects, self.input_kind)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description."""
        return {'params': self.params.to_dict(), 'input_kind': self.input_kind,
                'effects': self.effects}

    @classmethod
    def from_json(cls, path: str | os.PathLike[str]) -> Plant:
        """Read a plant from a JSON file.

        The file holds ``{"J": ..., "K_T": ..., "K_b": ..., "B": ..., "L_m": ...,
        "R_m": ...}`` (missing ones take the paper's values) and optionally
        ``"effects": {...}`` and ``"input_kind"``; a ``"truth"`` key is ignored.

        Raises
        ------
        ConfigError
            The file cannot be read, is not a JSON object, or holds a bad value.
        """
        try:
            with open(path) as fh:
                data = json.load(fh)
        except OSError as exc:
            raise ConfigError(f'{path}: cannot read ({exc.strerror})') from None
        except json.JSONDecodeError as exc:
            raise ConfigError(f'{path}: not valid JSON ({exc.msg} at line {exc.lineno})') \
                from None
        if not isinstance(data, dict):
            raise ConfigError(f'{path}: expected a JSON object of parameters')
        effects = data.pop('effects', {})
        kind = data.pop('input_kind', 'voltage')
        data.pop('truth', None)
        params = MotorParams.from_dict({**MotorParams().to_dict(), **data})
        return cls(params, kind, effects)


def n_states(input_kind: str, resonance: bool = False) -> int:
    """Number of states of the continuous model."""
    base = 2 if input_kind == 'voltage' else 1
    return base + (2 if resonance else 0)


def continuous_matrices(theta: Mapping[str, ArrayLike], input_kind: str = 'voltage',
                        resonance: Mapping[str, ArrayLike] | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Continuous state-space matrices for a batch of parameter sets.

    Parameters
    ----------
    theta : dict of array_like
        ``J, B`` (and ``K_T, K_b, L_m, R_m`` for a voltage plant), each shape (P,).
    input_kind : {'voltage', 'torque'}
    resonance : dict of array_like, optional
        ``r, f_r, zeta`` of the two-mass shaft, each shape (P,).

    Returns
    -------
    F : ndarray, shape (P, n, n)
        State matrix; state 0 is the motor speed, state 1 the current (voltage plant).
    G : ndarray, shape (P, n, 2)
        Input matrix; column 0 the input (voltage or torque), column 1 an extra torque
        acting on the motor shaft (friction, load).
    """
    J = np.atleast_1d(np.asarray(theta['J'], dtype=float))
    B = np.atleast_1d(np.asarray(theta['B'], dtype=float))
    P = J.shape[0]
    n = n_states(input_kind, resonance is not None)
    F = np.zeros((P, n, n))
    G = np.zeros((P, n, 2))
    Jm = J
    if resonance is not None:
        r = np.asarray(resonance['r'], dtype=float) * np.ones(P)
        Jm = J / (1 + r)
        Jl = J * r / (1 + r)
        ks = Jl * (2 * np.pi * np.asarray(resonance['f_r'], dtype=float)) ** 2
        cs = 2 * np.asarray(resonance['zeta'], dtype=float) * np.sqrt(ks * Jl)
    F[:, 0, 0] = -B / Jm
    G[:, 0, 1] = 1 / Jm
    if input_kind == 'voltage':
        K_T = np.asarray(theta['K_T'], dtype=float)
        K_b = np.asarray(theta['K_b'], dtype=float)
        L = np.asarray(theta['L_m'], dtype=float)
        R = np.asarray(theta['R_m'], dtype=float)
        F[:, 0, 1] = K_T / Jm
        F[:, 1, 0] = -K_b / L
        F[:, 1, 1] = -R / L
        G[:, 1, 0] = 1 / L
        k = 2
    else:
        G[:, 0, 0] = 1 / Jm
        k = 1
    if resonance is not None:
        # states k: load speed, k+1: shaft twist (motor angle - load angle)
        F[:, 0, 0] -= cs / Jm
        F[:, 0, k] = cs / Jm
        F[:, 0, k + 1] = -ks / Jm
        F[:, k, 0] = cs / Jl
        F[:, k, k] = -cs / Jl
        F[:, k, k + 1] = ks / Jl
        F[:, k + 1, 0] = 1.0
        F[:, k + 1, k] = -1.0
    return F, G


def discretize(F: np.ndarray, G: np.ndarray, dt: ArrayLike, method: str = 'zoh'
               ) -> tuple[np.ndarray, np.ndarray]:
    """Discretise ``dx/dt = F x + G u`` with the input held over each interval.

    Parameters
    ----------
    F : ndarray, shape (P, n, n)
    G : ndarray, shape (P, n, m)
    dt : array_like, shape (K,)
        Interval lengths [s]; one discretisation per interval length.
    method : {'zoh', 'euler'}
        ``'zoh'`` is exact (matrix exponential of the augmented matrix);
        ``'euler'`` is the paper's first-order truncation A = I + F T, b = G T.

    Returns
    -------
    A : ndarray, shape (P, K, n, n)
    Bd : ndarray, shape (P, K, n, m)
    """
    if method not in DISCRETISATIONS:
        raise ConfigError(f'discretisation must be one of {DISCRETISATIONS}, got {method!r}')
    dt = np.atleast_1d(np.asarray(dt, dtype=float))
    n = F.shape[1]
    if method == 'euler':
        eye = np.eye(n)
        A = eye + F[:, None] * dt[None, :, None, None]
        Bd = G[:, None] * dt[None, :, None, None]
        return A, Bd
    if n == 1:  # scalar plant: closed form, exact and immune to extreme F dt
        fdt = F[:, None, 0, 0] * dt[None, :]
        a = np.exp(fdt)
        with np.errstate(divide='ignore', invalid='ignore'):
            phi = np.where(fdt != 0.0, np.expm1(fdt) / np.where(fdt != 0.0, fdt, 1.0), 1.0)
        Bd = G[:, None] * (phi * dt[None, :])[:, :, None, None]
        return a[:, :, None, None], Bd

    if dt.size >= SPECTRAL_MIN_INTERVALS:
        return _discretize_spectral(F, G, dt)
    M = _held_input_matrix(F, G, dt)
    E = expm(M)
    return E[:, :, :n, :n], E[:, :, :n, n:]


SPECTRAL_MIN_INTERVALS = 8
"""From this many distinct interval lengths (a jittered record) :func:`discretize`
diagonalises each plant once and evaluates every interval from its eigenvalues."""
SPECTRAL_MAX_COND = 1e6
"""A plant whose eigenvectors are worse conditioned than this (nearly repeated
eigenvalues) is discretised by the matrix exponential instead."""


def _discretize_spectral(F: np.ndarray, G: np.ndarray, dt: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order hold for many interval lengths: ``F = V diag(l) V^-1`` once per
    plant, then ``A = V diag(exp(l dt)) V^-1`` and ``Bd = V diag(dt phi(l dt)) V^-1 G``
    with ``phi(z) = (exp(z) - 1) / z`` for every interval (a jittered record has an
    interval length per sample: one eigen-decomposition instead of one matrix
    exponential each). Plants with ill-conditioned eigenvectors take the exponential.
    Members of the batch with the same plant (a Jacobian's initial-state and effect
    columns) are discretised once; the runs of a record reuse the decomposition
    (:func:`_basis`)."""
    P, n, _ = F.shape
    m = G.shape[2]
    first, inverse, good, lam, C, D = _basis('zoh', *_key(F, G))
    A = np.empty((first.size, dt.size, n, n))
    Bd = np.empty((first.size, dt.size, n, m))
    if good.size:
        z = lam[:, None, :] * dt[None, :, None]          # (p, K, n)
        ez = np.exp(z)
        A[good] = (ez @ C).real.reshape(-1, dt.size, n, n)
        Bd[good] = ((_phi1(z, ez) * dt[None, :, None]) @ D).real.reshape(-1, dt.size, n, m)
    if good.size < first.size:
        bad = np.setdiff1d(np.arange(first.size), good)
        E = expm(_held_input_matrix(F[first[bad]], G[first[bad]], dt))
        A[bad], Bd[bad] = E[:, :, :n, :n], E[:, :, :n, n:]
    return (A, Bd) if first.size == P else (A[inverse], Bd[inverse])


def _key(F: np.ndarray, G: np.ndarray) -> tuple[bytes, bytes, tuple[int, ...], tuple[int, ...]]:
    """A batch of plants as the hashable arguments of :func:`_basis`."""
    F = np.ascontiguousarray(F, dtype=float)
    G = np.ascontiguousarray(G, dtype=float)
    return F.tobytes(), G.tobytes(), F.shape, G.shape


@functools.lru_cache(maxsize=16)
def _basis(kind: str, f: bytes, g: bytes, f_shape: tuple[int, ...], g_shape: tuple[int, ...],
           row: int = 1) -> tuple[np.ndarray, ...]:
    """The spectral data of a batch of plants (``f``, ``g``: the bytes of F and G).

    Returns ``(first, inverse, good, lam, C, D)``: the distinct plants ``first`` of the
    batch and each member's among them (``inverse``); the indices ``good`` into ``first``
    of the plants with well-conditioned eigenvectors (:func:`_eigen`) and their
    eigenvalues ``lam``; for ``kind`` ``'zoh'`` the outer products ``C[l] = V[:, l]
    Vi[l, :]`` and ``D[l] = V[:, l] (Vi G)[l, :]`` of F (flattened), for ``'heat'`` the
    rows ``C[k]`` of state ``row``'s row of exp(M s) and their products ``D`` (see
    :func:`interval_integrals`). Cached: a record of several runs simulates each
    batch once per run, and the Jacobian of a fit evaluates the plant of its centre
    again.
    """
    F = np.frombuffer(f).reshape(f_shape)
    G = np.frombuffer(g).reshape(g_shape)
    first, inverse = _distinct_plants(F, G)
    F, G = F[first], G[first]
    n, m = F.shape[1], G.shape[2]
    if kind == 'zoh':
        good, lam, V, Vi = _eigen(F)
        Vt = np.swapaxes(V, -1, -2)[:, :, :, None]
        C = (Vt * Vi[:, :, None, :]).reshape(-1, n, n * n)
        D = (Vt * (Vi @ G[good])[:, :, None, :]).reshape(-1, n, n * m)
        return first, inverse, good, lam, C, D
    good, lam, W, Wi = _eigen(_held_input_matrix(F, G, np.ones(1))[:, 0])
    d = n + m
    U = W[:, row, :, None] * Wi                               # (p, d, d)
    ka, kb = np.triu_indices(d)                               # Q's terms ab and ba
    UU = U[:, ka, :, None] * U[:, kb, None, :]
    UU = UU + np.where((ka != kb)[:, None, None], np.swapaxes(UU, -1, -2), 0.0)
    return first, inverse, good, lam, U, UU.reshape(-1, ka.size, d * d)


def _distinct_plants(F: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(first, inverse)``: the batch members with distinct ``(F, G)`` and, for every
    member, its plant among them (``F[first][inverse]`` is ``F``)."""
    P = F.shape[0]
    if P > 1:
        FG = np.concatenate([F.reshape(P, -1), G.reshape(P, -1)], axis=1)
        _, first, inverse = np.unique(FG, axis=0, return_index=True, return_inverse=True)
        if first.size < P:
            return first, inverse.ravel()
    return np.arange(P), np.arange(P)   # all distinct: in their own order


def _eigen(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(good, lam, V, V^-1)``: the eigen-decompositions ``F = V diag(lam) V^-1`` of the
    plants ``good`` (indices into the batch) whose eigenvectors are conditioned better
    than :data:`SPECTRAL_MAX_COND`; the others (nearly repeated or defective
    eigenvalues) are left to the matrix exponential."""
    P = F.shape[0]
    lam, V = np.linalg.eig(F)
    ok = np.isfinite(lam).all(axis=1) & np.isfinite(V).all(axis=(1, 2))
    cond = np.full(P, np.inf)
    cond[ok] = np.linalg.cond(V[ok])
    good = np.flatnonzero(cond < SPECTRAL_MAX_COND)
    Vg = V[good]
    return good, lam[good], Vg, np.linalg.inv(Vg)


def _phi1(z: np.ndarray, ez: np.ndarray | None = None) -> np.ndarray:
    """``(exp(z) - 1) / z`` elementwise (1 at z = 0; a series near it); ``ez``: exp(z)
    when already at hand."""
    ez = np.exp(z) if ez is None else ez
    with np.errstate(divide='ignore', invalid='ignore'):
        phi = (ez - 1.0) / z
    small = np.abs(z) < 1e-4
    if small.any():
        zs = z[small]
        phi[small] = 1.0 + zs / 2.0 + zs * zs / 6.0
    return phi


def _held_input_matrix(F: np.ndarray, G: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """``M dt`` with ``M = [[F, G], [0, 0]]``: ``z = [x, u]`` under a held input,
    ``dz/ds = M z``; shape (P, K, n + m, n + m) for P plants and K interval lengths."""
    P, n, _ = F.shape
    d = n + G.shape[2]
    M = np.zeros((P, dt.shape[0], d, d))
    M[:, :, :n, :n] = F[:, None]
    M[:, :, :n, n:] = G[:, None]
    M *= dt[None, :, None, None]
    return M


def interval_integrals(F: np.ndarray, G: np.ndarray, dt: ArrayLike, row: int = 1
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Integrals of one state over each held-input interval, for the heating model.

    With the input held, ``z = [x, u]`` evolves as ``dz/ds = M z``, ``M = [[F, G], [0, 0]]``,
    so state ``row`` is ``c' exp(M s) z0``. Returned: ``m = int_0^dt c' exp(M s) ds`` (its
    integral is ``m . z0``) and ``Q = int_0^dt exp(M s)' c c' exp(M s) ds`` (the integral of
    its square is ``z0' Q z0``): Van Loan's block exponentials for a few interval lengths;
    from :data:`SPECTRAL_MIN_INTERVALS` on (a jittered record) one eigen-decomposition
    ``M = W diag(mu) W^-1`` per plant, with which ``c' exp(M s)`` is a sum of exponentials
    ``exp(mu_k s) U[k]`` and both integrals are closed forms (also where ``exp(-M' dt)``
    of Van Loan's form overflows: a stiff plant).

    Parameters
    ----------
    F : ndarray, shape (P, n, n)
    G : ndarray, shape (P, n, m)
    dt : array_like, shape (K,)
        Interval lengths [s].
    row : int
        The state (1: the armature current).

    Returns
    -------
    m : ndarray, shape (P, K, n + m)
    Q : ndarray, shape (P, K, n + m, n + m)
    """
    dt = np.atleast_1d(np.asarray(dt, dtype=float))
    P, n, _ = F.shape
    d = n + G.shape[2]
    if dt.size < SPECTRAL_MIN_INTERVALS:
        return _interval_integrals_expm(F, G, dt, row)
    # a state that drives no other (the position) is left out of M: it would make M's
    # zero eigenvalue defective, and its entries of m and Q are zero
    drives = np.any(F != 0.0, axis=(0, 1))
    drives[row] = True
    if not drives.all():
        keep = np.concatenate([np.flatnonzero(drives), np.arange(n, d)])
        r = int(np.sum(drives[:row]))
        mk, Qk = interval_integrals(F[:, drives][:, :, drives], G[:, drives], dt, r)
        m = np.zeros((P, dt.size, d))
        Q = np.zeros((P, dt.size, d, d))
        m[:, :, keep] = mk
        Q[:, :, keep[:, None], keep] = Qk
        return m, Q
    first, inverse, good, mu, U, UU = _basis('heat', *_key(F, G), row)
    m = np.empty((first.size, dt.size, d))
    Q = np.empty((first.size, dt.size, d, d))
    if good.size:
        # state row of exp(M s) is sum_k exp(mu_k s) U[k], so m = sum_k int exp(mu_k s) ds
        # U[k] and Q = sum_kl int exp((mu_k + mu_l) s) ds U[k]' U[l] (UU: those products)
        z = mu[:, None, :] * dt[None, :, None]                    # (p, K, d)
        ez = np.exp(z)
        m[good] = ((_phi1(z, ez) * dt[None, :, None]) @ U).real
        ka, kb = np.triu_indices(d)
        phi2 = _phi1(z[:, :, ka] + z[:, :, kb], ez[:, :, ka] * ez[:, :, kb])
        Q[good] = ((phi2 * dt[None, :, None]) @ UU).real.reshape(-1, dt.size, d, d)
    if good.size < first.size:
        bad = np.setdiff1d(np.arange(first.size), good)
        m[bad], Q[bad] = _interval_integrals_expm(F[first[bad]], G[first[bad]], dt, row)
    return (m, Q) if first.size == P else (m[inverse], Q[inverse])


def _interval_integrals_expm(F: np.ndarray, G: np.ndarray, dt: np.ndarray, row: int
                             ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`interval_integrals` by two block matrix exponentials per interval."""
    P, n, _ = F.shape
    d = n + G.shape[2]
    K = dt.shape[0]
    M = _held_input_matrix(F, G, dt)
    c = np.zeros(d)
    c[row] = 1.0
    big = np.zeros((P, K, 2 * d, 2 * d))  # [[M, I], [0, 0]] dt: top right = int exp(M s)
    big[:, :, :d, :d] = M
    big[:, :, :d, d:] = np.eye(d) * dt[None, :, None, None]
    E = expm(big)
    m = E[:, :, row, d:]
    vl = np.zeros((P, K, 2 * d, 2 * d))  # [[-M', c c'], [0, M]] dt
    vl[:, :, :d, :d] = -np.swapaxes(M, -1, -2)
    vl[:, :, :d, d:] = np.outer(c, c) * dt[None, :, None, None]
    vl[:, :, d:, d:] = M
    V = expm(vl)
    Q = np.swapaxes(V[:, :, d:, d:], -1, -2) @ V[:, :, :d, d:]
    return np.ascontiguousarray(m), np.ascontiguousarray(Q)


def transfer_coefficients(p: Mapping[str, float], input_kind: str = 'voltage',
                          channels: Sequence[str] = ('speed',)) -> dict[str, float]:
    """The coefficients of the continuous transfer functions the data can determine.

    For a voltage plant, w/V = b0 / (s^2 + a1 s + a0) and
    i/V = (c1 s + c0) / (s^2 + a1 s + a0) with
    ``b0 = K_T/(J L_m)``, ``a1 = R_m/L_m + B/J``, ``a0 = (R_m B + K_T K_b)/(J L_m)``,
    ``c1 = 1/L_m``, ``c0 = B/(J L_m)``. For a torque plant, w/u = (1/J) / (s + B/J).
    Input-output data of the linear model determine exactly these numbers; a
    parameter is identifiable iff it is a locally unique function of them.

    Parameters
    ----------
    p : dict
        Parameter values by name.
    input_kind : {'voltage', 'torque'}
    channels : tuple of str
        Measured outputs: 'speed' and optionally 'current'.

    Returns
    -------
    dict
        ``{expression: value}`` in a fixed order.
    """
    if input_kind == 'torque':
        return {'1/J': 1.0 / p['J'], 'B/J': p['B'] / p['J']}
    J, K_T, K_b, B, L, R = (p[k] for k in PARAM_NAMES)
    out = {
        'K_T/(J*L_m)': K_T / (J * L),
        'R_m/L_m + B/J': R / L + B / J,
        '(R_m*B + K_T*K_b)/(J*L_m)': (R * B + K_T * K_b) / (J * L),
    }
    if 'current' in channels:
        out['1/L_m'] = 1.0 / L
        out['B/(J*L_m)'] = B / (J * L)
    return out
