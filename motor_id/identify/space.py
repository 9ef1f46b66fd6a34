"""The parameters of a fit: which are free, their search box and R_m's prior, and their
packing into parameter vectors and search coordinates (internal units)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import cast

import numpy as np
from numpy.typing import ArrayLike

from motor_id.effects import EFFECTS
from motor_id.errors import ConfigError
from motor_id.ga import Bounds
from motor_id.identify.units import InternalUnits
from motor_id.model import MECHANICAL_PARAMS, PARAM_NAMES, transfer_coefficients

VOLTAGE_FREE = tuple(name for name in PARAM_NAMES if name != 'R_m')
"""Free by default on a voltage plant: all but R_m, which is given (with a prior)."""
TORQUE_FREE = MECHANICAL_PARAMS
DEFAULT_BOUNDS = {
    'J': (1e-6, 10.0), 'K_T': (1e-3, 10.0), 'K_b': (1e-3, 10.0), 'B': (1e-7, 1.0),
    'L_m': (1e-5, 1.0),
}
TORQUE_BOUNDS = {'J': (1e-7, 1e4), 'B': (1e-8, 1e5)}
R_M_SPAN = 4.0      # a free R_m is searched in [given / 4, given * 4]
SPEED_ONLY_R_M = 1.0
"""The armature resistance [Ohm] a voltage plant is fitted at where the record cannot see
R_m (:func:`resistance_enters`): speed alone determines kS, kV, kA and the speed transfer
function, and every one of them is the same at any R_m, so a fixed internal value makes
every output the same whatever resistance is given."""


def resistance_enters(input_kind: str, has_current: bool,
                      fixed: Mapping[str, float] | None = None) -> bool:
    """Whether R_m enters a fit's outputs: a voltage plant with its current measured, or
    one with a parameter other than R_m held at a known value (its scale then ties the
    others to R_m). Speed-only voltage data otherwise see only combinations that R_m
    leaves unchanged (:data:`SPEED_ONLY_R_M`)."""
    return input_kind == 'voltage' and (has_current or bool(set(fixed or {}) - {'R_m'}))


def _effect_terms(effects: Mapping[str, Mapping[str, float]] | None,
                  free_effects: Iterable[str] | None
                  ) -> tuple[dict[str, Mapping[str, float]], list[str]]:
    """Complete effect parameters (catalogue defaults) and the checked free ones."""
    effects = {k: dict(v) for k, v in (effects or {}).items()}
    for e in effects:
        if e not in EFFECTS:
            raise ConfigError(f'unknown effect {e!r}')
        effects[e] = {**EFFECTS[e].defaults(), **effects[e]}
    free_eff = list(free_effects or ())
    for fe in free_eff:
        e, _, p = fe.partition('.')
        if e not in effects or p not in effects[e]:
            raise ConfigError(f'free effect parameter {fe!r} is not in the effects '
                              f'{sorted(effects)}')
    return effects, free_eff


def _plant_parameters(space: ParameterSpace, R_m: float | None, fixed: dict[str, float]
                      ) -> tuple[list[str], dict[str, tuple[float, float]], float | None]:
    """Plant parameter names, default search box and the given R_m (None: torque plant).

    Decides whether R_m is free: for a voltage plant with a fitted current channel (not
    ``paper``) and R_m not in ``fixed``; otherwise it goes into ``fixed`` at its given
    value.
    """
    if space.kind != 'voltage':
        unknown = set(fixed) - set(TORQUE_FREE)
        if unknown:
            raise ConfigError(f'cannot fix {sorted(unknown)}: the parameters of a torque '
                              f'plant are {list(TORQUE_FREE)}')
        return list(TORQUE_FREE), dict(TORQUE_BOUNDS), None
    given = fixed.get('R_m', R_m)
    if given is None:
        raise ConfigError('R_m (the armature resistance in Ohm, as measured) is required',
                          params=('R_m',))
    if not (np.isfinite(given) and given > 0):
        raise ConfigError(f'R_m must be a finite value > 0 Ohm, got {given}')
    tol = space.R_m_tolerance
    if not (np.isfinite(tol) and tol > 0):
        raise ConfigError(f'the R_m tolerance must be a finite fraction > 0 (0.1 = 10 %), '
                          f'got {tol}')
    names, box = list(VOLTAGE_FREE), dict(DEFAULT_BOUNDS)
    unknown = set(fixed) - set(names) - {'R_m'}
    if unknown:
        raise ConfigError(f'cannot fix {sorted(unknown)}: the parameters of a voltage '
                          f'plant are {names + ["R_m"]}')
    if 'R_m' not in fixed and 'current' in space.channels and space.method != 'paper':
        names.append('R_m')  # steady states V = R_m i + K_b w: the data see R_m
        r = space.units.to_internal('R_m', given)
        box['R_m'] = (r / R_M_SPAN, r * R_M_SPAN)
    else:
        fixed['R_m'] = float(given)
    return names, box, float(given)


def _search_box(box: Mapping[str, tuple[float, float]],
                bounds: Mapping[str, tuple[float, float]] | None, fitted: Sequence[str],
                units: InternalUnits) -> dict[str, tuple[float, float]]:
    """Default box updated by the user's ``bounds`` (SI -> internal) and effect ranges."""
    box = dict(box)
    for key, (lo, hi) in (bounds or {}).items():
        if key not in box and key not in fitted:
            raise ConfigError(f'bounds given for {key!r}, which is not fitted '
                              f'(fitted: {fitted})')
        box[key] = (units.to_internal(key, lo), units.to_internal(key, hi))
    for fe in fitted:
        if fe not in box:
            e, _, p = fe.partition('.')
            spec = {q.name: q for q in EFFECTS[e].params}[p]
            box[fe] = (spec.low, spec.high)
    return box


