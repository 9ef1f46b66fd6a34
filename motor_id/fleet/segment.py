"""Segments of a parameter's history: the two-sample statistic of every split, the levels
between changes, and the shape of a change (a step or a ramp).

The arrays are one history's kept estimates in logs, ``y``, and their weights ``w`` (one
over the variance: the day-to-day scatter squared plus the estimate's own error bar
squared); :mod:`motor_id.fleet.drift` tests and dates the changes with them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

RAMP_SEARCH = 10
"""A ramp's onset and end are searched this many recordings around the change points."""
RAMP_CHI2 = 9.0
"""A ramp is reported instead of a step when it fits better by this much (weighted sum
of squares, in variances: about p = 0.003 for one more parameter)."""


def split_stats(y: NDArray[np.float64], w: NDArray[np.float64], a: int, b: int,
                first: bool, most: int | None = None
                ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The splits k allowed in ``y[a:b]`` (with at most ``most`` recordings before them)
    and their ``T_k``."""
    lo = 1 if first else 2
    ks = np.arange(a + lo, b - 1 if most is None else min(b - 1, a + most + 1))
    if ks.size == 0:
        return ks, np.zeros(0)
    cw = np.cumsum(w[a:b])
    cs = np.cumsum(w[a:b] * y[a:b])
    wb, sb = cw[ks - a - 1], cs[ks - a - 1]
    wa, sa = cw[-1] - wb, cs[-1] - sb
    return ks, (sa / wa - sb / wb) / np.sqrt(1.0 / wa + 1.0 / wb)


def best_split(y: NDArray[np.float64], w: NDArray[np.float64], a: int, b: int,
               first: bool, most: int | None = None) -> tuple[int, float] | None:
    """The split of ``y[a:b]`` with the largest ``|T_k|`` and its ``T_k`` (None: none
    allowed)."""
    ks, t = split_stats(y, w, a, b, first, most)
    if not ks.size:
        return None
    j = int(np.argmax(np.abs(t)))
    return int(ks[j]), float(t[j])


def level_of(y: NDArray[np.float64], w: NDArray[np.float64], a: int, b: int
             ) -> tuple[float, float]:
    """Weighted mean of ``y[a:b]`` and its standard error."""
    ww = w[a:b]
    return float(np.sum(ww * y[a:b]) / np.sum(ww)), float(1.0 / math.sqrt(np.sum(ww)))


def change_groups(cps: list[tuple[int, float]], y: NDArray[np.float64],
                  w: NDArray[np.float64], gap: int) -> list[list[tuple[int, float]]]:
    """Change points in the same direction with at most ``gap`` recordings between them."""
    bounds = [0] + [c for c, _ in cps] + [int(y.size)]
    means = [level_of(y, w, bounds[j], bounds[j + 1])[0] for j in range(len(bounds) - 1)]
    out: list[list[tuple[int, float]]] = []
    for j, cp in enumerate(cps):
        sign = means[j + 1] > means[j]
        if out and cp[0] - out[-1][-1][0] <= gap and \
                (means[j] > means[j - 1]) == sign:
            out[-1].append(cp)
        else:
            out.append([cp])
    return out


def shape_change(y: NDArray[np.float64], w: NDArray[np.float64], a: int, first: int,
                 last: int, b: int, lo: int = 0) -> tuple[int, int]:
    """Onset and end of a change between the regimes ``a..first`` and ``last..b``: a
    step at ``first`` (onset = end), or the ramp (level, a straight line from the onset,
    level from the end on) that fits the estimates better by more than ``RAMP_CHI2``;
    the onset not before ``lo`` (after the change before it has ended)."""
    seg_y, seg_w = y[a:b], w[a:b]
    i = np.arange(a, b)
    best_step = best_ramp = (math.inf, first, first)
    for o in range(max(a + 1, first - RAMP_SEARCH, lo), first + 1):
        for e in range(max(last, o), min(b - 1, last + RAMP_SEARCH) + 1):
            x = np.clip((i - o + 1) / (e - o + 1), 0.0, 1.0)
            sw, sx, sxx = seg_w.sum(), (seg_w * x).sum(), (seg_w * x * x).sum()
            sy, sxy = (seg_w * seg_y).sum(), (seg_w * x * seg_y).sum()
            det = sw * sxx - sx * sx
            if det <= 0:
                continue
            slope = (sw * sxy - sx * sy) / det
            icpt = (sy - slope * sx) / sw
            sse = float(np.sum(seg_w * (seg_y - icpt - slope * x) ** 2))
            if e == o and sse < best_step[0]:
                best_step = (sse, o, e)
            elif e > o and sse < best_ramp[0]:
                best_ramp = (sse, o, e)
    if best_step[0] - best_ramp[0] > RAMP_CHI2:
        return best_ramp[1], best_ramp[2]
    if last > first:          # steps in one direction a few recordings apart: a ramp
        return first, last
    return best_step[1], best_step[2]
