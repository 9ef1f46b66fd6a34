"""Fit and select the extended model by simulation error, the way benchmarks score it.

The equation-error stages of the analysis (one-step predictions, the inverse dynamics of a
closed-loop record) find which named effects a record needs. A user who simulates the
model from the input alone (the EMPS benchmark, a feedforward design, a SysId log's step
tests) judges it by its simulation error, where small force errors add up over seconds.
This stage starts from the analysis' chosen model and

1. splits each run into contiguous blocks; every block is simulated from the input alone,
   from a state set by its first ``init_samples`` samples (the benchmark protocol);
2. refits the model by least squares on the blocks' simulation error of the channels the
   benchmark scores (position where it is measured; else speed and current);
3. tries the refinements of its effects (:attr:`motor_id.effects.EffectSpec.extends`:
   asymmetric, Stribeck and static friction refine Coulomb friction), each fitted on the
   training blocks and judged on the held-out blocks (every third), and keeps one only
   when it cuts the held-out simulation error by ``min_gain``;
4. refits the chosen model on every block.

Both models are reported: the equation-error one (for a closed-loop record, the inverse
dynamics estimate) and this one; ``motor-id validate`` simulates with this one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
import itertools
import math
from typing import TYPE_CHECKING

import numpy as np

from motor_id.analysis.frames import held_channels
from motor_id.analysis.friction import friction_summary
from motor_id.analysis.simulation_delay import (
    PROFILE_NFEV,
    PROFILED,
    samples_param,
)
from motor_id.analysis.simulation_family import (
    family_problem,
    fit_families,
    fit_family,
    fitted_values,
    StageSetup,
)
from motor_id.analysis.simulation_guard import reduced_model, stage_scales, unsound
from motor_id.analysis.simulation_problem import (
    make_blocks,
    open_samples,
    sim_channels,
    SimulationProblem,
)
from motor_id.analysis.simulation_result import (
    SimCandidate,
    SimulationStage,
    StageEstimates,
    StageModel,
)
from motor_id.analysis.simulation_uncertainty import stage_estimates
from motor_id.effects import EFFECTS
from motor_id.errors import FIT_ERRORS
from motor_id.identify.validation import SavedModel

if TYPE_CHECKING:
    from motor_id.recording import Recording


def refinements(model: SavedModel, rec: Recording | None = None) -> list[str]:
    """Effects to try on ``model``, each alone first: the refinements of its effects, an
    effect that refinements extend when the model lacks it (an equation-error stage that
    took asymmetric friction for a load torque never named Coulomb friction), an input
    delay when the model has none (a latency that one-step errors on held readings hide),
    a start latency where the input leaves zero (a drive that applies nothing for a while
    after it is enabled), and a lag of the speed sensor when both a position and a speed
    are scored (the position shows the motion unfiltered: a speed that lags it is
    filtered), and a coupling of two masses (``resonance``, every time: under dry
    friction the equation-error stage, which tries it on the linear model alone, does not
    find it)."""
    out = [e for e, spec in EFFECTS.items()
           if spec.extends and spec.extends in model.effects and e not in model.effects
           and model.input_kind in spec.kinds]
    bases = {spec.extends for spec in EFFECTS.values() if spec.extends}
    out += sorted(b for b in bases if b not in model.effects)
    for rule, applies in STAGE_RULES.items():
        out += [e for e, spec in EFFECTS.items() if spec.stage_rule == rule
                and e not in model.effects and applies(rec)]
    return out


def _position_and_speed(rec: Recording | None) -> bool:
    """Both a position and a speed are scored (a sensor lag shows as their mismatch)."""
    return rec is not None and {'position', 'speed'} <= set(sim_channels(rec))


def _leaves_zero(rec: Recording | None) -> bool:
    """The input of some run leaves zero after resting there (a drive that is enabled
    during the record: where a start latency would show)."""
    return rec is not None and any(
        bool(np.any((rec.input[a + 1:b] != 0.0) & (rec.input[a:b - 1] == 0.0)))
        for a, b in rec.segment_ranges)


STAGE_RULES: dict[str, Callable[[Recording | None], bool]] = {
    'always': lambda rec: True,
    'input_leaves_zero': _leaves_zero,
    'position_and_speed': _position_and_speed,
}
"""When the stage tries an effect that is not in the model
(:attr:`motor_id.effects.EffectSpec.stage_rule`), in the order the rules are tried."""


def pairs(helpful: Sequence[str]) -> list[tuple[str, ...]]:
    """Pairs of effects that each helped alone and can coexist (stiction and Stribeck
    friction both set the static level; one profile finds a delay or a start latency,
    not both); an added base effect (Coulomb friction) that
    helped is also paired with each of its refinements."""
    out: list[tuple[str, ...]] = [(a, b) for a, b in itertools.combinations(helpful, 2)
           if a not in EFFECTS[b].excludes and b not in EFFECTS[a].excludes
           and not (a in PROFILED and b in PROFILED)
           and not (EFFECTS[a].extends == b or EFFECTS[b].extends == a)]
    for base in helpful:
        out += [(base, e) for e, spec in EFFECTS.items() if spec.extends == base]
    return out


def simulation_stage(rec: Recording, model: SavedModel, init_samples: int = 20,
                     n_blocks: int = 6, min_gain: float = 0.05,
                     progress: Callable[[str], object] | None = None,
                     halves: bool = True, jobs: int = 1) -> SimulationStage:
    """Fit ``model`` and its refinements by simulation error (the report's
    ``simulation`` block).

    Parameters
    ----------
    rec : Recording
    model : SavedModel
        The analysis' chosen model (start values and effects).
    init_samples : int
        Samples at the start of each block that set its initial state.
    n_blocks : int
        About how many blocks the record is cut into; every third is held out.
    min_gain : float
        Fraction of the held-out simulation error a refinement must remove.
    progress : callable, optional
    halves : bool
        Refit the chosen model on each half of the blocks: the spread of the two is a
        floor under its error bars (:mod:`.simulation_uncertainty`).
    jobs : int
        Processes for the candidate fits of one step (forked; the result is the same).

    Returns
    -------
    SimulationStage
        The blocks, the held readings per channel, the candidates (each fitted on the
        training blocks, scored on the held-out ones), the chosen one refitted on every
        block with its estimates (values, error bars, determinacy) and RMSE.
    """
    say = progress or (lambda _msg: None)
    blocks = make_blocks(rec, n_blocks, init_samples, open_samples(rec, model, init_samples))
    held = blocks[2::3] if len(blocks) >= 3 else []
    train = [b for b in blocks if b not in held] if held else blocks
    frames = held_channels(rec, sim_channels(rec))
    fresh = {ch: ev.fresh for ch, ev in frames.items() if ev.found} or None
    for ch, ev in frames.items():
        if ev.found:
            say(f'  held readings on {ch}: {ev.reason}')
    setup = StageSetup(rec, init_samples, train, held, fresh, say,
                       stage_scales(rec, model.parameters))
    reduced = reduced_model(model)
    rival = reduced is not None
    cands, best = _search(setup, model, min_gain, jobs, rival=rival)
    swapped = _poles_swapped(model, rec)
    if swapped is not None and cands and cands[0].scored:
        more, best = _from_swapped(setup, swapped, cands[0], best, min_gain, jobs, rival)
        cands += more
    latency = _latency_for_delay(model, rec)
    if latency is not None:   # the delay swapped for a start latency: the better kept
        say('simulation error: the input delay swapped for a start latency')
        alt, alt_best = _search(setup, latency, min_gain, jobs, rival=rival)
        if alt_best is not None and (best is None or _beats(alt_best, best,
                                                            (1.0 - min_gain) ** 2)):
            best = alt_best
        cands += alt
    if best is not None:
        more, best = _both_delays(setup, best, (1.0 - min_gain) ** 2)
        cands += more
    fallback = ''
    if reduced is not None:
        cands, best, fallback = _with_rival(setup, reduced, cands, best, min_gain, jobs)
    shared = SimulationStage(channels=tuple(sim_channels(rec)), init_samples=init_samples,
                             blocks=tuple(blocks), heldout_blocks=tuple(held),
                             min_gain=min_gain, held_readings=frames, candidates=(),
                             fallback=fallback)
    if best is None:
        return replace(shared, candidates=tuple(cands), failed=(
            'no sound model could be fitted by simulation error (every candidate failed, '
            'diverged or was implausible)'))
    chosen, best_z, best_prob = best
    with np.errstate(all='ignore'):
        heldout_fit = best_prob.fit_percent(best_z, held) if held else {}
    if fresh:
        cands.append(_every_sample(setup, best_prob, chosen))
    say(f'simulation error: refitting {chosen.name} on all {len(blocks)} blocks')
    with np.errstate(all='ignore'):
        try:
            z, _ = best_prob.fit(blocks, best_z)
            why = unsound(best_prob.cost(z, blocks), best_prob.to_model(z)[1], setup.scales)
        except FIT_ERRORS as exc:
            why = str(exc)
        if why:   # keep the training blocks' fit
            say(f'simulation error: the refit on every block failed ({why})')
            z = best_z
        params, effects = best_prob.to_model(z)
        rmse = best_prob.rmse(z, blocks)
        try:
            estimates = stage_estimates(best_prob, z, blocks, halves, say)
        except FIT_ERRORS as exc:
            estimates = StageEstimates(failed=f'no error bars: {type(exc).__name__}: {exc}')
    return replace(shared, candidates=tuple(cands), chosen=chosen.name,
                   gains=_gains(cands, chosen),
                   model=StageModel(input_kind=model.input_kind, parameters=params,
                                    effects=effects), estimates=estimates,
                   friction=friction_summary(params, effects, model.input_kind), rmse=rmse,
                   heldout_fit=heldout_fit)


Best = tuple[SimCandidate, np.ndarray, SimulationProblem]
"""A fitted candidate, its values and its problem."""


def _search(setup: StageSetup, model: SavedModel, min_gain: float, jobs: int,
            base: Best | None = None, rival: bool = False
            ) -> tuple[list[SimCandidate], Best | None]:
    """``model`` and its refinements (:func:`refinements`), each alone then in
    :func:`pairs`, fitted on the training blocks: every candidate, and the best (one
    that beats the best so far by ``min_gain`` on the held-out blocks). ``base``:
    ``model`` fitted already; ``rival``: a simpler model will be searched where
    ``model`` itself is unsound (its refinements are then not tried)."""
    rec = setup.rec
    cands: list[SimCandidate] = []
    best: Best | None = None
    gain_needed = (1.0 - min_gain) ** 2    # on the squared error
    helpful: list[str] = []
    singles: list[tuple[str, ...]] = [(e,) for e in refinements(model, rec)]
    single_costs: dict[str, float] = {}
    fitted: dict[tuple[str, ...], tuple[float, dict[str, float]]] = {}
    """Per family fitted so far: its held-out cost and its values by free name."""
    best_family: tuple[str, ...] = ()
    for stage in ('base', 'singles', 'pairs'):
        families: list[tuple[str, ...]] = ([()] if stage == 'base' else
                                           singles if stage == 'singles' else pairs(helpful))
        fits = [base] if stage == 'base' and base is not None else \
            fit_families(setup, model, families, fitted, jobs)
        for extra, (cand, z, prob) in zip(families, fits, strict=True):
            cands.append(cand)
            if not cand.scored:
                continue
            fitted[extra] = (cand.heldout_cost, fitted_values(prob, z))
            if best is not None and cand.heldout_cost < gain_needed * best[0].heldout_cost:
                best = _polish(setup, best, cand, z, prob)
                fitted[best_family] = (best[0].heldout_cost, fitted_values(best[2], best[1]))
            if stage == 'singles':
                single_costs[extra[0]] = cand.heldout_cost
            if best is None or _beats((cand, z, prob), best, gain_needed,
                                      _rivals(extra, best_family)):
                best, best_family = (cand, z, prob), extra
        if stage == 'singles':   # judged against the base as polished by them all
            helpful = [e for e, c in single_costs.items()
                       if c < gain_needed * cands[0].heldout_cost]
        if best is None and rival:   # a diverged model is no start for refinements
            break
    return cands, best


def _with_rival(setup: StageSetup, reduced: SavedModel, cands: list[SimCandidate],
                best: Best | None, min_gain: float, jobs: int
                ) -> tuple[list[SimCandidate], Best | None, str]:
    """The analysis' model against its rival without the extra effects
    (:func:`.simulation_guard.reduced_model`): ``best`` stands where it is sound and
    beats the rival on the held-out blocks; otherwise the stage searches from the
    rival (its refinements and delays included). Returns the candidates, the best and
    why the stage fell back ('' where it did not)."""
    rival = fit_families(setup, reduced, [()], {}, 1)[0]
    r_cand = rival[0]
    if best is not None and (not r_cand.scored
                             or best[0].heldout_cost < r_cand.heldout_cost):
        return [*cands, r_cand], best, ''
    lead = best[0] if best is not None else cands[0]
    why = (f'{lead.name}, held-out cost {lead.heldout_cost:.4g}' if best is not None else
           f'no sound candidate ({lead.name}: {lead.failed})')
    note = (f'the model the analysis chose did no better in simulation than {r_cand.name} '
            f'(held-out cost {r_cand.heldout_cost:.4g}; best: {why}): the stage searched '
            f'again from {r_cand.name}')
    setup.say(f'simulation error: {note}')
    more, alt = _search(setup, reduced, min_gain, jobs, base=rival)
    return [*cands, *more], alt if alt is not None else best, note


def _rivals(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    """Families that differ by one delay for another (an input delay, a start latency):
    :func:`_beats` counts their free parameters."""
    diff = set(a) ^ set(b)
    return len(a) == len(b) and len(diff) == 2 and diff <= set(PROFILED)


def _beats(new: Best, old: Best, gain_needed: float, rivals: bool = True) -> bool:
    """``new`` replaces ``old``: its held-out cost is below ``gain_needed`` times the
    other's; for rivals (:func:`_rivals`) the one of fewer free parameters wins unless the
    other beats it so, and of as many the lower wins (a delay refined between samples has
    one more parameter than a whole-sample start latency)."""
    if new[0].heldout_cost < gain_needed * old[0].heldout_cost:
        return True
    if not rivals:
        return False
    n_new, n_old = len(new[2].free), len(old[2].free)
    if n_new != n_old:
        return n_new < n_old and not old[0].heldout_cost < gain_needed * new[0].heldout_cost
    return new[0].heldout_cost < old[0].heldout_cost


def _poles_swapped(model: SavedModel, rec: Recording) -> SavedModel | None:
    """``model`` with its winding's and its mechanics' time constants exchanged, where a
    voltage plant measured without a current has the winding the slower (None
    elsewhere): speed alone sees two poles and cannot tell which is the winding's, and
    a DC motor's winding is the faster. The equation-error stage can end with them
    exchanged (a SysId arm routine: L_m / R_m 44 ms, J R_m / (K_T K_b) 0.23 ms; kA 300
    times too small, then not determined, kV 3.7 % high)."""
    if model.input_kind != 'voltage' or rec.has_current:
        return None
    p = dict(model.parameters)
    tau_e = p['L_m'] / p['R_m']
    tau_m = p['J'] * p['R_m'] / (p['K_T'] * p['K_b'])
    if not tau_e > tau_m > 0.0:
        return None
    p['L_m'], p['J'] = tau_m * p['R_m'], tau_e * p['K_T'] * p['K_b'] / p['R_m']
    return SavedModel(model.input_kind, p, {e: dict(v) for e, v in model.effects.items()},
                      model.source)


def _from_swapped(setup: StageSetup, swapped: SavedModel, base: SimCandidate, best: Best | None,
                  min_gain: float, jobs: int, rival: bool
                  ) -> tuple[list[SimCandidate], Best | None]:
    """The analysis' model with its poles exchanged (:func:`_poles_swapped`) fitted;
    where it beats the model as fitted (``base``) held out by ``min_gain``, the stage
    searches from it too and keeps the lower of the two bests. Returns the candidates
    tried and the best."""
    first = fit_families(setup, swapped, [()], {}, 1)[0]
    first[0].start = SWAPPED
    if not first[0].scored or not first[0].heldout_cost < (1.0 - min_gain) ** 2 * \
            base.heldout_cost:
        return [first[0]], best
    setup.say('simulation error: the winding the faster pole (they came out exchanged)')
    alt, alt_best = _search(setup, swapped, min_gain, jobs, base=first, rival=rival)
    for c in alt:
        c.start = SWAPPED
    if alt_best is not None and (best is None
                                 or alt_best[0].heldout_cost < best[0].heldout_cost):
        best = alt_best
    return alt, best


SWAPPED = "the analysis' model with its winding and mechanics exchanged"
""":attr:`~.simulation_result.SimCandidate.start` of a fit from :func:`_poles_swapped`."""


def _latency_for_delay(model: SavedModel, rec: Recording) -> SavedModel | None:
    """``model`` with its input delay swapped for a start latency of as many samples,
    where it has a delay and the record's input leaves zero (None elsewhere).

    At a step from rest the two are alike (nothing for d samples, then the step); on a
    ramp a delay lags the whole input, a latency does not (a delay in its place biases
    kS by ramp rate x delay). The equation-error stage has no start latency (it acts
    only through the simulation), so it names a delay where the drive's enable is late:
    the stage fits both and keeps the better (both have one whole number of samples).
    """
    if 'input_delay' not in model.effects or 'start_latency' in model.effects or \
            not _leaves_zero(rec):
        return None
    effects = {('start_latency' if e == 'input_delay' else e): dict(v)
               for e, v in model.effects.items()}
    return SavedModel(model.input_kind, dict(model.parameters), effects, model.source)


def _both_delays(setup: StageSetup, best: Best, gain_needed: float
                 ) -> tuple[list[SimCandidate], Best]:
    """The chosen family with the other kind of delay added, where it has one and the
    other applies (a start latency where the input leaves zero): a drive that applies
    every command late (a CAN frame) and nothing for a while after it is enabled. One
    profile finds one of them (:func:`.simulation_fit.pairs` never pairs them), and
    alone it takes their total at every step, which a ramp's start and every step down
    then contradict (kS 17 % low on a routine of a 1-loop delay and a 2-loop enable
    latency). The other is profiled with the first held, then their total is split
    again: each whole split refitted briefly on the training blocks, the best fully.
    Returns the candidates tried and the best (replaced where the two beat it by
    ``gain_needed`` held out)."""
    cand, _, prob = best
    rec = setup.rec
    have = [e for e in PROFILED if e in cand.effects]
    other = [e for e in PROFILED if e not in cand.effects
             and STAGE_RULES.get(EFFECTS[e].stage_rule, lambda _r: True)(rec)]
    if len(have) != 1 or not other:
        return [], best
    added = fit_family(setup, _as_model(cand, cand.effects, prob.model.input_kind),
                       (other[0],))
    tried = [added[0]]
    if not added[0].scored or added[0].effects[other[0]][samples_param(other[0])] < 0.5:
        return tried, best   # none of the other: the model the search had
    split = _resplit(setup, added[0])
    if split is not None:
        tried.append(split[0])
        if split[0].scored and split[0].heldout_cost < added[0].heldout_cost:
            added = split
    return tried, added if added[0].heldout_cost < gain_needed * cand.heldout_cost else best


def _as_model(cand: SimCandidate, effects: Mapping[str, Mapping[str, float]],
              input_kind: str) -> SavedModel:
    """A fitted candidate's parameters with ``effects``, as a model to fit from."""
    return SavedModel(input_kind, dict(cand.parameters),
                      {e: dict(v) for e, v in effects.items()})


