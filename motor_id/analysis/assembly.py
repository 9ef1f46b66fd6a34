"""The report of an analysis, assembled from the chosen model and everything tried.

The linear and the chosen model refitted on all data (:func:`.outcome.final_fits`), the
headline parameters with the measurement grids', the residual diagnostics and the
steady-state map, the held-out scheme, the models as good as the chosen one with the
experiment that would separate them, and the adequacy of the chosen model with the
warnings the record gives.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.analysis import outcome, selection
from motor_id.analysis.candidates import dynamic_effects
from motor_id.analysis.diagnostics import (
    map_summary,
    residual_block,
    ResidualBlock,
    steady_state_map,
    SteadyPoint,
)
from motor_id.analysis.report import Baseline, ChosenBlock, DiscrepancyReport, HeldoutBlock
from motor_id.effects import EFFECTS
from motor_id.identify import determinacy
from motor_id.identify.result import EffectEstimate
from motor_id.metrics import normalised_fit

if TYPE_CHECKING:
    from motor_id.analysis.context import RecordContext
    from motor_id.analysis.inverse_dynamics import InverseDynamicsFit
    from motor_id.analysis.report import ModelScore
    from motor_id.analysis.simulation_result import SimulationStage
    from motor_id.identify import Identifier


def build_report(ctx: RecordContext, base: ModelScore, chosen: ModelScore,
                 ranked: list[ModelScore], say: Callable[[str], object], *, n_blocks: int,
                 min_gain: float, ambiguity: float, unexplained: bool) -> DiscrepancyReport:
    """The :class:`DiscrepancyReport` of one analysed record.

    Parameters
    ----------
    ctx : RecordContext
    base, chosen : ModelScore
        The linear model and the chosen one (``base`` itself when no effect counts).
    ranked : list of ModelScore
        Every model tried, the chosen first.
    say : callable
        ``say(message)`` for the final fits.
    n_blocks, min_gain, ambiguity
        As :class:`.analyzer.DiscrepancyAnalysis`.
    unexplained : bool
        The chosen model leaves structure (held-out error above the noise floors).
    """
    rec = ctx.rec
    full_base, full = outcome.final_fits(ctx.fitter, base, chosen, say)
    params = outcome.parameters(chosen, base, full)
    for m in ctx.measurement:
        params.update(m.parameters)
    dyn = 'none' if chosen is base else chosen.name
    names = ([] if chosen is base else [dyn]) + [m.name for m in ctx.measurement]
    verdict = '+'.join(names) if names else 'none'
    chosen_d = _chosen_block(chosen, base, full, dyn)
    idyn: InverseDynamicsFit | None = None
    if rec.input_kind == 'torque':
        idyn, params, chosen_d = outcome.torque_headline(rec, chosen, params, chosen_d)
    diag, points = _diagnostics(ctx, full_base, full, chosen, base)
    bres = full_base.result_
    baseline = Baseline(parameters=bres.parameters, fit=bres.fit,
                        heldout_error=base.heldout_error)
    split = ctx.split
    plot_data = {'time': rec.time, 'channels': split.channels, 'ys': split.ys,
                 'base': base.prediction['preds'], 'chosen': chosen.prediction['preds'],
                 'test': split.test, 'points': points}
    failed = [{'name': s.name, 'reason': s.failed} for s in ranked if s.failed]
    ambiguous = [] if chosen is base else selection.ambiguous(
        chosen, ranked, ambiguity, rec.input_kind, ctx.one_way)
    adequate, warnings = _adequacy(ctx, chosen, verdict, params, points)
    return DiscrepancyReport(
        verdict=verdict, effects=list(ctx.measurement) + list(ranked),
        unexplained=unexplained, ambiguous_with=ambiguous, parameters=params,
        baseline=baseline, chosen=chosen_d, diagnostics=diag,
        heldout=_heldout_block(ctx, base, chosen, n_blocks, min_gain),
        input_kind=rec.input_kind, channels=split.channels,
        measurement=ctx.measurement_evidence, failed=failed, inverse_dynamics=idyn,
        plot_data=plot_data, adequate=adequate, warnings=warnings, linear=rec.linear)


def _chosen_block(chosen: ModelScore, base: ModelScore, full: Identifier | None, dyn: str
                  ) -> ChosenBlock:
    """The report's ``chosen`` entry: name, estimator, effect values and the fit."""
    effects = dict(chosen.effects)   # the base's: a mechanism's gravity, or none
    if full is not None and (chosen is not base or base.effects):
        effects = {e: {p: (v.value if isinstance(v, EffectEstimate) else v)
                       for p, v in vals.items()}
                   for e, vals in dynamic_effects(full.result_.effects).items()}
    return ChosenBlock(name=dyn, estimator='output error (simulation)', effects=effects,
                       fit=full.result_.fit if (full is not None and chosen is not base)
                       else None)


STAGE_ESTIMATOR = 'simulation error (the simulation stage: simulation.model)'
"""The chosen block's estimator where the simulation stage chose the model."""


