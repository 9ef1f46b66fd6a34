"""Uncertainty of a fit: noise levels, covariance, structural identifiability, bootstrap.

Uncertainty is the Gauss-Newton (Cramer-Rao) covariance with each channel's noise level
estimated from its residuals. Identifiability comes from the rank of the map from the
parameters to the transfer-function coefficients (what input-output data can determine);
a prior on R_m is one more observation, a unit row in that map.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
import math
from typing import cast, TYPE_CHECKING

import numpy as np

from motor_id.effects import role_keys, role_value
from motor_id.identify.result import Combination, ParameterCovariance, UndeterminedDirection
from motor_id.metrics import correlation

if TYPE_CHECKING:
    from motor_id.identify.problem import IdentificationProblem

NULL_TOL = 1e-7     # singular value ratio below which a direction is structurally unseen
DETERMINED_TOL = 1e-6  # max projection of a parameter on the unseen directions
AT_BOUND = 1e-3     # share of the (log-)range within which an estimate is at its bound


def noise_levels(problem: IdentificationProblem, z: np.ndarray) -> tuple[list[float], np.ndarray]:
    """Per-channel noise std of the residuals at z and the matching weights (1/std)."""
    r = problem.output_residuals(z)
    sig: list[float] = []
    w: list[np.ndarray] = []
    i = 0
    d = z.size
    for n in problem.n_per:
        rc = r[i:i + n]
        swc = problem.sample_weight[i:i + n]
        dof = max(np.sum(swc) - d / len(problem.n_per), 1.0)
        s = float(np.sqrt(np.sum(swc * rc * rc) / dof))
        s = s if s > 0 else 1e-12 * (np.std(problem.y[i:i + n]) or 1.0)
        sig.append(s)
        w.append(swc / s)
        i += n
    return sig, np.concatenate(w)


def _log_coefficients(problem: IdentificationProblem, z: np.ndarray) -> np.ndarray:
    with np.errstate(all='ignore'):
        out: np.ndarray = np.log(np.abs(np.array(list(problem.coefficients(z).values()))))
    return out


def structural_jacobian(problem: IdentificationProblem, z: np.ndarray, prior: bool = True
                        ) -> np.ndarray:
    """d log|c| / dz of the transfer coefficients; effect parameters (and R_m's prior,
    when ``prior``) get unit rows."""
    d = z.size
    n_phys = len(problem.free)
    base = _log_coefficients(problem, z)
    extra = d - n_phys + (1 if prior and problem.r_m_prior is not None else 0)
    rows = np.zeros((base.size + extra, d))
    for j in range(n_phys):
        h = 1e-6
        zp = z.copy()
        zm = z.copy()
        zp[j] += h
        zm[j] -= h
        rows[:base.size, j] = (_log_coefficients(problem, zp)
                               - _log_coefficients(problem, zm)) / (2 * h)
    for j in range(n_phys, d):
        rows[base.size + j - n_phys, j] = 1.0
    if extra > d - n_phys:
        rows[-1, cast(tuple[int, float, float], problem.r_m_prior)[0]] = 1.0
    return rows


def structural(problem: IdentificationProblem, z: np.ndarray, prior: bool = True
               ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Generic structural rank, bases and per-parameter verdict near z.

    The rank of the coefficient map is evaluated at z and at three random points inside
    the bounds (fixed seed): a parameter counts as determined only if it is at all of
    them, so an estimate sitting on a special point (B at its lower bound, say) does not
    make a parameter look determined.

    Returns
    -------
    rank : int
    Vr, Vn : ndarray
        Bases of the identifiable and of the unseen directions (columns).
    determined : ndarray of bool
    """
    rng = np.random.default_rng(20261122)
    lo, hi = problem.z_bounds(z.size)
    points = [z] + [lo + rng.uniform(0.2, 0.8, z.size) * (hi - lo) for _ in range(3)]
    best: tuple[int, np.ndarray, np.ndarray] | None = None
    determined = np.ones(z.size, dtype=bool)
    for zz in points:
        Jc = structural_jacobian(problem, zz, prior)
        _, sc, Vt = np.linalg.svd(Jc, full_matrices=True)
        smax = sc[0] if sc.size and sc[0] > 0 else 1.0
        rank = int(np.sum(sc > NULL_TOL * smax))
        Vn = Vt[rank:].T
        proj = np.linalg.norm(Vn, axis=1) if Vn.size else np.zeros(z.size)
        determined &= proj < DETERMINED_TOL
        if best is None or rank > best[0]:
            best = (rank, Vt[:rank].T, Vn)
    best = cast(tuple[int, np.ndarray, np.ndarray], best)  # z is always one of the points
    return best[0], best[1], best[2], determined


