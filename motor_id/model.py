"""The DC motor model: parameters, named effect terms, continuous dynamics, discretisation.

Units are SI throughout: J [kg m^2], K_T [N m/A], K_b [V s/rad], B [N m s/rad],
L_m [H], R_m [Ohm], speed [rad/s], current [A], voltage [V], torque [N m].

Two plant kinds share this module:

* ``'voltage'``: the armature-voltage-driven motor, x = [speed, current],
  ``J dw/dt = K_T i - B w + tau_extra``, ``L_m di/dt = V - R_m i - K_b w``.
* ``'torque'``: a current- or torque-controlled drive seen from its mechanical side,
  x = [speed], ``J dw/dt = u - B w + tau_extra`` with u the applied torque (or force:
  then J is a mass and B a viscous coefficient in N s/m).

Every non-linear or extra physical term is a named *effect* of the catalogue
:data:`motor_id.effects.EFFECTS`; the simulator
(card), the fitter and the discrepancy analysis all use this one catalogue.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
import functools
import json
import math
import os
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from motor_id.contracts import INPUT_KINDS, UNITS
from motor_id.effects import validate_effects
from motor_id.errors import ConfigError
from motor_id.linalg import expm

__all__ = ['continuous_matrices', 'DISCRETISATIONS', 'discretize', 'interval_integrals',
           'MECHANICAL_PARAMS', 'MotorParams', 'n_states', 'PAPER_MOTOR', 'PARAM_NAMES',
           'PARAM_UNITS', 'Plant', 'transfer_coefficients']

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


@dataclass
class Plant:
    """A complete model: physical parameters, plant kind and the named effects it has."""

    params: MotorParams = field(default_factory=MotorParams)
    input_kind: str = 'voltage'
    effects: dict[str, dict[str, float]] = field(default_factory=dict)

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
        phi: np.ndarray = (ez - 1.0) / z
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
