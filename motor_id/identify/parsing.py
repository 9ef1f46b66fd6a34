"""Parsing of user-stated parameter values and search ranges (``--fix``, ``--bounds``)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from motor_id.errors import ConfigError
from motor_id.model import PARAM_NAMES


def parse_fixed(items: Iterable[str] | None, option: str = 'fixed') -> dict[str, float]:
    """Parse ``NAME=VALUE`` items: motor parameters known in advance.

    Parameters
    ----------
    items : iterable of str
    option : str
        How the user gave them (``--fix``, ``parameter fix``), for the messages.

    Returns
    -------
    dict
        ``{name: value}``.

    Raises
    ------
    ConfigError
        A malformed item, a name not in :data:`motor_id.model.PARAM_NAMES`, or a value
        that is not a finite positive number.
    """
    out: dict[str, float] = {}
    for item in items or ():
        name, sep, value = (x.strip() for x in item.partition('='))
        if not (sep and name):
            raise ConfigError(f'{option} takes NAME=VALUE, got {item!r}')
        if name not in PARAM_NAMES:
            raise ConfigError(f'{option}: unknown parameter {name!r}; use '
                              f'{", ".join(PARAM_NAMES)}')
        try:
            v = float(value)
        except ValueError:
            raise ConfigError(f'{option} {item!r}: {value!r} is not a number') from None
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f'{option} {item!r}: a physical parameter must be finite and '
                              '> 0')
        out[name] = v
    return out


def parse_bounds(items: Iterable[str] | None, option: str = 'bounds'
                 ) -> dict[str, tuple[float, float]]:
    """Parse ``NAME=LOW:HIGH`` items: search ranges.

    Parameters
    ----------
    items : iterable of str
    option : str
        How the user gave them, for the messages.

    Returns
    -------
    dict
        ``{name: (low, high)}``.

    Raises
    ------
    ConfigError
        A malformed item, a range that is not finite with LOW < HIGH, or, for the motor
        parameters (searched on a log scale), LOW <= 0. Other names (effect parameters)
        are checked by :class:`Identifier` against what it fits.
    """
    out: dict[str, tuple[float, float]] = {}
    for item in items or ():
        name, sep, rng = (x.strip() for x in item.partition('='))
        lo, sep2, hi = rng.partition(':')
        low: float | None
        high: float  # None only with low None, which raises below
        try:
            low, high = float(lo), float(hi)
        except ValueError:
            low = high = None  # type: ignore[assignment]
        if not (sep and sep2 and name) or low is None:
            raise ConfigError(f'{option} takes NAME=LOW:HIGH, got {item!r}')
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ConfigError(f'{option} {item!r}: need finite LOW < HIGH')
        if name in PARAM_NAMES and not low > 0:
            raise ConfigError(f'{option} {item!r}: {name} is searched on a log scale, '
                              'LOW must be > 0')
        out[name] = (low, high)
    return out
