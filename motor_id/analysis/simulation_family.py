"""One model family of the simulation-error stage fitted on the training blocks and scored
on the held-out ones (:func:`fit_family`), several at once on forked processes
(:func:`fit_families`); :mod:`.simulation_fit` searches over them."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import multiprocessing
from typing import TYPE_CHECKING

import numpy as np

from motor_id.analysis.simulation_delay import (
    profile_delay,
    profile_key,
    PROFILED,
    profiled,
    profiled_problem,
    samples_param,
)
from motor_id.analysis.simulation_guard import unsound
from motor_id.analysis.simulation_problem import fraction_keys, free_names, SimulationProblem
from motor_id.analysis.simulation_result import SimCandidate
from motor_id.analysis.simulation_uncertainty import LAG_SHORT
from motor_id.analysis.workers import _worker_start, longest_first
from motor_id.effects import EFFECTS, role_value
from motor_id.errors import FIT_ERRORS
from motor_id.identify.validation import SavedModel

if TYPE_CHECKING:
    from motor_id.recording import Recording


LONG_LAG = 5.0
"""A winding's time constant ``L_m / R_m`` [sample periods] over which a speed-only
model's second pole is taken for something else (:func:`takes_second_pole`)."""


def takes_second_pole(extra: Sequence[str], rec: Recording, model: SavedModel) -> bool:
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

def start_values(effect: str, effects: Mapping[str, Mapping[str, float]],
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

def fitted_values(prob: SimulationProblem, z: np.ndarray) -> dict[str, float]:
    """A fitted family's values by free name, and the delays its profile found
    (``input_delay.d``, ``start_latency.d``): what a larger family starts from."""
    out = {profile_key(e): float(prob.model.effects[e][samples_param(e)]) for e in PROFILED
           if e in prob.model.effects}
    out.update(zip(prob.free, z, strict=True))   # a delay refined between samples
    return out


def warm_start(fitted: Mapping[tuple[str, ...], tuple[float, dict[str, float]]],
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

_STAGE: tuple[StageSetup, SavedModel] | None = None
"""The stage a forked worker of :func:`fit_families` inherited."""


def fit_families(setup: StageSetup, model: SavedModel, families: Sequence[tuple[str, ...]],
                  fitted: Mapping[tuple[str, ...], tuple[float, dict[str, float]]],
                  jobs: int = 1) -> list[tuple[SimCandidate, np.ndarray, SimulationProblem]]:
    """:func:`fit_family` of each family, warm-started from ``fitted`` as it is now (so
    the results do not depend on ``jobs``), on up to ``jobs`` forked processes."""
    warms = [warm_start(fitted, f) for f in families]
    if jobs <= 1 or len(families) < 2 or 'fork' not in multiprocessing.get_all_start_methods():
        return [fit_family(setup, model, f, w) for f, w in zip(families, warms, strict=True)]
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
        prob = family_problem(setup, model, f)
        lag = profiled(f)
        d = cand.effects.get(lag, {}).get(samples_param(lag)) if lag else None
        out.append((cand, z, prob if d is None else profiled_problem(prob, d, lag)))
    return out


def _family_task(job: tuple[tuple[str, ...], dict[str, float]]
                 ) -> tuple[SimCandidate, np.ndarray]:
    """A worker's task: one family of the inherited stage, fitted."""
    if _STAGE is None:   # pragma: no cover - only reached in a forked worker
        raise RuntimeError('a stage worker without its stage (not started by fork)')
    cand, z, _ = fit_family(*_STAGE, *job)
    return cand, z


def family_problem(setup: StageSetup, model: SavedModel, extra: tuple[str, ...]
                    ) -> SimulationProblem:
    """The problem of ``model`` plus the refinements ``extra`` at their start values."""
    rec = setup.rec
    u_max = float(np.max(np.abs(rec.input)))
    scale = u_max if model.input_kind == 'torque' else \
        model.parameters['K_T'] * u_max / model.parameters['R_m']
    effects = dict(model.effects)
    for e in extra:   # in order: an added Coulomb friction before its refinements
        effects[e] = start_values(e, effects, scale)
    params = dict(model.parameters)
    if takes_second_pole(extra, rec, model):
        # the coupling takes the second pole: from the winding's lag it stays put (the
        # 2023 Miami drivetrain: from the long lag the fit kept it, 58.7 / 62.8 % on the
        # steps; from a short one it found the coupling, 77.7 / 72.9 %, held out -47 %)
        params['L_m'] = LAG_SHORT * rec.sample_period * params['R_m']
    m = SavedModel(model.input_kind, params, effects, model.source)
    # a delay the model brings (not profiled here) is refined between samples at once
    return SimulationProblem(rec, m, setup.init_samples,
                             free_names(m, rec) + fraction_keys(model.effects), setup.fresh)


def fit_family(setup: StageSetup, model: SavedModel, extra: tuple[str, ...],
                warm: Mapping[str, float] | None = None
                ) -> tuple[SimCandidate, np.ndarray, SimulationProblem]:
    """``model`` plus the refinements ``extra`` fitted on the training blocks (from the
    values ``warm`` by free name where given, else the model's and the refinements'
    no-change starts), scored on the held-out ones."""
    prob = family_problem(setup, model, extra)
    if takes_second_pole(extra, setup.rec, model):
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
