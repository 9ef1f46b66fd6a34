"""Reports for people and machines: JSON files and PNG plots of a fit."""

from __future__ import annotations

import json
import math
import os
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.contracts import channel_units

if TYPE_CHECKING:
    from motor_id.identify.result import IdentificationResult


def to_jsonable(obj: Any) -> Any:
    """Make an object JSON-safe: numpy to Python, tuples to lists, NaN/inf to None.

    Parameters
    ----------
    obj : object
        Nested dicts, lists, tuples, numpy arrays and scalars, Python scalars.

    Returns
    -------
    object
        The same structure with plain JSON types only (dict keys become str).
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_json(data: Any, path: str | os.PathLike[str]) -> None:
    """Write a report dict as indented JSON (NaN/inf become null)."""
    with open(path, 'w') as fh:
        json.dump(to_jsonable(data), fh, indent=2)
        fh.write('\n')


def _figure(rows: int, cols: int, size: tuple[float, float]) -> tuple[Any, Any, Any]:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(rows, cols, figsize=size, squeeze=False)
    return plt, fig, axes


def plot_fit(result: IdentificationResult, path: str | os.PathLike[str],
             title: str | None = None) -> str | os.PathLike[str]:
    """Measured vs model outputs (paper Fig. 4), GA parameter trajectories (Fig. 3),
    GA cost, and residual diagnostics, in one PNG.

    Parameters
    ----------
    result : motor_id.identify.IdentificationResult
    path : str
        Output PNG path.
    """
    plt, fig, axes = _figure(3, 2, (13, 11))
    _plot_outputs(result, axes[0])
    _plot_ga(result.ga.get('history', []), axes[1])
    _plot_residuals(result, axes[2])
    fig.suptitle(title or f'motor_id fit ({result.method})')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _plot_outputs(result: IdentificationResult, row: Any) -> None:
    pred = result.prediction
    channels = list(result.channels)
    t = pred['time']
    units = channel_units()
    for k, ch in enumerate(channels[:2]):
        ax = row[k]
        ax.plot(t, pred[ch + '_measured'], lw=1.0, label='measured')
        ax.plot(t, pred[ch], lw=1.0, ls='--', label='model')
        ax.set_title(f'{ch}: measured vs model (fit '
                     f'{result.fit["channels"][ch]["fit_percent"]:.2f} %)')
        ax.set_xlabel('time [s]')
        ax.set_ylabel(f'{ch} [{units.get(ch, "")}]')
        ax.legend(loc='best')
    if len(channels) < 2:
        ax = row[1]
        ax.plot(t, pred['input'], lw=1.0, color='k')
        ax.set_title('input')
        ax.set_xlabel('time [s]')
        ax.set_ylabel('input [V]' if result.input_kind == 'voltage' else 'input [N m]')


def _plot_ga(hist: list[dict[str, Any]], row: Any) -> None:
    ax = row[0]
    if hist:
        gens = [h['generation'] for h in hist]
        for n in list(hist[-1]['best']):
            vals = np.array([h['best'][n] for h in hist])
            final = vals[-1] if vals[-1] != 0 else 1.0
            ax.plot(gens, vals / final, label=n)
        ax.set_yscale('log')
        ax.legend(loc='best', fontsize=8)
    ax.set_title('GA best individual per generation (relative to final)')
    ax.set_xlabel('generation')
    ax = row[1]
    if hist:
        ax.semilogy(gens, [h['best_cost'] for h in hist], label='best')
        ax.semilogy(gens, [h['mean_cost'] for h in hist], label='mean', alpha=0.7)
        ax.legend(loc='best')
    ax.set_title('GA fitness (normalised MSE)')
    ax.set_xlabel('generation')


def _plot_residuals(result: IdentificationResult, row: Any) -> None:
    channels = list(result.channels)
    for k, ch in enumerate(channels[:2]):
        ax = row[k]
        m = result.fit['channels'][ch]
        lags = np.arange(1, len(m['autocorrelation']) + 1)
        ax.stem(lags, m['autocorrelation'], linefmt='C0-', markerfmt='C0o', basefmt=' ',
                label='residual autocorrelation')
        xl = np.arange(len(m['cross_correlation']))
        ax.plot(xl, m['cross_correlation'], 'C1s', ms=3, label='input cross-correlation')
        ax.axhline(m['band'], color='r', ls=':', lw=1)
        ax.axhline(-m['band'], color='r', ls=':', lw=1, label='99 % band')
        ax.set_title(f'{ch} residual diagnostics')
        ax.set_xlabel('lag [samples]')
        ax.legend(loc='best', fontsize=8)
    if len(channels) < 2:
        row[1].axis('off')
