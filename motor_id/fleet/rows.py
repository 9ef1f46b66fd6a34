"""What one task of a fleet run leaves: a row of estimates, or the reason it failed.

A row is one (recording, motor): where it came from, each parameter's value, standard
error and determined flag, the fit's quality and the analysis's verdict. It is a frozen
record inside; :meth:`EstimateRow.to_dict` gives the flat columns of estimates.parquet
and estimates.csv (:data:`COLUMNS`) and :meth:`EstimateRow.from_dict` reads them back.
A failure is a :class:`TaskFailure` (failed.json).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from motor_id.model import PARAM_NAMES
from motor_id.records import Record

ID_COLUMNS = ('robot', 'motor', 'recording', 'start_time')
SOURCE_COLUMNS = ('size', 'mtime_ns', 'settings', 'samples', 'duration_s')
PARAMETER_COLUMNS = tuple(c for p in PARAM_NAMES for c in (p, f'{p}_std', f'{p}_determined'))
QUALITY_COLUMNS = ('fit_speed', 'fit_current', 'adequate', 'warnings', 'verdict',
                   'unexplained', 'seconds', 'worker')
COLUMNS = ID_COLUMNS + SOURCE_COLUMNS + PARAMETER_COLUMNS + QUALITY_COLUMNS
"""Columns of estimates.parquet / estimates.csv, in order."""


@dataclass(frozen=True)
class ParameterValue(Record):
    """One parameter of one row: its value, standard error and determined flag (None:
    not known)."""

    value: float | None = None
    std: float | None = None
    determined: bool | None = None


@dataclass(frozen=True)
class EstimateRow:
    """The estimates of one motor in one recording (a row of estimates.parquet).

    Attributes
    ----------
    robot, motor, recording : str
    start_time : str or None
        The recording's first sample (ISO 8601, UTC).
    size, mtime_ns : int or None
        The recording's size and modification time (its key, with ``settings``).
    settings : str or None
        Hash of the motor's profile entry and the fit settings.
    samples : int or None
    duration_s : float or None
    parameters : mapping of str to ParameterValue
        By name (:data:`motor_id.model.PARAM_NAMES`).
    fit_speed, fit_current : float or None
        Fit % of each channel.
    adequate : bool or None
    warnings : str or None
        The fit's warnings, joined by '; '.
    verdict : str or None
        The discrepancy analysis's verdict (``--analyze``).
    unexplained : bool or None
    seconds : float or None
        The task's time on its worker.
    worker : str or None
        ``host:pid``.
    """

    robot: str
    motor: str
    recording: str
    start_time: str | None = None
    size: int | None = None
    mtime_ns: int | None = None
    settings: str | None = None
    samples: int | None = None
    duration_s: float | None = None
    parameters: Mapping[str, ParameterValue] = field(default_factory=dict)
    fit_speed: float | None = None
    fit_current: float | None = None
    adequate: bool | None = None
    warnings: str | None = None
    verdict: str | None = None
    unexplained: bool | None = None
    seconds: float | None = None
    worker: str | None = None

    def parameter(self, name: str) -> ParameterValue:
        """The parameter ``name`` (all None when the row has none)."""
        return self.parameters.get(name) or ParameterValue()

    def to_dict(self) -> dict[str, Any]:
        """The flat columns (:data:`COLUMNS`), for Parquet and CSV."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != 'parameters'}
        for name in PARAM_NAMES:
            p = self.parameter(name)
            out.update({name: p.value, f'{name}_std': p.std, f'{name}_determined': p.determined})
        return {c: out[c] for c in COLUMNS}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> EstimateRow:
        """A row from its flat columns (missing ones None)."""
        params = {name: ParameterValue(value=_opt(d.get(name), float),
                                       std=_opt(d.get(f'{name}_std'), float),
                                       determined=_opt(d.get(f'{name}_determined'), bool))
                  for name in PARAM_NAMES}
        return cls(robot=str(d['robot']), motor=str(d['motor']),
                   recording=str(d['recording']),
                   start_time=_opt(d.get('start_time'), str),
                   size=_opt(d.get('size'), int), mtime_ns=_opt(d.get('mtime_ns'), int),
                   settings=_opt(d.get('settings'), str),
                   samples=_opt(d.get('samples'), int),
                   duration_s=_opt(d.get('duration_s'), float), parameters=params,
                   fit_speed=_opt(d.get('fit_speed'), float),
                   fit_current=_opt(d.get('fit_current'), float),
                   adequate=_opt(d.get('adequate'), bool),
                   warnings=_opt(d.get('warnings'), str), verdict=_opt(d.get('verdict'), str),
                   unexplained=_opt(d.get('unexplained'), bool),
                   seconds=_opt(d.get('seconds'), float), worker=_opt(d.get('worker'), str))


@dataclass(frozen=True)
class TaskFailure(Record):
    """A task that left no row (a row of failed.json).

    Attributes
    ----------
    robot, motor, recording : str
    size, mtime_ns : int or None
    settings : str or None
    stage : str
        ``read``, ``fit``, ``analyze`` or ``engine`` (a worker lost).
    reason : str
        The one-line error.
    worker : str or None
    seconds : float or None
    """

    robot: str
    motor: str
    recording: str
    size: int | None = None
    mtime_ns: int | None = None
    settings: str | None = None
    stage: str = ''
    reason: str = ''
    worker: str | None = None
    seconds: float | None = None


TaskResult = EstimateRow | TaskFailure
"""What a task returns."""


def _opt(v: object, kind: type[Any]) -> Any:
    """``v`` as ``kind`` (None stays None; numpy scalars become Python's)."""
    return None if v is None else kind(v)
