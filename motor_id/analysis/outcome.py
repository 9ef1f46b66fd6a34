"""The outcome: the chosen model refitted on all data and its headline parameters."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any, cast, TYPE_CHECKING

import numpy as np

from motor_id.analysis.candidates import dynamic_effects, grid_only
from motor_id.analysis.inverse_dynamics import inverse_dynamics, InverseDynamicsFit
from motor_id.effects import EFFECTS, role_value
from motor_id.errors import FIT_ERRORS
from motor_id.identify.result import EffectEstimate

if TYPE_CHECKING:
    from motor_id.analysis.candidates import CandidateFitter
    from motor_id.analysis.report import ChosenBlock, ModelScore
    from motor_id.identify import Identifier
    from motor_id.recording import Recording


def final_fits(fitter: CandidateFitter, base: ModelScore, chosen: ModelScore,
               say: Callable[[str], object]) -> tuple[Identifier, Identifier | None]:
    """Linear and chosen model refitted on all data.

    Returns ``(full_base, full)`` fitted Identifiers; ``full`` is None when the chosen
    model fails on all data (its training-block fit then stands).
    """
    say('refitting the linear and the chosen model on all data')
    beff = {e: dict(v) for e, v in base.effects.items()}   # a mechanism's gravity
    try:
        full_base = fitter.fit_model(beff, [f'{e}.{p}' for e, v in beff.items() for p in v],
                                     fitter.start(base, beff), weight=False)
    except FIT_ERRORS as exc:
        say(f'  the linear model failed on all data ({exc}); keeping its training fit')
        full_base = cast('Identifier', fitter.linear_estimator)  # fitted by fit_linear
    if chosen is base:
        return full_base, full_base
    eff = {e: dict(v) for e, v in chosen.effects.items()}
    free = [f'{e}.{p}' for e, v in eff.items() for p in v
            if p not in grid_only(e)]
    try:
        full = fitter.fit_model(eff, free, fitter.start(chosen, eff), weight=False)
        if not all(np.all(np.isfinite(full.result_.prediction[c]))
                   for c in fitter.split.channels):
            raise ArithmeticError('non-finite prediction')
    except FIT_ERRORS as exc:
        say(f'  the chosen model failed on all data ({exc}); keeping its '
            'training-block fit')
        return full_base, None
    return full_base, full


def parameters(chosen: ModelScore, base: ModelScore, full: Identifier | None
               ) -> dict[str, Any]:
    """``{name: {value, std, determined}}`` of the chosen model (all-data fit)."""
    if full is None:
        return dict(chosen.parameters, **{k: {'value': v, 'std': None,
                                              'determined': True}
                                          for k, v in chosen.physical.items()})
    params = full.result_.to_dict()['parameters']
    if chosen is base and not base.effects:
        return params
    for e, vals in dynamic_effects(full.result_.effects).items():
        for p, v in vals.items():
            params[f'{e}.{p}'] = v.to_dict() if isinstance(v, EffectEstimate) else {
                'value': float(v), 'std': None, 'determined': True, 'grid': True}
    return params


def torque_headline(rec: Recording, chosen: ModelScore, params: dict[str, Any],
                    chosen_d: ChosenBlock
                    ) -> tuple[InverseDynamicsFit, dict[str, Any], ChosenBlock]:
    """Equation-error estimate; the headline for a closed-loop record.

    In closed loop the input depends on the measured output, and a free-run
    simulation of the open-loop plant drifts from the measured motion wherever the
    model misses a little friction, so the simulation error weighs those stretches
    differently from the equation; the inverse-dynamics estimate uses the measured
    motion itself and is the published method.
    """
    terms = [e for e in chosen.effects if e in EFFECTS and EFFECTS[e].mechanical_term]
    delay = int(role_value(chosen.effects, 'delay', 0))
    try:
        idyn = inverse_dynamics(rec, terms, delay=delay)
    except FIT_ERRORS as exc:
        return InverseDynamicsFit(failed=str(exc)), params, chosen_d
    if rec.meta.get('closed_loop') and idyn.physical and idyn.relative_error < 0.1:
        chosen_d = replace(
            chosen_d, estimator='inverse dynamics (equation error): the record is closed loop',
            output_error_parameters={k: dict(params[k]) for k in idyn.parameters
                                     if k in params})
        for k, v in idyn.parameters.items():
            params[k] = {'value': v.value, 'std': v.std, 'determined': True}
    return idyn, params, chosen_d
