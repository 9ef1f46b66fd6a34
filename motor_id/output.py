"""The output of a fit for people and machines: JSON files (with units) and PNG plots."""

from __future__ import annotations

from collections.abc import Mapping
import json
import math
import os
import re
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.contracts import channel_units, linear_unit, UNITS, units_of
from motor_id.effects import EFFECTS

if TYPE_CHECKING:
    from motor_id.ga import GenerationRecord
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


def attach_units(report: Any, input_kind: str = 'voltage', linear: bool = False) -> Any:
    """Give every constant of a report its ``"unit"``, in place; returns the report.

    A constant is a dict with a ``value``. Its unit comes from its name: a parameter or a
    feedforward constant (:func:`motor_id.contracts.units_of` of the plant kind, a linear
    axis in metres), an effect's parameter (``effect.param``, or ``param`` under its
    effect's key: the catalogue's unit), a loop gain or feedforward entry beside a
    ``units`` block, a time constant [s], or a combination of parameters named by its
    expression (``K_T/(J*L_m)`` -> ``(N m/A)/(kg m^2 H)``). A constant that already has
    a unit keeps it.
    """
    units = units_of(input_kind, linear)
    _attach(report, units, linear, (), None)
    return report


def _attach(node: Any, units: Mapping[str, str], linear: bool, path: tuple[str, ...],
            parent: Mapping[str, Any] | None) -> None:
    if isinstance(node, list):
        for item in node:
            _attach(item, units, linear, path, None)
        return
    if not isinstance(node, dict):
        return
    if 'value' in node and 'unit' not in node:
        unit = _unit_of(node, units, linear, path, parent)
        if unit is not None:
            node['unit'] = unit
    for k, v in list(node.items()):
        if k != 'units':
            _attach(v, units, linear, (*path, str(k)), node)


def _unit_of(entry: Mapping[str, Any], units: Mapping[str, str], linear: bool,
             path: tuple[str, ...], parent: Mapping[str, Any] | None) -> str | None:
    """The unit of one constant (None: its name says nothing known)."""
    name = entry.get('name') if isinstance(entry.get('name'), str) else (
        path[-1] if path else None)
    if name is None:
        return None
    beside = (parent or {}).get('units')
    if isinstance(beside, dict) and isinstance(beside.get(name), str):
        return str(beside[name])
    if name in units:
        return units[name]
    if name in ('electrical', 'mechanical'):
        return UNITS['time']
    effect, _, param = name.rpartition('.')
    if not effect and len(path) > 1:
        effect = path[-2]
    spec = EFFECTS.get(effect)
    unit = next((p.unit for p in spec.params if p.name == param), None) if spec else None
    if unit is not None:
        return linear_unit(unit) if linear else unit
    return expression_unit(name, units)


_TOKEN = re.compile(r'\s*([A-Za-z_][A-Za-z0-9_]*|\d+(?:\.\d*)?(?:[eE][-+]?\d+)?|\*\*|.)')


def expression_unit(expr: str, units: Mapping[str, str]) -> str | None:
    """The unit of a combination of parameters, from their units (None: not one).

    A sum has the unit of its first term; products and quotients are written out
    (``(R_m*B + K_T*K_b)/(J*L_m)`` -> ``(Ohm N m s/rad)/(kg m^2 H)``), not simplified.
    """
    tokens = [t for t in _TOKEN.findall(expr) if t.strip()]
    if not tokens or not any(t in units for t in tokens):
        return None
    try:
        unit, rest = _sum(tokens, units)
    except (KeyError, IndexError, ValueError):
        return None
    return unit if not rest and unit else None


def _sum(tokens: list[str], units: Mapping[str, str]) -> tuple[str, list[str]]:
    first, tokens = _product(tokens, units)
    while tokens and tokens[0] in '+-':
        _, tokens = _product(tokens[1:], units)
    return first, tokens


def _product(tokens: list[str], units: Mapping[str, str]) -> tuple[str, list[str]]:
    out, tokens = _power(tokens, units)
    while tokens and tokens[0] in ('*', '/'):
        op = tokens[0]
        nxt, tokens = _power(tokens[1:], units)
        if nxt != '1':
            out = (nxt if out == '1' and op == '*' else
                   f'{out} {_wrap(nxt)}' if op == '*' else f'{out}/{_wrap(nxt)}')
    return out, tokens


