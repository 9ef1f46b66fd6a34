"""The output-error problem of one recording: data, simulation, cost, residuals, Jacobian.

Its parameters (which are free, their bounds, R_m's prior, the search coordinates) are
a :class:`motor_id.identify.space.ParameterSpace`, which the problem extends with the data.

The problem works in internal units (:mod:`motor_id.identify.units`): SI exactly for
every ordinary recording, SI over powers of two for data in extreme units.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import copy
from typing import Any, cast, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.errors import ConfigError, DataError
from motor_id.identify.space import ParameterSpace
from motor_id.identify.units import InternalUnits
from motor_id.metrics import noise_floor
from motor_id.model import DISCRETISATIONS
from motor_id.simulate import interval_table, simulate_runs

if TYPE_CHECKING:
    from motor_id.recording import Recording

METHODS = (*DISCRETISATIONS, 'paper')
"""How a fit discretises the model: the model's discretisations, or the paper's Elman net."""
FAILED_RESIDUAL = 1e6       # weighted residual given to a diverging simulation
SEARCH_MAX_INTERVALS = 16
"""A record with more distinct interval lengths is searched on rounded ones
(:meth:`IdentificationProblem.for_search`)."""
SEARCH_GRID = 0.01
"""Relative grid of the rounded interval lengths (each within half of it)."""


def _pick_channels(rec: Recording, method: str, channels: Iterable[str] | None
                   ) -> tuple[str, ...]:
    """The output channels to fit (default: all measured; ``paper``: speed only)."""
    if channels is not None:
        channels = tuple(channels)
    elif method == 'paper':
        channels = ('speed',)
    else:
        channels = rec.channels()
    for ch in channels:
        if ch not in rec.channels():
            raise ConfigError(f'channel {ch!r} is not in the recording '
                              f'(it has {", ".join(rec.channels())})')
    return channels


def initial_tolerance(y: ArrayLike) -> float:
    """How far a run's initial state may sit from its first measured value: three times
    the channel's sample-to-sample noise, or half its resolution if larger.

    The noise is :func:`motor_id.metrics.noise_floor` (second differences, which a smooth
    response barely moves); a channel on a grid (an encoder, a quantised current) also
    gets half its smallest step.
    """
    y = np.asarray(y, dtype=float)
    scale = float(np.std(y)) or float(np.max(np.abs(y))) or 1.0
    if y.size < 4:
        return 0.1 * scale
    sigma = noise_floor(y)
    steps = np.abs(np.diff(y))
    steps = steps[steps > 1e-12 * scale]
    half_step = 0.5 * float(np.min(steps)) if steps.size else 0.0
    return max(3.0 * sigma, half_step, 1e-6 * scale)


class IdentificationProblem(ParameterSpace):
    """What a fit minimises: the model, its free parameters, the data and the cost.

    Built by :meth:`motor_id.identify.Identifier.fit` (``Identifier.problem_``); usable
    on its own by any optimiser (the benchmarks do). The parameter side (``free``,
    ``fixed``, ``bounds``, ``r_m_prior``, :meth:`expand`, :meth:`to_z`, :meth:`from_z`,
    :meth:`start_vector`, ...) is that of :class:`~motor_id.identify.space.ParameterSpace`.

    Parameters
    ----------
    rec : motor_id.recording.Recording
    method : {'zoh', 'euler', 'paper'}
    R_m : float or None
        The given armature resistance [Ohm] (voltage plants).
    R_m_tolerance : float
        Relative standard deviation of the given R_m: the width of its Gaussian prior
        when R_m is estimated.
    tie, fixed, bounds, channels, effects, free_effects
        As :class:`motor_id.identify.Identifier`.
    sample_weight : array_like, shape (N,), optional

    Attributes
    ----------
    bounds : motor_id.ga.Bounds
        Search box of the free parameters (internal units), in the order of ``x``.
    y : ndarray
        Measured outputs of the fitted channels side by side (internal units).
    weights : ndarray
        Per-sample weights of the cost: 1 / std of each channel times the sample weights.
    r_m_prior : tuple or None
        ``(index in x, mean, std)`` of R_m's Gaussian prior (internal units).
    units : motor_id.identify.units.InternalUnits
        Internal units (SI unless the data are in extreme units); ``units.to_physical``
        maps a parameter back.
    free, fixed : list, dict
        Free plant parameters (in ``x`` before the effect parameters) and fixed values.
    evaluations : int
        Parameter sets simulated so far.
    """

    def __init__(self, rec: Recording, method: str = 'zoh', R_m: float | None = None,
                 R_m_tolerance: float = 0.10, tie: bool | None = None,
                 fixed: Mapping[str, float] | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None,
                 channels: Iterable[str] | None = None,
                 effects: Mapping[str, Mapping[str, float]] | None = None,
                 free_effects: Iterable[str] | None = None,
                 sample_weight: ArrayLike | None = None) -> None:
        if method not in METHODS:
            raise ConfigError(f'method must be one of {METHODS}, got {method!r}')
        self.discretisation = 'zoh' if method == 'zoh' else 'euler'
        self.evaluations = 0
        self.forward_differences = False
        """One-sided Jacobian (d + 1 simulations): enough to rank candidate models."""
        channels = _pick_channels(rec, method, channels)
        super().__init__(rec.input_kind, method, channels,
                         InternalUnits.from_recording(rec, bool(effects)), R_m, R_m_tolerance,
                         tie, fixed, bounds, effects, free_effects)
        self._load(rec, sample_weight)

    # ------------------------------------------------------------------- data
    def _load(self, rec: Recording, sample_weight: ArrayLike | None) -> None:
        un = self.units
        self.time = un.signal(rec.time, 'time')
        self.input = un.signal(rec.input, 'input')
        self.segments = rec.segment_ranges
        # the measured position an effect reads (an arm's gravity), SI: a model with
        # effects is fitted in SI units
        self.position = None if rec.position is None else np.asarray(rec.position, float)
        signals: dict[str, np.ndarray | None] = {'speed': un.signal(rec.speed, 'speed')}
        if self.kind == 'voltage':
            signals['current'] = (un.signal(rec.current, 'current')
                                  if rec.current is not None else None)
        self.state_channels = tuple(signals)
        x0: list[float] = []
        lo: list[float] = []
        hi: list[float] = []
        for a, b in self.segments:
            for y in signals.values():
                if y is None:  # not measured: free within a wide range
                    v = 0.0
                    ref = cast(np.ndarray, signals['speed'])
                    span = 2.0 * float(np.max(np.abs(y if y is not None else ref))) + 1.0
                else:          # measured: data, within the noise of the first sample
                    v = float(y[a])
                    span = initial_tolerance(y[a:b])
                x0.append(v)
                lo.append(v - span)
                hi.append(v + span)
        self.x0 = np.array(x0, dtype=float)
        self.x0_bounds = (np.array(lo), np.array(hi))
        ys = [un.signal(getattr(rec, c), c) for c in self.channels]
        for ch, y in zip(self.channels, ys, strict=True):
            if np.ptp(y) == 0:
                raise DataError(f'the {ch} channel is constant ({float(y[0]):g} throughout): '
                                'it holds nothing to fit; check the sensor and the column '
                                'mapping, or leave the channel out')
        self.y = np.concatenate(ys)
        self.n_per = [y.size for y in ys]
        scales = [np.std(y) if np.std(y) > 0 else 1.0 for y in ys]
        self.weights = np.concatenate([np.full(y.size, 1.0 / s)
                                       for y, s in zip(ys, scales, strict=True)])
        self.sample_weight = np.ones(self.y.size)
        if sample_weight is not None:
            sw = np.asarray(sample_weight, dtype=float)
            if sw.shape != rec.time.shape or not np.all(np.isfinite(sw) & (sw >= 0)) \
                    or not np.any(sw > 0):
                raise ConfigError(f'sample_weight must hold {len(rec)} finite values >= 0, '
                                  'not all zero')
            self.sample_weight = np.tile(sw, len(ys))
            self.weights = self.weights * self.sample_weight

    # -------------------------------------------------------------- simulation
    def simulate_channels(self, X: ArrayLike, overrides: Mapping[str, float] | None = None
                          ) -> list[np.ndarray]:
        """Outputs per channel for parameter rows X (trailing columns: initial state).

        ``overrides`` replaces fixed parameter values (internal units).
        """
        X = np.atleast_2d(X)
        self.evaluations += X.shape[0]
        d = self.bounds.dim
        x0 = X[:, d:] if X.shape[1] > d else np.broadcast_to(self.x0, (X.shape[0],
                                                                       self.x0.size))
        theta, effects = self.expand(X[:, :d], overrides)
        with np.errstate(all='ignore'):
            out = simulate_runs(theta, self.time, self.input, self.kind,
                                self.discretisation, effects, x0, self.segments,
                                self.position)
        return [out[c] for c in self.channels]

    def state_names(self) -> list[str]:
        """Names of the initial-state coordinates (``x0:speed``; ``x0[k]:speed`` for the
        runs of a joined recording)."""
        multi = len(self.segments) > 1
        return [f'x0[{k}]:{ch}' if multi else f'x0:{ch}'
                for k in range(len(self.segments)) for ch in self.state_channels]

    def simulate(self, X: ArrayLike, overrides: Mapping[str, float] | None = None) -> np.ndarray:
        """All fitted channels side by side, shape (P, n_channels * N)."""
        return np.concatenate(self.simulate_channels(X, overrides), axis=1)

    def for_search(self) -> IdentificationProblem:
        """This problem with each time interval rounded to :data:`SEARCH_GRID` of itself
        (on a log scale), for the GA's global search; itself on a record with few
        distinct intervals.

        A jittered log has an interval length per sample (the real SysId log: 1,217
        distinct ones), and every one costs a discretisation of every member of the
        population. Rounded, the log takes about a hundred, each off by at most half a
        percent: the GA only has to find the basin. The refinement that follows, and so
        every reported number, simulates the intervals as logged.
        """
        dts, _ = interval_table(self.time)
        if dts.size <= SEARCH_MAX_INTERVALS:
            return self
        dt = np.diff(self.time)
        step = np.exp(np.round(np.log(dt) / SEARCH_GRID) * SEARCH_GRID)
        coarse = copy.copy(self)
        coarse.time = self.time[0] + np.concatenate([[0.0], np.cumsum(step)])
        return coarse

    def cost(self, X: ArrayLike) -> np.ndarray:
        """The GA's fitness: weighted mean squared output error (plus R_m's prior) per row.

        Equals ``sum(residuals(x)**2) / y.size`` for each row x.
        """
        ys = self.simulate_channels(X)
        c = np.zeros(ys[0].shape[0])
        n = ys[0].shape[1]
        with np.errstate(all='ignore'):
            for k, y in enumerate(ys):
                sl = slice(k * n, (k + 1) * n)
                e = y - self.y[sl]
                e *= self.weights[sl]
                c += np.einsum('ij,ij->i', e, e)
            p = self.prior_residuals(X)
            if p is not None:
                c += p * p
        c /= n * len(ys)
        return np.where(np.isfinite(c), c, np.inf)

    def residuals(self, x: ArrayLike, weights: np.ndarray | None = None) -> np.ndarray:
        """Weighted residuals at one parameter vector x (free parameters, internal units;
        trailing entries, if any, are the initial state); R_m's prior is the last entry.

        A diverging simulation gives :data:`FAILED_RESIDUAL` entries.
        """
        x = np.asarray(x, dtype=float)
        w = self.weights if weights is None else weights
        with np.errstate(all='ignore'):
            r = (self.simulate(x[None, :])[0] - self.y) * w
            p = self.prior_residuals(x[None, :self.bounds.dim])
        if p is not None:
            r = np.concatenate([r, p])
        return np.where(np.isfinite(r), r, FAILED_RESIDUAL)

    def output_residuals(self, z: np.ndarray) -> np.ndarray:
        """Simulated minus measured outputs (unweighted) at search vector z."""
        r: np.ndarray = self.simulate(self.from_z(z[None, :]))[0] - self.y
        return r

    # ------------------------------------------------------ least squares in z
    def z_bounds(self, size: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Bounds in search coordinates; with the initial state when ``size`` asks."""
        lo = self.to_z(np.array(self.bounds.low))
        hi = self.to_z(np.array(self.bounds.high))
        if size is not None and size > lo.size:
            lo = np.concatenate([lo, self.x0_bounds[0]])
            hi = np.concatenate([hi, self.x0_bounds[1]])
        return lo, hi

    def weighted_residuals(self, z: np.ndarray, weights: np.ndarray,
                           overrides: Mapping[str, float] | None = None) -> np.ndarray:
        """Weighted residuals at search vector z (with the prior entry, if any)."""
        x = self.from_z(z[None, :])
        with np.errstate(all='ignore'):
            r = (self.simulate(x, overrides)[0] - self.y) * weights
            p = self.prior_residuals(x[:, :self.bounds.dim])
        if p is not None:
            r = np.concatenate([r, p])
        return np.where(np.isfinite(r), r, FAILED_RESIDUAL)

    def jacobian_z(self, z: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Central-difference Jacobian of the weighted residuals w.r.t. z, one batch."""
        d = z.size
        h = 1e-5 * np.maximum(1.0, np.abs(z))
        # linear coordinates whose range is narrow (effect parameters of a small motor,
        # given bounds) step by a fraction of that range, never by more than before
        lo, hi = self.z_bounds(d)
        h = np.minimum(h, 1e-5 * np.maximum(np.abs(z), 1e-3 * (hi - lo)))
        h = np.where(self.log_mask(d), 1e-5, h)
        if self.forward_differences:   # d + 1 simulations instead of 2 d
            Z = np.repeat(z[None, :], d + 1, axis=0)
            Z[np.arange(d), np.arange(d)] += h
            Y = self.simulate(self.from_z(Z)) * weights[None, :]
            Jt = (Y[:d] - Y[d]) / h[:, None]
        else:
            Z = np.repeat(z[None, :], 2 * d, axis=0)
            Z[np.arange(d), np.arange(d)] += h
            Z[d + np.arange(d), np.arange(d)] -= h
            Y = self.simulate(self.from_z(Z)) * weights[None, :]
            Jt = (Y[:d] - Y[d:]) / (2 * h[:, None])
        if self.r_m_prior is not None:
            j, _, std = self.r_m_prior
            row = np.zeros((d, 1))
            row[j, 0] = np.exp(z[j]) / std  # d/dz of (exp(z) - mean) / std
            Jt = np.concatenate([Jt, row], axis=1)
        J: np.ndarray = Jt.T
        return J

    def refine(self, z0: np.ndarray, weights: np.ndarray, max_nfev: int = 60) -> Any:
        """Bounded least squares (trust region) from search vector z0."""
        lo, hi = self.z_bounds(z0.size)
        z0 = np.clip(z0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

        def jac(z: np.ndarray, w: np.ndarray) -> np.ndarray:
            J = self.jacobian_z(z, w)
            return np.where(np.isfinite(J), J, 0.0)

        from scipy.optimize import least_squares  # lazy: 0.6 s of import, used per fit

        return least_squares(self.weighted_residuals, z0, jac=jac, bounds=(lo, hi),
                             method='trf', x_scale='jac', max_nfev=max_nfev, xtol=1e-10,
                             ftol=1e-12, args=(weights,))
