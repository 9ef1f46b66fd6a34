"""Diagnostics of the linear model's residuals: correlation, binned means, steady-state map."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.analysis.heldout import binned_means
from motor_id.metrics import residual_diagnostics

if TYPE_CHECKING:
    from motor_id.recording import Recording

KEYS = ('autocorrelation_outside', 'cross_correlation_outside', 'white', 'independent')


def steady_state_map(rec: Recording, min_len: int | None = None) -> list[dict[str, Any]]:
    """Steady-state points (input, speed[, current]) from plateaus of the recording.

    Plateaus are runs of a constant input at least ``min_len`` samples long (the last
    40 % of each run is averaged, after the transient); when they hold fewer than three
    distinct input levels (a noisy measured input, say), quasi-steady windows of
    ``min_len`` samples (speed varying by less than 5 % of its spread) are used.

    Returns
    -------
    list of dict
        ``{'start', 'stop', 'input', 'speed'[, 'current']}`` per point; start/stop are
        the averaged sample range.
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
    points: list[dict[str, Any]] = []
    for a, b in ranges:
        p: dict[str, Any] = {'start': a, 'stop': b, 'input': float(np.mean(u[a:b])),
             'speed': float(np.mean(rec.speed[a:b]))}
        if rec.current is not None:
            p['current'] = float(np.mean(rec.current[a:b]))
        points.append(p)
    return points


def map_summary(points: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Straight-line fits ``speed = a input + b`` to the positive and negative plateaus.

    Returns the slope, intercept and the input at which the fitted speed is zero (an
    offset there points to friction, a brush drop or a dead zone) for each side with at
    least two points, and the quadratic coefficient over all points (curvature points to
    a quadratic load or saturation).
    """
    out: dict[str, Any] = {'n_points': len(points)}
    if not points:
        return out
    u = np.array([p['input'] for p in points])
    w = np.array([p['speed'] for p in points])
    tol = 1e-6 * (float(np.max(np.abs(u))) or 1.0)
    for side, sel in (('positive', u > 0), ('negative', u < 0)):
        if np.unique(np.round(u[sel] / tol)).size >= 2:
            a, b = np.polyfit(u[sel], w[sel], 1)
            out[side] = {'slope': float(a), 'intercept': float(b),
                         'zero_speed_input': float(-b / a) if a != 0 else None}
    if np.unique(np.round(u / tol)).size >= 3:
        c2, c1, c0 = np.polyfit(u, w, 2)
        out['quadratic'] = {'c2': float(c2), 'c1': float(c1), 'c0': float(c0)}
    return out


def residual_block(rec: Recording, channels: Sequence[str],
                   prediction: Mapping[str, ArrayLike],
                   after: Mapping[str, ArrayLike] | None = None) -> dict[str, Any]:
    """Residual diagnostics of a fit (``prediction``: IdentificationResult.prediction).

    Returns ``{'residual': {ch: ...}, 'binned': {ch: ...}}``; with ``after`` (the chosen
    model's prediction) also ``'residual_after'``.
    """
    variables: dict[str, np.ndarray] = {'speed': rec.speed, 'input': rec.input,
                                        'sign(speed)': rec.speed, 'sign(input)': rec.input}
    if rec.current is not None:
        variables.update({'current': rec.current, 'sign(current)': rec.current})
    out: dict[str, Any] = {'residual': {}, 'binned': {}}
    for c in channels:
        r = np.asarray(prediction[c + '_measured']) - np.asarray(prediction[c])
        dd = residual_diagnostics(r, rec.input)
        out['residual'][c] = {k: dd[k] for k in KEYS + (
            'band', 'autocorrelation', 'cross_correlation')}
        out['binned'][c] = binned_means(r, variables)
    if after is not None:
        out['residual_after'] = {}
        for c in channels:
            r = np.asarray(after[c + '_measured']) - np.asarray(after[c])
            dd = residual_diagnostics(r, rec.input)
            out['residual_after'][c] = {k: dd[k] for k in KEYS}
    return out