def _power(tokens: list[str], units: Mapping[str, str]) -> tuple[str, list[str]]:
    tok = tokens[0]
    if tok == '(':
        inner, tokens = _sum(tokens[1:], units)
        if tokens[0] != ')':
            raise ValueError('unbalanced')
        base, tokens = inner, tokens[1:]
    elif tok in units:
        base, tokens = units[tok], tokens[1:]
    else:
        float(tok)
        base, tokens = '1', tokens[1:]
    if tokens and tokens[0] in ('^', '**'):
        exp = tokens[1]
        float(exp)
        return (base if base == '1' else f'{_wrap(base)}^{exp}'), tokens[2:]
    return base, tokens


def _wrap(unit: str) -> str:
    return f'({unit})' if (' ' in unit or '/' in unit) else unit


def _figure(rows: int, cols: int, size: tuple[float, float]) -> tuple[Any, Any, Any]:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(rows, cols, figsize=size, squeeze=False)
    return plt, fig, axes


def plot_fit(result: IdentificationResult, path: str | os.PathLike[str],
             title: str | None = None, linear: bool = False) -> str | os.PathLike[str]:
    """Measured vs model outputs (paper Fig. 4), GA parameter trajectories (Fig. 3),
    GA cost, and residual diagnostics, in one PNG.

    Parameters
    ----------
    result : motor_id.identify.IdentificationResult
    path : str
        Output PNG path.
    title : str, optional
    linear : bool
        A linear axis: speed in m/s.
    """
    plt, fig, axes = _figure(3, 2, (13, 11))
    _plot_outputs(result, axes[0], linear)
    _plot_ga(result.ga.history, axes[1])
    _plot_residuals(result, axes[2])
    fig.suptitle(title or f'motor_id fit ({result.method})')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _plot_outputs(result: IdentificationResult, row: Any, linear: bool = False) -> None:
    pred = result.prediction
    channels = list(result.channels)
    t = pred['time']
    units = channel_units(result.input_kind, linear, position=True)
    for k, ch in enumerate(channels[:2]):
        ax = row[k]
        ax.plot(t, pred[ch + '_measured'], lw=1.0, label='measured')
        ax.plot(t, pred[ch], lw=1.0, ls='--', label='model')
        ax.set_title(f'{ch}: measured vs model (fit '
                     f'{result.fit.channels[ch].fit_percent:.2f} %)')
        ax.set_xlabel('time [s]')
        ax.set_ylabel(f'{ch} [{units.get(ch, "")}]')
        ax.legend(loc='best')
    if len(channels) < 2:
        ax = row[1]
        ax.plot(t, pred['input'], lw=1.0, color='k')
        ax.set_title('input')
        ax.set_xlabel('time [s]')
        ax.set_ylabel(f'input [{units["voltage"]}]')


def _plot_ga(hist: list[GenerationRecord], row: Any) -> None:
    ax = row[0]
    if hist:
        gens = [h.generation for h in hist]
        for n in list(hist[-1].best):
            vals = np.array([h.best[n] for h in hist])
            final = vals[-1] if vals[-1] != 0 else 1.0
            ax.plot(gens, vals / final, label=n)
        ax.set_yscale('log')
        ax.legend(loc='best', fontsize=8)
    ax.set_title('GA best individual per generation (relative to final)')
    ax.set_xlabel('generation')
    ax = row[1]
    if hist:
        ax.semilogy(gens, [h.best_cost for h in hist], label='best')
        ax.semilogy(gens, [h.mean_cost for h in hist], label='mean', alpha=0.7)
        ax.legend(loc='best')
    ax.set_title('GA fitness (normalised MSE)')
    ax.set_xlabel('generation')


def _plot_residuals(result: IdentificationResult, row: Any) -> None:
    channels = list(result.channels)
    for k, ch in enumerate(channels[:2]):
        ax = row[k]
        m = result.fit.channels[ch]
        lags = np.arange(1, len(m.autocorrelation) + 1)
        ax.stem(lags, m.autocorrelation, linefmt='C0-', markerfmt='C0o', basefmt=' ',
                label='residual autocorrelation')
        xl = np.arange(len(m.cross_correlation))
        ax.plot(xl, m.cross_correlation, 'C1s', ms=3, label='input cross-correlation')
        ax.axhline(m.band, color='r', ls=':', lw=1)
        ax.axhline(-m.band, color='r', ls=':', lw=1, label='99 % band')
        ax.set_title(f'{ch} residual diagnostics')
        ax.set_xlabel('lag [samples]')
        ax.legend(loc='best', fontsize=8)
    if len(channels) < 2:
        row[1].axis('off')
