"""The candidate search: every effect alone, then the chosen one extended, on held-out data.

Each dynamic candidate of the catalogue is fitted on top of the linear model and judged
on the held-out blocks (:func:`.selection.judge`); when one is significant, the
runners-up are refitted from its physical parameters (a poor start must not decide).
The chosen single (:func:`.selection.pick_single`) is extended by one more effect at a
time while structure is left and a combination beats it on held-out data, and the
extension stands only when the smaller model, refitted from the combination's
parameters, does not do as well. The fits of one step run on a :class:`.workers.FitPool`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import math
from typing import TYPE_CHECKING

from motor_id.analysis import selection
from motor_id.analysis.workers import FitTask
from motor_id.effects import EFFECTS, role_value

if TYPE_CHECKING:
    from motor_id.analysis.context import RecordContext
    from motor_id.analysis.report import ModelScore
    from motor_id.analysis.workers import FitPool


class CandidateSearch:
    """Finds the chosen model of one record among its candidate effects.

    Parameters
    ----------
    ctx : RecordContext
    fits : FitPool
        Runs the candidate fits of one step (one process or several).
    catalogue : sequence of str
        Candidate effects in catalogue order (the more common first: ties go to them).
    candidates : sequence of str
        The dynamic effects to try, in that order.
    say : callable
        ``say(message)`` for each result.
    min_gain, ambiguity, max_effects, structure_ratio, pool_size
        As :class:`.analyzer.DiscrepancyAnalysis`.
    """

    def __init__(self, ctx: RecordContext, fits: FitPool, catalogue: Sequence[str],
                 candidates: Sequence[str], say: Callable[[str], object], *,
                 min_gain: float, ambiguity: float, max_effects: int,
                 structure_ratio: float, pool_size: int) -> None:
        self.ctx = ctx
        self.fits = fits
        self.catalogue = catalogue
        self.candidates = candidates
        self.say = say
        self.min_gain = min_gain
        self.ambiguity = ambiguity
        self.max_effects = max_effects
        self.structure_ratio = structure_ratio
        self.pool_size = pool_size
        self._ranked: list[ModelScore] = []
        self._added: dict[str, float] = {}

    def structure(self, model: ModelScore) -> bool:
        """True when ``model`` leaves held-out error above ``structure_ratio`` floors."""
        return model.heldout_error > self.structure_ratio * self.ctx.split.floor

    def judge(self, s: ModelScore, ref: ModelScore) -> ModelScore:
        """:func:`.selection.judge` of ``s`` against ``ref`` on this record (in place)."""
        return selection.judge(s, ref, self.ctx.split, self.min_gain, self.ctx.fitter.scales)

    # ------------------------------------------------------------------ singles
    def singles(self, base: ModelScore) -> list[ModelScore]:
        """Every candidate alone on top of ``base``, best first (held-out error)."""
        singles: list[ModelScore] = []
        tasks = [FitTask(name, base) for name in self.candidates]
        for name, fitted in zip(self.candidates, self.fits.map(tasks), strict=True):
            s = self.judge(fitted, base)
            self._evidence_against(s)
            self._offset_evidence(s)
            singles.append(s)
            self.say(f'  {name:<20} ' + (f'failed: {s.failed}' if s.failed else
                                         f'gain {100 * s.gain:6.1f} %') +
                     f'  ({s.seconds:.2f} s){"  *" if s.significant else ""}')
        singles.sort(key=_order)
        if singles and singles[0].significant:
            # a poor start must not decide the verdict: refit the runners-up from the
            # physical parameters of the best (the linear fit may sit at a bound)
            lead = singles[0]
            again = [(k, s) for k, s in enumerate(singles[1:self.pool_size + 1], 1)
                     if not s.failed and s.gain >= self.min_gain]
            tasks = [FitTask(s.name, base, seed=lead) for _, s in again]
            for (k, s), fitted in zip(again, self.fits.map(tasks), strict=True):
                r = self.judge(fitted, base)
                self._offset_evidence(r)
                if not r.failed and r.train_error < s.train_error:
                    singles[k] = r
                    self.say(f'  {s.name:<20} gain {100 * r.gain:6.1f} %  (restarted '
                             f'from {lead.name}){"  *" if r.significant else ""}')
            singles.sort(key=_order)
        return singles

    def _evidence_against(self, s: ModelScore) -> None:
        """What the record itself says against a candidate (in place): a delay of two
        samples or more while the speed answers input steps within one."""
        d = role_value(s.effects, 'delay', None)
        if d is not None and d >= 2 and self.ctx.at_once:
            s.implausible = (f'a delay of {d:.0f} samples, but the speed answers input '
                             'steps within one sample')
            s.significant = False

    def _offset_evidence(self, s: ModelScore) -> None:
        """What the steady states say for a candidate (in place): where they show a
        static offset both ways, a friction-like single effect (``named_on_offset``)
        that cuts the held-out error by ``min_gain`` and passes BIC counts although it
        improves fewer than half of the held-out sub-blocks. It acts only near zero speed
        and where motion starts, which few sub-blocks hold; elsewhere its refit of the
        linear terms moves the error a little either way. (A real drivetrain's log: gain
        61 %, 5 of 12 sub-blocks, offset at +-0.4 V; an input delay of gain 30 % was
        named instead and kS reported 0.)"""
        spec = EFFECTS.get(s.name)
        if (s.significant or self.ctx.steady is None or spec is None
                or not spec.named_on_offset or s.failed):
            return
        s.significant = bool(s.gain >= self.min_gain and s.delta_bic < 0
                             and not s.at_bound and not s.implausible)

    # ------------------------------------------------------------------ selection
    def select(self, base: ModelScore, singles: Sequence[ModelScore]
               ) -> tuple[ModelScore, list[ModelScore]]:
        """``(chosen, ranked)``: the chosen model (``base`` when no effect counts) and
        every model tried, the chosen first, then significant ones by held-out error."""
        self._ranked = list(singles)
        self._added = {}
        chosen = selection.pick_single(singles, self.catalogue, self.structure,
                                       self.ambiguity, self.ctx.electrical) or base
        first = [n for n, spec in EFFECTS.items() if spec.named_on_offset]
        if self.ctx.steady and chosen.name not in first:
            # the plateaus show a static offset both ways: a friction-like effect that
            # does as well on held-out data is named before others
            alt = [s for s in singles if s.significant and s.name in first and
                   s.heldout_error <= (1 + self.ambiguity) * chosen.heldout_error]
            if alt:
                chosen = alt[0]
        alike = [n for n, spec in EFFECTS.items() if spec.shows_offset]
        if self.ctx.steady and self.ctx.offsets_alike and chosen.name in alike:
            # the record cannot tell them apart (it never drives against the motion, and
            # without a current a brush drop follows the motion's sign as friction
            # does): their held-out errors differ by how each fits the noise at rest, so
            # the more common is named (both sides of a drivetrain get the same verdict;
            # the 2023 Miami log's right side had been named brush_drop, its left
            # coulomb_friction)
            chosen = min((s for s in singles if s.significant and s.name in alike),
                         key=lambda s: self.catalogue.index(s.name))
        while (chosen is not base and len(chosen.name.split('+')) < self.max_effects
               and self.structure(chosen)):
            nxt = self._add_effect(base, chosen, singles)
            if nxt is None:
                break
            chosen = nxt
        ranked = self._ranked
        ranked.sort(key=lambda s: (s is not chosen, not s.significant, bool(s.failed),
                                   s.heldout_error))
        return chosen, ranked

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
        if self.ctx.one_way:  # one sign of speed: friction and a constant load are one term
            pool = [s for s in pool if not any(set(pair) <= set(have + [s.name])
                                               for pair in selection.one_way_pairs())]
        pool = pool[:self.pool_size]
        trials: list[ModelScore] = []
        fitted = self.fits.map([FitTask(s.name, base, prior=chosen) for s in pool])
        for s, f in zip(pool, fitted, strict=True):
            t = self.judge(f, chosen)
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
            self.say(f'  {t.name:<40} ' + (f'failed: {t.failed}' if t.failed else
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
        fitter = self.ctx.fitter
        last = combo.name.split('+')[-1]
        prior_name = chosen.name.split('+')
        prior: ModelScore | None = None
        for e in prior_name[:-1]:
            prior = fitter.fit(e, base, prior=prior, seed=combo)
        again = fitter.fit(prior_name[-1], base, prior=prior, seed=combo)
        if again.failed or again.heldout_error >= chosen.heldout_error:
            return combo
        cut = 1.0 - combo.heldout_error / again.heldout_error
        self.say(f'  {chosen.name} refitted from {combo.name}: held-out error '
                 f'{again.heldout_error:.4g}; {last} adds {100 * cut:.1f} %')
        if cut < self.min_gain:
            combo.significant = False
            combo.implausible = (f'{chosen.name} refitted from these parameters does as '
                                 f'well ({last} adds {100 * cut:.1f} %)')
            return None
        return combo


def _order(s: ModelScore) -> tuple[bool, float]:
    return (bool(s.failed), s.heldout_error if math.isfinite(s.heldout_error) else math.inf)
