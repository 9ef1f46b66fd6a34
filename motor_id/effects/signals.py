"""What a sensor does to a signal: a grid (a counter, an ADC) and a count difference."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['interval_mean', 'on_grid']


def interval_mean(y: ArrayLike) -> np.ndarray:
    """Mean of a sampled signal over each sample's preceding interval (trapezoid rule).

    What a count difference measures: ``(theta[k] - theta[k-1]) / (t[k] - t[k-1])`` is
    the mean speed over ``(t[k-1], t[k]]``. The first sample has no preceding interval
    and keeps its value.

    Parameters
    ----------
    y : ndarray, shape (..., N)

    Returns
    -------
    ndarray, shape (..., N)
    """
    y = np.asarray(y, dtype=float)
    out = y.copy()
    out[..., 1:] = 0.5 * (y[..., 1:] + y[..., :-1])
    return out


def on_grid(y: ArrayLike, q: ArrayLike) -> np.ndarray:
    """Round to a grid of step ``q`` (a counter or an ADC); where ``q <= 0``, ``y`` as is.

    The one quantiser: the simulator's sensors and the project's case generator use it.
    """
    q = np.asarray(q, dtype=float)
    return np.where(q > 0, np.round(y / np.where(q > 0, q, 1.0)) * q, y)
