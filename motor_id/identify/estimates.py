"""The result of a fit, assembled at the best parameters found: covariance, estimates,
identifiability, the determinacy verdicts and warnings, and the bootstrap intervals."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from motor_id.identify import blocks, determinacy, uncertainty
from motor_id.identify.problem import IdentificationProblem
from motor_id.identify.result import (
    Estimate,
    GaSummary,
    Identifiability,
    IdentificationResult,
    Refinement,
)

if TYPE_CHECKING:
    from motor_id.recording import Recording


def build_result(rec: Recording, problem: IdentificationProblem, x_best: np.ndarray,
                 z_best: np.ndarray, J: np.ndarray, sigma: Sequence[float], w: np.ndarray,
                 pred: np.ndarray, *, error_blocks: int, r_m_fixed_by_caller: bool
                 ) -> tuple[IdentificationResult, np.ndarray]:
    """The result at the best vector (its ``ga`` and ``refinement`` blocks left empty).

    Parameters
    ----------
    rec : Recording
    problem : IdentificationProblem
    x_best, z_best : ndarray
        The best parameter vector and search vector (with the initial state, if fitted).
    J : ndarray
        Jacobian of the weighted residuals at ``z_best``.
    sigma : sequence of float
        Estimated noise level of each fitted channel (internal units).
    w : ndarray
        The weights those noise levels give.
    pred : ndarray
        The simulated outputs at ``x_best``.
    error_blocks : int
        Contiguous blocks per run of the robust covariance's score variance.
    r_m_fixed_by_caller : bool
        R_m was among the caller's fixed values (the resistance block says so).

    Returns
    -------
    result : IdentificationResult
    covariance : ndarray
        Over the search coordinates (``Identifier.covariance_``).
    """
    names = list(problem.bounds.names)
    state_names = problem.state_names()[:z_best.size - len(names)]
    names = names + state_names
    rank, Vr, Vn, determined = uncertainty.structural(problem, z_best)
    cov_gn, cond = uncertainty.covariance(J, Vr, rank)
    ids, k = uncertainty.block_ids(problem.n_per, error_blocks)
    r_w = problem.weighted_residuals(z_best, w)
    cov_rob = uncertainty.robust_covariance(J, r_w, Vr, ids, k)
    fit, prediction = blocks.fit_block(rec, problem, x_best, sigma, pred, names, state_names)
    # white: by the portmanteau test and by the fit block's own lag-by-lag verdict, so
    # that the report never calls residuals white in one place and correlated in another
    n_data = sum(problem.n_per)
    white = uncertainty.residuals_white(r_w[:n_data], problem.n_per, w[:n_data]) and \
        all(m.white for m in fit.channels.values())
    cov = uncertainty.combine(cov_gn, cov_rob, white)
    lg = problem.log_mask(len(names))
    std_z = np.sqrt(np.maximum(np.diag(cov), 0.0))
    bound = np.zeros(len(names), dtype=bool)
    bound[:problem.bounds.dim] = uncertainty.at_bound(problem, z_best)
    params = blocks.estimates(problem, names, x_best, std_z, lg, determined, bound)
    undetermined, _ = uncertainty.undetermined_directions(names, Vn, determined, lg)
    prior, by_data = blocks.prior_verdict(problem, z_best)
    idf = Identifiability(
        rank=rank - len(state_names), n_free=len(names) - len(state_names),
        free=names[:len(names) - len(state_names)], nuisance=state_names, condition=cond,
        basis='transfer-function coefficients (structural); covariance from output '
              'sensitivities on the identifiable subspace',
        fully_determined=rank == len(names), tie_K_T_eq_K_b=bool(problem.tie),
        channels=list(problem.channels),
        error_bars='Gauss-Newton (the residuals are white)' if white else
                   'the larger of Gauss-Newton and block sandwich (the residuals are '
                   'correlated)',
        prior=prior, r_m_determined_by_data=by_data)
    warnings = _honesty(rec, problem, params)
    adequate, why = determinacy.adequacy(
        {ch: m.fit_percent for ch, m in fit.channels.items()})
    if not adequate:
        for e in params.values():
            if not e.assumed and e.determined:
                determinacy.mark_undetermined(e, why[0])
    result = IdentificationResult(
        adequate=adequate, warnings=why + warnings,
        method=problem.method, input_kind=problem.kind, channels=problem.channels,
        parameters=params,
        identifiable_combinations=uncertainty.combinations(problem, z_best, cov),
        undetermined_directions=undetermined, identifiability=idf, fit=fit,
        ga=GaSummary(generations=0, evaluations=0, seconds=0.0), refinement=Refinement(),
        assumptions=blocks.assumptions_block(problem),
        effects=blocks.effects_block(problem, x_best, std_z, determined, bound),
        prediction=prediction, parameter_covariance=blocks.covariance_block(
            problem, params, names, cov),
        units=problem.units.rescaling())
    if problem.kind == 'voltage':
        result.resistance = blocks.resistance_block(problem, params, r_m_fixed_by_caller)
        if problem.r_m_prior is None:
            dz = uncertainty.r_m_sensitivity(problem, z_best, w, J, cov_gn)
            result.r_m_sensitivity = blocks.sensitivity_block(problem, params, names, dz)
    return result, cov


def _honesty(rec: Recording, problem: IdentificationProblem, params: dict[str, Estimate]
             ) -> list[str]:
    """Floors the stds and marks what this record leaves open (warnings)."""
    for e in params.values():
        if not e.assumed:
            e.std = determinacy.floor_std(e.value, e.std)
    noise = {ch: determinacy.relative_noise(getattr(rec, ch)) for ch in problem.channels}
    r_m = params['R_m'].value if 'R_m' in params else None
    return determinacy.practical(params, rec.sample_period, noise, r_m)


def bootstrap_intervals(problem: IdentificationProblem, result: IdentificationResult,
                        z_best: np.ndarray, w: np.ndarray, rng: np.random.Generator,
                        n: int) -> None:
    """Set the 95 % percentile interval of every determined estimated parameter from
    ``n`` residual-bootstrap refits (:func:`motor_id.identify.uncertainty.bootstrap`)."""
    samples = uncertainty.bootstrap(problem, z_best, w, n, rng)
    names = list(problem.bounds.names)
    for name, e in result.parameters.items():
        src = 'K_T' if (problem.tie and name == 'K_b') else name
        if e.determined and not e.assumed and src in names:
            col = samples[:, names.index(src)]
            lo, hi = np.percentile(col, 2.5), np.percentile(col, 97.5)
            e.ci95 = (problem.units.to_physical(src, float(lo)),
                      problem.units.to_physical(src, float(hi)))
    result.refinement = replace(result.refinement, bootstrap=int(n))
