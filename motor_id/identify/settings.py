"""The settings of a fit, validated once: :class:`FitSettings` (and the stages' knobs).

Every front end (the command line, the identifier node, the fleet's tasks, the
discrepancy analysis) states what it asks of a fit in one :class:`FitSettings`; a bad
value fails when the settings are made, with a :class:`~motor_id.errors.ConfigError` that
names the field (its ``params``: the command line adds the flag that sets it). Whether a
recording needs the armature resistance is decided in one place,
:func:`require_resistance`.

:class:`FitStages` holds the internal knobs of the fit's stages (the analysis's candidate
refits and warm starts set them); they are not part of the public constructor.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
import math
from numbers import Integral, Real
from typing import Any

import numpy as np

from motor_id.errors import ConfigError
from motor_id.identify.problem import METHODS
from motor_id.identify.space import resistance_enters
from motor_id.model import PARAM_NAMES


def require_resistance(R_m: float | None, input_kind: str, has_current: bool,
                       fixed: Mapping[str, float] | None = None) -> None:
    """The one check that a recording's fit has the armature resistance it needs.

    R_m is needed where it enters the outputs
    (:func:`~motor_id.identify.space.resistance_enters`): voltage-input data with a
    measured current, or with a parameter other than R_m held fixed. Speed-only voltage
    data do not need it (their fit uses an internal value that changes no output).

    Parameters
    ----------
    R_m : float or None
        The given resistance [Ohm] (or ``fixed['R_m']``).
    input_kind : str
    has_current : bool
    fixed : mapping, optional

    Raises
    ------
    ConfigError
        R_m is needed and not given (``params``: ``('R_m',)``, and ``'fixed'`` where a
        fixed parameter makes it enter).
    """
    given = (fixed or {}).get('R_m', R_m)
    if given is None and resistance_enters(input_kind, has_current, fixed):
        others = set(fixed or {}) - {'R_m'}
        raise ConfigError('R_m (the armature resistance in Ohm, as measured) is required '
                          'for voltage-input data with a measured current or a fixed '
                          'parameter other than R_m (speed alone does not need it)',
                          params=('R_m', 'fixed') if others else ('R_m',))


def _fail(name: str, text: str) -> ConfigError:
    return ConfigError(f'{name}{"" if text.startswith(":") else " "}{text}', params=(name,))


def _real(v: Any) -> bool:
    return isinstance(v, Real) and not isinstance(v, bool)


def _whole(v: Any) -> bool:
    return isinstance(v, Integral) and not isinstance(v, bool)


def _values(name: str, given: Mapping[str, Any] | None) -> dict[str, float] | None:
    """``fixed``: known values of motor parameters, finite and > 0."""
    if given is None:
        return None
    if not isinstance(given, Mapping):
        raise _fail(name, f'takes a mapping NAME: VALUE, got {given!r}')
    out: dict[str, float] = {}
    for key, v in given.items():
        if key not in PARAM_NAMES:
            raise _fail(name, f': unknown parameter {key!r}; use {", ".join(PARAM_NAMES)}')
        if not (_real(v) and math.isfinite(v) and v > 0):
            raise _fail(name, f': {key} must be a finite number > 0, got {v!r}')
        out[str(key)] = float(v)
    return out


def _ranges(name: str, given: Mapping[str, Any] | None
            ) -> dict[str, tuple[float, float]] | None:
    """``bounds``: finite ``(low, high)``, low <= high, low > 0 for motor parameters."""
    if given is None:
        return None
    if not isinstance(given, Mapping):
        raise _fail(name, f'takes a mapping NAME: (LOW, HIGH), got {given!r}')
    out: dict[str, tuple[float, float]] = {}
    for key, rng in given.items():
        try:
            lo, hi = rng
        except (TypeError, ValueError):
            raise _fail(name, f': {key} takes (LOW, HIGH), got {rng!r}') from None
        if not (_real(lo) and _real(hi) and math.isfinite(lo) and math.isfinite(hi)
                and lo <= hi):
            raise _fail(name, f': {key} needs finite LOW <= HIGH, got {rng!r}')
        if key in PARAM_NAMES and lo <= 0:
            raise _fail(name, f': {key} is searched on a log scale: LOW must be > 0, '
                              f'got {lo!r}')
        out[str(key)] = (float(lo), float(hi))
    return out


def _names(name: str, given: Iterable[str] | None) -> tuple[str, ...] | None:
    if given is None:
        return None
    if isinstance(given, str) or not all(isinstance(x, str) for x in given):
        raise _fail(name, f'takes a sequence of names, got {given!r}')
    return tuple(given)


@dataclass(frozen=True)
class FitSettings:
    """What a fit is asked to do, validated when made (as pycma's ``CMAOptions``).

    Parameters
    ----------
    method : {'zoh', 'euler', 'paper'}
        The discretisation (:data:`motor_id.identify.METHODS`); ``paper``: the paper as
        published (Euler, GA only, speed only).
    R_m : float or None
        Given armature resistance [Ohm] (an ohmmeter reading); needed where it enters
        the outputs (:func:`require_resistance`). With a fitted current channel (not
        ``paper``) and R_m not in ``fixed`` it is estimated with this value as a
        Gaussian prior; otherwise it is held fixed.
    R_m_tolerance : float
        Relative standard deviation of that prior (0.10: good to about 10 %), > 0.
    tie : bool or None
        Impose K_T = K_b (SI units). ``None``: on when a current channel is present and
        the method is not ``paper``.
    fixed : mapping, optional
        Known values ``{name: value}`` of motor parameters (finite, > 0): an explicit
        extra assumption; those parameters are not fitted (``{'R_m': v}`` holds R_m).
    bounds : mapping, optional
        ``{name: (low, high)}`` search ranges overriding the defaults; effect parameters
        are named ``effect.param``; a motor parameter's low is > 0.
    channels : sequence of str, optional
        Output channels to fit; default all measured (``paper``: speed only).
    effects : mapping, optional
        ``{effect: {param: value}}`` terms included in the model (from
        :data:`motor_id.effects.EFFECTS`).
    free_effects : sequence of str, optional
        ``'effect.param'`` entries of ``effects`` to estimate.
    start : mapping, optional
        A starting parameter set; seeds the GA and the refinement.
    population, generations : int
        GA population (>= 2) and generations (>= 1), the paper's defaults.
    crossover, mutation : float
        GA probabilities in [0, 1].
    random_state : int, Generator or None
        The seed: the same seed reproduces the same fit bit for bit.
    bootstrap : int
        Residual-bootstrap refits for percentile intervals (0: off).

    Raises
    ------
    ConfigError
        A bad value; the message starts with the field's name, which ``params`` holds.

    Examples
    --------
    >>> from motor_id import FitSettings, Identifier
    >>> settings = FitSettings(R_m=2.3, random_state=0)
    >>> settings.replace(generations=40).generations
    40
    >>> Identifier(settings).settings == Identifier(R_m=2.3, random_state=0).settings
    True
    >>> FitSettings(R_m=-1.0)
    Traceback (most recent call last):
    ...
    motor_id.errors.ConfigError: R_m must be a finite value > 0 Ohm, got -1.0
    """

    method: str = 'zoh'
    R_m: float | None = None
    R_m_tolerance: float = 0.10
    tie: bool | None = None
    fixed: Mapping[str, float] | None = None
    bounds: Mapping[str, tuple[float, float]] | None = None
    channels: Sequence[str] | None = None
    effects: Mapping[str, Mapping[str, float]] | None = None
    free_effects: Sequence[str] | None = None
    start: Mapping[str, float] | None = None
    population: int = 20
    generations: int = 160
    crossover: float = 0.75
    mutation: float = 0.04
    random_state: int | np.random.Generator | None = None
    bootstrap: int = 0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise _fail('method', f'must be one of {METHODS}, got {self.method!r}')
        if self.R_m is not None and not (_real(self.R_m) and math.isfinite(self.R_m)
                                         and self.R_m > 0):
            raise _fail('R_m', f'must be a finite value > 0 Ohm, got {self.R_m!r}')
        tol = self.R_m_tolerance
        if not (_real(tol) and math.isfinite(tol) and tol > 0):
            raise _fail('R_m_tolerance', f'(the R_m tolerance) must be a finite fraction > 0 '
                                         f'(0.1 = 10 %), got {tol!r}')
        if self.tie is not None and not isinstance(self.tie, (bool, np.bool_)):
            raise _fail('tie', f'takes True, False or None, got {self.tie!r}')
        for name, low in (('population', 2), ('generations', 1), ('bootstrap', 0)):
            v = getattr(self, name)
            if not (_whole(v) and v >= low):
                raise _fail(name, f'must be a whole number >= {low}, got {v!r}')
        for name in ('crossover', 'mutation'):
            v = getattr(self, name)
            if not (_real(v) and 0 <= v <= 1):
                raise _fail(name, f'(a probability) must be in [0, 1], got {v!r}')
        rs = self.random_state
        if not (rs is None or isinstance(rs, np.random.Generator)
                or (isinstance(rs, (int, np.integer)) and not isinstance(rs, bool)
                    and rs >= 0)):
            raise _fail('random_state', f'takes a seed >= 0, a numpy Generator or None, '
                                        f'got {rs!r}')
        self._set('fixed', _values('fixed', self.fixed))
        self._set('bounds', _ranges('bounds', self.bounds))
        self._set('channels', _names('channels', self.channels))
        self._set('free_effects', _names('free_effects', self.free_effects))
        for name in ('effects', 'start'):
            v = getattr(self, name)
            if v is not None and not isinstance(v, Mapping):
                raise _fail(name, f'takes a mapping, got {v!r}')
            self._set(name, None if v is None else dict(v))

    def _set(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)   # the normalised copy, before first use

    @classmethod
    def of(cls, **values: Any) -> FitSettings:
        """Settings from keyword values; an unknown name is a :class:`ConfigError`
        naming it and the known ones (rather than a ``TypeError``)."""
        _known(values)
        return cls(**values)

    def replace(self, **changes: Any) -> FitSettings:
        """A copy with ``changes``, validated again."""
        _known(changes)
        return replace(self, **changes) if changes else self

    @property
    def resistance(self) -> float | None:
        """The R_m the fit is given: ``fixed['R_m']``, else :attr:`R_m`."""
        return (self.fixed or {}).get('R_m', self.R_m)

    def check_resistance(self, input_kind: str, has_current: bool) -> None:
        """:func:`require_resistance` for these settings on such a recording."""
        require_resistance(self.R_m, input_kind, has_current, self.fixed)


def _known(values: Mapping[str, Any]) -> None:
    unknown = sorted(set(values) - set(SETTING_NAMES))
    if unknown:
        raise ConfigError(f'unknown fit setting(s) {", ".join(unknown)}; known: '
                          f'{", ".join(SETTING_NAMES)}', params=tuple(unknown))


SETTING_NAMES = tuple(f.name for f in fields(FitSettings))
"""The fields of :class:`FitSettings`."""


@dataclass(frozen=True)
class FitStages:
    """The internal knobs of a fit's stages (not public: the analysis and warm starts).

    Parameters
    ----------
    use_ga : bool
        False skips the GA and refines from ``start`` only (warm starts).
    refine_starts : int
        Distinct GA individuals the refinement starts from.
    widen : bool
        Refit in a widened default box where a physical parameter sits on one of its
        sides (:meth:`motor_id.identify.Identifier.fit`).
    error_blocks : int
        Contiguous blocks per run of the robust covariance's score variance.
    settle : bool
        Refit without what the record cannot carry (a current the model does not
        explain, an R_m its prior holds); off for the analysis's candidates.
    reweight : int
        Largest number of refinements re-weighted by the estimated noise levels.
    max_nfev : int
        Largest number of residual evaluations of each least-squares refinement.
    quick_jacobian : bool
        One-sided differences in the refinement's Jacobian (the covariance always uses
        central ones).
    """

    use_ga: bool = True
    refine_starts: int = 3
    widen: bool = True
    error_blocks: int = 10
    settle: bool = True
    reweight: int = 4
    max_nfev: int = 60
    quick_jacobian: bool = False


STAGE_NAMES = tuple(f.name for f in fields(FitStages))
"""The knobs of :class:`FitStages`."""
