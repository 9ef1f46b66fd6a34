"""A motor held against its siblings: the same motor on the other robots, from the first day.

Siblings are the motors with the same name in the profile, or with the same ``type:``
key. Each motor's current level of a parameter (the weighted mean of its estimates since
its last change, with its relative standard error ``se``: :class:`DriftFinding.level`)
is compared, in logs, with the other siblings' levels: their mean ``m`` and sample
standard deviation ``S`` (the spread from unit to unit, their own error bars included)
give the prediction ``t = (level - m) / sqrt(S^2 (1 + 1/k) + se^2)`` of a k-sibling
reference, Student t with k - 1 degrees of freedom when the motor is like the others.
Its normal score beyond ``threshold`` reports the motor.

Leaving the motor out of its own reference keeps it from widening the spread it is
tested against; a few siblings give a wide reference (t tails with few degrees of
freedom), so a small fleet reports only gross differences. This is a finding apart from
drift over time: a motor that was off from its first recording never changes in its own
history.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from motor_id.fleet.drift import normal_score
from motor_id.records import Record

MIN_SIBLINGS = 3
"""Siblings (other motors) a reference needs."""


@dataclass(frozen=True)
class SiblingFinding(Record):
    """One motor's parameter against its siblings'.

    Attributes
    ----------
    outlier : bool
        Outside the siblings' spread by more than the error bars allow.
    level, level_std : float or None
        The motor's current level and its relative standard error.
    reference : float or None
        The siblings' level (geometric mean; the motor left out).
    spread : float or None
        Their relative spread from unit to unit (sample standard deviation in logs).
    deviation : float or None
        ``level / reference - 1``.
    score : float or None
        The normal score of the prediction t statistic.
    threshold : float
    siblings : int
        Other motors in the reference.
    reason : str or None
        Why the motor was not compared.
    """

    outlier: bool
    siblings: int
    threshold: float
    level: float | None = None
    level_std: float | None = None
    reference: float | None = None
    spread: float | None = None
    deviation: float | None = None
    score: float | None = None
    reason: str | None = None


def compare_siblings(levels: Sequence[tuple[float | None, float | None]],
                     threshold: float) -> list[SiblingFinding]:
    """Each member of a group against the others.

    Parameters
    ----------
    levels : sequence of (level, relative std)
        One per motor of the group (None: no level, not compared and not a reference).
    threshold : float
        Normal score beyond which a motor is reported.

    Returns
    -------
    list of SiblingFinding
        In the order of ``levels``.
    """
    have = [j for j, (v, _) in enumerate(levels) if v is not None and v > 0]
    logs = {j: math.log(float(levels[j][0] or 0.0)) for j in have}
    out = []
    for j, (value, std) in enumerate(levels):
        others = [logs[i] for i in have if i != j]
        k = len(others)
        if value is None or not value > 0:
            out.append(SiblingFinding(outlier=False, siblings=k, threshold=threshold,
                                      reason='no estimate'))
            continue
        se = float(std or 0.0)
        if k < MIN_SIBLINGS:
            out.append(SiblingFinding(outlier=False, siblings=k, threshold=threshold,
                                      level=value, level_std=se,
                                      reason=f'{k} sibling(s); the reference needs '
                                             f'{MIN_SIBLINGS}'))
            continue
        m = float(np.mean(others))
        spread = float(np.std(others, ddof=1))
        scale = math.sqrt(spread ** 2 * (1 + 1 / k) + se ** 2)
        diff = logs[j] - m
        t = diff / scale if scale > 0 else (math.copysign(math.inf, diff) if diff else 0.0)
        score = normal_score(t, k - 1) if math.isfinite(t) else 37.0
        out.append(SiblingFinding(
            outlier=score > threshold, siblings=k, threshold=threshold, level=value,
            level_std=se, reference=math.exp(m), spread=spread,
            deviation=math.exp(logs[j] - m) - 1.0, score=math.copysign(score, t)))
    return out
