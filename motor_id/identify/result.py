"""What a fit produced: per-parameter estimates and the result with its JSON and table."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import math
from typing import Any, cast

import numpy as np

from motor_id.ga import GenerationRecord
from motor_id.metrics import ChannelFit
from motor_id.records import optional, Record


@dataclass(frozen=True)
class Bound(Record):
    """What the record allows of a parameter it does not determine: an upper bound or an
    interval (SI)."""

    upper: float | None = optional()
    interval: tuple[float, float] | None = optional()


@dataclass
class Estimate:
    """One parameter's estimate (SI units)."""

    value: float | None = None
    std: float | None = None
    determined: bool = False
    assumed: bool = False
    particular_value: float | None = None
    ci95: tuple[float, float] | None = None
    at_bound: bool = False
    reason: str | None = None
    bound: Bound | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; undetermined parameters have value and std null."""
        d: dict[str, Any] = {'value': self.value, 'std': self.std, 'determined': self.determined,
             'at_bound': bool(self.at_bound)}
        if self.assumed:
            d['assumed'] = True
        if self.particular_value is not None:
            d['particular_value'] = self.particular_value
        if self.ci95 is not None:
            d['bootstrap_ci95'] = list(self.ci95)
        if self.reason:
            d['reason'] = self.reason
        if self.bound:
            d['bound'] = self.bound.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Estimate:
        """The estimate of a :meth:`to_dict` (a missing key: its default)."""
        ci, bound = d.get('bootstrap_ci95'), d.get('bound')
        return cls(value=d.get('value'), std=d.get('std'),
                   determined=bool(d.get('determined', False)),
                   assumed=bool(d.get('assumed', False)),
                   particular_value=d.get('particular_value'),
                   ci95=None if ci is None else (ci[0], ci[1]),
                   at_bound=bool(d.get('at_bound', False)), reason=d.get('reason'),
                   bound=None if bound is None else Bound.from_dict(bound))


@dataclass(frozen=True)
class EffectEstimate(Record):
    """A fitted effect parameter (SI): its value, std (None: not determined), whether the
    record determines it and whether it sits on its search bound."""

    value: float
    std: float | None
    determined: bool
    at_bound: bool


EffectValues = dict[str, dict[str, float | EffectEstimate]]
"""A fit's effects: ``{effect: {parameter: held value, or the fitted EffectEstimate}}``."""


@dataclass(frozen=True)
class Combination(Record):
    """A combination of the parameters the record determines (a transfer-function
    coefficient, SysId's kV, kA, kS, kG), SI, with its delta-method std."""

    name: str
    value: float
    std: float | None
    determined: bool = True
    note: str | None = optional()


@dataclass(frozen=True)
class UndeterminedDirection(Record):
    """A direction in parameter space that leaves the output unchanged: its free pivot
    parameter and the exponents (log parameters) or coefficients of each parameter."""

    free: str
    exponents: dict[str, float]
    description: str


@dataclass(frozen=True)
class Identifiability(Record):
    """The structural rank and what it rests on (``identifiability`` of the JSON)."""

    rank: int
    n_free: int
    free: list[str]
    nuisance: list[str]
    condition: float
    basis: str
    fully_determined: bool
    tie_K_T_eq_K_b: bool  # noqa: N815 - the JSON key, with the model's symbols
    channels: list[str]
    error_bars: str
    prior: str | None = optional()
    r_m_determined_by_data: bool | None = optional()


@dataclass(frozen=True)
class FitQuality(Record):
    """Per-channel fit metrics (data's units), noise levels, cost and initial state."""

    channels: dict[str, ChannelFit]
    noise_std: dict[str, float]
    cost: float
    initial_state: dict[str, float]
    widened: dict[str, tuple[float, float]] | None = optional()


@dataclass(frozen=True)
class GaSummary(Record):
    """The GA's settings, stop reasons and history (best parameters SI)."""

    generations: int
    evaluations: int
    seconds: float
    best_cost: float | None = optional()
    stop: dict[str, int] | None = optional()
    population: int | None = optional()
    crossover: float | None = optional()
    mutation: float | None = optional()
    history: list[GenerationRecord] = field(default_factory=list)


@dataclass(frozen=True)
class Refinement(Record):
    """The least-squares refinement (``used`` False for the paper method)."""

    used: bool = False
    starts: int | None = optional()
    nfev: int | None = optional()
    status: int | None = optional()
    message: str | None = optional()
    bootstrap: int | None = optional()