def _resplit(setup: StageSetup, cand: SimCandidate) -> Best | None:
    """``cand`` (with both delays) at the whole split of their total that fits the
    training blocks best after a brief refit (:data:`.simulation_delay.PROFILE_NFEV`
    evaluations each), fitted fully and scored; None where that is its own split."""
    delay, latency = PROFILED
    total = int(round(sum(cand.effects[e][samples_param(e)] for e in PROFILED)))
    own = int(np.floor(cand.effects[delay][samples_param(delay)] + 1e-9))

    def split(d: int) -> SavedModel:   # its own split as it is, with its fraction
        return _as_model(cand, cand.effects if d == own else {
            **cand.effects, delay: {samples_param(delay): float(d)},
            latency: {samples_param(latency): float(total - d)}}, setup.rec.input_kind)

    best_cost, best_split = math.inf, own
    # each at least one sample (one alone is the search's), and its own split (which
    # may have less) refitted as briefly
    for d in sorted({*range(1, total), own}):
        prob = family_problem(setup, split(d), ())
        try:
            with np.errstate(all='ignore'):
                z, _ = prob.fit(setup.train, prob.start(), max_nfev=PROFILE_NFEV)
                cost = prob.cost(z, setup.train)
        except FIT_ERRORS:
            continue
        if cost < best_cost:
            best_cost, best_split = cost, d
    return None if best_split == own else fit_family(setup, split(best_split), ())


