"""The discrepancy analysis: what the linear model misses, which named effect explains it.

Steps (each in its own module): measurement grids from the values themselves
(:mod:`.measurement`); the held-out split (:mod:`.heldout`); the linear model and, with
the current measured, the resistance profile; every dynamic candidate of
:data:`motor_id.model.EFFECTS` alone (:mod:`.candidates`); the verdict, a second effect
only when it beats the best one-effect model on held-out data, ambiguity
(:mod:`.selection`); final fits, diagnostics and the inverse-dynamics estimate
(:mod:`.inverse_dynamics`); the report (:mod:`.report`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import contextlib
import math
import time
from typing import Any, cast, TYPE_CHECKING

import numpy as np

from motor_id.analysis import outcome, selection
from motor_id.analysis.candidates import CandidateFitter, data_scales, dynamic_effects, FIT_ERRORS
from motor_id.analysis.diagnostics import map_summary, residual_block, steady_state_map
from motor_id.analysis.heldout import HeldOutSplit, noise_floor
from motor_id.analysis.inverse_dynamics import electrical_evidence
from motor_id.analysis.measurement import find_measurement_effects
from motor_id.analysis.report import DiscrepancyReport, ModelScore
from motor_id.analysis.simulation_fit import simulation_stage
from motor_id.errors import ConfigError, DataError, IdentificationError
from motor_id.identify import determinacy
from motor_id.identify.validation import SavedModel
from motor_id.metrics import normalised_fit
from motor_id.model import EFFECTS

if TYPE_CHECKING:
    from motor_id.identify import Identifier
    from motor_id.recording import Recording

CANDIDATES = tuple(e for e, spec in EFFECTS.items() if not spec.extends)
"""Candidate effects, in catalogue order (the more common first)."""


class DiscrepancyAnalysis:
    """Find the named effect that the linear model misses.

    Parameters
    ----------
    R_m : float, optional
        Known armature resistance [Ohm] (voltage plants). With the current measured
        every fit estimates it under the prior N(R_m, (R_m_tolerance R_m)^2)
        (:class:`motor_id.identify.Identifier`), so an ohmmeter's error is not taken
        for heating, a brush drop or a dead zone.
    candidates : sequence of str, optional
        Effects to try; default every effect of the catalogue that applies.
    random_state : int or None
        Seed of the base model's GA.
    min_gain : float
        Smallest held-out gain (relative cut of the held-out error) that counts.
    ambiguity : float
        Candidates whose held-out error is within this fraction of the winner's are
        reported as indistinguishable.
    max_effects : int
        Largest number of dynamic effects combined.
    structure_ratio : float
        Held-out error above this multiple of the noise floor counts as unexplained.
    n_blocks : int
        Number of blocks of the held-out split.
    max_delay : int, optional
        Largest input delay tried [samples]; default min(40, N / 25).
    generations : int
        GA generations of the base fit (100: its best cost settles by generation 40-60
        on the records tried, and the refinement from its three best starts follows).
    pool_size : int
        Second effects are tried from this many best single effects.
    starts : int
        Distinct grid points each candidate's refinement starts from.
    R_m_tolerance : float
        Relative standard deviation of the prior on R_m (with the current measured).
    init_samples : int
        With a measured position, the model is also fitted and its refinements chosen by
        simulation error (:mod:`.simulation_fit`), each block simulated from a state set
        by its first ``init_samples`` samples; 0 skips that stage.
    """

    def __init__(self, R_m: float | None = None, candidates: Sequence[str] | None = None,
                 random_state: int | None = 0, min_gain: float = 0.05,
                 ambiguity: float = 0.03, max_effects: int = 3, structure_ratio: float = 1.5,
                 n_blocks: int = 10, max_delay: int | None = None, generations: int = 100,
                 pool_size: int = 4, starts: int = 2, R_m_tolerance: float = 0.10,
                 init_samples: int = 20) -> None:
        self.R_m = R_m
        self.candidates = candidates
        self.random_state = random_state
        self.min_gain = min_gain
        self.ambiguity = ambiguity
        self.max_effects = max_effects
        self.structure_ratio = structure_ratio
        self.n_blocks = n_blocks
        self.max_delay = max_delay
        self.generations = generations
        self.pool_size = pool_size
        self.starts = starts
        self.R_m_tolerance = R_m_tolerance
        self.init_samples = init_samples

    def fit(self, rec: Recording, progress: Callable[[str], object] | None = None
            ) -> DiscrepancyAnalysis:
        """Run the analysis.

        Parameters
        ----------
        rec : Recording
        progress : callable, optional
            ``progress(message)`` for each step (the CLI prints them to stderr).

        Returns
        -------
        self
            With ``report_`` (:class:`DiscrepancyReport`).
        """
        with _single_blas_thread(), np.errstate(all='ignore'):
            return self._fit(rec, progress)

    # ------------------------------------------------------------------ steps
    def _say(self, msg: str) -> None:
        if self._progress is not None:
            self._progress(msg)

    def _check(self, rec: Recording) -> list[str]:
        rec.validate()  # also rejects corrupt cells (1e300) whose squares would overflow
        if rec.input_kind == 'voltage' and self.R_m is None:
            raise ConfigError('the armature resistance R_m is required for voltage-input '
                              'data (--resistance R)')
        if len(rec) < 10 * self.n_blocks:
            raise DataError(f'too few samples for a held-out analysis: {len(rec)} '
                            f'(need at least {10 * self.n_blocks})')
        names = self.candidates if self.candidates is not None else CANDIDATES
        for n in names:
            if n not in EFFECTS:
                raise ConfigError(f'unknown candidate effect {n!r}; known: {sorted(EFFECTS)}')
        return [n for n in names if rec.input_kind in EFFECTS[n].kinds]

    def _setup(self, rec: Recording, names: Sequence[str]) -> None:
        self._rec = rec
        self._cands = [n for n in names if EFFECTS[n].category == 'dynamic']
        meas, self._meas_evidence = find_measurement_effects(rec)
        self._meas = [m for m in meas if m.name in names]
        quant = {m.evidence.channel: (m.q, m.evidence.offset) for m in self._meas}
        for m in self._meas:
            self._say(f'  {m.name}: values on a grid of {m.q:.5g} (coherence '
                      f'{m.evidence.coherence:.3f}, p = {m.evidence.p_value:.2g})')
        self._split = HeldOutSplit(rec, self.n_blocks, quant)
        self._electrical: dict[str, Any] | None = None
        if rec.input_kind == 'voltage' and rec.has_current:
            try:
                self._electrical = electrical_evidence(rec)
            except FIT_ERRORS as exc:
                self._electrical = {'failed': str(exc), 'favoured': None}
        max_delay = self.max_delay if self.max_delay is not None else \
            int(min(40, max(2, len(rec) // 25)))
        self._T = float(rec.time[-1] - rec.time[0])
        self._dt = float(np.median(np.diff(rec.time)))
        self._at_once = selection.responds_at_once(rec, noise_floor(rec.speed))
        self._one_way = selection.one_direction(rec)
        self._steady = selection.steady_offset(map_summary(steady_state_map(rec)))
        self._fitter = CandidateFitter(rec, self._split, self.R_m, self.random_state,
                                       self.starts, max_delay, self.R_m_tolerance)

    def _linear(self, rec: Recording) -> ModelScore:
        self._say(f'fitting the linear model ({len(rec)} samples, '
                  f'{100 * np.mean(self._split.test):.0f} % held out)')
        f = self._fitter
        try:
            base = f.fit_linear(self.generations)
        except FIT_ERRORS as exc:
            raise IdentificationError(f'the linear model cannot be fitted: {exc}') from None
        if base.failed:
            raise IdentificationError(f'the linear model cannot be fitted: {base.failed}')
        base = self._speed_reading(base)
        self._resistance = f.resistance
        counted = any(m.name == 'speed_quantization' for m in self._meas)
        f.scales = data_scales(rec, base.physical, f.R_m, self._T, self._dt, f.max_delay,
                               counted)
        if self._electrical:
            f.extra_starts = dict(self._electrical.get('start', {}))
        base.significant = False
        # a grid that cannot rank its points gets spread starts only when the linear
        # model leaves structure to explain (on a clean record they cost time for nothing)
        f.spread = self._structure(base)
        self._say(f'  held-out error {base.heldout_error:.4g} '
                  f'(noise floor {self._split.floor:.4g})')
        return base

    def _speed_reading(self, base: ModelScore) -> ModelScore:
        """Speed on an encoder grid: read at the samples, or a count difference?

        A count difference is the mean speed over the sample period (half a period
        behind the sampled speed, and smoothed); a quantised speed sensor reads the
        speed at the sample. The linear model is fitted both ways and the reading with
        the lower held-out error holds for every model of the analysis (an unmodelled
        reading would otherwise be credited to a dynamic effect).
        """
        grid = next((m for m in self._meas if m.name == 'speed_quantization'), None)
        if grid is None:
            return base
        f = self._fitter
        kept = (f.resistance, f.linear_estimator, f.physical_bounds)
        f.reading = {'speed_quantization': {'q': 0.0, 'counted': 1.0}}
        counted: ModelScore | None
        try:
            counted = f.fit_linear(self.generations)
        except FIT_ERRORS as exc:
            counted = None
            self._say(f'  the speed as a count difference cannot be fitted ({exc})')
        better = counted is not None and not counted.failed and \
            counted.heldout_error < base.heldout_error
        grid.extra['counted'] = 1.0 if better else 0.0
        grid.extra['reading_heldout_error'] = {
            'sampled': base.heldout_error,
            'count difference': counted.heldout_error if counted is not None else None}
        self._say('  speed reading: ' + (
            'a count difference (the mean over each sample period)' if better else
            'sampled at the sample instants') + f' (held-out error {base.heldout_error:.4g}'
            ' sampled, ' + (f'{counted.heldout_error:.4g}' if counted is not None else '-')
            + ' counted)')
        if better:
            return cast(ModelScore, counted)
        f.reading = {}
        f.resistance, f.linear_estimator, f.physical_bounds = kept
        return base

    def _judge(self, s: ModelScore, ref: ModelScore) -> ModelScore:
        return selection.judge(s, ref, self._split, self.min_gain, self._fitter.scales)

    def _singles(self, base: ModelScore) -> list[ModelScore]:
        singles: list[ModelScore] = []
        for name in self._cands:
            s = self._judge(self._fitter.fit(name, base), base)
            self._evidence_against(s)
            singles.append(s)
            self._say(f'  {name:<20} ' + (f'failed: {s.failed}' if s.failed else
                                          f'gain {100 * s.gain:6.1f} %') +
                      f'  ({s.seconds:.2f} s){"  *" if s.significant else ""}')
        singles.sort(key=_order)
        if singles and singles[0].significant:
            # a poor start must not decide the verdict: refit the runners-up from the
            # physical parameters of the best (the linear fit may sit at a bound)
            lead = singles[0]
            for k, s in enumerate(singles[1:self.pool_size + 1], 1):
                if s.failed or s.gain < self.min_gain:
                    continue
                r = self._judge(self._fitter.fit(s.name, base, seed=lead), base)
                if not r.failed and r.train_error < s.train_error:
                    singles[k] = r
                    self._say(f'  {s.name:<20} gain {100 * r.gain:6.1f} %  (restarted '
                              f'from {lead.name}){"  *" if r.significant else ""}')
            singles.sort(key=_order)
        return singles

    def _evidence_against(self, s: ModelScore) -> None:
        """What the record itself says against a candidate (in place): a delay of two
        samples or more while the speed answers input steps within one."""
        d = s.effects.get('input_delay', {}).get('d')
        if d is not None and d >= 2 and self._at_once:
            s.implausible = (f'a delay of {d:.0f} samples, but the speed answers input '
                             'steps within one sample')
            s.significant = False

    def _structure(self, model: ModelScore) -> bool:
        return model.heldout_error > self.structure_ratio * self._split.floor

    def _add_effect(self, base: ModelScore, chosen: ModelScore, singles: Sequence[ModelScore]
                    ) -> ModelScore | None:
        """The best significant extension of ``chosen`` by one more effect, or None."""
        have = chosen.name.split('+')
        # an effect that alone cut the held-out error by less than a quarter of min_gain,
        # or that made the previous, smaller model worse, is not tried again
        # (nor is one that sat on a search limit or was implausible alone: so it would
        # on top of another)
        pool = [s for s in singles if s.gain >= self.min_gain / 4 and not s.failed
                and not s.at_bound and not s.implausible
                and s.name not in have and self._added.get(s.name, 1.0) > 0]
        if self._one_way:  # one sign of speed: friction and a constant load are one term
            pool = [s for s in pool if not set(selection.ONE_WAY) <= set(have + [s.name])]
        trials: list[ModelScore] = []
        for s in pool[:self.pool_size]:
            t = self._judge(self._fitter.fit(s.name, base, prior=chosen), chosen)
            t.reference, t.gain_over_reference = chosen.name, t.gain
            parts = {s.name: chosen.heldout_error}
            if len(have) == 1:
                parts[chosen.name] = s.heldout_error
            t.components = selection.components(t, singles, parts)
            marg = [c['marginal'] for e, c in t.components.items() if e in parts]
            if any(m < self.min_gain for m in marg):
                t.significant = False
            t.gain = float(1.0 - t.heldout_error / base.heldout_error) \
                if not t.failed else 0.0
            self._say(f'  {t.name:<40} ' + (f'failed: {t.failed}' if t.failed else
                      f'gain over {chosen.name} {100 * t.gain_over_reference:6.1f} %'))
            trials.append(t)
            self._added[s.name] = t.gain_over_reference if not t.failed else -1.0
        self._ranked.extend(trials)
        ok = sorted((t for t in trials if t.significant), key=lambda t: t.heldout_error)
        return self._confirm(base, chosen, ok[0]) if ok else None

    def _confirm(self, base: ModelScore, chosen: ModelScore, combo: ModelScore
                 ) -> ModelScore | None:
        """The combination, unless ``chosen`` refitted from its parameters does as well.

        The combination's refinement can find a better optimum of the effects ``chosen``
        already has; then its gain belongs to the optimiser, not to the added effect.
        """
        last = combo.name.split('+')[-1]
        prior_name = chosen.name.split('+')
        prior: ModelScore | None = None
        for e in prior_name[:-1]:
            prior = self._fitter.fit(e, base, prior=prior, seed=combo)
        again = self._fitter.fit(prior_name[-1], base, prior=prior, seed=combo)
        if again.failed or again.heldout_error >= chosen.heldout_error:
            return combo
        cut = 1.0 - combo.heldout_error / again.heldout_error
        self._say(f'  {chosen.name} refitted from {combo.name}: held-out error '
                  f'{again.heldout_error:.4g}; {last} adds {100 * cut:.1f} %')
        if cut < self.min_gain:
            combo.significant = False
            combo.implausible = (f'{chosen.name} refitted from these parameters does as '
                                 f'well ({last} adds {100 * cut:.1f} %)')
            return None
        return combo

    def _select(self, base: ModelScore, singles: Sequence[ModelScore]
                ) -> tuple[ModelScore, list[ModelScore]]:
        self._ranked = list(singles)
        self._added: dict[str, float] = {}
        chosen = selection.pick_single(singles, CANDIDATES, self._structure, self.ambiguity,
                                       self._electrical) or base
        if self._steady and chosen.name not in ('coulomb_friction', 'dead_zone'):
            # the plateaus show a static offset both ways: a friction-like effect that
            # does as well on held-out data is named before others
            alt = [s for s in singles if s.significant and s.name in
                   ('coulomb_friction', 'dead_zone') and
                   s.heldout_error <= (1 + self.ambiguity) * chosen.heldout_error]
            if alt:
                chosen = alt[0]
        while (chosen is not base and len(chosen.name.split('+')) < self.max_effects
               and self._structure(chosen)):
            nxt = self._add_effect(base, chosen, singles)
            if nxt is None:
                break
            chosen = nxt
        ranked = self._ranked
        ranked.sort(key=lambda s: (s is not chosen, not s.significant, bool(s.failed),
                                   s.heldout_error))
        return chosen, ranked

    def _fit(self, rec: Recording, progress: Callable[[str], object] | None
             ) -> DiscrepancyAnalysis:
        t_start = time.perf_counter()
        self._progress = progress
        names = self._check(rec)
        self._setup(rec, names)
        base = self._linear(rec)
        singles = self._singles(base)
        chosen, ranked = self._select(base, singles)
        self.report_ = self._report(rec, base, chosen, ranked)
        if rec.has_position and self.init_samples:
            model = SavedModel.from_report(self.report_.to_dict(), use_simulation=False)
            self.report_.simulation = simulation_stage(
                rec, model, self.init_samples, min_gain=self.min_gain, progress=self._say)
        self.report_.seconds = time.perf_counter() - t_start
        return self

    # ------------------------------------------------------------------ report
    def _report(self, rec: Recording, base: ModelScore, chosen: ModelScore,
                ranked: list[ModelScore]) -> DiscrepancyReport:
        full_base, full = outcome.final_fits(self._fitter, base, chosen, self._say)
        params = outcome.parameters(chosen, base, full)
        for m in self._meas:
            params.update(m.parameters)
        dyn = 'none' if chosen is base else chosen.name
        names = ([] if chosen is base else [dyn]) + [m.name for m in self._meas]
        verdict = '+'.join(names) if names else 'none'
        chosen_d: dict[str, Any] = {'name': dyn, 'estimator': 'output error (simulation)',
                    'effects': {} if chosen is base else chosen.effects,
                    'fit': full.result_.fit if (full is not None and chosen is not base)
                    else None}
        if full is not None and chosen is not base:
            chosen_d['effects'] = {e: {p: (v['value'] if isinstance(v, dict) else v)
                                       for p, v in vals.items()}
                                   for e, vals in
                                   dynamic_effects(full.result_.effects).items()}
        idyn: dict[str, Any] | None = None
        if rec.input_kind == 'torque':
            idyn, params, chosen_d = outcome.torque_headline(rec, chosen, params, chosen_d)
        diag, points = self._diagnostics(rec, full_base, full, chosen, base)
        return self._assemble(rec, base, chosen, ranked, verdict, params, chosen_d, diag,
                              points, full_base, idyn)

    def _diagnostics(self, rec: Recording, full_base: Identifier, full: Identifier | None,
                     chosen: ModelScore, base: ModelScore
                     ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        after = full.result_.prediction if (full is not None and chosen is not base) \
            else None
        diag = residual_block(rec, self._split.channels, full_base.result_.prediction,
                              after)
        diag['noise_floor'] = self._split.floor
        diag['channel_noise_floor'] = self._split.channel_floors
        if self._electrical is not None:
            diag['electrical'] = self._electrical
        points = steady_state_map(rec)
        k = self._split.channels.index('speed')
        for p in points:
            a, b = p['start'], p['stop']
            p['speed_linear'] = float(np.mean(full_base.result_.prediction['speed'][a:b]))
            if chosen is not base:
                p['speed_chosen'] = float(np.mean(chosen.prediction['preds'][k][a:b]))
        diag['steady_state'] = {**map_summary(points), 'points': points}
        return diag, points

    def _assemble(self, rec: Recording, base: ModelScore, chosen: ModelScore,
                  ranked: list[ModelScore], verdict: str, params: dict[str, Any],
                  chosen_d: dict[str, Any], diag: dict[str, Any], points: list[dict[str, Any]],
                  full_base: Identifier, idyn: dict[str, Any] | None) -> DiscrepancyReport:
        held = list(range(2, self.n_blocks, 3))
        scheme = (f'{len(rec.segment_ranges)} separate runs; the last is held out whole'
                  if self._split.by_run else
                  f'{self.n_blocks} blocks, blocks {held} held out (the simulation runs '
                  'through them)')
        heldout = {'scheme': scheme, 'by_run': self._split.by_run,
                   'fraction': float(np.mean(self._split.test)),
                   'blocks': self._split.blocks, 'base_error': base.heldout_error,
                   'final_error': chosen.heldout_error, 'noise_floor': self._split.floor,
                   'min_gain': self.min_gain, 'resistance': self._resistance}
        bres = full_base.result_
        baseline = {'parameters': bres.to_dict()['parameters'], 'fit': bres.fit,
                    'heldout_error': base.heldout_error}
        plot_data = {'time': rec.time, 'channels': self._split.channels,
                     'ys': self._split.ys, 'base': base.prediction['preds'],
                     'chosen': chosen.prediction['preds'], 'test': self._split.test,
                     'points': points}
        failed = [{'name': s.name, 'reason': s.failed} for s in ranked if s.failed]
        ambiguous = [] if chosen is base else selection.ambiguous(
            chosen, ranked, self.ambiguity, rec.input_kind, self._one_way)
        adequate, warnings = self._adequacy(chosen, verdict, params)
        return DiscrepancyReport(
            verdict=verdict, effects=list(self._meas) + list(ranked),
            unexplained=bool(self._structure(chosen)), ambiguous_with=ambiguous,
            parameters=params, baseline=baseline, chosen=chosen_d, diagnostics=diag,
            heldout=heldout, input_kind=rec.input_kind, channels=self._split.channels,
            measurement=self._meas_evidence, failed=failed, inverse_dynamics=idyn,
            plot_data=plot_data, adequate=adequate, warnings=warnings)

    def _adequacy(self, chosen: ModelScore, verdict: str, params: dict[str, Any]
                  ) -> tuple[bool, list[str]]:
        """``(adequate, warnings)``: the chosen model's held-out fit of the speed, the
        steady-state evidence the verdict leaves out, one-direction data."""
        k = self._split.channels.index('speed')
        y = self._split.ys[k][self._split.test]
        yh = np.asarray(chosen.prediction['preds'][k])[self._split.test]
        fit = normalised_fit(y, yh)
        adequate, warnings = determinacy.adequacy(
            {'speed': fit}, hint='no named effect explains this record (a load that '
            'changes along it, a second input?)')
        if warnings:
            warnings[0] = warnings[0].replace('the model explains',
                                              'the chosen model explains (held out)')
        if not adequate:
            for p in params.values():
                if isinstance(p, dict) and p.get('determined') and not p.get('grid'):
                    p['particular_value'] = p.get('value')
                    p['value'], p['std'], p['determined'] = None, None, False
                    p['reason'] = 'model inadequate'
        if self._steady and not any(e in verdict for e in
                                    ('coulomb_friction', 'dead_zone', 'brush_drop')):
            warnings.append('the steady states show a static offset both ways (zero speed '
                            f'at input {self._steady[0]:.3g} and {self._steady[1]:.3g}): '
                            'Coulomb friction or a dead band that the verdict does not name')
        if self._one_way:
            warnings.append('the speed kept one sign: the model holds for this direction '
                            'only')
        return adequate, warnings


def _order(s: ModelScore) -> tuple[bool, float]:
    return (bool(s.failed), s.heldout_error if math.isfinite(s.heldout_error) else math.inf)


def _single_blas_thread() -> contextlib.AbstractContextManager[Any]:
    """Limit BLAS to one thread: the analysis does many small solves, where threads only
    contend (a no-op without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1)
