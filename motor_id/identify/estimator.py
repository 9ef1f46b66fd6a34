"""The estimator: GA fit of the constrained Elman net, then least-squares refinement."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
import math
import time
from typing import Any, cast, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.errors import ConfigError, IdentificationError, MotorIdError
from motor_id.ga import GeneticAlgorithm
from motor_id.identify import blocks, determinacy, uncertainty
from motor_id.identify.problem import IdentificationProblem
from motor_id.identify.result import Estimate, IdentificationResult
from motor_id.model import PARAM_NAMES

if TYPE_CHECKING:
    from motor_id.recording import Recording

_Progress = Callable[[int, int, float], object]

WIDEN = 1e3
"""Factor by which a side of the default box that a fit sits on is moved outward."""
PRIOR_DOMINATES = 0.7071
"""R_m's posterior std above this fraction of its prior's: the prior carries more of the
estimate than the data do."""
WIDEN_ROUNDS = 3
"""Largest number of widenings (a freed inertia may push the viscous friction to its
bound, as on a hobby motor)."""
_SETTINGS = ('method', 'R_m', 'tie', 'population', 'generations', 'crossover', 'mutation',
             'random_state', 'fixed', 'bounds', 'channels', 'effects', 'free_effects',
             'start', 'use_ga', 'bootstrap', 'refine_starts', 'R_m_tolerance', 'widen',
             'error_blocks', 'settle', 'reweight', 'max_nfev', 'quick_jacobian')


class Identifier:
    """Estimate physical motor parameters from a recording.

    Parameters
    ----------
    method : {'zoh', 'euler', 'paper'}
    R_m : float
        Given armature resistance [Ohm] (an ohmmeter reading); required for a voltage
        plant. With a fitted current channel (not ``paper``) and R_m not in ``fixed``,
        R_m is estimated with this value as a Gaussian prior; otherwise it is held fixed.
    R_m_tolerance : float
        Relative standard deviation of that prior (0.10: the given value is good to
        about 10 %).
    tie : bool or None
        Impose K_T = K_b (SI units). ``None``: on when a current channel is present and
        the method is not ``paper``.
    population, generations, crossover, mutation : GA settings (the paper's defaults).
    random_state : int, Generator or None
    fixed : dict, optional
        Known values ``{name: value}``: an explicit extra assumption; those parameters are
        not fitted (``{'R_m': v}`` holds R_m fixed).
    bounds : dict, optional
        ``{name: (low, high)}`` search ranges overriding the defaults; effect
        parameters are named ``effect.param``.
    channels : tuple, optional
        Output channels to fit; default all measured (``paper``: speed only).
    effects : dict, optional
        ``{effect: {param: value}}`` terms included in the model (from
        :data:`motor_id.model.EFFECTS`).
    free_effects : sequence of str, optional
        ``'effect.param'`` entries of ``effects`` to estimate.
    start : dict, optional
        A starting parameter set; seeds the GA and the refinement.
    use_ga : bool
        False skips the GA and refines from ``start`` only (warm starts).
    bootstrap : int
        Number of residual-bootstrap refits for percentile intervals (0 = off).
    refine_starts : int
        Number of distinct GA individuals the refinement starts from.
    widen : bool
        A physical parameter that the GA's fit leaves on a side of the *default* box (a
        hobby motor's inertia below 1e-6 kg m^2, say) is not an estimate: that side is
        moved :data:`WIDEN` times outward and the fit repeated, up to
        :data:`WIDEN_ROUNDS` times, keeping the lower cost. Ranges given in ``bounds``,
        fixed parameters and R_m (held by its prior) are never widened; nor are warm
        starts (``use_ga=False``). ``widened_`` holds the ranges that were moved.
    error_blocks : int
        Contiguous blocks per run of the robust covariance's score variance
        (:func:`motor_id.identify.uncertainty.robust_covariance`).
    settle : bool
        Refit without what the record cannot carry (a current channel the model does not
        explain, an R_m its prior holds): see :meth:`_settle`. The discrepancy analysis
        turns it off for its candidates, which must all be scored on the same channels.
    reweight : int
        Largest number of refinements re-weighted by the estimated noise levels.
    max_nfev : int
        Largest number of residual evaluations of each least-squares refinement.
    quick_jacobian : bool
        One-sided differences in the refinement's Jacobian (the analysis ranks its
        candidates with them); the covariance always uses central differences.
    """

    def __init__(self, method: str = 'zoh', R_m: float | None = None, tie: bool | None = None,
                 population: int = 20, generations: int = 160, crossover: float = 0.75,
                 mutation: float = 0.04,
                 random_state: int | np.random.Generator | None = None,
                 fixed: Mapping[str, float] | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None,
                 channels: Iterable[str] | None = None,
                 effects: Mapping[str, Mapping[str, float]] | None = None,
                 free_effects: Iterable[str] | None = None,
                 start: Mapping[str, float] | None = None, use_ga: bool = True,
                 bootstrap: int = 0, refine_starts: int = 3, R_m_tolerance: float = 0.10,
                 widen: bool = True, error_blocks: int = 10, settle: bool = True,
                 reweight: int = 4, max_nfev: int = 60, quick_jacobian: bool = False) -> None:
        self.method = method
        self.R_m = R_m
        self.tie = tie
        self.population = population
        self.generations = generations
        self.crossover = crossover
        self.mutation = mutation
        self.random_state = random_state
        self.fixed = fixed
        self.bounds = bounds
        self.channels = channels
        self.effects = effects
        self.free_effects = free_effects
        self.start = start
        self.use_ga = use_ga
        self.bootstrap = bootstrap
        self.refine_starts = refine_starts
        self.R_m_tolerance = R_m_tolerance
        self.widen = widen
        self.error_blocks = error_blocks
        self.settle = settle
        self.reweight = reweight
        self.max_nfev = max_nfev
        self.quick_jacobian = quick_jacobian

    def fit(self, rec: Recording, progress: _Progress | None = None,
            sample_weight: ArrayLike | None = None) -> Identifier:
        """Fit the model to a recording.

        Parameters
        ----------
        rec : motor_id.recording.Recording
        progress : callable, optional
            ``progress(generation, generations, best_cost)``; returning True cancels
            the GA (the best so far is then refined and reported).
        sample_weight : array_like, shape (N,), optional
            Non-negative weight of each sample in the cost (every channel); 0 leaves a
            sample out of the fit while the simulation still runs through it (held-out
            blocks for validation).

        Returns
        -------
        self
            With ``result_`` (:class:`IdentificationResult`), ``params_`` (dict, SI),
            ``problem_`` (:class:`IdentificationProblem`), ``covariance_`` (ndarray over
            the search coordinates: log of the positive parameters, then the initial
            state) and ``history_`` (GA generations).

        Raises
        ------
        ConfigError, DataError
            Bad settings or unusable data.
        IdentificationError
            The fit could not produce a finite result (a diverging model, a numerical
            failure); the message says why.
        """
        t_start = time.perf_counter()
        rec.validate()
        try:
            self._fit(rec, progress, sample_weight)
            self.widened_: dict[str, tuple[float, float]] = {}
            if self.widen and self.use_ga:
                self._widen(rec, progress, sample_weight)
            if self.settle:
                self._settle(rec, progress, sample_weight)
        except MotorIdError:
            raise
        except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
            raise IdentificationError(f'the fit failed ({type(exc).__name__}: {exc})') \
                from exc
        self.result_.seconds = time.perf_counter() - t_start
        return self

    def _widen(self, rec: Recording, progress: _Progress | None,
               sample_weight: ArrayLike | None) -> None:
        """Refit with the default box widened where a physical parameter sits on it."""
        for _ in range(WIDEN_ROUNDS):
            sides = self._on_default_bound()
            if not sides:
                return
            again = self._variant(bounds={**(self.bounds or {}), **self.widened_, **sides})
            again._fit(rec, progress, sample_weight)
            if not again.result_.fit['cost'] <= self.result_.fit['cost']:
                return
            self._adopt(again, 'history_')
            self.widened_.update(sides)
            self.result_.fit['widened'] = {k: [float(lo), float(hi)]
                                           for k, (lo, hi) in self.widened_.items()}

    def _settle(self, rec: Recording, progress: _Progress | None,
                sample_weight: ArrayLike | None) -> None:
        """Refit without what the record cannot carry (a warm start from the estimate).

        A current channel that takes fewer than :data:`determinacy.MIN_LEVELS` values, or
        that the model explains less than :data:`determinacy.CHANNEL_FIT` %, is left out
        (it would only drag the speed fit and R_m); an R_m whose estimate leans on its
        prior more than on the data (posterior std above 1/sqrt(2) of the prior's) is
        held at the given value. The warnings say which and why.
        """
        res = self.result_
        notes: list[str] = []
        channels, fixed = self.channels, dict(self.fixed or {})
        cur = res.fit['channels'].get('current')
        if cur is not None and self.channels is None and rec.current is not None:
            levels = determinacy.channel_levels(rec.current)
            why: str | None
            if levels < determinacy.MIN_LEVELS:
                why = f'the current takes only {levels} distinct values'
            elif not cur['fit_percent'] >= determinacy.CHANNEL_FIT:
                why = f'the model explains {cur["fit_percent"]:.1f} % of the current'
            else:
                why = None
            if why:
                channels = ('speed',)
                notes.append(f'{why}: it cannot carry R_m or L_m; fitted on the speed '
                             'alone with R_m at the given value')
        r = res.resistance or {}
        if channels is self.channels and r.get('estimated') and (
                r.get('std') is None or r['std'] > PRIOR_DOMINATES * r['prior_std']
                or not res.identifiability.get('r_m_determined_by_data', True)):
            fixed['R_m'] = r['given']
            notes.append(f'the data do not determine R_m; the given value '
                         f'{r["given"]:.4g} Ohm is used')
        if not notes:
            return
        start = {k: v for k, v in self.params_.items() if v is not None}
        again = self._variant(fixed=fixed, channels=channels, start=start, use_ga=False,
                              bounds={**(self.bounds or {}), **self.widened_} or None)
        again._fit(rec, None, sample_weight)
        res2 = again.result_
        res2.ga, res2.warnings = res.ga, notes + res2.warnings
        if res2.resistance is not None and 'R_m' in fixed and 'R_m' not in (self.fixed or {}):
            res2.resistance['note'] = notes[-1]
            res2.resistance['data_estimate'] = {'value': r.get('estimate'),
                                                'std': r.get('std')}
        self._adopt(again)

    def _variant(self, **changes: Any) -> Identifier:
        """An unwidened Identifier with these settings changed (the refits above)."""
        return Identifier(**{**{k: getattr(self, k) for k in _SETTINGS}, 'widen': False,
                             **changes})

    def _adopt(self, other: Identifier, *extra: str) -> None:
        """Take over the fitted state of ``other`` (and the ``extra`` attributes)."""
        for attr in ('problem_', 'result_', 'params_', 'covariance_', *extra):
            setattr(self, attr, getattr(other, attr))

    def _on_default_bound(self) -> dict[str, tuple[float, float]]:
        """``{name: (low, high)}`` SI: the widened range of each physical parameter the
        fit left on a side of the default box (never one the caller bounded)."""
        prob = self.problem_
        params = self.result_.to_dict()['parameters']
        caller = set(self.bounds or {})
        out: dict[str, tuple[float, float]] = {}
        for name, lo, hi in zip(prob.bounds.names, prob.bounds.low, prob.bounds.high, strict=True):
            v = params.get(name, {})
            x = v.get('value', v.get('particular_value'))
            if x is None:
                x = v.get('particular_value')
            structural = v.get('value') is None and not v.get('reason')
            if name not in PARAM_NAMES or name == 'R_m' or name in caller or \
                    not v.get('at_bound') or x is None or structural:
                continue  # (an undetermined parameter's place in the box is arbitrary)
            if name in self.widened_:
                lo, hi = self.widened_[name]
            else:
                lo, hi = (prob.units.to_physical(name, x) for x in (lo, hi))
            near_lo = x <= lo or (x < hi and math.log(x / lo) < math.log(hi / x))
            out[name] = (lo / WIDEN, hi) if near_lo else (lo, hi * WIDEN)
        return out

    def _fit(self, rec: Recording, progress: _Progress | None,
             sample_weight: ArrayLike | None) -> None:
        problem = IdentificationProblem(
            rec, method=self.method, R_m=self.R_m, R_m_tolerance=self.R_m_tolerance,
            tie=self.tie, fixed=self.fixed, bounds=self.bounds, channels=self.channels,
            effects=self.effects, free_effects=self.free_effects,
            sample_weight=sample_weight)
        self.problem_ = problem
        rng = np.random.default_rng(self.random_state)   # a Generator comes back as is
        ga, best, ga_seconds = self._run_ga(problem, rng, progress)
        problem.forward_differences = bool(self.quick_jacobian)
        z_best, refine_info = self._refine(problem, ga, best)
        problem.forward_differences = False
        x_best = problem.from_z(z_best)
        with np.errstate(all='ignore'):
            pred = problem.simulate(x_best[None, :])[0]
        if not (np.all(np.isfinite(x_best)) and np.all(np.isfinite(pred))):
            raise IdentificationError('the model diverges at the best parameters found: '
                                      'check the units of the data and the --bounds')
        sigma, w = uncertainty.noise_levels(problem, z_best)
        J = problem.jacobian_z(z_best, w)
        result = self._build_result(rec, problem, x_best, z_best, J, sigma, w, pred)
        result.ga = self._ga_block(problem, ga, ga_seconds)
        result.refinement = refine_info
        if self.bootstrap and self.method != 'paper':
            self._bootstrap(problem, result, z_best, w, rng)
        self.result_ = result
        self.params_ = result.values()
        self.history_ = [] if ga is None else [h.to_dict() for h in ga.history_]

    # -------------------------------------------------------------- the search
    def _run_ga(self, problem: IdentificationProblem, rng: np.random.Generator,
                progress: _Progress | None
                ) -> tuple[GeneticAlgorithm | None, np.ndarray, float]:
        """The paper's network training; returns (ga or None, best vector, seconds)."""
        t_ga = time.perf_counter()
        x_start = None
        if self.start is not None:
            x_start = problem.start_vector(self.start)
        if not self.use_ga:
            if x_start is None:
                raise ConfigError('use_ga=False needs a start parameter set')
            return None, x_start, time.perf_counter() - t_ga
        ga = GeneticAlgorithm(problem.bounds, self.population, self.generations,
                              self.crossover, self.mutation, x0=x_start, random_state=rng)
        while not ga.stop():
            with np.errstate(over='ignore'):  # Bounds.decode takes exp of linear genes too
                X = ga.ask()
            ga.tell(problem.cost(X))
            if progress is not None and progress(ga.generation_, ga.generations,
                                                 ga.best_cost_):
                ga.cancel()
        if not np.isfinite(ga.best_cost_):
            raise IdentificationError('no parameter set inside the search bounds gives a '
                                      'finite simulation: check the units of the data and '
                                      'the --bounds')
        return ga, cast(np.ndarray, ga.best_), time.perf_counter() - t_ga

    def _refine(self, problem: IdentificationProblem, ga: GeneticAlgorithm | None, best: np.ndarray
                ) -> tuple[np.ndarray, dict[str, Any]]:
        """Least squares from the GA's best individuals (not for ``paper``)."""
        z_best = problem.to_z(best)
        if self.method == 'paper':
            return z_best, {'used': False}
        # the refinement also estimates the initial state (nuisance parameters):
        # starting from a noisy first sample would bias the fit
        z_best = np.concatenate([z_best, problem.x0])
        starts = [z_best]
        if ga is not None and self.refine_starts > 1:
            order = np.argsort(cast(np.ndarray, ga.costs_))
            pop = problem.to_z(ga.bounds.decode(ga.genes_))
            for k in order:
                if len(starts) >= self.refine_starts:
                    break
                zk = np.concatenate([pop[k], problem.x0])
                if all(np.max(np.abs(zk - s)) > 0.05 for s in starts):
                    starts.append(zk)
        sols = [problem.refine(s, problem.weights, self.max_nfev) for s in starts]
        sol = min(sols, key=lambda s: s.cost)
        z_best = sol.x
        # re-weight by the estimated noise levels and restart until the cost settles
        # (a trust-region run can stall on a tiny step far from the optimum)
        for _ in range(self.reweight):
            w = uncertainty.noise_levels(problem, z_best)[1]
            prev = np.sum(problem.weighted_residuals(z_best, w) ** 2)
            sol = problem.refine(z_best, w, self.max_nfev)
            z_best = sol.x
            if prev - 2 * sol.cost <= 1e-9 * prev:
                break
        return z_best, {'used': True, 'starts': len(starts), 'nfev': int(sol.nfev),
                        'status': int(sol.status), 'message': str(sol.message)}

    # ------------------------------------------------------------ the result
    def _build_result(self, rec: Recording, problem: IdentificationProblem, x_best: np.ndarray,
                      z_best: np.ndarray, J: np.ndarray, sigma: Sequence[float], w: np.ndarray,
                      pred: np.ndarray) -> IdentificationResult:
        names = list(problem.bounds.names)
        state_names = problem.state_names()[:z_best.size - len(names)]
        names = names + state_names
        rank, Vr, Vn, determined = uncertainty.structural(problem, z_best)
        cov_gn, cond = uncertainty.covariance(J, Vr, rank)
        ids, k = uncertainty.block_ids(problem.n_per, self.error_blocks)
        cov_rob = uncertainty.robust_covariance(
            J, problem.weighted_residuals(z_best, w), Vr, ids, k)
        cov = uncertainty.combine(cov_gn, cov_rob)
        self.covariance_ = cov
        lg = problem.log_mask(len(names))
        std_z = np.sqrt(np.maximum(np.diag(cov), 0.0))
        bound = np.zeros(len(names), dtype=bool)
        bound[:problem.bounds.dim] = uncertainty.at_bound(problem, z_best)
        params = blocks.estimates(problem, names, x_best, std_z, lg, determined, bound)
        undetermined, self._free_choice = uncertainty.undetermined_directions(
            names, Vn, determined, lg)
        fit, prediction = blocks.fit_block(rec, problem, x_best, sigma, pred, names, state_names)
        idf = {'rank': rank - len(state_names), 'n_free': len(names) - len(state_names),
               'free': names[:len(names) - len(state_names)], 'nuisance': state_names,
               'condition': cond,
               'basis': 'transfer-function coefficients (structural); covariance from '
                        'output sensitivities on the identifiable subspace',
               'fully_determined': rank == len(names),
               'tie_K_T_eq_K_b': bool(problem.tie), 'channels': list(problem.channels)}
        idf.update(blocks.prior_verdict(problem, z_best))
        warnings = self._honesty(rec, problem, params, fit)
        adequate, why = determinacy.adequacy(
            {ch: m['fit_percent'] for ch, m in fit['channels'].items()})
        if not adequate:
            for e in params.values():
                if not e.assumed and e.determined:
                    determinacy.mark_undetermined(e, why[0])
        result = IdentificationResult(
            adequate=adequate, warnings=why + warnings,
            method=self.method, input_kind=problem.kind, channels=problem.channels,
            parameters=params,
            identifiable_combinations=uncertainty.combinations(problem, z_best, cov),
            undetermined_directions=undetermined, identifiability=idf, fit=fit, ga={},
            refinement={}, assumptions=self._assumptions(problem),
            effects=blocks.effects_block(problem, x_best, std_z, determined, bound),
            prediction=prediction, parameter_covariance=blocks.covariance_block(
                problem, params, names, cov),
            units=problem.units.to_dict())
        if problem.kind == 'voltage':
            result.resistance = self._resistance_block(problem, params)
            if problem.r_m_prior is None:
                dz = uncertainty.r_m_sensitivity(problem, z_best, w, J, cov_gn)
                result.r_m_sensitivity = blocks.sensitivity_block(problem, params, names, dz)
        return result

    def _honesty(self, rec: Recording, problem: IdentificationProblem, params: dict[str, Estimate],
                 fit: dict[str, Any]) -> list[str]:
        """Floors the stds and marks what this record leaves open (warnings)."""
        for e in params.values():
            if not e.assumed:
                e.std = determinacy.floor_std(e.value, e.std)
        noise = {ch: determinacy.relative_noise(getattr(rec, ch)) for ch in problem.channels}
        r_m = params['R_m'].value if 'R_m' in params else None
        return determinacy.practical(params, rec.sample_period, noise, r_m)

    def _assumptions(self, problem: IdentificationProblem) -> dict[str, Any]:
        fixed = {k: problem.units.to_physical(k, v) for k, v in problem.fixed.items()}
        return {'R_m': fixed.get('R_m'), 'R_m_given': problem.R_m_given,
                'R_m_prior': None if problem.r_m_prior is None else {
                    'mean': problem.R_m_given,
                    'std': problem.R_m_tolerance * cast(float, problem.R_m_given)},
                'K_T_eq_K_b': bool(problem.tie),
                'fixed': {k: v for k, v in fixed.items() if k != 'R_m'},
                'discretisation': problem.discretisation}

    def _resistance_block(self, problem: IdentificationProblem, params: dict[str, Estimate]
                          ) -> dict[str, Any]:
        given = cast(float, problem.R_m_given)  # a voltage plant's
        if problem.r_m_prior is None:
            if 'R_m' in (self.fixed or {}):
                why = 'fixed by --fix R_m'
            elif 'current' not in problem.channels:
                why = 'no current channel fitted: the data cannot see R_m; see ' \
                      'r_m_sensitivity for what an error in it does'
            else:
                why = 'the paper method holds R_m fixed'
            return {'given': given, 'estimate': given, 'std': None, 'relative_change': 0.0,
                    'estimated': False, 'note': why}
        e = params['R_m']
        if e.value is None:
            return {'given': given, 'estimate': given, 'std': None, 'relative_change': 0.0,
                    'estimated': False, 'note': e.reason or 'not determined',
                    'prior_std': problem.R_m_tolerance * given}
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
        return {'given': given, 'estimate': e.value, 'std': e.std, 'relative_change': rel,
                'estimated': True, 'note': note,
                'prior_std': prior_std * given}

    def _ga_block(self, problem: IdentificationProblem, ga: GeneticAlgorithm | None,
                  ga_seconds: float) -> dict[str, Any]:
        if ga is None:
            return {'generations': 0, 'evaluations': 0, 'seconds': ga_seconds,
                    'history': []}
        history = [h.to_dict() for h in ga.history_]
        if problem.units.rescaled:
            for h in history:
                h['best'] = {k: problem.units.to_physical(k, v) for k, v in h['best'].items()}
        return {'generations': ga.generation_, 'evaluations': ga.evaluations_,
                'seconds': ga_seconds, 'best_cost': ga.best_cost_,
                'stop': {k: v for k, v in ga.stop().items()},
                'population': ga.population, 'crossover': ga.crossover,
                'mutation': ga.mutation, 'history': history}

    def _bootstrap(self, problem: IdentificationProblem, result: IdentificationResult,
                   z_best: np.ndarray, w: np.ndarray, rng: np.random.Generator) -> None:
        samples = uncertainty.bootstrap(problem, z_best, w, self.bootstrap, rng)
        names = list(problem.bounds.names)
        for n, e in result.parameters.items():
            src = 'K_T' if (problem.tie and n == 'K_b') else n
            if e.determined and not e.assumed and src in names:
                col = samples[:, names.index(src)]
                lo, hi = np.percentile(col, 2.5), np.percentile(col, 97.5)
                e.ci95 = (problem.units.to_physical(src, float(lo)),
                          problem.units.to_physical(src, float(hi)))
        result.refinement['bootstrap'] = int(self.bootstrap)