def _gains(cands: Sequence[SimCandidate], chosen: SimCandidate) -> dict[str, float]:
    """Per effect of the chosen model: the share of the held-out simulation error it
    removes, ``1 - cost with / cost without`` (from the candidate without it). Held
    readings are a fact of the values (:mod:`.frames`), not a gain; the candidate
    ``... (every sample)`` shows the chosen model fitted on every sample as logged."""
    # (from the same start: a search from the poles exchanged repeats the names)
    by_name = {c.name: c for c in cands if c.scored and c.start == chosen.start}
    parts = chosen.name.split('+')
    out: dict[str, float] = {}
    for e in parts:
        without = '+'.join(p for p in parts if p != e) or 'linear'
        if without in by_name and e in EFFECTS:
            out[e] = 1.0 - chosen.heldout_cost / by_name[without].heldout_cost
    return out


def _polish(setup: StageSetup, best: tuple[SimCandidate, np.ndarray, SimulationProblem],
            cand: SimCandidate, z: np.ndarray, prob: SimulationProblem
            ) -> tuple[SimCandidate, np.ndarray, SimulationProblem]:
    """``best`` refitted from where ``cand``, a model that contains it, ended.

    With dry friction the simulation error is only piecewise smooth, and a fit stops at
    a point that depends on its path: a candidate can beat the model it refines with an
    extra parameter that does nothing (a static level below the Coulomb level), because
    its other parameters took a better path. Refitted from the candidate's values of the
    parameters they share, the smaller model shows what the path was worth; the gain
    that remains is the effect's. The refit replaces ``best`` only where it is better.
    """
    b_cand, b_z, b_prob = best
    if not set(b_cand.name.split('+')) < set(cand.name.split('+')):
        return best
    where = dict(zip(prob.free, z, strict=True))
    z0 = np.array([where.get(n, v) for n, v in zip(b_prob.free, b_z, strict=True)])
    setup.say(f'simulation error: refitting {b_cand.name} from where {cand.name} ended')
    try:
        with np.errstate(all='ignore'):
            z1, nfev = b_prob.fit(setup.train, z0)
            score_on = setup.held or setup.train
            cost = b_prob.cost(z1, score_on)
    except FIT_ERRORS:
        return best
    if not cost < b_cand.heldout_cost:
        return best
    b_cand.parameters, b_cand.effects = b_prob.to_model(z1)
    b_cand.train_rmse = b_prob.rmse(z1, setup.train)
    if setup.held:
        b_cand.heldout_rmse = b_prob.rmse(z1, setup.held)
    b_cand.heldout_cost = cost
    b_cand.nfev += nfev
    b_cand.polished_from = cand.name
    return b_cand, z1, b_prob


def _every_sample(setup: StageSetup, prob: SimulationProblem, chosen: SimCandidate
                  ) -> SimCandidate:
    """The chosen model fitted on every sample as logged, scored on the held-out fresh
    samples: what modelling the held readings gains."""
    plain = SimulationProblem(setup.rec, prob.model, setup.init_samples, prob.free)
    name = chosen.name + ' (every sample)'
    setup.say(f'simulation error: fitting {name} on {len(setup.train)} blocks')
    cand = SimCandidate(name=name)
    try:
        with np.errstate(all='ignore'):
            z, cand.nfev = plain.fit(setup.train)
            cand.parameters, cand.effects = plain.to_model(z)
            score_on = setup.held or setup.train
            cand.heldout_rmse = prob.rmse(z, score_on)
            cand.heldout_cost = prob.cost(z, score_on)
    except FIT_ERRORS as exc:
        cand.failed = f'{type(exc).__name__}: {exc}'
    return cand
