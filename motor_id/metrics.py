"""Fit quality and residual diagnostics: fit %, RMS, autocorrelation, input cross-correlation."""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

from motor_id.records import Record

Z99 = 2.576


@dataclass(frozen=True)
class ChannelFit(Record):
    """Fit %, RMS error and residual diagnostics of one output channel
    (:func:`channel_metrics`; ``to_dict()``: these keys in this order)."""

    fit_percent: float
    rms: float
    n_samples: int
    max_lag: int
    band: float
    autocorrelation: list[float]
    cross_correlation: list[float]
    autocorrelation_outside: float
    cross_correlation_outside: float
    white: bool
    independent: bool


def normalised_fit(y: ArrayLike, y_hat: ArrayLike) -> float:
    """Normalised fit in percent: ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``."""
    y = np.asarray(y, dtype=float)
    den = np.linalg.norm(y - y.mean())
    if den == 0:
        return float('nan')
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / den))


def correlation(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``r_ab(tau)`` for tau = 0..max_lag (b lags a)."""
    a = np.asarray(a, dtype=float) - np.mean(a)
    b = np.asarray(b, dtype=float) - np.mean(b)
    n = a.size
    den = np.sqrt(np.dot(a, a) * np.dot(b, b))
    if den == 0:
        return np.zeros(max_lag + 1)
    return np.array([np.dot(a[:n - k], b[k:]) / den for k in range(max_lag + 1)])


@dataclass(frozen=True)
class ResidualTests(Record):
    """Whiteness and independence of a residual sequence (:func:`residual_diagnostics`)."""

    max_lag: int
    band: float
    autocorrelation: list[float]
    cross_correlation: list[float]
    autocorrelation_outside: float
    cross_correlation_outside: float
    white: bool
    independent: bool


def residual_diagnostics(residual: ArrayLike, u: np.ndarray, max_lag: int = 25
                         ) -> ResidualTests:
    """Whiteness and independence tests of a residual sequence.

    Parameters
    ----------
    residual : array_like
        Measured minus simulated output.
    u : array_like
        The input.
    max_lag : int

    Returns
    -------
    ResidualTests
        ``autocorrelation`` (lags 1..max_lag), ``cross_correlation`` with the input
        (lags 0..max_lag), the 99 % confidence ``band`` (2.58/sqrt(N)), and the share
        of lags outside the band for each (``*_outside``); ``white`` / ``independent``
        are True when at most 5 % of lags fall outside.
    """
    e = np.asarray(residual, dtype=float)
    n = e.size
    band = Z99 / np.sqrt(n)
    ac = correlation(e, e, max_lag)[1:]
    cc = correlation(u, e, max_lag)
    ac_out = float(np.mean(np.abs(ac) > band))
    cc_out = float(np.mean(np.abs(cc) > band))
    return ResidualTests(max_lag=max_lag, band=float(band), autocorrelation=ac.tolist(),
                         cross_correlation=cc.tolist(), autocorrelation_outside=ac_out,
                         cross_correlation_outside=cc_out, white=ac_out <= 0.05,
                         independent=cc_out <= 0.05)


def channel_metrics(y: ArrayLike, y_hat: ArrayLike, u: np.ndarray, max_lag: int = 25
                    ) -> ChannelFit:
    """Fit %, RMS error and residual diagnostics of one output channel."""
    y = np.asarray(y, dtype=float)
    e = y - np.asarray(y_hat, dtype=float)
    d = residual_diagnostics(e, u, max_lag)
    return ChannelFit(fit_percent=normalised_fit(y, y_hat),
                      rms=float(np.sqrt(np.mean(e * e))), n_samples=int(y.size),
                      max_lag=d.max_lag, band=d.band, autocorrelation=d.autocorrelation,
                      cross_correlation=d.cross_correlation,
                      autocorrelation_outside=d.autocorrelation_outside,
                      cross_correlation_outside=d.cross_correlation_outside, white=d.white,
                      independent=d.independent)


def noise_floor(y: ArrayLike) -> float:
    """Robust white-noise level of a smooth signal from its second differences.

    For white noise of variance s^2 the second difference has variance 6 s^2; the median
    absolute deviation ignores the few large differences at steps. A quantised signal
    (most differences exactly zero) falls back to a trimmed RMS.

    Parameters
    ----------
    y : array_like
        One channel.

    Returns
    -------
    float
        The noise standard deviation, in the unit of ``y``.
    """
    y = np.asarray(y, dtype=float)
    if y.size < 5:
        return 0.0
    with np.errstate(all='ignore'):
        d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    d2 = d2[np.isfinite(d2)]
    if d2.size == 0:
        return 0.0
    mad = np.median(np.abs(d2 - np.median(d2)))
    if mad > 0:
        return float(1.4826 * mad / math.sqrt(6.0))
    cut = np.percentile(np.abs(d2), 99)
    keep = d2[np.abs(d2) <= cut]
    return float(np.sqrt(np.mean(keep * keep) / 6.0)) if keep.size else 0.0
