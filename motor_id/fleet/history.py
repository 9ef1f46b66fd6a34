"""Per robot, motor and parameter: the history of estimates, what the drift test says, and
how the motor compares with its siblings.

Only rows whose fit is adequate and whose parameter is determined enter a history (an
inadequate fit says the model does not explain that recording; its numbers are not a
measurement of the motor). Siblings (the same motor name, or the same ``type:`` key of
the profile, on the other robots) share the day-to-day scatter the drift test uses
(:mod:`motor_id.fleet.scatter`) and give each other a reference level
(:mod:`motor_id.fleet.siblings`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from motor_id.fleet.drift import DriftFinding, DriftRule, series
from motor_id.fleet.rows import EstimateRow
from motor_id.fleet.siblings import compare_siblings, SiblingFinding
from motor_id.model import PARAM_NAMES, PARAM_UNITS

UNITS = PARAM_UNITS

Point = tuple[Any, float, 'float | None', str]
"""One estimate of a history: (start_time, value, std, recording)."""


@dataclass(frozen=True)
class DriftRow:
    """One robot, motor and parameter: its drift finding (a row of drift.json).

    Attributes
    ----------
    robot, motor, parameter : str
    group : str
        The siblings' key (the profile's ``type:``, else the motor's name).
    unit : str
    finding : DriftFinding
    outliers : tuple of str
        Start times of the estimates left out as gross errors.
    """

    robot: str
    motor: str
    parameter: str
    group: str
    unit: str
    finding: DriftFinding
    outliers: tuple[str, ...] = ()

    @property
    def detected(self) -> bool:
        """A change was found."""
        return self.finding.detected

    @property
    def change(self) -> float | None:
        """Relative change of the latest regime (:attr:`DriftFinding.change`)."""
        return self.finding.change

    @property
    def since(self) -> str | None:
        """Date (YYYY-MM-DD) of the first recording after the last change."""
        return self.finding.since[:10] if self.finding.since else None

    @property
    def z(self) -> float | None:
        """The change in day-to-day scatters."""
        return self.finding.z

    def to_dict(self) -> dict[str, Any]:
        """The drift.json row: ``robot, motor, parameter, group, unit`` and the
        finding's fields (``since`` as a date, ``outliers`` as start times)."""
        d = {'robot': self.robot, 'motor': self.motor, 'parameter': self.parameter,
             'group': self.group, 'unit': self.unit, **self.finding.to_dict()}
        d['since'] = self.since
        d['outliers'] = list(self.outliers)
        return d


@dataclass(frozen=True)
class SiblingRow:
    """One robot, motor and parameter against its siblings (a row of siblings.json)."""

    robot: str
    motor: str
    parameter: str
    group: str
    unit: str
    finding: SiblingFinding

    @property
    def outlier(self) -> bool:
        """Outside the siblings' spread by more than the error bars allow."""
        return self.finding.outlier

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``robot, motor, parameter, group, unit`` and the finding."""
        return {'robot': self.robot, 'motor': self.motor, 'parameter': self.parameter,
                'group': self.group, 'unit': self.unit, **self.finding.to_dict()}


@dataclass(frozen=True)
class FleetFindings:
    """Drift over time and the sibling comparison of every robot, motor and parameter."""

    drift: tuple[DriftRow, ...]
    siblings: tuple[SiblingRow, ...]

    def drifting(self) -> list[DriftRow]:
        """The drift rows that found a change."""
        return [d for d in self.drift if d.detected]

    def odd(self) -> list[SiblingRow]:
        """The motors outside their siblings' spread."""
        return [s for s in self.siblings if s.outlier]


def histories(rows: Iterable[EstimateRow], parameters: Sequence[str] = PARAM_NAMES
              ) -> dict[tuple[str, str], dict[str, list[Point]]]:
    """``{(robot, motor): {parameter: [(start_time, value, std, recording), ...]}}`` in
    time order, from result rows (adequate fits, determined parameters)."""
    out: dict[tuple[str, str], dict[str, list[Point]]] = {}
    for r in sorted(rows, key=lambda r: (r.start_time or '', r.recording)):
        per = out.setdefault((r.robot, r.motor), {p: [] for p in parameters})
        if r.adequate is False:
            continue
        for p in parameters:
            x = r.parameter(p)
            if x.value is None or x.determined is False:
                continue
            per[p].append((r.start_time, x.value, x.std, r.recording))
    return out


def fleet_findings(rows: Iterable[EstimateRow], rule: DriftRule | None = None,
                   groups: Mapping[str, str] | None = None,
                   parameters: Sequence[str] = PARAM_NAMES) -> FleetFindings:
    """Drift and sibling findings of result rows.

    Parameters
    ----------
    rows : iterable of EstimateRow
    rule : DriftRule, optional
    groups : mapping, optional
        Motor name -> siblings' key (the profile's ``type:``); a motor not in it is its
        own key (the same name on every robot).
    parameters : sequence of str

    Returns
    -------
    FleetFindings
        Drift rows drifting first (largest |z| first), sibling rows outliers first
        (largest |score| first), then by robot, motor, parameter.
    """
    rule = rule or DriftRule()
    hist = histories(rows, parameters)
    keys = sorted(hist)
    group_of = {k: (groups or {}).get(k[1], k[1]) for k in keys}
    drift: list[DriftRow] = []
    siblings: list[SiblingRow] = []
    for p in parameters:
        unit = UNITS.get(p, '')
        prepared = {k: series([t for t, _, _, _ in hist[k][p]], [v for _, v, _, _ in hist[k][p]],
                              [s for _, _, s, _ in hist[k][p]]) for k in keys}
        for g in sorted(set(group_of.values())):
            members = [k for k in keys if group_of[k] == g]
            pool = rule.pool([prepared[k] for k in members], [k[0] for k in members])
            found = {k: rule.scan_series(prepared[k], pool) for k in members}
            for k in members:
                times = [hist[k][p][i][0] for i in found[k].outliers]
                drift.append(DriftRow(k[0], k[1], p, g, unit, found[k], tuple(times)))
            levels = [(found[k].level, found[k].level_std) for k in members]
            for k, s in zip(members, compare_siblings(levels, rule.sibling_threshold),
                            strict=True):
                siblings.append(SiblingRow(k[0], k[1], p, g, unit, s))

    def order(r: DriftRow | SiblingRow) -> tuple[str, str, int]:
        return (r.robot, r.motor,
                PARAM_NAMES.index(r.parameter) if r.parameter in PARAM_NAMES else 99)
    drift.sort(key=lambda r: (not r.detected, -abs(r.z or 0.0) if r.detected else 0.0,
                              *order(r)))
    siblings.sort(key=lambda r: (not r.outlier, -abs(r.finding.score or 0.0)
                                 if r.outlier else 0.0, *order(r)))
    return FleetFindings(tuple(drift), tuple(siblings))


def drift_table(rows: Iterable[EstimateRow], rule: DriftRule | None = None,
                groups: Mapping[str, str] | None = None,
                parameters: Sequence[str] = PARAM_NAMES) -> list[DriftRow]:
    """The drift rows of :func:`fleet_findings` (one per robot, motor and parameter)."""
    return list(fleet_findings(rows, rule, groups, parameters).drift)
