"""The optimisation of a fit: the paper's GA over the problem's box, then bounded least squares
from its best individuals, re-weighted by the estimated noise levels."""

from __future__ import annotations

from collections.abc import Callable, Mapping
import time
from typing import cast

import numpy as np

from motor_id.errors import ConfigError, IdentificationError
from motor_id.ga import GeneticAlgorithm
from motor_id.identify import uncertainty
from motor_id.identify.problem import IdentificationProblem
from motor_id.identify.result import Refinement

Progress = Callable[[int, int, float], object]
"""``progress(generation, generations, best_cost)``; returning True cancels the GA."""


def run_ga(problem: IdentificationProblem, rng: np.random.Generator,
           progress: Progress | None, *, start: Mapping[str, float] | None, use_ga: bool,
           population: int, generations: int, crossover: float, mutation: float
           ) -> tuple[GeneticAlgorithm | None, np.ndarray, float]:
    """The paper's network training, seeded with ``start`` (SI) if given.

    Returns
    -------
    ga : GeneticAlgorithm or None
        None when ``use_ga`` is off (the start is then the best vector).
    best : ndarray
        The best parameter vector (internal units).
    seconds : float
    """
    t_ga = time.perf_counter()
    x_start = None
    if start is not None:
        x_start = problem.start_vector(start)
    if not use_ga:
        if x_start is None:
            raise ConfigError('use_ga=False needs a start parameter set')
        return None, x_start, time.perf_counter() - t_ga
    ga = GeneticAlgorithm(problem.bounds, population, generations, crossover, mutation,
                          x0=x_start, random_state=rng)
    search = problem.for_search()   # a jittered log's intervals rounded for the GA
    while not ga.stop():
        with np.errstate(over='ignore'):  # Bounds.decode takes exp of linear genes too
            X = ga.ask()
        ga.tell(search.cost(X))
        if progress is not None and progress(ga.generation_, ga.generations, ga.best_cost_):
            ga.cancel()
    problem.evaluations = search.evaluations
    if not np.isfinite(ga.best_cost_):
        raise IdentificationError('no parameter set inside the search bounds gives a '
                                  'finite simulation: check the units of the data and '
                                  'the search bounds', params=('bounds',))
    return ga, cast(np.ndarray, ga.best_), time.perf_counter() - t_ga


def refine(problem: IdentificationProblem, ga: GeneticAlgorithm | None, best: np.ndarray, *,
           method: str, refine_starts: int, reweight: int, max_nfev: int
           ) -> tuple[np.ndarray, Refinement]:
    """Least squares from the GA's best individuals (not for ``paper``).

    Returns
    -------
    z_best : ndarray
        The best search vector; with the initial state unless ``method`` is ``paper``.
    info : Refinement
        The result's ``refinement`` block.
    """
    z_best = problem.to_z(best)
    if method == 'paper':
        return z_best, Refinement(used=False)
    # the refinement also estimates the initial state (nuisance parameters):
    # starting from a noisy first sample would bias the fit
    z_best = np.concatenate([z_best, problem.x0])
    starts = [z_best]
    if ga is not None and refine_starts > 1:
        order = np.argsort(cast(np.ndarray, ga.costs_))
        pop = problem.to_z(ga.bounds.decode(ga.genes_))
        for k in order:
            if len(starts) >= refine_starts:
                break
            zk = np.concatenate([pop[k], problem.x0])
            if all(np.max(np.abs(zk - s)) > 0.05 for s in starts):
                starts.append(zk)
    sols = [problem.refine(s, problem.weights, max_nfev) for s in starts]
    sol = min(sols, key=lambda s: s.cost)
    z_best = sol.x
    # re-weight by the estimated noise levels and restart until the cost settles
    # (a trust-region run can stall on a tiny step far from the optimum)
    for _ in range(reweight):
        w = uncertainty.noise_levels(problem, z_best)[1]
        prev = np.sum(problem.weighted_residuals(z_best, w) ** 2)
        sol = problem.refine(z_best, w, max_nfev)
        z_best = sol.x
        if prev - 2 * sol.cost <= 1e-9 * prev:
            break
    return z_best, Refinement(used=True, starts=len(starts), nfev=int(sol.nfev),
                              status=int(sol.status), message=str(sol.message))