@dataclass(frozen=True)
class Prior(Record):
    """A Gaussian prior (SI)."""

    mean: float | None
    std: float


@dataclass(frozen=True)
class Assumptions(Record):
    """What the fit took as given: R_m, its prior, K_T = K_b, fixed values, the
    discretisation (SI)."""

    R_m: float | None
    R_m_given: float | None
    R_m_prior: Prior | None
    K_T_eq_K_b: bool
    fixed: dict[str, float]
    discretisation: str


@dataclass(frozen=True)
class ValueStd(Record):
    """A value and its std (None: unknown)."""

    value: float | None
    std: float | None


@dataclass(frozen=True)
class Resistance(Record):
    """What the fit says about R_m of a voltage plant: the given value, the estimate and
    the verdict (``note``)."""

    given: float | None
    estimate: float | None
    std: float | None
    relative_change: float | None
    estimated: bool
    enters: bool | None = optional()
    internal: float | None = optional()
    note: str = ''
    prior_std: float | None = optional()
    data_estimate: ValueStd | None = optional()


@dataclass(frozen=True)
class ParameterCovariance(Record):
    """Covariance of the determined estimated parameters in linear SI units."""

    names: list[str]
    matrix: list[list[float]]


@dataclass(frozen=True)
class Rescaling(Record):
    """The powers of two the data were rescaled by internally (extreme units)."""

    note: str
    exponents: dict[str, int]


