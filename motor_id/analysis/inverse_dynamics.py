"""Equation-error (inverse dynamics) estimates: the mechanical and the electrical equation.

Both regress a filtered equation on filtered regressors (parallel filtering, as in
IDIM-LS): no simulation, so no drift of a free-run prediction and no dependence on the
initial state. The mechanical one gives the published EMPS numbers; the electrical one,
with the current measured, tells heating, a brush drop and a dead zone apart by the
shape of the voltage each one removes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.effects import EFFECTS, role_params
from motor_id.errors import ConfigError, DataError
from motor_id.records import omit_if_failed, optional, Record

if TYPE_CHECKING:
    from motor_id.recording import Recording


@dataclass(frozen=True, kw_only=True)
class RegressionEstimate(Record):
    """A least-squares coefficient and its standard deviation."""

    value: float
    std: float


@dataclass(frozen=True, kw_only=True)
class InverseDynamicsFit(Record):
    """The mechanical equation error's estimate (:func:`inverse_dynamics`), or why it
    failed: ``parameters`` (J, B and ``effect.param``), ``relative_error`` (norm of the
    equation residual over norm of the filtered input), the filter ``cutoff`` [Hz], the
    input ``delay`` [samples]; ``physical``: no negative inertia or friction."""

    failed: str = optional('', when='empty')
    parameters: dict[str, RegressionEstimate] = optional({}, when=omit_if_failed)
    cutoff: float = optional(math.nan, when=omit_if_failed)
    delay: int = optional(0, when=omit_if_failed)
    physical: bool = optional(False, when=omit_if_failed)
    relative_error: float = optional(math.nan, when=omit_if_failed)
    model: str = optional('', when=omit_if_failed)


@dataclass(frozen=True, kw_only=True)
class ElectricalEvidence(Record):
    """What the electrical equation error says (:func:`electrical_evidence`), or why it
    failed: the share of the base equation error each term removes (``explained``), the
    ``favoured`` term (or None), the ``parameter`` of each term's best grid point, R_m
    under the favoured term and without a term, each term's effect ``start``."""

    failed: str = optional('', when='empty')
    explained: dict[str, float] = optional({}, when=omit_if_failed)
    favoured: str | None = None
    parameter: dict[str, float | None] = optional({}, when=omit_if_failed)
    R_m: float = optional(math.nan, when=omit_if_failed)
    R_m_base: float = optional(math.nan, when=omit_if_failed)
    start: dict[str, dict[str, float]] = optional({}, when=omit_if_failed)
    model: str = optional('', when=omit_if_failed)


def _filter(dt: float, cutoff: float) -> Any:
    from scipy.signal import butter
    wn = min(cutoff * 2 * dt, 0.99)
    return butter(4, wn)


def inverse_dynamics(rec: Recording, terms: Sequence[str] | None = None,
                     cutoff: float | None = None, delay: int = 0, min_speed: float = 0.02
                     ) -> InverseDynamicsFit:
    """Equation-error (inverse dynamics) least squares for a torque-input plant.

    Fits ``u = J dw/dt + B w + T_c sgn(w) + T_L + k_q w|w|`` (the terms asked for: each
    effect's :attr:`~motor_id.effects.EffectSpec.mechanical_term`) with the speed, its
    derivative and the input all low-pass filtered by the same zero-phase Butterworth
    filter (parallel filtering, as in IDIM-LS); the first and last 2 % of samples are
    dropped, and with dry friction the samples near rest.

    Parameters
    ----------
    rec : Recording
        ``input_kind == 'torque'``.
    terms : sequence of str, optional
        Effects with a mechanical term (Coulomb friction, a constant load, a quadratic
        load); default the published EMPS model's: dry friction and a constant load.
    cutoff : float, optional
        Filter cut-off [Hz]; default a tenth of the Nyquist frequency.
    delay : int
        Input delay in samples (from an ``input_delay`` effect).
    min_speed : float
        With Coulomb friction, samples slower than this fraction of the top speed are
        left out (at rest the friction takes any value up to T_c).

    Returns
    -------
    InverseDynamicsFit
    """
    from scipy.signal import filtfilt

    if rec.input_kind != 'torque':
        raise ConfigError('inverse dynamics needs a torque-input recording')
    if terms is None:
        terms = [s.name for s, _ in role_params('kS', 'torque')] + \
            [s.name for s, _ in role_params('load')]
    t = rec.time
    dt = float(np.mean(np.diff(t)))
    cutoff = float(cutoff or 0.05 / dt)
    b, a = _filter(dt, cutoff)
    u = rec.input
    if delay > 0:
        u = np.concatenate([np.full(delay, u[0]), u[:-delay]])
    w = filtfilt(b, a, rec.speed)
    cols = _mechanical_columns(w, t, terms)
    trim = max(1, int(0.02 * t.size))
    keep = np.zeros(t.size, dtype=bool)
    keep[trim:-trim] = True
    if any(MECHANICAL_TERMS[e].away_from_rest for e in terms if e in MECHANICAL_TERMS):
        # at rest the friction is anything up to T_c, not T_c sgn(w): leave out the
        # samples near zero speed
        keep &= np.abs(w) > min_speed * np.max(np.abs(w))
    X = np.column_stack(list(cols.values()))[keep]
    y = filtfilt(b, a, u)[keep]
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ theta
    cov = np.linalg.pinv(X.T @ X) * float(res @ res) / max(y.size - theta.size, 1)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    params = {k: RegressionEstimate(value=float(v), std=float(s))
              for k, v, s in zip(cols, theta, std, strict=True)}
    physical = bool(theta[0] > 0 and theta[1] >= 0 and all(
        params[k].value >= 0 for k in params if k in _NON_NEGATIVE))
    return InverseDynamicsFit(
        parameters=params, cutoff=cutoff, delay=int(delay), physical=physical,
        relative_error=float(np.linalg.norm(res) / (np.linalg.norm(y) or 1.0)),
        model='u = J dw/dt + B w' + ''.join(MECHANICAL_TERMS[k].text for k in terms
                                            if k in MECHANICAL_TERMS))


