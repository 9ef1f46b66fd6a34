"""The pieces of a fit's result: estimates, effects, fit metrics, prior verdict,
covariance, R_m sensitivity, assumptions, resistance and GA blocks, each built from the
fitted problem."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import cast, TYPE_CHECKING

import numpy as np

from motor_id.identify import determinacy, uncertainty
from motor_id.identify.problem import IdentificationProblem
from motor_id.identify.result import (
    Assumptions,
    EffectEstimate,
    EffectValues,
    Estimate,
    FitQuality,
    GaSummary,
    ParameterCovariance,
    Prior,
    Resistance,
)
from motor_id.identify.space import SPEED_ONLY_R_M, TORQUE_FREE
from motor_id.metrics import channel_metrics
from motor_id.model import PARAM_NAMES

if TYPE_CHECKING:
    from motor_id.ga import GeneticAlgorithm
    from motor_id.identify.result import IdentificationResult
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
                  determined: np.ndarray, bound: np.ndarray) -> EffectValues:
    """The fit's effects: the held values, and an :class:`EffectEstimate` of each free
    effect parameter."""
    eff_out: EffectValues = {e: dict(v) for e, v in problem.effects.items()}
    for j, fe in enumerate(problem.free_effects):
        e, _, p = fe.partition('.')
        k = len(problem.free) + j
        eff_out[e][p] = EffectEstimate(
            value=float(x_best[k]),
            std=determinacy.floor_std(x_best[k], std_z[k]) if determined[k] else None,
            determined=bool(determined[k]), at_bound=bool(bound[k]))
    return eff_out


def fit_block(rec: Recording, problem: IdentificationProblem, x_best: np.ndarray,
               sigma: Sequence[float],
               pred: np.ndarray, names: list[str], state_names: list[str]
               ) -> tuple[FitQuality, dict[str, np.ndarray]]:
    """Per-channel fit metrics (in the data's units) and the predictions."""
    un = problem.units
    channels, noise_std = {}, {}
    prediction: dict[str, np.ndarray] = {'time': rec.time, 'input': rec.input}
    i = 0
    for ch, n, sg in zip(problem.channels, problem.n_per, sigma, strict=True):
        m = channel_metrics(problem.y[i:i + n], pred[i:i + n], problem.input)
        channels[ch] = replace(m, rms=float(un.physical_signal(m.rms, ch)))
        noise_std[ch] = float(un.physical_signal(sg, ch))
        prediction[ch] = un.physical_signal(pred[i:i + n], ch)
        prediction[ch + '_measured'] = getattr(rec, ch)
        i += n
    fit = FitQuality(
        channels=channels, noise_std=noise_std,
        cost=float(np.mean(((pred - problem.y) * problem.weights) ** 2)),
        initial_state={n: float(un.physical_signal(x_best[names.index(n)], n.split(':')[1]))
                       for n in state_names})
    return fit, prediction


def prior_verdict(problem: IdentificationProblem, z_best: np.ndarray
                  ) -> tuple[str | None, bool | None]:
    """What R_m's prior does to the identifiability verdict: ``(prior, by_data)``, the
    ``prior`` and ``r_m_determined_by_data`` of the verdict (None, None without a prior)."""
    if problem.r_m_prior is None:
        return None, None
    j = problem.r_m_prior[0]
    by_data = bool(uncertainty.structural(problem, z_best, prior=False)[3][j])
    given, tol = problem.R_m_given, problem.R_m_tolerance
    text = (f'R_m is estimated with a Gaussian prior N({given:.4g}, ({tol:.0%} of it)^2) Ohm '
            '(one extra residual); ' +
            ('the data alone determine it (steady states V = R_m i + K_b w)' if by_data
             else 'the data alone do not determine it: the prior does'))
    return text, by_data


def covariance_block(problem: IdentificationProblem, params: dict[str, Estimate],
                      names: list[str], cov: np.ndarray) -> ParameterCovariance | None:
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


def assumptions_block(problem: IdentificationProblem) -> Assumptions:
    """``assumptions``: what the fit took as given (R_m, its prior, K_T = K_b, fixed values,
    the discretisation), SI."""
    fixed = {k: problem.units.to_physical(k, v) for k, v in problem.fixed.items()}
    return Assumptions(
        R_m=fixed.get('R_m'), R_m_given=problem.R_m_given,
        R_m_prior=None if problem.r_m_prior is None else Prior(
            mean=problem.R_m_given,
            std=problem.R_m_tolerance * cast(float, problem.R_m_given)),
        K_T_eq_K_b=bool(problem.tie),
        fixed={k: v for k, v in fixed.items() if k != 'R_m'},
        discretisation=problem.discretisation)


def resistance_block(problem: IdentificationProblem, params: dict[str, Estimate],
                     fixed_by_caller: bool) -> Resistance:
    """``resistance`` of a voltage plant: the given R_m, the estimate and what it says
    (``fixed_by_caller``: R_m was among the caller's fixed values)."""
    given = cast(float, problem.R_m_given)  # a voltage plant's
    if problem.r_m_prior is None:
        if fixed_by_caller:
            why = 'fixed by --fix R_m'
        elif 'current' not in problem.channels:
            why = 'no current channel fitted: the data cannot see R_m; see ' \
                  'r_m_sensitivity for what an error in it does'
        else:
            why = 'the paper method holds R_m fixed'
        return Resistance(given=given, estimate=given, std=None, relative_change=0.0,
                          estimated=False, note=why)
    e = params['R_m']
    if e.value is None:
        return Resistance(given=given, estimate=given, std=None, relative_change=0.0,
                          estimated=False, note=e.reason or 'not determined',
                          prior_std=problem.R_m_tolerance * given)
    rel = e.value / given - 1.0
    prior_std = problem.R_m_tolerance
    if e.std is None or e.std > 0.5 * prior_std * given:
        note = 'the data hardly determine R_m; the estimate leans on the given value'
    elif abs(rel) <= max(2 * e.std / given, 0.01):
        note = 'consistent with the given value'
    elif rel > 0:
        note = 'a warm motor, or leads and brushes in series?'
    else:
        note = 'below the given value: a cold motor, or a wrong --resistance?'
    if e.at_bound:
        note += '; at its search bound'
    return Resistance(given=given, estimate=e.value, std=e.std, relative_change=rel,
                      estimated=True, note=note, prior_std=prior_std * given)


def unseen_resistance(result: IdentificationResult, given: float | None) -> None:
    """Mark R_m as not entering ``result`` (fitted at :data:`~.space.SPEED_ONLY_R_M`):
    its estimate not determined, the ``resistance`` block saying so, no sensitivity."""
    note = (f'R_m does not enter: speed-only voltage data determine kS, kV, kA and the '
            f'speed transfer function, which are the same at any R_m; fitted at an '
            f'internal {SPEED_ONLY_R_M:g} Ohm')
    result.parameters['R_m'] = Estimate(particular_value=SPEED_ONLY_R_M, reason=note)
    result.resistance = Resistance(
        given=given, estimate=None, std=None, relative_change=None, estimated=False,
        enters=False, internal=SPEED_ONLY_R_M,
        note=note + ('' if given is None else f'; the given {given:g} Ohm is not used'))
    result.r_m_sensitivity = None


def ga_block(problem: IdentificationProblem, ga: GeneticAlgorithm | None,
             ga_seconds: float) -> GaSummary:
    """``ga``: the GA's settings, stop reason and history (best parameters SI)."""
    if ga is None:
        return GaSummary(generations=0, evaluations=0, seconds=ga_seconds)
    history = list(ga.history_)
    if problem.units.rescaled:
        history = [replace(h, best={k: problem.units.to_physical(k, v)
                                    for k, v in h.best.items()}) for h in history]
    return GaSummary(generations=ga.generation_, evaluations=ga.evaluations_,
                     seconds=ga_seconds, best_cost=ga.best_cost_, stop=dict(ga.stop()),
                     population=ga.population, crossover=ga.crossover,
                     mutation=ga.mutation, history=history)