class ParameterSpace:
    """The free parameters of a model fitted to some output channels, and their packing.

    A parameter vector ``x`` holds the free plant parameters (:attr:`free`), then the
    free effect parameters (:attr:`free_effects`), in internal units; a search vector
    ``z`` holds the logarithms of the positive ones (:meth:`to_z`). Either may carry
    trailing initial-state coordinates, which are never on a log scale.

    Parameters
    ----------
    kind : {'voltage', 'torque'}
        The plant's input.
    method : {'zoh', 'euler', 'paper'}
    channels : tuple of str
        The fitted output channels (which parameters they can carry).
    units : motor_id.identify.units.InternalUnits
    R_m, R_m_tolerance, tie, fixed, bounds, effects, free_effects
        As :class:`motor_id.identify.IdentificationProblem`.

    Attributes
    ----------
    bounds : motor_id.ga.Bounds
        Search box of the free parameters (internal units), in the order of ``x``.
    free, fixed : list, dict
        Free plant parameters (in ``x`` before the effect parameters) and fixed values.
    effects, free_effects : dict, list
        Every effect's parameter values (catalogue defaults completed) and the free ones.
    r_m_prior : tuple or None
        ``(index in x, mean, std)`` of R_m's Gaussian prior (internal units).
    R_m_given : float or None
        The given armature resistance [Ohm] (None for a torque plant).
    """

    def __init__(self, kind: str, method: str, channels: tuple[str, ...], units: InternalUnits,
                 R_m: float | None, R_m_tolerance: float, tie: bool | None,
                 fixed: Mapping[str, float] | None,
                 bounds: Mapping[str, tuple[float, float]] | None,
                 effects: Mapping[str, Mapping[str, float]] | None,
                 free_effects: Iterable[str] | None) -> None:
        self.kind = kind
        self.method = method
        self.channels = channels
        self.units = units
        fixed = {k: float(v) for k, v in (fixed or {}).items()}
        self.R_m_tolerance = float(R_m_tolerance)
        names, box, self.R_m_given = _plant_parameters(self, R_m, fixed)
        if tie is None:
            tie = (self.kind == 'voltage' and 'current' in self.channels
                   and self.method != 'paper')
        self.tie = bool(tie and self.kind == 'voltage')
        free = [n for n in names if n not in fixed and not (self.tie and n == 'K_b')]
        self.effects, self.free_effects = _effect_terms(effects, free_effects)
        order = free + self.free_effects
        box = _search_box(box, bounds, order, self.units)
        self.fixed = {k: self.units.to_internal(k, v) for k, v in fixed.items()}
        self.free = free
        self.bounds = Bounds(tuple(order), tuple(box[n][0] for n in order),
                             tuple(box[n][1] for n in order),
                             tuple(n in PARAM_NAMES for n in order))
        self.r_m_prior: tuple[int, float, float] | None = None
        if 'R_m' in free:
            mean = self.units.to_internal('R_m', cast(float, self.R_m_given))
            self.r_m_prior = (free.index('R_m'), mean, self.R_m_tolerance * mean)

    def expand(self, X: ArrayLike, overrides: Mapping[str, float] | None = None
               ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]]]:
        """Parameter rows X (P, d) -> (theta dict, effects dict) batches for the model."""
        X = np.atleast_2d(X)
        P = X.shape[0]
        theta = {k: np.full(P, v) for k, v in {**self.fixed, **(overrides or {})}.items()}
        for j, n in enumerate(self.free):
            theta[n] = X[:, j]
        if self.tie:
            theta['K_b'] = theta['K_T']
        effects = {e: {p: np.full(P, v) for p, v in vals.items()}
                   for e, vals in self.effects.items()}
        for j, fe in enumerate(self.free_effects):
            e, _, p = fe.partition('.')
            effects[e][p] = X[:, len(self.free) + j]
        return theta, effects

    def prior_residuals(self, X: ArrayLike) -> np.ndarray | None:
        """R_m's prior residual ``(R_m - given) / std`` per row of X, or None."""
        if self.r_m_prior is None:
            return None
        j, mean, std = self.r_m_prior
        return (np.atleast_2d(X)[:, j] - mean) / std

    def log_mask(self, size: int) -> np.ndarray:
        """Which of ``size`` coordinates are on a log scale (initial states never are)."""
        lg = np.zeros(size, dtype=bool)
        lg[:self.bounds.dim] = self.bounds.log
        return lg

    def to_z(self, x: ArrayLike) -> np.ndarray:
        """Parameters (and initial state) -> search coordinates (log of the positive ones)."""
        x = np.asarray(x, dtype=float)
        lg = self.log_mask(np.shape(x)[-1])
        with np.errstate(all='ignore'):
            return np.where(lg, np.log(np.where(lg, np.maximum(x, 1e-300), 1.0)), x)

    def from_z(self, z: ArrayLike) -> np.ndarray:
        """Search coordinates -> parameters."""
        lg = self.log_mask(np.shape(z)[-1])
        with np.errstate(over='ignore'):
            return np.where(lg, np.exp(z), z)

    def start_vector(self, start: Mapping[str, float]) -> np.ndarray:
        """A starting parameter vector from SI values ``{name: value}``, clipped to bounds."""
        vals: list[float] = []
        for n in self.bounds.names:
            if '.' in n:
                e, _, p = n.partition('.')
                vals.append(self.effects[e][p] if n not in start else start[n])
            elif n == 'R_m' and n not in start:
                vals.append(cast(tuple[int, float, float], self.r_m_prior)[1])
            else:
                if n not in start:
                    raise ConfigError(f'start values lack {n!r}')
                vals.append(self.units.to_internal(n, start[n]))
        out: np.ndarray = np.clip(np.array(vals, dtype=float), self.bounds.low, self.bounds.high)
        return out

    def values_at(self, z: np.ndarray) -> dict[str, float]:
        """Full ``{name: value}`` of the physical parameters at free vector z (internal)."""
        x = self.from_z(z)
        v = dict(self.fixed)
        for j, n in enumerate(self.free):
            v[n] = x[j]
        if self.tie:
            v['K_b'] = v['K_T']
        return v

    def coefficients(self, z: np.ndarray, physical: bool = False) -> dict[str, float]:
        """The transfer-function coefficients the data determine, at z."""
        v = self.values_at(z)
        if physical:
            v = {k: self.units.to_physical(k, val) for k, val in v.items()}
        with np.errstate(all='ignore'):
            return transfer_coefficients(v, self.kind, self.channels)