MECHANICAL_TERMS = {n: spec.mechanical_term for n, spec in EFFECTS.items()
                    if spec.mechanical_term}
"""Torque terms the mechanical equation error can carry (each effect's own)."""
_NON_NEGATIVE = {f'{n}.{term.param}' for n, term in MECHANICAL_TERMS.items()
                 if EFFECTS[n].param(term.param).low >= 0}
"""Mechanical terms whose sign is physical: a negative value is not a motor."""


def _mechanical_columns(w: np.ndarray, t: np.ndarray, terms: Sequence[str]
                       ) -> dict[str, np.ndarray]:
    """Regressors of ``u = J dw/dt + B w + ...`` from the filtered speed, the terms in
    catalogue order."""
    cols = {'J': np.gradient(w, t), 'B': w}
    for n, term in MECHANICAL_TERMS.items():
        if n in terms:
            cols[f'{n}.{term.param}'] = term.column(w)
    return cols


def _electrical_columns(rec: Recording) -> dict[str, list[tuple[float | None, np.ndarray]]]:
    """Candidate regressors ``{effect: [(param value, column), ...]}`` (unfiltered), each
    effect's :attr:`~motor_id.effects.EffectSpec.electrical_term`."""
    t, u, i = rec.time, rec.input, rec.current
    if i is None:
        raise DataError('the electrical regressors need the measured current')
    return {n: spec.electrical_term.columns(t, u, i) for n, spec in EFFECTS.items()
            if spec.electrical_term}


def electrical_evidence(rec: Recording, cutoff: float | None = None) -> ElectricalEvidence:
    """Which voltage-side effect the electrical equation error points to, and R_m.

    Regresses the filtered voltage on the filtered current, its derivative and the
    speed (``V = R_m i + L_m di/dt + K_b w``), then on each of: the heating term
    ``h(t) i`` (h a first-order lag of i^2 with time constant tau_th: the voltage error
    grows with the integral of i^2), the brush term ``sgn(i)`` (follows the current at
    once) and the dead-zone term ``sgn(V) min(|V|, V_dz)`` (follows the input). A term
    with a negative coefficient explains nothing.

    Parameters
    ----------
    rec : Recording
        A voltage plant with the current measured.
    cutoff : float, optional
        Filter cut-off [Hz]; default a tenth of the Nyquist frequency.

    Returns
    -------
    ElectricalEvidence
        ``favoured``: the term that removes clearly most, or None; ``R_m``: the
        resistance estimate under the favoured term, else the base one; ``parameter``:
        tau_th or V_dz of the best grid point; ``start``: each term's effect parameters
        from the regression (refinement starts).
    """
    from scipy.signal import filtfilt

    if rec.input_kind != 'voltage' or not rec.has_current:
        raise ConfigError('the electrical equation needs a voltage plant with current')
    t = rec.time
    dt = float(np.median(np.diff(t)))
    b, a = _filter(dt, float(cutoff or 0.05 / dt))

    def f(x: np.ndarray) -> np.ndarray:
        return filtfilt(b, a, x)

    if rec.current is None:
        raise DataError('the electrical evidence needs the measured current')
    i_f = f(rec.current)
    base = np.column_stack([i_f, np.gradient(i_f, t), f(rec.speed)])
    y = f(rec.input)
    trim = max(1, int(0.02 * t.size))
    sl = slice(trim, t.size - trim)
    th0, rss0 = _lstsq(base[sl], y[sl])
    explained: dict[str, float] = {}
    best: dict[str, float | None] = {}
    R: dict[str, float] = {}
    starts: dict[str, dict[str, float]] = {}
    for name, cols in _electrical_columns(rec).items():
        explained[name], best[name], R[name] = 0.0, None, float(th0[0])
        coef = 0.0
        for value, col in cols:
            with np.errstate(all='ignore'):
                rho = abs(np.corrcoef(col, rec.input)[0, 1])
            if rho > 0.995:
                continue  # a term proportional to the input (a binary input): no evidence
            X = np.column_stack([base, f(col)])[sl]
            th, rss = _lstsq(X, y[sl])
            gain = 1.0 - rss / rss0 if rss0 > 0 else 0.0
            if th[-1] > 0 and gain > explained[name]:
                explained[name], best[name], R[name] = float(gain), value, float(th[0])
                coef = float(th[-1])
        starts[name] = EFFECTS[name].electrical_term.start(best[name], coef)
    order = sorted(explained, key=lambda k: -explained[k])
    top, second = explained[order[0]], explained[order[1]]
    favoured = order[0] if top >= 0.2 and top >= 1.5 * second + 0.05 else None
    return ElectricalEvidence(
        explained=explained, favoured=favoured, parameter=best,
        R_m=R[favoured] if favoured else float(th0[0]), R_m_base=float(th0[0]),
        start={k: v for k, v in starts.items() if v and explained[k] > 0},
        model='V = R_m i + L_m di/dt + K_b w [+ term]')


def _lstsq(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ theta
    return theta, float(r @ r)