def _num(x: float | None, spec: str = '.4g') -> str:
    """Format a number for the table; None and NaN print as '-'."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return '-'
    return format(x, spec)


@dataclass
class IdentificationResult:
    """Everything a fit produced; serialises to the documented JSON shape.

    Examples
    --------
    Speed alone determines three combinations of the parameters (rank 3), not each of
    them; the feedforward constants kV and kA are such combinations:

    >>> from motor_id import Identifier
    >>> from motor_id.testing.recordings import paper_recording, SI_MOTOR
    >>> rec = paper_recording(SI_MOTOR, speed_noise=0.005, seed=1, with_current=False)
    >>> res = Identifier(R_m=2.3, random_state=0).fit(rec).result_
    >>> res.parameters['J'].value, res.parameters['J'].determined
    (None, False)
    >>> res.identifiability.rank
    3
    >>> kV = next(c for c in res.identifiable_combinations if c.name == 'kV')
    >>> round(kV.value, 3)
    0.667
    """

    method: str
    input_kind: str
    channels: tuple[str, ...]
    parameters: dict[str, Estimate]
    identifiable_combinations: list[Combination]
    undetermined_directions: list[UndeterminedDirection]
    identifiability: Identifiability
    fit: FitQuality
    ga: GaSummary
    refinement: Refinement
    assumptions: Assumptions
    effects: EffectValues = field(default_factory=dict)
    prediction: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    seconds: float = 0.0
    resistance: Resistance | None = None
    r_m_sensitivity: dict[str, float | None] | None = None
    parameter_covariance: ParameterCovariance | None = None
    units: Rescaling | None = None
    adequate: bool = True
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The JSON shape documented in docs/user-guide.md (extra keys beyond the contract)."""
        d: dict[str, Any] = {
            'adequate': bool(self.adequate),
            'warnings': list(self.warnings),
            'parameters': {k: v.to_dict() for k, v in self.parameters.items()},
            'identifiable_combinations': [c.to_dict() for c in self.identifiable_combinations],
            'undetermined_directions': [u.to_dict() for u in self.undetermined_directions],
            'identifiability': self.identifiability.to_dict(),
            'fit': self.fit.to_dict(),
            'method': self.method,
            'input_kind': self.input_kind,
            'channels': list(self.channels),
            'assumptions': self.assumptions.to_dict(),
            'effects': {e: {p: v.to_dict() if isinstance(v, EffectEstimate) else v
                            for p, v in vals.items()} for e, vals in self.effects.items()},
            'ga': self.ga.to_dict(),
            'refinement': self.refinement.to_dict(),
            'seconds': self.seconds,
            'parameter_covariance': None if self.parameter_covariance is None else
            self.parameter_covariance.to_dict(),
        }
        if self.resistance is not None:
            d['resistance'] = self.resistance.to_dict()
        if self.r_m_sensitivity is not None:
            d['r_m_sensitivity'] = self.r_m_sensitivity
        if self.units is not None:
            d['units'] = self.units.to_dict()
        return d

    def values(self) -> dict[str, float | None]:
        """``{name: value}`` of every parameter, using the particular value if undetermined."""
        out: dict[str, float | None] = {}
        for k, e in self.parameters.items():
            out[k] = e.value if e.value is not None else e.particular_value
        return out

    def summary(self) -> str:
        """A plain-text table for people."""
        lines = [f'method: {self.method}   channels: {", ".join(self.channels)}   '
                 f'plant: {self.input_kind} input']
        lines += self._parameter_lines()
        for name, (lo, hi) in (self.fit.widened or {}).items():
            lines.append(f'  {name}: the fit sat on the default range; searched again in '
                         f'{lo:.3g} .. {hi:.3g}')
        lines += self._resistance_lines()
        if not self.adequate:
            lines.append('MODEL INADEQUATE: ' + self.warnings[0])
        for w in self.warnings[(0 if self.adequate else 1):]:
            lines.append('warning: ' + w)
        lines += self._identifiability_lines()
        for ch, m in self.fit.channels.items():
            lines.append(f'fit {ch}: {_num(m.fit_percent, ".2f")} %  RMS '
                         f'{_num(m.rms)}  residual white: {m.white}  independent of '
                         f'input: {m.independent}')
        lines.append(f'GA: {self.ga.generations} generations, {self.ga.evaluations} '
                     f'evaluations, {self.ga.seconds:.3f} s; total {self.seconds:.2f} s')
        return '\n'.join(lines)

    def _parameter_lines(self) -> list[str]:
        lines = [f'{"parameter":<12}{"estimate":>14}{"std":>12}  note']
        for name, e in self.parameters.items():
            if e.value is None:
                if e.bound and e.bound.upper is not None:
                    shown = f'< {e.bound.upper:.3g}'
                elif e.bound and e.bound.interval is not None:
                    shown = '{:.3g}..{:.3g}'.format(*e.bound.interval)
                else:
                    shown = '-'
                why = 'not determined' + (' (model inadequate)' if not self.adequate else
                                          ' by this data')
                if name == 'R_m' and self.resistance and self.resistance.enters is False:
                    why = 'does not enter (speed-only voltage data)'
                lines.append(f'{name:<12}{shown:>14}{"-":>12}  {why}')
                continue
            std = '-' if e.std is None else f'{e.std:.4g}'
            note = 'assumed (given)' if e.assumed else ''
            if e.at_bound:
                note += ' at bound (the search range limits it; the std is not meaningful: ' \
                        'widen --bounds or check the units)'
            if e.ci95 is not None:
                note += f' bootstrap 95%: [{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]'
            lines.append(f'{name:<12}{e.value:>14.6g}{std:>12}  {note.strip()}'.rstrip())
        return lines

    def _resistance_lines(self) -> list[str]:
        lines: list[str] = []
        r = self.resistance
        if r is not None:
            if r.enters is False:
                lines.append(f'R_m: {r.note}')
            elif r.estimated:
                lines.append(f'R_m: given {r.given:.3g} Ohm, the data say '
                             f'{r.estimate:.4g} +- {_num(r.std, ".2g")} Ohm '
                             f'({100 * cast(float, r.relative_change):+.1f} %: {r.note})')
            else:
                lines.append(f'R_m: {r.given:.4g} Ohm, given and held fixed ({r.note})')
        if self.r_m_sensitivity:
            moves = ', '.join(f'{k} {v:+.2f} %' for k, v in self.r_m_sensitivity.items()
                              if v is not None)
            if moves:
                lines.append(f'  a +1 % error in R_m moves: {moves}')
        return lines

    def _identifiability_lines(self) -> list[str]:
        idf = self.identifiability
        lines = [f'identifiability: rank {idf.rank} of {idf.n_free} free '
                 f'parameter(s), condition {idf.condition:.3g}']
        if idf.prior:
            lines.append('  ' + idf.prior)
        if self.undetermined_directions:
            pivots = [d.free for d in self.undetermined_directions]
            lines.append(f'{len(pivots)} direction(s) in parameter space leave the output '
                         f'unchanged: {", ".join(pivots)} can take any value, and the '
                         'others follow:')
            for d in self.undetermined_directions:
                lines.append('  ' + d.description)
            lines.append('  add a measured channel (current), the K_T = K_b tie, or a known '
                         'value (--fix NAME=VALUE) to determine them')
        if self.identifiable_combinations:
            lines.append('determined combinations:')
            for c in self.identifiable_combinations:
                std = '' if c.std is None else f' +- {c.std:.4g}'
                lines.append(f'  {c.name:<28} = {c.value:.6g}{std}')
        return lines
