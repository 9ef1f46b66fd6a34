"""The estimator: GA fit of the constrained Elman net, then least-squares refinement.

:class:`Identifier` holds the settings and runs the stages of a fit (a first fit, refits
in a widened box, a settling refit); the search itself is :mod:`.optimize`, the result
:mod:`.estimates`."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import replace
import math
import time
from typing import Any, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.errors import IdentificationError, MotorIdError
from motor_id.identify import blocks, determinacy, estimates, optimize, uncertainty
from motor_id.identify.optimize import Progress
from motor_id.identify.problem import IdentificationProblem
from motor_id.identify.result import ValueStd
from motor_id.identify.space import resistance_enters, SPEED_ONLY_R_M
from motor_id.model import PARAM_NAMES

if TYPE_CHECKING:
    from motor_id.recording import Recording

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
        :data:`motor_id.effects.EFFECTS`).
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

    Examples
    --------
    The paper's motor simulated (K_T = K_b = 0.66, 0.5 % speed and 1 % current noise):

    >>> from motor_id import Identifier
    >>> from motor_id.testing.recordings import paper_recording, SI_MOTOR
    >>> rec = paper_recording(SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=1)
    >>> K_T = Identifier(R_m=2.3, random_state=0).fit(rec).result_.parameters['K_T']
    >>> round(K_T.value, 3), K_T.determined, bool(K_T.std < 0.01 * K_T.value)
    (0.66, True, True)
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

    def fit(self, rec: Recording, progress: Progress | None = None,
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

    def _widen(self, rec: Recording, progress: Progress | None,
               sample_weight: ArrayLike | None) -> None:
        """Refit with the default box widened where a physical parameter sits on it."""
        for _ in range(WIDEN_ROUNDS):
            sides = self._on_default_bound()
            if not sides:
                return
            again = self._variant(bounds={**(self.bounds or {}), **self.widened_, **sides})
            again._fit(rec, progress, sample_weight)
            if not again.result_.fit.cost <= self.result_.fit.cost:
                return
            self._adopt(again, 'history_')
            self.widened_.update(sides)
            self.result_.fit = replace(self.result_.fit, widened={
                k: (float(lo), float(hi)) for k, (lo, hi) in self.widened_.items()})

    def _settle(self, rec: Recording, progress: Progress | None,
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
        cur = res.fit.channels.get('current')
        if cur is not None and self.channels is None and rec.current is not None:
            levels = determinacy.channel_levels(rec.current)
            why: str | None
            if levels < determinacy.MIN_LEVELS:
                why = f'the current takes only {levels} distinct values'
            elif not cur.fit_percent >= determinacy.CHANNEL_FIT:
                why = f'the model explains {cur.fit_percent:.1f} % of the current'
            else:
                why = None
            if why:
                channels = ('speed',)
                notes.append(f'{why}: it cannot carry R_m or L_m; fitted on the speed '
                             'alone with R_m at the given value')
        r = res.resistance
        if channels is self.channels and r is not None and r.estimated and (
                r.std is None or r.prior_std is None or r.std > PRIOR_DOMINATES * r.prior_std
                or res.identifiability.r_m_determined_by_data is False) and \
                r.given is not None:
            fixed['R_m'] = r.given
            notes.append(f'the data do not determine R_m; the given value '
                         f'{r.given:.4g} Ohm is used')
        if not notes:
            return
        start = {k: v for k, v in self.params_.items() if v is not None}
        again = self._variant(fixed=fixed, channels=channels, start=start, use_ga=False,
                              bounds={**(self.bounds or {}), **self.widened_} or None)
        again._fit(rec, None, sample_weight)
        res2 = again.result_
        res2.ga, res2.warnings = res.ga, notes + res2.warnings
        if res2.resistance is not None and 'R_m' in fixed and 'R_m' not in (self.fixed or {}):
            res2.resistance = replace(res2.resistance, note=notes[-1], data_estimate=ValueStd(
                value=None if r is None else r.estimate, std=None if r is None else r.std))
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

    def _fit(self, rec: Recording, progress: Progress | None,
             sample_weight: ArrayLike | None) -> None:
        unseen, R_m, fixed = _resistance_used(rec, self.R_m, self.fixed)
        problem = IdentificationProblem(
            rec, method=self.method, R_m=R_m, R_m_tolerance=self.R_m_tolerance,
            tie=self.tie, fixed=fixed, bounds=self.bounds, channels=self.channels,
            effects=self.effects, free_effects=self.free_effects,
            sample_weight=sample_weight)
        self.problem_ = problem
        rng = np.random.default_rng(self.random_state)   # a Generator comes back as is
        ga, best, ga_seconds = optimize.run_ga(
            problem, rng, progress, start=self.start, use_ga=self.use_ga,
            population=self.population, generations=self.generations,
            crossover=self.crossover, mutation=self.mutation)
        problem.forward_differences = bool(self.quick_jacobian)
        z_best, refine_info = optimize.refine(
            problem, ga, best, method=self.method, refine_starts=self.refine_starts,
            reweight=self.reweight, max_nfev=self.max_nfev)
        problem.forward_differences = False
        x_best = problem.from_z(z_best)
        with np.errstate(all='ignore'):
            pred = problem.simulate(x_best[None, :])[0]
        if not (np.all(np.isfinite(x_best)) and np.all(np.isfinite(pred))):
            raise IdentificationError('the model diverges at the best parameters found: '
                                      'check the units of the data and the search bounds',
                                      params=('bounds',))
        sigma, w = uncertainty.noise_levels(problem, z_best)
        J = problem.jacobian_z(z_best, w)
        result, self.covariance_ = estimates.build_result(
            rec, problem, x_best, z_best, J, sigma, w, pred, error_blocks=self.error_blocks,
            r_m_fixed_by_caller='R_m' in (fixed or {}))
        if unseen:
            blocks.unseen_resistance(result, (self.fixed or {}).get('R_m', self.R_m))
        result.ga = blocks.ga_block(problem, ga, ga_seconds)
        result.refinement = refine_info
        if self.bootstrap and self.method != 'paper':
            estimates.bootstrap_intervals(problem, result, z_best, w, rng, self.bootstrap)
        self.result_ = result
        self.params_ = result.values()
        self.history_ = [] if ga is None else [h.to_dict() for h in ga.history_]


def _resistance_used(rec: Recording, R_m: float | None, fixed: Mapping[str, float] | None
                     ) -> tuple[bool, float | None, Mapping[str, float] | None]:
    """``(unseen, R_m, fixed)`` a fit uses: where R_m does not enter (speed-only voltage
    data, :func:`~motor_id.identify.space.resistance_enters`) the internal
    :data:`~motor_id.identify.space.SPEED_ONLY_R_M`, never the given value, so that no
    output depends on it."""
    if rec.input_kind != 'voltage' or resistance_enters(rec.input_kind, rec.has_current,
                                                        fixed):
        return False, R_m, fixed
    return True, SPEED_ONLY_R_M, {k: v for k, v in (fixed or {}).items() if k != 'R_m'} or None