def chosen_by_stage(chosen: ChosenBlock, sim: SimulationStage | None) -> ChosenBlock:
    """The report's ``chosen`` block once the simulation stage has run: the stage's model,
    the one the report's feedforward and ``motor-id validate`` use (its refinements, a
    start latency in place of a delay), with the search's model in ``equation_error``;
    ``chosen`` itself where the stage fitted no model."""
    if sim is None or sim.model is None or sim.chosen is None:
        return chosen
    return ChosenBlock(name=sim.chosen, estimator=STAGE_ESTIMATOR,
                       effects={e: dict(v) for e, v in sim.model.effects.items()}, fit=None,
                       equation_error=chosen)


def _heldout_block(ctx: RecordContext, base: ModelScore, chosen: ModelScore, n_blocks: int,
                   min_gain: float) -> HeldoutBlock:
    """The report's ``heldout`` entry: the split's scheme and the errors on it."""
    split = ctx.split
    held = list(range(2, n_blocks, 3))
    scheme = (f'{len(ctx.rec.segment_ranges)} separate runs; the last is held out whole'
              if split.by_run else
              f'{n_blocks} blocks, blocks {held} held out (the simulation runs '
              'through them)')
    return HeldoutBlock(scheme=scheme, by_run=split.by_run,
                        fraction=float(np.mean(split.test)), blocks=split.blocks,
                        base_error=base.heldout_error, final_error=chosen.heldout_error,
                        noise_floor=split.floor, min_gain=min_gain,
                        resistance=ctx.resistance)


def _diagnostics(ctx: RecordContext, full_base: Identifier, full: Identifier | None,
                 chosen: ModelScore, base: ModelScore
                 ) -> tuple[ResidualBlock, list[SteadyPoint]]:
    """Residual diagnostics before and after, the noise floors and the steady-state map
    with the linear and the chosen model's mean speed on each plateau."""
    rec, split = ctx.rec, ctx.split
    after = full.result_.prediction if (full is not None and chosen is not base) \
        else None
    diag = residual_block(rec, split.channels, full_base.result_.prediction, after)
    k = split.channels.index('speed')
    linear = full_base.result_.prediction['speed']
    points = [replace(p, speed_linear=float(np.mean(linear[p.start:p.stop])),
                      speed_chosen=None if chosen is base else
                      float(np.mean(chosen.prediction['preds'][k][p.start:p.stop])))
              for p in steady_state_map(rec)]
    return replace(diag, noise_floor=split.floor, channel_noise_floor=split.channel_floors,
                   electrical=ctx.electrical,
                   steady_state=replace(map_summary(points), points=tuple(points))), points


def _offset_unexplained(steady: tuple[float, float], points: Sequence[SteadyPoint]) -> bool:
    """The static offset both ways of the steady-state map is not the chosen model's own:
    on either side the model's mean speeds at the same points put zero speed less than
    half as far from zero input (no points: not known, so True).

    Quasi-steady windows of a slow ramp (a SysId quasistatic test) lag it by kA / kV
    times the ramp rate, which looks like an offset both ways: a frictionless flywheel's
    routine (kV 0.02025, kA 0.0010 at 1 V/s) shows one at +0.071 / -0.076 V, and its
    linear model at +0.070 / -0.079 V."""
    model = []
    for p in points:
        w = p.speed_chosen if p.speed_chosen is not None else p.speed_linear
        if w is None:
            return True
        model.append(replace(p, speed=w))
    own = selection.steady_offset(map_summary(model)) if model else None
    if own is None:
        return True
    return any(abs(o) < 0.5 * abs(m) for o, m in zip(own, steady, strict=True))


NO_EFFECT = 'no named effect explains this record (a load that changes along it, a second ' \
    'input?)'
"""Why an analysis whose models all explain too little of the speed is inadequate."""
EXPLAINS = 'the chosen model explains (held out)'
"""How the inadequacy warning of the equation-error stage's chosen model begins."""


def _adequacy(ctx: RecordContext, chosen: ModelScore, verdict: str, params: dict[str, Any],
              points: Sequence[SteadyPoint] = ()) -> tuple[bool, list[str]]:
    """``(adequate, warnings)``: the chosen model's held-out fit of the speed, the
    steady-state evidence the verdict leaves out (:func:`_offset_unexplained`),
    one-direction data."""
    split = ctx.split
    k = split.channels.index('speed')
    y = split.ys[k][split.test]
    yh = np.asarray(chosen.prediction['preds'][k])[split.test]
    fit = normalised_fit(y, yh)
    adequate, warnings = determinacy.adequacy({'speed': fit}, hint=NO_EFFECT)
    if warnings:
        warnings[0] = warnings[0].replace('the model explains', EXPLAINS)
    if not adequate:
        for p in params.values():
            if isinstance(p, dict) and p.get('determined') and not p.get('grid'):
                p['particular_value'] = p.get('value')
                p['value'], p['std'], p['determined'] = None, None, False
                p['reason'] = 'model inadequate'
    steady = ctx.steady
    offset = [n for n, spec in EFFECTS.items() if spec.shows_offset]
    if steady and not any(e in verdict for e in offset) \
            and _offset_unexplained(steady, points):
        warnings.append('the steady states show a static offset both ways (zero speed '
                        f'at input {steady[0]:.3g} and {steady[1]:.3g}): '
                        'Coulomb friction or a dead band that the verdict does not name')
    if ctx.one_way:
        warnings.append('the speed kept one sign: the model holds for this direction '
                        'only')
    return adequate, warnings
