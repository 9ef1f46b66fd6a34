"""A joint's mechanism in a fit: its gravity effect started from the equation error and
fitted with the plant (an elevator's constant load, an arm's T_g cos(theta + offset))."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.effects import EFFECTS, mechanism_effect
from motor_id.errors import DataError, IdentificationError

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


def equation_error(rec: Recording, effect: str,
                   cutoff: float | None = None) -> np.ndarray:
    """WPILib SysId's equation-error fit with a joint's gravity: ``[kS, kV, kA, *coef]`` of
    ``u = kS sgn(w) + kV w + kA dw/dt + coef . columns(position)`` in input units, each run
    filtered on its own (a fourth-order Butterworth at ``cutoff`` [Hz], default a tenth of
    the Nyquist frequency).

    Raises
    ------
    DataError
        No position, or every run too short for the filter.
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
    return np.asarray(theta, dtype=float)


def position_start(rec: Recording, effect: str, torque_per_input: float,
                   cutoff: float | None = None,
                   theta: np.ndarray | None = None) -> dict[str, float]:
    """An effect's parameters from the position regressors of its entry
    (:attr:`~motor_id.effects.EffectSpec.position_term`: a joint's gravity), by the
    equation error of :func:`equation_error`: the start of the fit.

    Parameters
    ----------
    rec : Recording
        With the position measured.
    effect : str
    torque_per_input : float
        Torque per input unit: K_T / R_m for a voltage plant, 1 for a torque plant.
    cutoff : float, optional
        Filter cut-off [Hz]; default a tenth of the Nyquist frequency.
    theta : ndarray, optional
        :func:`equation_error`'s result, where it was computed already.
    """
    if theta is None:
        theta = equation_error(rec, effect, cutoff)
    spec = EFFECTS[effect]
    term = spec.position_term
    assert term is not None   # equation_error checked it
    return {k: float(np.clip(v, spec.param(k).low, spec.param(k).high))
            for k, v in term.params(theta[3:], torque_per_input).items()}


def plant_start(rec: Recording, effect: str, theta: np.ndarray, fitted: Mapping[str, float],
                effects: Mapping[str, Any]) -> dict[str, float] | None:
    """A whole start from the equation error ``theta`` (:func:`equation_error`): the plant,
    Coulomb friction (where the model has it) and the gravity, at the fitted K_T and R_m
    (K_b below kV / 2) and the electrical time constant a twentieth of a sample period
    (speed alone does not see them); None where kV or kA is not positive.

    The plant fitted without gravity is no start for a joint whose gravity outweighs its
    friction: an elevator that falls when the input is off drives that fit to the edges
    of its box (kS 1.6 +- 14 V, kG 2.5 +- 22 V for 0.1 and 1.0 on a SysId routine).
    """
    kS, kV, kA = (float(x) for x in theta[:3])
    if not (kV > 0 and kA > 0):
        return None
    if rec.input_kind == 'voltage':
        R, K = fitted.get('R_m') or 1.0, fitted.get('K_T') or 1.0
        K_b = min(fitted.get('K_b') or K, kV / 2.0)
        per = K / R
        start = {'K_T': K, 'K_b': K_b, 'R_m': R, 'B': (kV - K_b) * per, 'J': kA * per,
                 'L_m': 0.05 * rec.sample_period * R}
    else:
        per = 1.0
        start = {'J': kA, 'B': kV}
    if 'coulomb_friction' in effects:
        start['coulomb_friction.T_c'] = max(kS, 0.0) * per
    start |= {f'{effect}.{k}': v for k, v in position_start(rec, effect, per,
                                                             theta=theta).items()}
    return start


def with_gravity(fitted: Identifier, rec: Recording, mechanism: str,
                 sample_weight: ArrayLike | None = None, **changes: Any) -> Identifier:
    """``fitted`` (an Identifier fitted on ``rec``) refitted with the gravity of
    ``mechanism`` in the model (with its other settings, but ``changes``); ``fitted``
    itself for ``'simple'``.

    Two starts, the better fit kept: the fitted plant with the gravity of the equation
    error, and the whole equation-error model (:func:`plant_start`). Speed alone cannot
    tell the electrical pole from the mechanical one: where the two fits end within
    :data:`POLE_TIE` of each other's cost, the one whose electrical time constant is the
    shorter (:func:`electrical_first`, as in a DC motor) is kept.
    """
    gravity = check_mechanism(rec, mechanism)
    if not gravity:
        return fitted
    p = {k: v for k, v in fitted.params_.items() if v is not None}
    K, R = p.get('K_T'), p.get('R_m')   # None where the data do not determine it
    per_input = K / R if K and R and rec.input_kind == 'voltage' else 1.0
    theta = equation_error(rec, gravity)
    start = position_start(rec, gravity, per_input, theta=theta)
    keys = {f'{gravity}.{k}': v for k, v in start.items()}
    effects = {**(fitted.settings.effects or {}), gravity: start}
    free = [*(fitted.settings.free_effects or ()), *keys]
    best: Identifier | None = None
    fits: list[Identifier] = []
    whole = plant_start(rec, gravity, theta, p, effects)
    for begin in ({**p, **keys}, *(() if whole is None else ({**p, **whole},))):
        est = fitted._variant(effects=effects, free_effects=free, start=begin,
                              use_ga=False, **changes)   # own refit of its settings
        try:
            with np.errstate(all='ignore'):
                est.fit(rec, sample_weight=sample_weight)
        except IdentificationError:
            if begin is not None and best is None and whole is None:
                raise
            continue
        fits.append(est)
        if best is None or est.result_.fit.cost < best.result_.fit.cost:
            best = est
    if best is None:
        raise IdentificationError(f'the fit with the {gravity} diverged from every start')
    if not rec.has_current and not electrical_first(best):
        return next((e for e in fits if electrical_first(e)
                     and e.result_.fit.cost <= (1.0 + POLE_TIE) * best.result_.fit.cost),
                    best)
    return best


POLE_TIE = 0.05
"""Fits of a speed-only record within this fraction of each other's cost are a tie
between the two assignments of its poles (:func:`with_gravity`)."""


def electrical_first(est: Identifier) -> bool:
    """The fit's electrical time constant L_m / R_m is shorter than its mechanical one
    J / B (False for a torque plant, which has none)."""
    p = est.params_
    L, R, J, B = (p.get(k) for k in ('L_m', 'R_m', 'J', 'B'))
    return bool(L and R and J and B and L / R < J / B)
