"""One task of a fleet run: read one motor of one recording on the worker, fit, keep numbers.

:func:`run_task` is what the engine ships to a worker: it gets a path (never the bag's
bytes), reads the recording there, fits it (and with ``analyze`` runs the discrepancy
analysis), and returns one flat row of numbers; the samples are dropped with the task.
It never raises: a failure comes back as a row with ``status: failed``, the stage
(``read``, ``fit``, ``analyze``) and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import datetime as dt
import os
import socket
import time
import traceback
from typing import SupportsFloat, TYPE_CHECKING

from motor_id.errors import MotorIdError
from motor_id.fleet.config import FleetFit, MotorSpec
from motor_id.fleet.rows import EstimateRow, ParameterValue, TaskFailure, TaskResult
from motor_id.model import PARAM_NAMES

if TYPE_CHECKING:
    from motor_id.identify import FitSettings
    from motor_id.recording import Recording


@dataclass(frozen=True)
class Task:
    """What a worker needs for one (recording, motor)."""

    path: str
    robot: str
    size: int
    mtime_ns: int
    motor: MotorSpec
    fit: FleetFit
    analyze: bool
    settings: str

    @property
    def ident(self) -> tuple[str, str]:
        """``(recording, motor)``: the row this task fills."""
        return (self.path, self.motor.name)


def run_task(task: Task) -> TaskResult:
    """Read, fit and (optionally) analyse one motor of one recording.

    Parameters
    ----------
    task : Task

    Returns
    -------
    EstimateRow or TaskFailure
        The row of estimates, or the stage that failed (``read``, ``fit``, ``analyze``)
        and the reason.
    """
    started = time.perf_counter()
    source = EstimateRow(robot=task.robot, motor=task.motor.name, recording=task.path,
                         size=task.size, mtime_ns=task.mtime_ns, settings=task.settings,
                         worker=f'{socket.gethostname()}:{os.getpid()}')
    stage = 'read'
    try:
        rec = read_motor(task)
        stage = 'fit'
        row = fit_row(rec, task, source)
        if task.analyze:
            stage = 'analyze'
            verdict, unexplained = analysis_verdict(rec, task)
            row = replace(row, verdict=verdict, unexplained=unexplained)
    except MotorIdError as exc:
        return _failed(source, stage, str(exc), started)
    except Exception as exc:   # noqa: BLE001  a task's failure is data: kept with its reason
        where = traceback.extract_tb(exc.__traceback__)[-1:]
        at = f' at {os.path.basename(where[0].filename)}:{where[0].lineno}' if where else ''
        return _failed(source, stage, f'{type(exc).__name__}: {exc}{at}', started)
    return replace(row, seconds=time.perf_counter() - started)


def _failed(source: EstimateRow, stage: str, reason: str, started: float) -> TaskFailure:
    return TaskFailure(robot=source.robot, motor=source.motor, recording=source.recording,
                       size=source.size, mtime_ns=source.mtime_ns, settings=source.settings,
                       stage=stage, reason=reason, worker=source.worker,
                       seconds=time.perf_counter() - started)


def read_motor(task: Task) -> Recording:
    """The motor's recording, read by the bag mapping, shifted and validated."""
    from motor_id.data.load import load_recording
    from motor_id.data.shift import shift_input
    m = task.motor
    rec = load_recording(task.path, mapping=m.mapping())
    if m.shift:
        rec = shift_input(rec, m.shift)
    rec.validate()
    return rec


def _start_time(rec: Recording, task: Task) -> str:
    ns = rec.meta.get('time_origin_ns')
    if ns is None:
        ns = task.mtime_ns
    return dt.datetime.fromtimestamp(ns / 1e9, dt.timezone.utc).isoformat(
        timespec='milliseconds').replace('+00:00', 'Z')


def fit_settings(task: Task, rec: Recording) -> FitSettings:
    """The task's :class:`~motor_id.identify.FitSettings`; R_m checked for ``rec``."""
    settings = task.fit.settings(task.motor)
    try:
        settings.check_resistance(rec.input_kind, rec.has_current)
    except MotorIdError as exc:
        raise type(exc)(f'motor {task.motor.name}: {exc} (the motor\'s "resistance" in the '
                        'fleet configuration)', params=exc.params) from None
    return settings


def fit_row(rec: Recording, task: Task, source: EstimateRow) -> EstimateRow:
    """The numbers a fit leaves: every parameter's value, std and determined flag, fit %,
    adequacy and warnings, added to ``source`` (the row's robot, motor, recording, ...)."""
    from motor_id.identify import Identifier
    result = Identifier(fit_settings(task, rec)).fit(rec).result_
    params = {}
    for name in PARAM_NAMES:
        p = result.parameters.get(name)
        params[name] = ParameterValue(determined=False) if p is None else ParameterValue(
            value=_num(p.value), std=_num(p.std),
            determined=bool(p.determined))
    channels = result.fit.channels
    fit = {ch: _num(channels[ch].fit_percent) if ch in channels else None
           for ch in ('speed', 'current')}
    return replace(source, start_time=_start_time(rec, task), samples=len(rec),
                   duration_s=float(rec.time[-1] - rec.time[0]), parameters=params,
                   fit_speed=fit['speed'], fit_current=fit['current'],
                   adequate=bool(result.adequate),
                   warnings='; '.join(str(w) for w in result.warnings or []))


def analysis_verdict(rec: Recording, task: Task) -> tuple[str, bool]:
    """The discrepancy analysis's verdict and whether it left the data unexplained."""
    from motor_id.analysis import DiscrepancyAnalysis
    m = task.motor
    ana = DiscrepancyAnalysis(R_m=m.resistance, random_state=task.fit.seed,
                              R_m_tolerance=m.resistance_tolerance / 100.0)
    rep = ana.fit(rec).report_
    return str(rep.verdict), bool(rep.unexplained)


def _num(v: SupportsFloat | None) -> float | None:
    return None if v is None else float(v)
