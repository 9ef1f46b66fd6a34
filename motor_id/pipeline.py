"""One path from a recording to the full fit report: estimates, data, controller block.

The CLI (``motor-id fit``, ``replay --offline``) prints and writes a :class:`FitReport`;
the identifier node publishes one. Nothing else assembles fit reports, so the JSON, the
ROS parameters file and the node's parameters say the same thing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
import math
from typing import Any

import numpy as np

from motor_id.controller import from_fit, to_ros_parameters
from motor_id.controller.result import ControllerDesign
from motor_id.effects import EFFECTS
from motor_id.errors import MotorIdError
from motor_id.identify import Identifier
from motor_id.identify.mechanism import check_mechanism, with_gravity
from motor_id.identify.result import EffectEstimate, EffectValues, IdentificationResult
from motor_id.identify.scales import data_scales, default_max_delay
from motor_id.model import PARAM_NAMES
from motor_id.output import attach_units
from motor_id.recording import Recording
from motor_id.records import optional, Record


@dataclass(frozen=True)
class DataBlock(Record):
    """What the report says about the data it was fitted to (the node adds the card's
    sequence numbers and times of its window)."""

    source: str | None
    samples: int
    sample_period: float
    regular: bool
    channels: list[str]
    input_kind: str
    runs: int
    linear: bool
    seq_first: int | None = optional()
    seq_last: int | None = optional()
    t_first: float | None = optional()
    t_last: float | None = optional()
    gaps_skipped: int | None = optional()


def data_block(rec: Recording, **extra: Any) -> DataBlock:
    """What the report says about the data it was fitted to (``extra``: more of
    :class:`DataBlock`'s fields, or another ``source``)."""
    return DataBlock(source=extra.pop('source', rec.meta.get('source')), samples=len(rec),
                     sample_period=rec.sample_period, regular=rec.is_regular,
                     channels=list(rec.channels()), input_kind=rec.input_kind,
                     runs=len(rec.segment_ranges), linear=rec.linear, **extra)


@dataclass(frozen=True)
class EffectSearch(Record):
    """How a fit's effects were searched on the record's own scale
    (:func:`scale_effect_search`)."""

    linear_first: bool
    K_T_held: bool
    ranges: dict[str, tuple[float, float]]
    note: str


@dataclass(frozen=True)
class AliasGuard(Record):
    """A speed-only fit whose poles aliased, refitted (:func:`alias_guard`)."""

    aliased_pair_hz: float
    nyquist_hz: float
    fit_percent: float
    refit_fit_percent: float
    L_m_bounds: tuple[float, float]
    kept: str


@dataclass
class FitReport:
    """A fit with everything a user gets from it.

    Attributes
    ----------
    result : IdentificationResult
    data : DataBlock
        :func:`data_block` of the recording.
    design : ControllerDesign or None
        The controller design, None when there is none (``controller``: its JSON).
    controller_error : str or None
        Why there is no controller design.
    extra : dict
        Further top-level keys the caller gives (a shift check, the bag, the hardware id,
        units).
    effect_search, alias_guard : EffectSearch, AliasGuard or None
        How the effects were searched; a refit of aliased poles.
    """

    result: IdentificationResult
    data: DataBlock
    design: ControllerDesign | None = None
    controller_error: str | None = None
    controller_summary: str = ''
    extra: dict[str, Any] = field(default_factory=dict)
    effect_search: EffectSearch | None = None
    alias_guard: AliasGuard | None = None

    @property
    def adequate(self) -> bool:
        """The model explains enough of the record (see :mod:`.identify.determinacy`)."""
        return bool(self.result.adequate)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` shape (docs/user-guide.md): the fit, ``data``, ``controller``,
        extras; every constant with its ``unit`` (:func:`motor_id.output.attach_units`)."""
        d = self.result.to_dict()
        d['data'] = self.data.to_dict()
        if self.design is not None:
            d['controller'] = self.design.to_dict()
        elif self.controller_error is not None:
            d['controller'] = {'error': self.controller_error}
        d.update(self.extra)
        for key, block in (('effect_search', self.effect_search),
                           ('alias_guard', self.alias_guard)):
            if block is not None:
                d[key] = block.to_dict()
        return attach_units(d, self.result.input_kind, bool(self.data.linear))

    def to_ros_parameters(self, node_name: str = '/**', unknown: str = 'omit'
                          ) -> dict[str, dict[str, dict[str, float]]]:
        """``{node: {'ros__parameters': {...}}}``: ``estimate.NAME``, ``estimate.NAME_std``
        and ``controller.*``.

        Parameters
        ----------
        node_name : str
        unknown : {'omit', 'nan'}
            What an unknown value becomes: left out (a parameters file: ROS parameters
            have no null) or NaN (a node's declared parameter that must always exist).
        """
        params: dict[str, float] = {}
        for name, p in self.result.to_dict()['parameters'].items():
            for key, v in ((name, p.get('value')), (f'{name}_std', p.get('std'))):
                if v is not None:
                    params[f'estimate.{key}'] = float(v)
                elif unknown == 'nan':
                    params[f'estimate.{key}'] = math.nan
        if self.design is not None:
            flat = to_ros_parameters(self.design, node_name)[node_name]
            params.update(flat['ros__parameters'])
        return {node_name: {'ros__parameters': params}}

    def summary(self) -> str:
        """The fit's table and the controller's, for people."""
        parts = [self.result.summary()]
        if self.controller_summary:
            parts.append(self.controller_summary)
        elif self.controller_error:
            parts.append(f'controller design not possible: {self.controller_error}')
        return '\n'.join(parts)


def controller_for(result: IdentificationResult, linear: bool, sample_period: float | None,
                   options: Mapping[str, Any] | None = None
                   ) -> tuple[ControllerDesign | None, str | None, str]:
    """``(design, error, summary)`` of the controller design for a fit's result."""
    kw = dict(options or {})
    if sample_period is not None:
        kw['sample_period'] = sample_period
    try:
        design = from_fit(result, linear=linear, **kw)
    except MotorIdError as exc:  # the fit stands; say why there is no design
        return None, str(exc), ''
    return design, None, design.summary()


def scale_effect_search(rec: Recording, identifier: Identifier) -> EffectSearch | None:
    """Search a fit's effects on the record's own scale: a linear fit first.

    An effect parameter's allowed range spans every motor (a Coulomb torque of 0 to
    1000 N m): a GA drawn over it finds a motor stuck by friction as good as any. So,
    for a fit with free effect parameters that the settings neither bound nor start:

    1. the linear model is fitted;
    2. the model with the effects is fitted by the GA from the linear fit, each such
       effect parameter searched in its catalogue search range on this record's scales
       (:meth:`motor_id.effects.EffectParam.search_range`, as the analysis searches its
       candidates). Where the linear fit leaves K_T undetermined (speed alone), K_T is
       held at its particular value meanwhile: a torque range is on the scale of that
       K_T, and the GA would otherwise move K_T along its unseen direction away from it;
    3. ``identifier`` is set to refine from that fit (``start``, no GA), so that its
       report says what the record determines, K_T free again.

    Returns
    -------
    EffectSearch or None
        The report's ``effect_search`` block (the ranges searched), None when nothing was
        changed.
    """
    s = identifier.settings
    free = [fe for fe in s.free_effects or () if fe not in (s.bounds or {})]
    if not free or s.start is not None or not identifier.stages.use_ga:
        return None
    linear = identifier.with_settings(
        effects=None, free_effects=None,
        bounds={k: v for k, v in (s.bounds or {}).items() if '.' not in k} or None)
    with np.errstate(all='ignore'):
        linear.fit(rec)
    physical = {k: v for k, v in linear.result_.values().items() if v is not None}
    if 'K_T' not in physical:
        return None
    scales = data_scales(rec, physical, physical.get('R_m'), float(rec.time[-1] - rec.time[0]),
                         rec.sample_period, default_max_delay(len(rec)))
    ranges = {}
    for fe in free:
        e, _, p = fe.partition('.')
        ranges[fe] = next(q for q in EFFECTS[e].params if q.name == p).search_range(scales)
    held = linear.result_.parameters['K_T'].value is None and 'K_T' not in (s.fixed or {})
    start = {k: v for k, v in physical.items() if k != 'R_m'}
    if held:
        start.pop('K_T')
    scaled = identifier.with_settings(bounds={**(s.bounds or {}), **ranges}, start=start)
    if held:   # at the R_m the linear fit used (an internal one where R_m does not enter)
        scaled = scaled.with_settings(fixed={**(s.fixed or {}), 'K_T': physical['K_T']},
                                      R_m=physical['R_m'])
    with np.errstate(all='ignore'):
        scaled.fit(rec)
    values = {k: v for k, v in scaled.result_.values().items() if v is not None}
    identifier.warm_start({**{k: v for k, v in values.items() if k != 'R_m'},
                           **{fe: _effect_value(scaled.result_.effects, fe) for fe in free}})
    return EffectSearch(
        linear_first=True, K_T_held=held,
        ranges={k: (float(v[0]), float(v[1])) for k, v in ranges.items()},
        note='each effect parameter searched on the scale of this record (its catalogue '
             "search range at the linear fit's torque, speed and input scales) by the GA "
             'from the linear fit' + (', K_T held at its particular value (speed alone '
                                      'cannot tell it), then refined with K_T free'
                                      if held else ''))


def aliased_poles(result: IdentificationResult, sample_period: float) -> float | None:
    """The frequency [Hz] of a fitted oscillatory pole pair above the Nyquist frequency
    of the samples (None: none), for a voltage plant fitted on speed alone.

    Sampled every T, the pair ``-a +- j w`` with ``w > pi / T`` gives the same samples as
    its alias ``-a +- j (w - 2 pi / T)``: with ``w`` near ``2 pi / T`` that is a real,
    slow pole. Speed alone cannot tell them apart; the pair is no physical motor's.
    """
    if result.input_kind != 'voltage' or 'current' in result.channels:
        return None
    v = {k: x for k, x in result.values().items() if x is not None}
    if any(k not in v for k in PARAM_NAMES):
        return None
    J, K_T, K_b, B, L, R = (v[k] for k in PARAM_NAMES)
    a1, a0 = R / L + B / J, (R * B + K_T * K_b) / (J * L)
    disc = a1 * a1 - 4.0 * a0
    if disc >= 0:
        return None
    w = math.sqrt(-disc) / 2.0
    return w / (2 * math.pi) if w > math.pi / sample_period else None


def alias_guard(rec: Recording, identifier: Identifier, given: Identifier
                ) -> AliasGuard | None:
    """Refit a speed-only fit whose poles alias (:func:`aliased_poles`) with the
    electrical time constant below half a sample period (where speed cannot see it).

    ``given`` is ``identifier`` as it was given (unfitted). The refit replaces the fit in
    ``identifier`` when it explains the speed as well (within 0.05 fit-% points): the
    record cannot prefer the aliased pair, and a motor's electrical time constant this
    short is the rule. Otherwise the fit stays and a warning says kA is not to be trusted.

    Returns
    -------
    AliasGuard or None
        The report's ``alias_guard`` block; None when the poles do not alias.
    """
    T = rec.sample_period
    hz = aliased_poles(identifier.result_, T)
    if hz is None or 'L_m' in (identifier.settings.fixed or {}):
        return None
    r_m = identifier.result_.values()['R_m'] or 1.0
    bounds = given.settings.bounds or {}
    low = bounds.get('L_m', (1e-5 * r_m * T, 0.0))[0]
    refit = given.with_settings(bounds={**bounds,
                                        'L_m': (min(low, r_m * T / 4), r_m * T / 2)})
    scale_effect_search(rec, refit)
    with np.errstate(all='ignore'):
        refit.fit(rec)
    before = identifier.result_.fit.channels['speed'].fit_percent
    after = refit.result_.fit.channels['speed'].fit_percent
    lo, hi = (refit.settings.bounds or {})['L_m']
    if after >= before - 0.05 and aliased_poles(refit.result_, T) is None:
        identifier.__dict__.update({k: v for k, v in refit.__dict__.items()
                                    if k.endswith('_')})
        kept = 'refit'
        identifier.result_.warnings.append(
            f'the first fit had oscillatory poles at {hz:.3g} Hz, above the Nyquist '
            f'frequency {0.5 / T:.3g} Hz of the samples (an alias of a slow real pole); '
            'refitted with the electrical time constant L_m/R_m below half a sample '
            f'period: speed fit {after:.2f} % (was {before:.2f} %)')
    else:
        kept = 'first fit'
        identifier.result_.identifiable_combinations = [
            replace(c, determined=False, note='the fitted poles alias at this sample period')
            if c.name == 'kA' else c for c in identifier.result_.identifiable_combinations]
        identifier.result_.warnings.append(
            f'the fitted poles oscillate at {hz:.3g} Hz, above the Nyquist frequency '
            f'{0.5 / T:.3g} Hz of the samples: they alias, and kA is not to be trusted '
            '(record at a shorter loop period)')
    return AliasGuard(aliased_pair_hz=hz, nyquist_hz=0.5 / T, fit_percent=before,
                      refit_fit_percent=after, L_m_bounds=(lo, hi), kept=kept)


def _effect_value(effects: EffectValues, key: str) -> float:
    """The fitted value of ``effect.param`` in a result's effects."""
    e, _, p = key.partition('.')
    entry = effects[e][p]
    return float(entry.value if isinstance(entry, EffectEstimate) else entry)


def fit_report(rec: Recording, identifier: Identifier, *,
             controller_options: Mapping[str, Any] | None = None,
             sample_period: float | None = None,
             progress: Callable[[int, int, float], bool | None] | None = None,
             data: Mapping[str, Any] | None = None,
             extra: Mapping[str, Any] | None = None,
             mechanism: str = 'simple') -> FitReport:
    """Fit ``rec`` and build the full report.

    Parameters
    ----------
    rec : Recording
    identifier : Identifier
        Its settings; it is fitted here (``identifier.result_`` afterwards).
    controller_options : dict, optional
        Keyword arguments of :func:`motor_id.controller.from_fit` (loop
        bandwidths).
    sample_period : float, optional
        The controller's sample period (default: the record's median period).
    progress : callable, optional
        Passed to :meth:`Identifier.fit`.
    data, extra : dict, optional
        More keys for the ``data`` block and the top level.
    mechanism : {'simple', 'elevator', 'arm'}
        What the joint moves (:data:`motor_id.effects.MECHANISMS`): the fit is refitted
        with the mechanism's gravity in the model, started from its equation-error
        values (:func:`motor_id.identify.mechanism.with_gravity`); the controller block
        then has ``kG`` (and an arm's ``offset``).

    Raises
    ------
    MotorIdError
        The fit itself failed (bad data or settings, no finite result).

    Examples
    --------
    >>> from motor_id import fit_report, Identifier
    >>> from motor_id.testing.recordings import paper_recording, SI_MOTOR
    >>> rec = paper_recording(SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=1)
    >>> report = fit_report(rec, Identifier(R_m=2.3, random_state=0))
    >>> report.adequate
    True
    >>> ff = report.design.feedforward
    >>> round(ff.kV.value, 3), ff.units['kV']
    (0.667, 'V s/rad')
    >>> sorted(report.to_dict())[:4]
    ['adequate', 'assumptions', 'channels', 'controller']
    """
    check_mechanism(rec, mechanism)   # before the fit: a missing position is found at once
    given = identifier.with_settings()   # before the search changes it
    search = scale_effect_search(rec, identifier)
    identifier.fit(rec, progress=progress)
    guard = alias_guard(rec, identifier, given)
    res = with_gravity(identifier, rec, mechanism).result_
    block = data_block(rec, **dict(data or {}))
    period = sample_period if sample_period is not None else rec.sample_period
    design, error, text = controller_for(res, block.linear, period, controller_options)
    return FitReport(result=res, data=block, design=design, controller_error=error,
                     controller_summary=text, extra=dict(extra or {}), effect_search=search,
                     alias_guard=guard)
