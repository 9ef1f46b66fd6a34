"""What a record determines in practice: parameters the data leave open, and adequacy.

Structural identifiability (:mod:`.uncertainty`) says which parameters a perfect record
of this kind could determine. A real record can still leave one open: an electrical time
constant far below the sample period hides the inductance, a flat cost leaves a relative
error bar of order one, a channel the model does not explain cannot carry what only it
would determine. And a model that explains too little of a record is no basis for any
number. This module turns those cases into ``determined: false`` with the reason (and a
bound where the data give one), and into the report's ``adequate`` flag and warnings.
"""

from __future__ import annotations

from collections.abc import Mapping
import math

import numpy as np

from motor_id.identify.result import Bound, Estimate
from motor_id.metrics import noise_floor

MAX_RELATIVE_STD = 0.5
"""A parameter whose (robust) relative standard deviation exceeds this is not determined:
the record allows it to change by a factor of 1.65 at one sigma."""
MIN_RELATIVE_STD = 1e-6
"""No reported std is below this fraction of its value: below it the arithmetic, not the
record, sets the number."""
ADEQUATE_FIT = 50.0
"""Fit % of the speed (held-out where there is a held-out score) below which a model is
inadequate: it explains less than half of the speed's variation."""
CHANNEL_FIT = 20.0
"""Fit % below which a secondary channel (current) is not explained by the model and
cannot carry the parameters that only it determines."""
MIN_LEVELS = 4
"""A channel that takes fewer distinct values than this holds no waveform to fit."""
MAX_LOG_SPREAD = 50.0
"""Largest log-width of a reported interval (e^50 ~ 5e21: beyond, "anything")."""
VISIBLE = 1e-3
"""Smallest relative residue of a step, one sample later, that a record can show."""


def floor_std(value: float | None, std: float | None) -> float | None:
    """``std`` raised to :data:`MIN_RELATIVE_STD` of ``|value|`` (None stays None)."""
    if std is None or value is None:
        return std
    return max(float(std), MIN_RELATIVE_STD * abs(float(value)))


def channel_levels(y: np.ndarray) -> int:
    """Number of distinct values of a channel (to 1e-9 of its range)."""
    y = np.asarray(y, dtype=float)
    span = float(np.ptp(y)) or 1.0
    return int(np.unique(np.round(y / (1e-9 * span))).size)


def relative_noise(y: np.ndarray) -> float:
    """Sample-to-sample noise of a channel (:func:`motor_id.metrics.noise_floor`)
    relative to its standard deviation, clipped to [:data:`VISIBLE`, 0.5]."""
    y = np.asarray(y, dtype=float)
    s = float(np.std(y))
    if y.size < 4 or s == 0:
        return 0.5
    return float(min(max(noise_floor(y) / s, VISIBLE), 0.5))


def inductance_bound(L_m: float, R_m: float, period: float, noise: float) -> float | None:
    """Upper bound on L_m when the electrical time constant is too short to be seen.

    After a voltage step the current's transient decays by ``exp(-T R_m / L_m)`` in one
    sample period T; once that is below the channel's relative noise the record cannot
    tell L_m from any smaller value. Returns that largest invisible L_m,
    ``R_m T / ln(1 / noise)``, when the estimate lies below it; else None.
    """
    limit = R_m * period / math.log(1.0 / noise)
    return limit if L_m < limit else None


def mark_undetermined(est: Estimate, reason: str, bound: Bound | None = None) -> None:
    """Turn an :class:`~motor_id.identify.result.Estimate` into "not determined"."""
    if est.value is not None:
        est.particular_value = est.value
    est.value = None
    est.std = None
    est.determined = False
    est.reason = reason
    if bound:
        est.bound = bound


def practical(params: Mapping[str, Estimate], period: float, noise: Mapping[str, float],
              R_m: float | None) -> list[str]:
    """Mark parameters the record does not determine in practice; return warnings.

    Parameters
    ----------
    params : dict
        ``{name: Estimate}`` with robust stds (changed in place).
    period : float
        Median sample period [s].
    noise : dict
        Relative noise per channel (:func:`relative_noise`).
    R_m : float or None
        The armature resistance in use (voltage plants).
    """
    warnings = []
    L = params.get('L_m')
    if L is not None and L.value is not None and L.determined and not L.assumed and R_m:
        ch = 'current' if 'current' in noise else 'speed'
        upper = inductance_bound(L.value, R_m, period, noise[ch])
        if upper is not None:
            text = (f'L_m < {upper:.3g} H: the electrical time constant '
                    f'({L.value / R_m:.2g} s) is below the sample period ({period:.3g} s); '
                    f'its transient is gone within one sample')
            mark_undetermined(L, text, Bound(upper=upper))
            warnings.append(text)
    for name, e in params.items():
        if not e.determined or e.assumed or e.value is None or e.std is None:
            continue
        rel = e.std / abs(e.value) if e.value else math.inf
        if rel > MAX_RELATIVE_STD:
            spread = min(2.0 * rel, MAX_LOG_SPREAD)   # (a std of 1e3 x the value: 1e-22..)
            lo = e.value * math.exp(-spread) if e.value > 0 else e.value - 2 * e.std
            hi = e.value * math.exp(spread) if e.value > 0 else e.value + 2 * e.std
            text = (f'{name} is not determined by this record: its relative error bar is '
                    f'{100 * rel:.0f} % (data allow about {lo:.3g} .. {hi:.3g})')
            mark_undetermined(e, text, Bound(interval=(lo, hi)))
            warnings.append(text)
    return warnings


HINT = 'look for what the record contains that the model lacks (motor-id analyze)'


def adequacy(fit_percent: Mapping[str, float | None], primary: str = 'speed',
             hint: str = HINT) -> tuple[bool, list[str]]:
    """``(adequate, warnings)`` from the fit % of each channel.

    A model that explains less than :data:`ADEQUATE_FIT` % of the primary channel is
    inadequate; a secondary channel under :data:`CHANNEL_FIT` % gets a warning.
    """
    warnings = []
    ok = True
    p = fit_percent.get(primary)
    if p is None or not math.isfinite(p) or p < ADEQUATE_FIT:
        ok = False
        shown = 'no' if p is None or not math.isfinite(p) else f'{p:.1f} %'
        warnings.append(f'the model explains {shown} of the {primary} (an adequate model '
                        f'explains at least {ADEQUATE_FIT:.0f} %): its parameters are not '
                        f'presented as determined; {hint}')
    for ch, v in fit_percent.items():
        if ch != primary and v is not None and math.isfinite(v) and v < CHANNEL_FIT:
            warnings.append(f'the model explains {v:.1f} % of the {ch}: that channel '
                            'cannot carry the parameters only it would determine')
    return ok, warnings
