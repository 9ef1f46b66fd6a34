"""The pieces of a fit's result: estimates, effects, fit metrics, prior verdict,
covariance and R_m sensitivity blocks, each built from the fitted problem."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast, TYPE_CHECKING

import numpy as np

from motor_id.identify import determinacy, uncertainty
from motor_id.identify.problem import IdentificationProblem
from motor_id.identify.result import Estimate
from motor_id.identify.space import TORQUE_FREE
from motor_id.metrics import channel_metrics
from motor_id.model import PARAM_NAMES

if TYPE_CHECKING:
    from motor_id.recording import Recording

def estimates(problem: IdentificationProblem, names: list[str], x_best: np.ndarray,
               std_z: np.ndarray, lg: np.ndarray, determined: np.ndarray, bound: np.ndarray
               ) -> dict[str, Estimate]:
    """Estimates of every plant parameter (SI)."""
    params: dict[str, Estimate] = {}
    all_names = list(PARAM_NAMES) if problem.kind == 'voltage' else list(TORQUE_FREE)
    for n in all_names:
        if n in problem.fixed:
            params[n] = Estimate(problem.units.to_physical(n, problem.fixed[n]), 0.0, True,
                                 assumed=True)
            continue
        src = 'K_T' if (problem.tie and n == 'K_b') else n
        j = names.index(src)
        value = problem.units.to_physical(src, float(x_best[j]))
        if determined[j]:
            std = std_z[j] * x_best[j] if lg[j] else std_z[j]
            params[n] = Estimate(value, problem.units.to_physical(src, float(std)), True,
                                 at_bound=bool(bound[j]))
        else:
            params[n] = Estimate(None, None, False, particular_value=value,
                                 at_bound=bool(bound[j]))
    return params


def effects_block(problem: IdentificationProblem, x_best: np.ndarray, std_z: np.ndarray,
                   determined: np.ndarray, bound: np.ndarray) -> dict[str, dict[str, Any]]:
    eff_out: dict[str, dict[str, Any]] = {e: dict(v) for e, v in problem.effects.items()}
    for j, fe in enumerate(problem.free_effects):
        e, _, p = fe.partition('.')
        k = len(problem.free) + j
        eff_out[e][p] = {'value': float(x_best[k]),
                         'std': determinacy.floor_std(x_best[k], std_z[k])
                         if determined[k] else None,
                         'determined': bool(determined[k]), 'at_bound': bool(bound[k])}
    return eff_out


def fit_block(rec: Recording, problem: IdentificationProblem, x_best: np.ndarray,
               sigma: Sequence[float],
               pred: np.ndarray, names: list[str], state_names: list[str]
               ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Per-channel fit metrics (in the data's units) and the predictions."""
    un = problem.units
    fit: dict[str, Any] = {'channels': {}, 'noise_std': {}}
    prediction: dict[str, np.ndarray] = {'time': rec.time, 'input': rec.input}
    i = 0
    for ch, n, sg in zip(problem.channels, problem.n_per, sigma, strict=True):
        m = channel_metrics(problem.y[i:i + n], pred[i:i + n], problem.input)
        m['rms'] = float(un.physical_signal(m['rms'], ch))
        fit['channels'][ch] = m
        fit['noise_std'][ch] = float(un.physical_signal(sg, ch))
        prediction[ch] = un.physical_signal(pred[i:i + n], ch)
        prediction[ch + '_measured'] = getattr(rec, ch)
        i += n
    fit['cost'] = float(np.mean(((pred - problem.y) * problem.weights) ** 2))
    fit['initial_state'] = {n: float(un.physical_signal(x_best[names.index(n)],
                                                        n.split(':')[1]))
                            for n in state_names}
    return fit, prediction


def prior_verdict(problem: IdentificationProblem, z_best: np.ndarray) -> dict[str, Any]:
    """What R_m's prior does to the identifiability verdict (empty without a prior)."""
    if problem.r_m_prior is None:
        return {}
    j = problem.r_m_prior[0]
    by_data = bool(uncertainty.structural(problem, z_best, prior=False)[3][j])
    given, tol = problem.R_m_given, problem.R_m_tolerance
    text = (f'R_m is estimated with a Gaussian prior N({given:.4g}, ({tol:.0%} of it)^2) Ohm '
            '(one extra residual); ' +
            ('the data alone determine it (steady states V = R_m i + K_b w)' if by_data
             else 'the data alone do not determine it: the prior does'))
    return {'prior': text, 'r_m_determined_by_data': by_data}


def covariance_block(problem: IdentificationProblem, params: dict[str, Estimate],
                      names: list[str], cov: np.ndarray) -> dict[str, Any] | None:
    """``parameter_covariance`` over the determined estimated plant parameters (SI)."""
    index: dict[str, int] = {}
    values: dict[str, float] = {}
    for n, e in params.items():
        src = 'K_T' if (problem.tie and n == 'K_b') else n
        if e.determined and not e.assumed and src in names:
            index[n] = names.index(src)
            values[n] = cast(float, e.value)  # determined: a value
    return uncertainty.parameter_covariance(list(index), values, cov, index)


def sensitivity_block(problem: IdentificationProblem, params: dict[str, Estimate],
                       names: list[str], dz: np.ndarray) -> dict[str, float | None]:
    """``{name: % change per +1 % in R_m}`` of the determined estimated parameters."""
    out: dict[str, float | None] = {}
    for n, e in params.items():
        if e.assumed:
            continue
        src = 'K_T' if (problem.tie and n == 'K_b') else n
        out[n] = float(dz[names.index(src)]) if e.determined else None
    return out
