"""Diagnostics of the linear model's residuals: correlation, binned means, steady-state map."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.analysis.heldout import binned_means, BinnedMeans
from motor_id.metrics import residual_diagnostics
from motor_id.records import optional, Record

if TYPE_CHECKING:
    from motor_id.analysis.inverse_dynamics import ElectricalEvidence
    from motor_id.recording import Recording


@dataclass(frozen=True, kw_only=True)
class SteadyPoint(Record):
    """A steady state: the input, speed (and current) averaged over ``[start, stop)``;
    in a report also the linear and the chosen model's mean speed there."""

    start: int
    stop: int
    input: float
    speed: float
    current: float | None = optional()
    speed_linear: float | None = optional()
    speed_chosen: float | None = optional()


@dataclass(frozen=True, kw_only=True)
class SideFit(Record):
    """``speed = slope input + intercept`` over one side's plateaus."""

    slope: float
    intercept: float
    zero_speed_input: float | None


@dataclass(frozen=True, kw_only=True)
class Quadratic(Record):
    """``speed = c2 input^2 + c1 input + c0`` over every plateau."""

    c2: float
    c1: float
    c0: float


@dataclass(frozen=True, kw_only=True)
class SteadyStateMap(Record):
    """The straight lines of :func:`map_summary` (and, in a report, the points)."""

    n_points: int
    positive: SideFit | None = optional()
    negative: SideFit | None = optional()
    quadratic: Quadratic | None = optional()
    points: tuple[SteadyPoint, ...] | None = optional()


@dataclass(frozen=True, kw_only=True)
class ResidualTest(Record):
    """Whiteness of a residual and its independence of the input
    (:func:`motor_id.metrics.residual_diagnostics`): the share of lags outside the 99 %
    band; the band and the correlations themselves for the linear model's residual."""

    autocorrelation_outside: float
    cross_correlation_outside: float
    white: bool
    independent: bool
    band: float | None = optional()
    autocorrelation: list[float] | None = optional()
    cross_correlation: list[float] | None = optional()


@dataclass(frozen=True, kw_only=True)
class ResidualBlock(Record):
    """The linear model's residual per channel (:func:`residual_block`), the chosen
    one's, and in a report the noise floors, the electrical evidence and the map."""

    residual: dict[str, ResidualTest]
    binned: dict[str, dict[str, BinnedMeans]]
    residual_after: dict[str, ResidualTest] | None = optional()
    noise_floor: float | None = optional()
    channel_noise_floor: dict[str, float] | None = optional()
    electrical: ElectricalEvidence | None = optional()
    steady_state: SteadyStateMap | None = optional()


def steady_state_map(rec: Recording, min_len: int | None = None) -> list[SteadyPoint]:
    """Steady-state points (input, speed[, current]) from plateaus of the recording.

    Plateaus are runs of a constant input at least ``min_len`` samples long (the last
    40 % of each run is averaged, after the transient); when they hold fewer than three
    distinct input levels (a noisy measured input, say), quasi-steady windows of
    ``min_len`` samples (speed varying by less than 5 % of its spread) are used.

    Returns
    -------
    list of SteadyPoint
        ``start``/``stop`` are the averaged sample range.
    """
    u = rec.input
    n = u.size
    min_len = int(min_len or max(10, n // 100))
    scale = float(np.max(np.abs(u))) or 1.0
    change = np.flatnonzero(np.abs(np.diff(u)) > 1e-9 * scale) + 1
    edges = np.concatenate([[0], change, [n]])
    ranges: list[tuple[int, int]] = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b - a >= min_len:
            ranges.append((int(b - max(3, int(0.4 * (b - a)))), int(b)))
    levels = np.unique(np.round(np.array([u[a] for a, _ in ranges]) / (1e-6 * scale)))
    if levels.size < 3:
        ranges = []
        spread = float(np.std(rec.speed)) or 1.0
        for a in range(0, n - min_len + 1, min_len):
            seg = rec.speed[a:a + min_len]
            if np.std(seg) < 0.05 * spread:
                ranges.append((a, a + min_len))
    return [SteadyPoint(start=a, stop=b, input=float(np.mean(u[a:b])),
                        speed=float(np.mean(rec.speed[a:b])),
                        current=(None if rec.current is None
                                 else float(np.mean(rec.current[a:b]))))
            for a, b in ranges]


def map_summary(points: Sequence[SteadyPoint]) -> SteadyStateMap:
    """Straight-line fits ``speed = a input + b`` to the positive and negative plateaus.

    Returns the slope, intercept and the input at which the fitted speed is zero (an
    offset there points to friction, a brush drop or a dead zone) for each side with at
    least two points, and the quadratic coefficient over all points (curvature points to
    a quadratic load or saturation).
    """
    if not points:
        return SteadyStateMap(n_points=0)
    u = np.array([p.input for p in points])
    w = np.array([p.speed for p in points])
    tol = 1e-6 * (float(np.max(np.abs(u))) or 1.0)
    sides: list[SideFit | None] = []
    for sel in (u > 0, u < 0):
        fit = None
        if np.unique(np.round(u[sel] / tol)).size >= 2:
            a, b = np.polyfit(u[sel], w[sel], 1)
            fit = SideFit(slope=float(a), intercept=float(b),
                          zero_speed_input=float(-b / a) if a != 0 else None)
        sides.append(fit)
    quadratic = None
    if np.unique(np.round(u / tol)).size >= 3:
        c2, c1, c0 = np.polyfit(u, w, 2)
        quadratic = Quadratic(c2=float(c2), c1=float(c1), c0=float(c0))
    return SteadyStateMap(n_points=len(points), positive=sides[0], negative=sides[1],
                          quadratic=quadratic)


def residual_block(rec: Recording, channels: Sequence[str],
                   prediction: Mapping[str, ArrayLike],
                   after: Mapping[str, ArrayLike] | None = None) -> ResidualBlock:
    """Residual diagnostics of a fit (``prediction``: IdentificationResult.prediction)
    per channel, and with ``after`` (the chosen model's prediction) its residual's."""
    variables: dict[str, np.ndarray] = {'speed': rec.speed, 'input': rec.input,
                                        'sign(speed)': rec.speed, 'sign(input)': rec.input}
    if rec.current is not None:
        variables.update({'current': rec.current, 'sign(current)': rec.current})
    residual: dict[str, ResidualTest] = {}
    binned: dict[str, dict[str, BinnedMeans]] = {}
    for c in channels:
        r = np.asarray(prediction[c + '_measured']) - np.asarray(prediction[c])
        residual[c] = _residual_test(r, rec.input, full=True)
        binned[c] = binned_means(r, variables)
    residual_after = None
    if after is not None:
        residual_after = {}
        for c in channels:
            r = np.asarray(after[c + '_measured']) - np.asarray(after[c])
            residual_after[c] = _residual_test(r, rec.input, full=False)
    return ResidualBlock(residual=residual, binned=binned, residual_after=residual_after)


def _residual_test(r: np.ndarray, u: np.ndarray, full: bool) -> ResidualTest:
    """The :class:`ResidualTest` of residual ``r`` against input ``u``; ``full``: with the
    band and the correlations."""
    dd = residual_diagnostics(r, u)
    return ResidualTest(
        autocorrelation_outside=dd.autocorrelation_outside,
        cross_correlation_outside=dd.cross_correlation_outside, white=dd.white,
        independent=dd.independent, band=dd.band if full else None,
        autocorrelation=dd.autocorrelation if full else None,
        cross_correlation=dd.cross_correlation if full else None)