def covariance(J: np.ndarray, Vr: np.ndarray, rank: int) -> tuple[np.ndarray, float]:
    """Gauss-Newton covariance on the identifiable subspace and its condition number."""
    Jr = J @ Vr  # output sensitivities along the identifiable directions
    fisher_r = Jr.T @ Jr
    sr = np.linalg.svd(fisher_r, compute_uv=False) if rank else np.zeros(0)
    cov = Vr @ np.linalg.pinv(fisher_r, rcond=1e-15) @ Vr.T
    cond = float(sr[0] / sr[-1]) if rank and sr[-1] > 0 else float('inf')
    return cov, cond


def block_ids(n_per: Sequence[int], n_blocks: int,
              segments: Sequence[tuple[int, int]] | None = None) -> tuple[np.ndarray, int]:
    """Block index of every residual row: contiguous blocks in time, the same block for
    every channel at one sample (channels measured together share their errors).

    Parameters
    ----------
    n_per : list of int
        Rows per channel (each channel holds the same N samples).
    n_blocks : int
        Blocks per record (fewer when the record is short: at least 20 samples each).
    segments : list of (int, int), optional
        Sample ranges of separate recordings; each is split on its own.
    """
    n = n_per[0]
    segments = segments or [(0, n)]
    ids = np.empty(n, dtype=int)
    nxt = 0
    for a, b in segments:
        k = int(max(2, min(n_blocks, (b - a) // 20)))
        ids[a:b] = nxt + (np.arange(b - a) * k) // (b - a)
        nxt += k
    return np.tile(ids, len(n_per)), nxt


def robust_covariance(J: np.ndarray, r: np.ndarray, Vr: np.ndarray, ids: np.ndarray,
                      n_blocks: int) -> np.ndarray:
    """Sandwich covariance with a block (batch-means) estimate of the score variance.

    The Gauss-Newton covariance ``(J^T J)^-1`` holds when the weighted residuals are white
    with unit variance. On real records they are dominated by what the model lacks: slow,
    correlated, and different from one stretch of the record to the next. The sandwich
    ``H^-1 M H^-1`` (``H = J^T J``) takes the variance ``M`` of the score ``J^T r`` from
    the record itself: the scores summed over contiguous blocks are nearly independent
    however the residuals are correlated within a block, so their spread measures how
    much each stretch of the record pulls the estimate its own way.

    Parameters
    ----------
    J : ndarray, shape (M, d)
        Weighted residual Jacobian (rows beyond ``ids.size``: prior rows).
    r : ndarray, shape (M,)
        Weighted residuals at the estimate.
    Vr : ndarray, shape (d, rank)
        Basis of the identifiable directions.
    ids : ndarray of int
        Block of each data row (:func:`block_ids`).
    n_blocks : int

    Returns
    -------
    ndarray, shape (d, d)

    Notes
    -----
    ``M = K / (K - 1) sum_k (s_k - s_mean)(s_k - s_mean)^T`` over the K block scores,
    plus the prior rows' own Gauss-Newton information. With white residuals ``M``
    estimates ``H`` and the sandwich equals the Gauss-Newton covariance on average.
    """
    Jr = J @ Vr
    n = ids.size
    g = Jr[:n] * r[:n, None]
    S = np.column_stack([np.bincount(ids, weights=g[:, j], minlength=n_blocks)
                         for j in range(g.shape[1])]) if g.shape[1] else \
        np.zeros((n_blocks, 0))
    S -= S.mean(axis=0)
    meat = S.T @ S * (n_blocks / max(n_blocks - 1, 1))
    if J.shape[0] > n:
        meat += Jr[n:].T @ Jr[n:]
    Hinv = np.linalg.pinv(Jr.T @ Jr, rcond=1e-15)
    out: np.ndarray = Vr @ (Hinv @ meat @ Hinv) @ Vr.T
    return out


WHITE_LAGS = 20
"""Autocorrelation lags of :func:`residuals_white` (Ljung-Box)."""
WHITE_LEVEL = 0.01
"""Significance level of :func:`residuals_white`, shared by the channels (Bonferroni)."""


def residuals_white(r: np.ndarray, n_per: Sequence[int], weight: np.ndarray | None = None
                    ) -> bool:
    """True when no channel's residuals show autocorrelation (Ljung-Box test over
    :data:`WHITE_LAGS` lags at :data:`WHITE_LEVEL`, split between the channels).

    The Gauss-Newton covariance assumes white residuals of the estimated level; where
    the record confirms that, it is the efficient error bar, and the block sandwich
    (whose estimate of the score variance has only as many degrees of freedom as the
    record has blocks) would only add its own scatter: taking the larger of the two would
    widen clean-data error bars by some 9 % on average for ten blocks. Samples of zero
    ``weight`` (held out) are left out.
    """
    from scipy.stats import chi2  # lazy: scipy.stats is slow to import

    i = 0
    level = WHITE_LEVEL / max(len(n_per), 1)
    for n in n_per:
        rc = r[i:i + n] if weight is None else r[i:i + n][weight[i:i + n] != 0]
        i += n
        h = min(WHITE_LAGS, rc.size // 10)
        if h < 1:
            continue
        rho = correlation(rc, rc, h)[1:]   # all zero for a constant channel
        q = rc.size * (rc.size + 2) * float(np.sum(rho ** 2 / (rc.size - np.arange(1, h + 1))))
        if float(chi2.sf(q, h)) < level:
            return False
    return True


def combine(cov_gn: np.ndarray, cov_rob: np.ndarray, white: bool = False) -> np.ndarray:
    """The larger of the two standard deviations per coordinate, with the robust
    estimate's correlations (the Gauss-Newton ones where it has none); ``white``
    (:func:`residuals_white`): the Gauss-Newton covariance as it is."""
    if white:
        return cov_gn
    s_gn = np.sqrt(np.maximum(np.diag(cov_gn), 0.0))
    s_rob = np.sqrt(np.maximum(np.diag(cov_rob), 0.0))
    base, s_base = (cov_rob, s_rob) if np.all(s_rob[s_gn > 0] > 0) else (cov_gn, s_gn)
    s = np.maximum(s_gn, s_rob)
    scale = np.divide(s, s_base, out=np.zeros_like(s), where=s_base > 0)
    out: np.ndarray = base * np.outer(scale, scale)
    return out


def undetermined_directions(names: Sequence[str], Vn: np.ndarray, determined: np.ndarray,
                            log_mask: np.ndarray
                            ) -> tuple[list[UndeterminedDirection], tuple[list[str], list[str]]]:
    """The unseen directions with one free "pivot" parameter each (QR column pivoting).

    Returns
    -------
    directions : list of UndeterminedDirection
    choice : (list, list)
        The pivot names and the other undetermined names.
    """
    if not Vn.size:
        return [], ([], [])
    from scipy.linalg import qr  # lazy: only for undetermined directions

    _, _, piv = qr(Vn.T, pivoting=True)
    piv = np.sort(piv[:Vn.shape[1]])
    basis = Vn @ np.linalg.inv(Vn[piv])
    pivots = [names[j] for j in piv]
    others = [n for j, n in enumerate(names) if j not in piv and not determined[j]]
    out: list[UndeterminedDirection] = []
    for k, v in enumerate(basis.T):
        comp = {names[j]: round(float(c), 4) for j, c in enumerate(v) if abs(c) > 1e-6}
        desc = ' '.join(f'{n}^{c:+.3g}' if log_mask[names.index(n)] else f'{n}{c:+.3g}'
                        for n, c in comp.items() if abs(c) >= 1e-3)
        out.append(UndeterminedDirection(free=pivots[k], exponents=comp,
                                         description=f'multiply {desc} by any common factor'))
    return out, (pivots, others)


def feedforward(v: Mapping[str, float]) -> dict[str, float]:
    """WPILib SysId's kV and kA of a voltage plant from any point of its parameters.

    ``kV = a0 / b0 = (R_m B + K_T K_b) / K_T`` and ``kA = a1 / b0 = (R_m J + B L_m) / K_T``
    with the speed transfer function ``b0 / (s^2 + a1 s + a0)``: the ratios speed-only
    data determine even where J, K_T, K_b, B, L_m are not (``kA`` includes the term
    ``B L_m / K_T``, which SysId's first-order model has no place for and which is far
    below ``R_m J / K_T`` for any motor whose electrical time constant is short).
    """
    return {'kV': (v['R_m'] * v['B'] + v['K_T'] * v['K_b']) / v['K_T'],
            'kA': (v['R_m'] * v['J'] + v['B'] * v['L_m']) / v['K_T']}


def feedforward_of(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]]
                   ) -> dict[str, float]:
    """WPILib SysId's constants of a voltage plant with its friction effects: ``kV``,
    ``kA`` (as :func:`motor_id.identify.uncertainty.feedforward`) and the static
    voltage ``kS`` (Coulomb torque through R_m / K_T, a brush drop, a dead band), per
    direction when friction is asymmetric (``kS-``, ``kV-``); with a joint's gravity
    ``kG`` (its torque through R_m / K_T) and an arm's ``offset`` [rad, in (-pi, pi]]."""
    R, K_T, K_b = params['R_m'], params['K_T'], params['K_b']
    B, J, L = params['B'], params['J'], params['L_m']
    tc = role_value(effects, 'kS', scale='torque')
    tl = role_value(effects, 'load')
    v0 = role_value(effects, 'kS', scale='input') + role_value(effects, 'dead_band')
    out = {'kS': v0 + (tc + tl) * R / K_T, 'kV': (R * B + K_T * K_b) / K_T,
           'kA': (R * J + B * L) / K_T}
    if role_keys(effects, 'kS_extra_negative') or tl:
        out['kS-'] = v0 + (tc + role_value(effects, 'kS_extra_negative') - tl) * R / K_T
        out['kV-'] = (R * (B + role_value(effects, 'kV_extra_negative')) + K_T * K_b) / K_T
    if role_keys(effects, 'kG'):   # a joint's gravity: kG [cos(theta + offset)]
        out['kG'] = role_value(effects, 'kG') * R / K_T
    if role_keys(effects, 'offset'):
        out['offset'] = math.remainder(role_value(effects, 'offset'), 2.0 * math.pi)
    return out


DELTA_STEP = 1e-6
"""Forward-difference step of :func:`delta_method` in the search coordinates."""


def delta_method(fn: Callable[[np.ndarray], Mapping[str, float]], z: np.ndarray,
                 cov: np.ndarray, n: int | None = None
                 ) -> tuple[dict[str, float], dict[str, float]]:
    """Values of ``fn`` at ``z`` and their delta-method standard deviations.

    Parameters
    ----------
    fn : callable
        Search coordinates to named quantities.
    z : ndarray, shape (d,)
        Where to evaluate (search coordinates).
    cov : ndarray, shape (d, d)
        Covariance of ``z``.
    n : int, optional
        Differentiate in the first ``n`` coordinates only (default all); the others are
        held, their entries of the gradient are 0.

    Returns
    -------
    values : dict
        ``fn(z)``.
    std : dict
        ``sqrt(g^T cov g)`` per quantity, ``g`` its forward-difference gradient (step
        :data:`DELTA_STEP`).
    """
    base = dict(fn(z))
    ups = []
    for j in range(z.size if n is None else n):
        zp = z.copy()
        zp[j] += DELTA_STEP
        ups.append(fn(zp))
    std = {}
    for key, val in base.items():
        g = np.zeros(z.size)
        for j, up in enumerate(ups):
            g[j] = (up[key] - val) / DELTA_STEP
        std[key] = float(np.sqrt(max(g @ cov @ g, 0.0)))
    return base, std


def combinations(problem: IdentificationProblem, z_best: np.ndarray, cov: np.ndarray
                 ) -> list[Combination]:
    """The transfer-function coefficients (SI), with delta-method standard errors; for a
    voltage plant fitted on speed alone also SysId's kV and kA (:func:`feedforward`) and,
    with a static-friction effect, kS (:func:`feedforward_of`)."""

    static = bool(role_keys(problem.effects, 'kS') or role_keys(problem.effects, 'dead_band')
                  or role_keys(problem.effects, 'load'))
    gravity = bool(role_keys(problem.effects, 'kG'))

    def values(z: np.ndarray) -> dict[str, float]:
        out = problem.coefficients(z, physical=True)
        if problem.kind == 'voltage' and 'current' not in problem.channels:
            v = {k: problem.units.to_physical(k, x) for k, x in problem.values_at(z).items()}
            with np.errstate(all='ignore'):
                out.update(feedforward(v))
                if static or gravity:   # T_c R_m / K_T, T_g R_m / K_T are determined
                    ff = feedforward_of(v, _effects_at(problem, z))
                    out.update({k: ff[k] for k in ('kS', 'kG') if k in ff
                                and (static or k != 'kS')})
        return out

    base, std = delta_method(values, z_best, cov, len(problem.free))
    return [Combination(name=key, value=float(val),
                        std=max(std[key], 1e-6 * abs(float(val)))) for key, val in base.items()]


def _effects_at(problem: IdentificationProblem, z: np.ndarray) -> dict[str, dict[str, float]]:
    """The effect parameters (SI) at search vector ``z``: the free ones from it, the
    others as held."""
    x = problem.from_z(z)
    effects = {e: dict(vals) for e, vals in problem.effects.items()}
    for j, name in enumerate(problem.free_effects):
        e, _, p = name.partition('.')
        effects[e][p] = float(x[len(problem.free) + j])
    return effects


def at_bound(problem: IdentificationProblem, z: np.ndarray) -> np.ndarray:
    """Per free parameter: on or within :data:`AT_BOUND` of its (log-)range from a bound.

    A linear (effect) parameter whose range starts at 0 is not at a bound near 0: a
    magnitude that small is an estimate of "hardly any" (as the analysis judges it).
    """
    d = problem.bounds.dim
    lo, hi = problem.z_bounds()
    tol = AT_BOUND * (hi - lo)
    low_open = ~problem.log_mask(d) & (lo == 0.0)
    out: np.ndarray = ((z[:d] <= lo + tol) & ~low_open) | (z[:d] >= hi - tol)
    return out


def r_m_sensitivity(problem: IdentificationProblem, z: np.ndarray, weights: np.ndarray,
                    J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Percent change of each free estimate per +1 % error in a fixed R_m (linearised).

    The estimate moves by ``dz = -cov J^T dr/dlog(R_m)`` where r are the weighted
    residuals; parameters not determined get None.
    """
    r = problem.fixed['R_m']
    h = 1e-4
    up = problem.weighted_residuals(z, weights, {'R_m': r * np.exp(h)})
    down = problem.weighted_residuals(z, weights, {'R_m': r * np.exp(-h)})
    dz: np.ndarray = -cov @ (J.T @ ((up - down) / (2 * h)))
    return dz


def parameter_covariance(names: Sequence[str], values: Mapping[str, float], cov: np.ndarray,
                         index: Mapping[str, int]) -> ParameterCovariance | None:
    """Covariance of the determined estimated physical parameters in linear SI units.

    Parameters
    ----------
    names : list of str
        Parameters to include, in order.
    values : dict
        Their SI values.
    cov : ndarray
        Covariance over the search coordinates (log of the physical parameters).
    index : dict
        ``{name: coordinate}`` (K_b under the tie maps to K_T's coordinate).
    """
    if not names:
        return None
    idx = [index[n] for n in names]
    scale = np.array([values[n] for n in names])
    m = cov[np.ix_(idx, idx)] * np.outer(scale, scale)
    return ParameterCovariance(names=list(names), matrix=m.tolist())


def bootstrap(problem: IdentificationProblem, z_best: np.ndarray, weights: np.ndarray, n_boot: int,
              rng: np.random.Generator, block: int = 50) -> np.ndarray:
    """Residual moving-block bootstrap: refit ``n_boot`` times from the estimate.

    Returns
    -------
    ndarray, shape (n_boot, d)
        Refitted parameter vectors (internal units).
    """
    y_true = problem.y.copy()
    r = -problem.output_residuals(z_best)
    y_hat = y_true - r
    samples: list[np.ndarray] = []
    try:
        for _ in range(int(n_boot)):
            r_star = np.empty_like(r)
            i = 0
            for n in problem.n_per:
                seg = r[i:i + n]
                starts = rng.integers(0, max(n - block, 1), n // block + 1)
                r_star[i:i + n] = np.concatenate([seg[s:s + block] for s in starts])[:n]
                i += n
            problem.y = y_hat + r_star
            sol = problem.refine(z_best, weights, max_nfev=20)
            samples.append(problem.from_z(sol.x))
    finally:
        problem.y = y_true
    return np.array(samples)
