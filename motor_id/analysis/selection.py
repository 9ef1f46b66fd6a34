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
import math
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.effects import EFFECTS

if TYPE_CHECKING:
    from motor_id.analysis.heldout import HeldOutSplit
    from motor_id.analysis.report import ModelScore
    from motor_id.recording import Recording

EXPERIMENTS = {
    frozenset(('coulomb_friction', 'load_torque')):
        'reverse the motor (bipolar_steps with rests): Coulomb friction changes sign '
        'with the speed, a constant load torque does not',
    frozenset(('coulomb_friction', 'brush_drop')):
        'measure the current and brake hard (steps down) so that the current reverses '
        'while the speed keeps its sign: friction follows the speed, the brush drop the '
        'current',
    frozenset(('coulomb_friction', 'dead_zone')):
        'measure the current and decelerate with the input still positive: friction '
        'raises the current needed at a given speed, a dead zone lowers the voltage '
        'that reaches the motor',
    frozenset(('brush_drop', 'dead_zone')):
        'braking steps in which the current reverses while the input keeps its sign: '
        'a brush drop follows the current sign, a dead zone the input sign',
    frozenset(('resistance_drift', 'brush_drop')):
        'measure the current over a long run at a constant load: heating makes the '
        'voltage error grow with the integral of i^2, a brush drop is there at once',
    frozenset(('resistance_drift', 'dead_zone')):
        'measure the current and repeat the same steps cold and warm: heating changes '
        'the response over time, a dead zone does not',
    frozenset(('load_torque', 'brush_drop')):
        'reverse the motor: a brush drop changes sign with the current, a load torque '
        'keeps its sign',
    frozenset(('load_torque', 'dead_zone')):
        'reverse the input: a dead zone is symmetric, a constant load is not',
    frozenset(('quadratic_load', 'voltage_saturation')):
        'a staircase of input levels below and above the suspected limit: a quadratic '
        'load bends the steady-state map smoothly, saturation cuts it flat',
    frozenset(('quadratic_load', 'coulomb_friction')):
        'a staircase of several steady speeds: friction offsets the speed-input map by '
        'a constant, a quadratic load bends it',
    frozenset(('sensor_lag', 'input_delay')):
        'fast steps or a PRBS with the current measured: a delay shifts the whole '
        'response, a sensor lag smooths only the speed reading',
    frozenset(('sensor_lag', 'resonance')):
        'a multisine through the suspected resonance: a lag only attenuates, a '
        'compliant shaft rings',
    frozenset(('input_delay', 'resonance')):
        'a multisine through the suspected resonance: a delay only shifts the phase, '
        'a compliant shaft rings',
}
TORQUE_EXPERIMENTS = {
    frozenset(('coulomb_friction', 'dead_zone')):
        'log the current with its sign and brake with the torque reversed while the '
        'shaft still turns: friction follows the speed sign, a dead zone the torque sign '
        '(a torque whose sign is inferred from the speed makes both act alike)',
    frozenset(('coulomb_friction', 'load_torque')):
        'reverse the motion: friction changes sign with the speed, a constant load or '
        'force offset does not',
}
"""Experiments for torque-input plants where they differ from :data:`EXPERIMENTS`."""
GENERIC_EXPERIMENT = ('an excitation that visits more operating points: bipolar steps with '
                      'rests at several amplitudes, a PRBS, and the current measured')


def experiment(a: str, b: str, input_kind: str) -> str:
    """The experiment that separates effects ``a`` and ``b``."""
    key = frozenset((a, b))
    return ((TORQUE_EXPERIMENTS.get(key) if input_kind == 'torque' else None)
            or EXPERIMENTS.get(key, GENERIC_EXPERIMENT))


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


ALIAS = 0.8
"""A mode above this fraction of the Nyquist frequency is an alias, not a resonance."""


def aliased(effects: Mapping[str, Mapping[str, float]], scales: Mapping[str, float]) -> str:
    """Why a model's pole is an alias of the sampling ('' when it is not).

    A resonance at or near the Nyquist frequency (half the sample rate) cannot be told
    from an alias of anything faster, nor from a discrete-time artefact of the fit.
    """
    res = effects.get('resonance')
    rate = scales.get('per_sample')
    if not res or not rate or 'f_r' not in res:
        return ''
    nyquist = 0.5 * rate
    if res['f_r'] >= ALIAS * nyquist:
        return (f'a resonance at {res["f_r"]:.3g} Hz is at or above {ALIAS:.0%} of the '
                f'Nyquist frequency ({nyquist:.3g} Hz): an alias, not a physical mode')
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


def steady_offset(summary: Mapping[str, Any]) -> tuple[float, float] | None:
    """The zero-speed inputs of the steady-state map when they point to static friction
    (or a dead band): positive on the positive side and negative on the negative side.

    Returns ``(u_pos, u_neg)`` or None.
    """
    pos, neg = summary.get('positive'), summary.get('negative')
    if not pos or not neg:
        return None
    up, un = pos.get('zero_speed_input'), neg.get('zero_speed_input')
    if up is None or un is None or not (up > 0 > un):
        return None
    return up, un


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
                electrical: Mapping[str, Any] | None = None) -> ModelScore | None:
    """The chosen one-effect model, or None.

    The best significant single by held-out error; when even it leaves structure,
    error differences within ``ambiguity`` reflect the misfit, so the more common effect
    (catalogue order) is named. Among heating, brush drop and dead zone the electrical
    equation error (``electrical['favoured']``) decides when it is one of the
    significant candidates.
    """
    sig = [s for s in singles if s.significant]
    if not sig:
        return None
    chosen = sig[0]
    if structure(chosen):
        ties = [s for s in sig if s.heldout_error <= (1 + ambiguity) * chosen.heldout_error]
        chosen = min(ties, key=lambda s: catalogue.index(s.name))
    fav = (electrical or {}).get('favoured')
    trio = ('resistance_drift', 'brush_drop', 'dead_zone')
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


ONE_WAY = ('coulomb_friction', 'load_torque')


def ambiguous(chosen: ModelScore, ranked: Sequence[ModelScore], ambiguity: float, input_kind: str,
              one_way: bool = False) -> list[dict[str, Any]]:
    """Other significant single models as good as the chosen one, with experiments.

    With ``one_way`` (the speed kept one sign) Coulomb friction and a constant load act
    alike: whichever the verdict names, the other is listed, and the model holds for
    that direction only.
    """
    out: list[dict[str, Any]] = []
    have = chosen.name.split('+')
    if one_way:
        for a, b in (ONE_WAY, ONE_WAY[::-1]):
            if a in have and b not in have:
                out.append({'name': b, 'gain': None,
                            'experiment': experiment(a, b, input_kind),
                            'note': f'the speed kept one sign: {a} and {b} act alike; the '
                                    'model holds for this direction only'})
    for s in ranked:
        if s is chosen or not s.significant or '+' in s.name:
            continue
        if s.name in have or any(o['name'] == s.name for o in out):
            continue
        if s.heldout_error <= (1 + ambiguity) * chosen.heldout_error:
            main = chosen.name.split('+')[0]
            out.append({'name': s.name, 'gain': s.gain,
                        'experiment': experiment(main, s.name, input_kind)})
    return out
