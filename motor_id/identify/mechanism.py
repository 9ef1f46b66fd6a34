"""A joint's mechanism in a fit: its gravity effect started from the equation error and
fitted with the plant (an elevator's constant load, an arm's T_g cos(theta + offset))."""

from __future__ import annotations

from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.effects import EFFECTS, mechanism_effect
from motor_id.errors import DataError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from motor_id.identify.estimator import Identifier
    from motor_id.recording import Recording


def check_mechanism(rec: Recording, mechanism: str) -> str:
    """The gravity effect of ``mechanism`` ('' for ``'simple'``), checked against ``rec``.

    Raises
    ------
    ConfigError
        An unknown mechanism.
    DataError
        Its gravity reads the position and ``rec`` has none.
    """
    gravity = mechanism_effect(mechanism)
    if gravity and EFFECTS[gravity].position and not rec.has_position:
        raise DataError(f'mechanism {mechanism!r} needs the measured position ({gravity} '
                        'reads it): the recording has no position channel',
                        params=('mechanism',))
    return gravity


def position_start(rec: Recording, effect: str, torque_per_input: float,
                   cutoff: float | None = None) -> dict[str, float]:
    """An effect's parameters from the position regressors of its entry
    (:attr:`~motor_id.effects.EffectSpec.position_term`: a joint's gravity), by the
    equation error ``u = kS sgn(w) + kV w + kA dw/dt + ...`` in input units (WPILib
    SysId's model), each run filtered on its own: the start of the fit.

    Parameters
    ----------
    rec : Recording
        With the position measured.
    effect : str
    torque_per_input : float
        Torque per input unit: K_T / R_m for a voltage plant, 1 for a torque plant.
    cutoff : float, optional
        Filter cut-off [Hz]; default a tenth of the Nyquist frequency.
    """
    from scipy.signal import butter, filtfilt

    term = EFFECTS[effect].position_term
    if term is None or rec.position is None:
        raise DataError(f'{effect} needs the measured position')
    dt = rec.sample_period
    b, a = butter(4, min(float(cutoff or 0.05 / dt) * 2 * dt, 0.99))
    rows, ys = [], []
    for lo, hi in rec.segment_ranges:
        if hi - lo < 4 * 3 * max(len(a), len(b)):
            continue
        t, w = rec.time[lo:hi], filtfilt(b, a, rec.speed[lo:hi])
        cols = [np.sign(w), w, np.gradient(w, t)]
        cols += [filtfilt(b, a, c) for c in term.columns(rec.position[lo:hi])]
        trim = max(1, int(0.02 * t.size))
        rows.append(np.column_stack(cols)[trim:-trim])
        ys.append(filtfilt(b, a, rec.input[lo:hi])[trim:-trim])
    if not rows:
        raise DataError('the runs are too short for an equation-error start')
    theta, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(ys), rcond=None)
    spec = EFFECTS[effect]
    return {k: float(np.clip(v, spec.param(k).low, spec.param(k).high))
            for k, v in term.params(theta[3:], torque_per_input).items()}


def with_gravity(fitted: Identifier, rec: Recording, mechanism: str,
                 sample_weight: ArrayLike | None = None, **changes: Any) -> Identifier:
    """``fitted`` (an Identifier fitted on ``rec``) refitted with the gravity of
    ``mechanism`` in the model, from its equation-error start and the fitted parameters
    (with its other settings, but ``changes``); ``fitted`` itself for ``'simple'``."""
    gravity = check_mechanism(rec, mechanism)
    if not gravity:
        return fitted
    p = {k: v for k, v in fitted.params_.items() if v is not None}
    K, R = p.get('K_T'), p.get('R_m')   # None where the data do not determine it
    per_input = K / R if K and R and rec.input_kind == 'voltage' else 1.0
    start = position_start(rec, gravity, per_input)
    keys = {f'{gravity}.{k}': v for k, v in start.items()}
    effects = {**(fitted.effects or {}), gravity: start}
    free = [*(fitted.free_effects or ()), *keys]
    est = fitted._variant(effects=effects, free_effects=free,
                          start={**p, **keys}, use_ga=False,   # own refit of its settings
                          **changes)
    with np.errstate(all='ignore'):
        est.fit(rec, sample_weight=sample_weight)
    return est
