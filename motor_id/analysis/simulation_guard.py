"""What the simulation-error stage may choose: a sound model, and the simpler rival that
the analysis' extra effects must beat.

The equation-error stages judge a joint's gravity from the measured position; the
simulation closes that loop through the simulated position. An effect that helps the
first can make the second diverge (an arm record: a 1 Hz overdamped "resonance" chosen
by the equation error, held-out simulation cost 1.8 at its start, 1.09 after the fit,
every feedforward constant then undetermined). So a candidate of the stage counts only
when it is sound (:func:`unsound`), and the analysis' model competes with the model
without its extra effects (:func:`reduced_model`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from motor_id.effects import EFFECTS
from motor_id.identify.scales import data_scales, default_max_delay
from motor_id.identify.validation import SavedModel

if TYPE_CHECKING:
    from motor_id.recording import Recording

DIVERGED = 1.0
"""A held-out cost (mean squared simulation error, each channel in units of its spread
over the record) at or above this explains nothing: the model is no better than the
signals' own spread."""


def stage_scales(rec: Recording, parameters: Mapping[str, float]) -> dict[str, float]:
    """The record's data scales (:func:`motor_id.identify.scales.data_scales`) that the
    effects' plausibility checks read (the sample rate for a resonance's alias)."""
    dt = float(np.median(np.diff(rec.time)))
    R = parameters.get('R_m') or 1.0
    return data_scales(rec, {'K_T': parameters.get('K_T') or 1.0, 'R_m': R}, R,
                       float(rec.time[-1] - rec.time[0]), dt, default_max_delay(len(rec)))


def unsound(heldout_cost: float, effects: Mapping[str, Mapping[str, float]],
            scales: Mapping[str, float]) -> str:
    """Why a fitted candidate cannot be the stage's model ('' when it can): it diverged
    (:data:`DIVERGED`), or an effect's values fail its plausibility check
    (:attr:`motor_id.effects.EffectSpec.check`: a resonance at the Nyquist frequency)."""
    if heldout_cost >= DIVERGED:
        return (f'diverged: held-out simulation cost {heldout_cost:.3g}, at or above '
                f'{DIVERGED:g} (the error as large as the signals themselves)')
    for e, vals in effects.items():
        spec = EFFECTS.get(e)
        why = spec.check(vals, scales) if spec is not None and spec.check else ''
        if why:
            return f'implausible: {why}'
    return ''


def reduced_model(model: SavedModel) -> SavedModel | None:
    """``model`` without the effects the simulation-error stage did not add and cannot
    judge by refinement: kept are the mechanism's gravity, the effects that others refine
    (Coulomb friction) and the measurement effects; None when nothing would be dropped.

    The stage's search adds refinements and delays to the analysis' model; this is the
    rival that the analysis' other effects must beat in simulation."""
    bases = {spec.extends for spec in EFFECTS.values() if spec.extends}
    keep = {e: dict(v) for e, v in model.effects.items()
            if EFFECTS[e].category != 'dynamic' or EFFECTS[e].mechanism or e in bases}
    if len(keep) == len(model.effects):
        return None
    return SavedModel(model.input_kind, dict(model.parameters), keep, model.source)
