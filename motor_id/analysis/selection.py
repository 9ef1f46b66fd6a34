"""Model selection: significance against a reference, the verdict, combinations, ambiguity.

A model counts as *significant* against its reference (the linear model for one effect,
the best one-effect model for a second effect) when it cuts the reference's held-out
error by at least ``min_gain`` and improves at least half of the held-out sub-blocks, or
by at least ``CONSISTENT min_gain`` and improves the sub-blocks beyond chance (or,
when the held-out blocks are blind to a misfit the training blocks show, cuts the
training error by ``4 min_gain`` without worsening the held-out error), beats it
in BIC (with the sample count reduced for residual autocorrelation), has no parameter
at a search limit and is plausible (:meth:`motor_id.effects.EffectSpec.implausible`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
from typing import TYPE_CHECKING

import numpy as np

from motor_id.effects import Confusion, EFFECTS
from motor_id.records import optional, Record

if TYPE_CHECKING:
    from motor_id.analysis.diagnostics import SteadyStateMap
    from motor_id.analysis.heldout import HeldOutSplit
    from motor_id.analysis.inverse_dynamics import ElectricalEvidence
    from motor_id.analysis.report import ModelScore
    from motor_id.recording import Recording

GENERIC_EXPERIMENT = ('an excitation that visits more operating points: bipolar steps with '
                      'rests at several amplitudes, a PRBS, and the current measured')


def confusion(a: str, b: str) -> Confusion | None:
    """What the entry of ``a`` or of ``b`` says about taking one for the other."""
    for x, y in ((a, b), (b, a)):
        spec = EFFECTS.get(x)
        found = next((c for c in spec.confused_with if c.other == y), None) if spec else None
        if found:
            return found
    return None


def experiment(a: str, b: str, input_kind: str) -> str:
    """The experiment that separates effects ``a`` and ``b`` (their entries'
    :class:`~motor_id.effects.Confusion`; a generic one where neither names the other)."""
    c = confusion(a, b)
    if c is None:
        return GENERIC_EXPERIMENT
    return (c.torque_experiment if input_kind == 'torque' else '') or c.experiment


def one_way_pairs() -> list[tuple[str, str]]:
    """Pairs of effects that act alike on a record whose speed keeps one sign."""
    return [(name, c.other) for name, spec in EFFECTS.items() for c in spec.confused_with
            if c.one_way]


CONSISTENT = 0.4
"""A smaller held-out gain, from ``CONSISTENT * min_gain`` on, counts when the sub-blocks
agree beyond chance (:data:`SIGN_ALPHA`): at high noise a real effect cuts only a small
share of an error that is mostly noise, but it cuts it everywhere."""
SIGN_ALPHA = 1e-3
"""Level of the sign test over the held-out sub-blocks (12 of 12 improved: p = 2.4e-4)."""


def sign_test(wins: float, n: int) -> float:
    """One-sided sign test: the chance of ``wins`` or more of ``n`` by coin flips."""
    if n <= 0:
        return 1.0
    return sum(math.comb(n, k) for k in range(int(wins), n + 1)) / 2.0 ** n


def judge(score: ModelScore, ref: ModelScore, split: HeldOutSplit, min_gain: float,
          scales: Mapping[str, float]) -> ModelScore:
    """Gain, block wins, BIC and significance of ``score`` against ``ref`` (in place).

    The gain is ``1 - error / error_ref`` on the held-out blocks.
    """
    if score.failed or not math.isfinite(score.heldout_error):
        score.gain, score.significant = 0.0, False
        return score
    score.gain = float(1.0 - score.heldout_error / ref.heldout_error) \
        if ref.heldout_error > 0 else 0.0
    a, b = score.prediction['sub'], ref.prediction['sub']
    score.block_wins = float(np.mean(a < b))
    n_eff = split.n_eff(score.prediction['preds'])
    dk = score.n_extra - ref.n_extra
    if score.train_error > 0 and ref.train_error > 0:
        score.delta_bic = float(n_eff * 2 * math.log(score.train_error / ref.train_error)
                                + dk * math.log(n_eff))
    if not score.implausible:
        score.implausible = aliased(score.effects, scales)
    if not score.implausible:
        for e, vals in score.effects.items():
            if e in EFFECTS and vals:
                score.implausible = EFFECTS[e].implausible(vals, scales)
                if score.implausible:
                    break
    wins = int(np.sum(a < b))
    heldout_ok = (score.gain >= min_gain and score.block_wins >= 0.5) or \
        (score.gain >= CONSISTENT * min_gain and sign_test(wins, a.size) <= SIGN_ALPHA)
    score.significant = bool((heldout_ok or _blind_heldout(score, ref, split, min_gain))
                             and score.delta_bic < 0 and not score.at_bound
                             and not score.implausible)
    return score


def aliased(effects: Mapping[str, Mapping[str, float]], scales: Mapping[str, float]) -> str:
    """Why a model is implausible by an effect's own rule
    (:attr:`motor_id.effects.EffectSpec.check`: a resonance at the Nyquist frequency is an
    alias of the sampling), '' when none."""
    for e, vals in effects.items():
        spec = EFFECTS.get(e)
        reason = spec.check(vals, scales) if spec and spec.check else ''
        if reason:
            return reason
    return ''


def responds_at_once(rec: Recording, floor_speed: float) -> bool:
    """True when the speed answers input steps within one sample.

    At every large input step (over a fifth of the input's range) the speed change over
    the next sample, in the step's direction, is compared with the noise: when most
    steps move the speed by over three noise stds at once, no input delay of two or more
    samples is plausible.
    """
    du = np.diff(rec.input)   # du[j]: the input held from t[j+1] on changes
    big = np.flatnonzero(np.abs(du) > 0.2 * (np.ptp(rec.input) or 1.0))
    big = big[big + 2 < len(rec)]
    if big.size < 2 or floor_speed <= 0:
        return False
    w = rec.speed
    before = w[big + 1] - w[big]         # the interval before the new input acts
    after = w[big + 2] - w[big + 1]      # the first interval under the new input
    moved = np.sign(du[big]) * (after - before) > 3.0 * math.sqrt(2.0) * floor_speed
    return bool(np.mean(moved) > 0.5)


def one_direction(rec: Recording) -> bool:
    """True when the speed keeps one sign (at least 97 % of the moving samples)."""
    w = rec.speed
    moving = np.abs(w) > 0.05 * (np.max(np.abs(w)) or 1.0)
    if not np.any(moving):
        return False
    pos = float(np.mean(w[moving] > 0))
    return pos >= 0.97 or pos <= 0.03


def steady_offset(summary: SteadyStateMap) -> tuple[float, float] | None:
    """The zero-speed inputs of the steady-state map when they point to static friction
    (or a dead band): positive on the positive side and negative on the negative side.

    Returns ``(u_pos, u_neg)`` or None.
    """
    pos, neg = summary.positive, summary.negative
    if not pos or not neg:
        return None
    up, un = pos.zero_speed_input, neg.zero_speed_input
    if up is None or un is None or not (up > 0 > un):
        return None
    return up, un


def offsets_alike(rec: Recording, floor: float, offset: tuple[float, float] | None) -> bool:
    """True when the record cannot tell apart the effects that show a static offset
    (Coulomb friction, a dead zone): its input never drives against the motion, nor
    stays below the offset while the speed is up (where friction brakes and a dead
    zone coasts). Samples within three noise floors of zero speed do not count."""
    if offset is None or rec.input_kind != 'voltage' or rec.has_current:
        return False
    u, w = rec.input, rec.speed
    moving = np.abs(w) > 3.0 * floor
    against = moving & (u * np.sign(w) < 0.0)
    below = moving & (np.abs(u) < 0.5 * min(abs(offset[0]), abs(offset[1])))
    return bool(np.mean(against | below) <= 0.005)


def _blind_heldout(score: ModelScore, ref: ModelScore, split: HeldOutSplit, min_gain: float
                   ) -> bool:
    """True when the held-out blocks cannot see a misfit the training blocks show.

    The reference already predicts the held-out blocks to the noise floor while its
    training error is several times larger (the effect acts where no block was held
    out, e.g. a winding heating up from cold at the start); then a candidate counts when
    it cuts the training error by ``4 min_gain`` without worsening the held-out error.
    """
    floor = split.floor
    blind = ref.heldout_error <= 1.2 * floor and ref.train_error >= 3.0 * floor
    train_gain = 1.0 - score.train_error / ref.train_error if ref.train_error > 0 else 0.0
    return bool(blind and train_gain >= 4 * min_gain and score.gain >= -0.01)


def pick_single(singles: Sequence[ModelScore], catalogue: Sequence[str],
                structure: Callable[[ModelScore], bool], ambiguity: float,
                electrical: ElectricalEvidence | None = None) -> ModelScore | None:
    """The chosen one-effect model, or None.

    The best significant single by held-out error; when even it leaves structure,
    error differences within ``ambiguity`` reflect the misfit, so the more common effect
    (catalogue order) is named. Among the effects the electrical equation error tells
    apart (heating, brush drop, dead zone: each with an ``electrical_term``) its verdict
    (``electrical.favoured``) decides when it is one of the significant candidates.
    """
    sig = [s for s in singles if s.significant]
    if not sig:
        return None
    chosen = sig[0]
    if structure(chosen):
        ties = [s for s in sig if s.heldout_error <= (1 + ambiguity) * chosen.heldout_error]
        chosen = min(ties, key=lambda s: catalogue.index(s.name))
    fav = electrical.favoured if electrical is not None else None
    trio = [n for n, spec in EFFECTS.items() if spec.electrical_term]
    if fav and chosen.name in trio and fav != chosen.name:
        alt = [s for s in sig if s.name == fav]
        if alt:
            chosen = alt[0]
    return chosen


def components(combo: ModelScore, singles: Sequence[ModelScore], parts_error: Mapping[str, float]
               ) -> dict[str, dict[str, float]]:
    """Each effect's own gain alone and its marginal gain on top of the others.

    ``parts_error`` maps each effect of the combination to the held-out error of the
    combination without it.
    """
    out: dict[str, dict[str, float]] = {}
    for e in combo.name.split('+'):
        alone = next((s.gain for s in singles if s.name == e), 0.0)
        rest = parts_error.get(e, math.inf)
        marg = 1.0 - combo.heldout_error / rest if math.isfinite(rest) and rest > 0 else 0.0
        out[e] = {'alone': float(alone), 'marginal': float(marg)}
    return out


@dataclass(frozen=True, kw_only=True)
class Ambiguity(Record):
    """A model as good as the chosen one (its held-out ``gain``; None for one the record
    cannot tell apart at all) and the ``experiment`` that would separate them."""

    name: str
    gain: float | None
    experiment: str
    note: str | None = optional()


def ambiguous(chosen: ModelScore, ranked: Sequence[ModelScore], ambiguity: float, input_kind: str,
              one_way: bool = False) -> list[Ambiguity]:
    """Other significant single models as good as the chosen one, with experiments.

    With ``one_way`` (the speed kept one sign) Coulomb friction and a constant load act
    alike: whichever the verdict names, the other is listed, and the model holds for
    that direction only.
    """
    out: list[Ambiguity] = []
    have = chosen.name.split('+')
    if one_way:
        for a, b in [p for pair in one_way_pairs() for p in (pair, pair[::-1])]:
            if a in have and b not in have:
                out.append(Ambiguity(
                    name=b, gain=None, experiment=experiment(a, b, input_kind),
                    note=f'the speed kept one sign: {a} and {b} act alike; the model holds '
                         'for this direction only'))
    for s in ranked:
        if s is chosen or not s.significant or '+' in s.name:
            continue
        if s.name in have or any(o.name == s.name for o in out):
            continue
        if s.heldout_error <= (1 + ambiguity) * chosen.heldout_error:
            main = chosen.name.split('+')[0]
            out.append(Ambiguity(name=s.name, gain=s.gain,
                                 experiment=experiment(main, s.name, input_kind)))
    return out
