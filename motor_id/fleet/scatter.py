"""A parameter's day-to-day scatter, pooled over a motor and its siblings.

Each history is a parameter's estimates in time order, in logs (every change relative),
each with its own relative standard error s (the fit's error bar). What the motor does
from one recording to the next beyond those error bars (temperature on R_m, say) is the
day-to-day scatter tau: an estimate is ``y_i = level + e_i + f_i`` with ``e_i ~ N(0,
tau^2)`` and ``f_i ~ N(0, s_i^2)``.

tau is estimated from the differences of consecutive estimates, ``d = y_i+1 - y_i``
with variance ``2 tau^2 + s_i^2 + s_i+1^2`` whatever the level: a step in a history
moves one difference, a ramp a few by a fraction each, so a change does not inflate
the scatter it is tested against. The estimate is Huber's M-estimate of scale on the
standardised differences (each squared one clipped at ``HUBER_C^2``; the root of
``mean(min(d^2 / (2 tau^2 + v), c^2)) = E[min(Z^2, c^2)]``), floored at ``floor``, on
every difference of every history of the group (the motor and its siblings: the same
motor on the other robots) up to a given time, so that the test at a recording uses
what was known then.

Siblings on one robot share its conditions (its temperature moves both wheels' R_m
alike), so their differences at one recording count once toward the degrees of
freedom (the scale still uses them all). Its effective degrees of freedom
``DOF_PER_DIFFERENCE`` x (differences so counted) were measured
by simulation (``var(log tau_hat^2) = 2 / dof`` for normal estimates; consecutive
differences share an estimate, so they are not independent, and clipping costs a
little): the drift test pays for an uncertain scatter with Student-t tails.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass
import functools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

HUBER_C = 2.5
"""Clip of a squared standardised difference (in standard deviations)."""
DOF_PER_DIFFERENCE = 0.6
"""Effective degrees of freedom of the scatter per difference pooled (measured, see the
module docstring)."""


@functools.cache
def _huber_beta(c: float) -> float:
    """``E[min(Z^2, c^2)]`` for a standard normal Z."""
    from scipy import special
    pdf = math.exp(-0.5 * c * c) / math.sqrt(2 * math.pi)
    tail = float(special.ndtr(-c))
    return (1.0 - 2 * tail) - 2 * c * pdf + c * c * 2 * tail


@dataclass(frozen=True)
class Scatter:
    """The day-to-day scatter at one time.

    Attributes
    ----------
    tau : float
        Relative standard deviation from day to day beyond the error bars (log units).
    dof : float
        Its effective degrees of freedom (0: nothing to estimate it from).
    differences : int
        Differences of consecutive estimates it rests on.
    """

    tau: float
    dof: float
    differences: int


def scatter_of(d: NDArray[np.float64], v: NDArray[np.float64], floor: float,
               independent: int | None = None) -> Scatter:
    """Huber's scale estimate of tau from differences ``d`` with known parts ``v``.

    Parameters
    ----------
    d : ndarray
        Differences of consecutive log estimates.
    v : ndarray
        ``s_i^2 + s_i+1^2`` of each difference (the error bars' share of its variance).
    floor : float
        Smallest tau returned.
    independent : int, optional
        How many of the differences are independent (default: all).

    Returns
    -------
    Scatter
    """
    m = int(d.size)
    if m == 0:
        return Scatter(tau=floor, dof=0.0, differences=0)
    dof = DOF_PER_DIFFERENCE * (m if independent is None else independent)
    beta = _huber_beta(HUBER_C)
    c2 = HUBER_C ** 2
    d2 = d * d

    def excess(tau: float) -> float:
        return float(np.mean(np.minimum(d2 / (2 * tau * tau + v), c2))) - beta
    if excess(floor) <= 0.0:
        return Scatter(tau=floor, dof=dof, differences=m)
    from scipy.optimize import brentq
    top = math.log(max(float(np.sqrt(d2.max() / (2 * beta))), floor) * 2)
    root = brentq(lambda u: excess(math.exp(u)), math.log(floor), top, xtol=1e-9)
    return Scatter(tau=math.exp(root), dof=dof, differences=m)



class ScatterPool:
    """Every difference of consecutive estimates of a group's histories, by time.

    Parameters
    ----------
    histories : sequence of (times, y, rel)
        Per history: the times (sortable, comparable across histories: ISO text of one
        format, or datetimes), the log estimates and their relative errors, in time order.
    floor : float
        Smallest tau.
    units : sequence of str, optional
        The robot of each history: differences of one robot at one time count once
        toward the degrees of freedom (default: every history on its own robot).
    """

    def __init__(self, histories: Sequence[tuple[Sequence[Any], NDArray[np.float64],
                                                 NDArray[np.float64]]],
                 floor: float, units: Sequence[str] | None = None) -> None:
        items: list[tuple[Any, float, float, tuple[Any, ...]]] = []
        for k, (times, y, rel) in enumerate(histories):
            unit = units[k] if units is not None else str(k)
            for i in range(1, len(y)):
                items.append((times[i], float(y[i] - y[i - 1]),
                              float(rel[i] ** 2 + rel[i - 1] ** 2), (unit, times[i])))
        items.sort(key=lambda x: x[0])
        self.floor = floor
        self._times = [t for t, _, _, _ in items]
        self._d = np.array([d for _, d, _, _ in items], dtype=float)
        self._v = np.array([v for _, _, v, _ in items], dtype=float)
        seen: set[tuple[Any, ...]] = set()
        self._independent = [0]
        for *_, key in items:
            seen.add(key)
            self._independent.append(len(seen))
        self._cache: dict[int, Scatter] = {}

    def __len__(self) -> int:
        return int(self._d.size)

    def at(self, time: Any = None) -> Scatter:
        """The scatter from the differences whose later estimate is at or before
        ``time`` (None: all)."""
        m = len(self._times) if time is None else bisect_right(self._times, time)
        got = self._cache.get(m)
        if got is None:
            got = scatter_of(self._d[:m], self._v[:m], self.floor, self._independent[m])
            self._cache[m] = got
        return got
