"""The estimator: GA fit of the constrained Elman net, then least-squares refinement.

:class:`Identifier` holds the settings and runs the stages of a fit (a first fit, refits
in a widened box, a settling refit); the search itself is :mod:`.optimize`, the result
:mod:`.estimates`."""

from __future__ import annotations

from collections.abc import Mapping
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
from motor_id.identify.settings import FitSettings, FitStages, STAGE_NAMES
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


class Identifier:
    """Estimate physical motor parameters from a recording.

    Parameters
    ----------
    settings : FitSettings, optional
        What the fit is asked to do (:class:`motor_id.identify.FitSettings`, validated
        when made); default ``FitSettings()``.
    **values
        Fields of :class:`~motor_id.identify.FitSettings` replacing those of ``settings``
        (``Identifier(R_m=2.3, random_state=0)``); an unknown name is a
        :class:`~motor_id.errors.ConfigError`.

    Notes
    -----
    A fit runs in stages: the GA and a least-squares refinement from its best
    individuals; where a physical parameter sits on a side of the *default* box (a hobby
    motor's inertia below 1e-6 kg m^2, say) that side is moved :data:`WIDEN` times
    outward and the fit repeated, up to :data:`WIDEN_ROUNDS` times, keeping the lower
    cost (ranges given in ``bounds``, fixed parameters and R_m are never widened, nor are
    warm starts; ``widened_`` holds the ranges that were moved); then a refit without
    what the record cannot carry (:meth:`_settle`). Their knobs are internal
    (:class:`motor_id.identify.settings.FitStages`).

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

    def __init__(self, settings: FitSettings | None = None, **values: Any) -> None:
        self.settings = (FitSettings() if settings is None else settings).replace(**values)
        self._stages = FitStages()

    @property
    def stages(self) -> FitStages:
        """The internal knobs of the fit's stages (read only)."""
        return self._stages

    def with_settings(self, **changes: Any) -> Identifier:
        """A new, unfitted Identifier with these settings changed (the same stages)."""
        return _make(self.settings.replace(**changes), self._stages)

    def warm_start(self, start: Mapping[str, float]) -> Identifier:
        """Refine from ``start`` at the next fit, without the GA; returns self."""
        self.settings = self.settings.replace(start=start)
        self._stages = replace(self._stages, use_ga=False)
        return self

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
        self.settings.check_resistance(rec.input_kind, rec.has_current)
        try:
            self._fit(rec, progress, sample_weight)
            self.widened_: dict[str, tuple[float, float]] = {}
            if self._stages.widen and self._stages.use_ga:
                self._widen(rec, progress, sample_weight)
            if self._stages.settle:
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
            bounds = {**(self.settings.bounds or {}), **self.widened_, **sides}
            again = self._variant(bounds=bounds)
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
        channels, fixed = self.settings.channels, dict(self.settings.fixed or {})
        cur = res.fit.channels.get('current')
        if cur is not None and self.settings.channels is None and rec.current is not None:
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
        if channels is self.settings.channels and r is not None and r.estimated and (
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
                              bounds={**(self.settings.bounds or {}), **self.widened_} or None)
        again._fit(rec, None, sample_weight)
        res2 = again.result_
        res2.ga, res2.warnings = res.ga, notes + res2.warnings
        given = self.settings.fixed or {}
        if res2.resistance is not None and 'R_m' in fixed and 'R_m' not in given:
            res2.resistance = replace(res2.resistance, note=notes[-1], data_estimate=ValueStd(
                value=None if r is None else r.estimate, std=None if r is None else r.std))
        self._adopt(again)

    def _variant(self, **changes: Any) -> Identifier:
        """An unwidened Identifier with these settings (and stage knobs) changed (the
        refits above, :func:`motor_id.identify.mechanism.with_gravity`)."""
        stages = {k: changes.pop(k) for k in STAGE_NAMES if k in changes}
        return _make(self.settings.replace(**changes),
                     replace(self._stages, **{'widen': False, **stages}))

    def _adopt(self, other: Identifier, *extra: str) -> None:
        """Take over the fitted state of ``other`` (and the ``extra`` attributes)."""
        for attr in ('problem_', 'result_', 'params_', 'covariance_', *extra):
            setattr(self, attr, getattr(other, attr))

    def _on_default_bound(self) -> dict[str, tuple[float, float]]:
        """``{name: (low, high)}`` SI: the widened range of each physical parameter the
        fit left on a side of the default box (never one the caller bounded)."""
        prob = self.problem_
        params = self.result_.to_dict()['parameters']
        caller = set(self.settings.bounds or {})
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
        s, st = self.settings, self._stages
        unseen, R_m, fixed = _resistance_used(rec, s.R_m, s.fixed)
        problem = IdentificationProblem(
            rec, method=s.method, R_m=R_m, R_m_tolerance=s.R_m_tolerance, tie=s.tie,
            fixed=fixed, bounds=s.bounds, channels=s.channels, effects=s.effects,
            free_effects=s.free_effects, sample_weight=sample_weight)
        self.problem_ = problem
        rng = np.random.default_rng(s.random_state)   # a Generator comes back as is
        ga, best, ga_seconds = optimize.run_ga(
            problem, rng, progress, start=s.start, use_ga=st.use_ga,
            population=s.population, generations=s.generations, crossover=s.crossover,
            mutation=s.mutation)
        problem.forward_differences = bool(st.quick_jacobian)
        z_best, refine_info = optimize.refine(
            problem, ga, best, method=s.method, refine_starts=st.refine_starts,
            reweight=st.reweight, max_nfev=st.max_nfev)
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
            rec, problem, x_best, z_best, J, sigma, w, pred, error_blocks=st.error_blocks,
            r_m_fixed_by_caller='R_m' in (fixed or {}))
        if unseen:
            blocks.unseen_resistance(result, s.resistance)
        result.ga = blocks.ga_block(problem, ga, ga_seconds)
        result.refinement = refine_info
        if s.bootstrap and s.method != 'paper':
            estimates.bootstrap_intervals(problem, result, z_best, w, rng, s.bootstrap)
        self.result_ = result
        self.params_ = result.values()
        self.history_ = [] if ga is None else [h.to_dict() for h in ga.history_]

def _make(settings: FitSettings, stages: FitStages) -> Identifier:
    est = Identifier(settings)
    est._stages = stages
    return est


def staged(settings: FitSettings, **stages: Any) -> Identifier:
    """An Identifier with internal stage knobs set (:class:`FitStages`: the analysis's
    candidate refits, warm starts); not part of the public API."""
    return _make(settings, FitStages(**stages))


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
