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
from dataclasses import dataclass, replace
import itertools
import multiprocessing
from typing import TYPE_CHECKING

import numpy as np

from motor_id.analysis.frames import held_channels
from motor_id.analysis.friction import friction_summary
from motor_id.analysis.simulation_delay import (
    profile_delay,
    profile_key,
    PROFILED,
    profiled,
    profiled_problem,
    samples_param,
)
from motor_id.analysis.simulation_guard import reduced_model, stage_scales, unsound
from motor_id.analysis.simulation_problem import (
    fraction_keys,
    free_names,
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
from motor_id.analysis.simulation_uncertainty import LAG_SHORT, stage_estimates
from motor_id.analysis.workers import _worker_start, longest_first
from motor_id.effects import EFFECTS, role_value
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


LONG_LAG = 5.0
"""A winding's time constant ``L_m / R_m`` [sample periods] over which a speed-only
model's second pole is taken for something else (:func:`_takes_second_pole`)."""


def _takes_second_pole(extra: Sequence[str], rec: Recording, model: SavedModel) -> bool:
    """``extra`` adds a coupling of two masses (a plant term) to a voltage plant measured
    by speed (and position) alone whose winding's time constant came out over
    :data:`LONG_LAG` samples: speed alone sees two poles, and a slow second one is the
    coupling's rather than a winding's (the 2023 Miami drivetrain: 51 samples, 0.26 s,
    where its wheels slip on the floor while the robot catches up). The family then
    starts from a short winding lag (:data:`~.simulation_uncertainty.LAG_SHORT`)."""
    if not any(EFFECTS[e].plant_term for e in extra) or model.input_kind != 'voltage' \
            or rec.has_current:
        return False
    p = model.parameters
    return bool(p.get('L_m', 0.0) / p.get('R_m', 1.0) > LONG_LAG * rec.sample_period)


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


def _start_values(effect: str, effects: Mapping[str, Mapping[str, float]],
                  drive_scale: float) -> dict[str, float]:
    """A refinement's start (its entry's
    :attr:`~motor_id.effects.EffectSpec.stage_start`): no change from the model it
    refines (static friction at the Coulomb level plus a little); an added Coulomb
    friction at 2 % of the largest drive torque ``drive_scale``; a delay of none (its
    grid search follows)."""
    spec = EFFECTS[effect]
    vals = spec.defaults()
    if spec.stage_start:
        vals.update(spec.stage_start(drive_scale, role_value(effects, 'kS', scale='torque')))
    elif effect in PROFILED:
        vals = {p.name: 0.0 for p in spec.params}
    return vals


@dataclass
class StageSetup:
    """What every candidate of one stage shares."""

    rec: Recording
    init_samples: int
    train: list[tuple[int, int]]
    held: list[tuple[int, int]]
    fresh: dict[str, np.ndarray] | None
    say: Callable[[str], object]
    scales: dict[str, float]
    """The record's data scales (the effects' plausibility checks read them)."""


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
    latency = _latency_for_delay(model, rec)
    if latency is not None:   # the delay swapped for a start latency: the better kept
        say('simulation error: the input delay swapped for a start latency')
        alt, alt_best = _search(setup, latency, min_gain, jobs, rival=rival)
        if alt_best is not None and (best is None or _beats(alt_best, best,
                                                            (1.0 - min_gain) ** 2)):
            best = alt_best
        cands += alt
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
            _fit_families(setup, model, families, fitted, jobs)
        for extra, (cand, z, prob) in zip(families, fits, strict=True):
            cands.append(cand)
            if not cand.scored:
                continue
            fitted[extra] = (cand.heldout_cost, _values(prob, z))
            if best is not None and cand.heldout_cost < gain_needed * best[0].heldout_cost:
                best = _polish(setup, best, cand, z, prob)
                fitted[best_family] = (best[0].heldout_cost, _values(best[2], best[1]))
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
    rival = _fit_families(setup, reduced, [()], {}, 1)[0]
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


def _gains(cands: Sequence[SimCandidate], chosen: SimCandidate) -> dict[str, float]:
    """Per effect of the chosen model: the share of the held-out simulation error it
    removes, ``1 - cost with / cost without`` (from the candidate without it). Held
    readings are a fact of the values (:mod:`.frames`), not a gain; the candidate
    ``... (every sample)`` shows the chosen model fitted on every sample as logged."""
    by_name = {c.name: c for c in cands if c.scored}
    parts = chosen.name.split('+')
    out: dict[str, float] = {}
    for e in parts:
        without = '+'.join(p for p in parts if p != e) or 'linear'
        if without in by_name and e in EFFECTS:
            out[e] = 1.0 - chosen.heldout_cost / by_name[without].heldout_cost
    return out


def _values(prob: SimulationProblem, z: np.ndarray) -> dict[str, float]:
    """A fitted family's values by free name, and the delays its profile found
    (``input_delay.d``, ``start_latency.d``): what a larger family starts from."""
    out = {profile_key(e): float(prob.model.effects[e][samples_param(e)]) for e in PROFILED
           if e in prob.model.effects}
    out.update(zip(prob.free, z, strict=True))   # a delay refined between samples
    return out


def _warm_start(fitted: Mapping[tuple[str, ...], tuple[float, dict[str, float]]],
                extra: tuple[str, ...]) -> dict[str, float]:
    """Start values for the family ``extra`` from the fitted families it contains (the
    base, and for a pair each of its effects alone), the best fitted last so its values
    win: a larger model starts no worse than the best smaller one found, where every
    family started from the equation-error values and a refinement could end above the
    model it refines."""
    nested = [f for f in fitted if set(f) < set(extra)]
    out: dict[str, float] = {}
    for f in sorted(nested, key=lambda f: -fitted[f][0]):
        out.update(fitted[f][1])
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


_STAGE: tuple[StageSetup, SavedModel] | None = None
"""The stage a forked worker of :func:`_fit_families` inherited."""


def _fit_families(setup: StageSetup, model: SavedModel, families: Sequence[tuple[str, ...]],
                  fitted: Mapping[tuple[str, ...], tuple[float, dict[str, float]]],
                  jobs: int = 1) -> list[tuple[SimCandidate, np.ndarray, SimulationProblem]]:
    """:func:`_fit_family` of each family, warm-started from ``fitted`` as it is now (so
    the results do not depend on ``jobs``), on up to ``jobs`` forked processes."""
    warms = [_warm_start(fitted, f) for f in families]
    if jobs <= 1 or len(families) < 2 or 'fork' not in multiprocessing.get_all_start_methods():
        return [_fit_family(setup, model, f, w) for f, w in zip(families, warms, strict=True)]
    global _STAGE
    _STAGE = (setup, model)   # inherited by the workers forked below
    try:
        with multiprocessing.get_context('fork').Pool(min(jobs, len(families)),
                                                      initializer=_worker_start) as pool:
            # the profiled families (a delay grid each) are the longest fits
            done = list(longest_first(pool, _family_task, list(zip(families, warms,
                                                                    strict=True)),
                                      [float(bool(profiled(f))) for f in families]))
    finally:
        _STAGE = None
    out = []
    for f, (cand, z) in zip(families, done, strict=True):
        prob = _family_problem(setup, model, f)
        lag = profiled(f)
        d = cand.effects.get(lag, {}).get(samples_param(lag)) if lag else None
        out.append((cand, z, prob if d is None else profiled_problem(prob, d, lag)))
    return out


def _family_task(job: tuple[tuple[str, ...], dict[str, float]]
                 ) -> tuple[SimCandidate, np.ndarray]:
    """A worker's task: one family of the inherited stage, fitted."""
    if _STAGE is None:   # pragma: no cover - only reached in a forked worker
        raise RuntimeError('a stage worker without its stage (not started by fork)')
    cand, z, _ = _fit_family(*_STAGE, *job)
    return cand, z


def _family_problem(setup: StageSetup, model: SavedModel, extra: tuple[str, ...]
                    ) -> SimulationProblem:
    """The problem of ``model`` plus the refinements ``extra`` at their start values."""
    rec = setup.rec
    u_max = float(np.max(np.abs(rec.input)))
    scale = u_max if model.input_kind == 'torque' else \
        model.parameters['K_T'] * u_max / model.parameters['R_m']
    effects = dict(model.effects)
    for e in extra:   # in order: an added Coulomb friction before its refinements
        effects[e] = _start_values(e, effects, scale)
    params = dict(model.parameters)
    if _takes_second_pole(extra, rec, model):
        # the coupling takes the second pole: from the winding's lag it stays put (the
        # 2023 Miami drivetrain: from the long lag the fit kept it, 58.7 / 62.8 % on the
        # steps; from a short one it found the coupling, 77.7 / 72.9 %, held out -47 %)
        params['L_m'] = LAG_SHORT * rec.sample_period * params['R_m']
    m = SavedModel(model.input_kind, params, effects, model.source)
    # a delay the model brings (not profiled here) is refined between samples at once
    return SimulationProblem(rec, m, setup.init_samples,
                             free_names(m, rec) + fraction_keys(model.effects), setup.fresh)


def _fit_family(setup: StageSetup, model: SavedModel, extra: tuple[str, ...],
                warm: Mapping[str, float] | None = None
                ) -> tuple[SimCandidate, np.ndarray, SimulationProblem]:
    """``model`` plus the refinements ``extra`` fitted on the training blocks (from the
    values ``warm`` by free name where given, else the model's and the refinements'
    no-change starts), scored on the held-out ones."""
    prob = _family_problem(setup, model, extra)
    if _takes_second_pole(extra, setup.rec, model):
        # a coupling that takes the second pole starts from the equation-error plant
        # with a short winding lag, not from the plant the smaller families fitted
        # around the long one (the Miami drivetrain's: J and K_b near 0, held out no
        # better with the coupling)
        warm = {k: v for k, v in (warm or {}).items() if '.' in k}
    name = '+'.join(e for e in prob.model.effects if EFFECTS[e].category == 'dynamic'
                    or e in PROFILED) or 'linear'
    setup.say(f'simulation error: fitting {name} on {len(setup.train)} blocks')
    cand = SimCandidate(name=name)
    z = np.array([(warm or {}).get(n, v) for n, v in zip(prob.free, prob.start(),
                                                          strict=True)])
    try:
        with np.errstate(all='ignore'):
            lag = profiled(extra)
            if lag:
                prob, z, cand.nfev = profile_delay(prob, setup.train, z, lag,
                                                    (warm or {}).get(profile_key(lag)))
            else:
                z, cand.nfev = prob.fit(setup.train, z)
            cand.parameters, cand.effects = prob.to_model(z)
            cand.train_rmse = prob.rmse(z, setup.train)
            score_on = setup.held or setup.train
            if setup.held:
                cand.heldout_rmse = prob.rmse(z, setup.held)
            cand.heldout_cost = prob.cost(z, score_on)
        cand.failed = unsound(cand.heldout_cost, cand.effects, setup.scales)
    except FIT_ERRORS as exc:
        cand.failed = f'{type(exc).__name__}: {exc}'
    return cand, z, prob
