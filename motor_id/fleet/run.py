"""A fleet run from recordings to estimates, drift.json, siblings.json and report.html: the
one path."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import json
import time

from motor_id.fleet.config import FleetConfig
from motor_id.fleet.discover import find_recordings, RecordingRef
from motor_id.fleet.engine import DaskEngine
from motor_id.fleet.history import DriftRow, fleet_findings, SiblingRow
from motor_id.fleet.rows import EstimateRow, TaskFailure, TaskResult
from motor_id.fleet.store import ResultStore
from motor_id.fleet.task import run_task, Task

Progress = Callable[[int, int, int, 'TaskResult | None'], None]
"""``progress(done, failed, left, result)`` after each task (result None at the start)."""


@dataclass
class FleetRun:
    """What a run did: counts, the time it took, the findings, the files written."""

    tasks: int = 0
    skipped: int = 0
    done: int = 0
    failed: int = 0
    seconds: float = 0.0
    drift: tuple[DriftRow, ...] = ()
    siblings: tuple[SiblingRow, ...] = ()
    files: dict[str, str] = field(default_factory=dict)

    def drifting(self) -> list[DriftRow]:
        """The drift rows that flagged a change."""
        return [d for d in self.drift if d.detected]

    def odd(self) -> list[SiblingRow]:
        """The motors outside their siblings' spread."""
        return [s for s in self.siblings if s.outlier]


def plan(recordings: Sequence[RecordingRef], config: FleetConfig,
         analyze: bool = False) -> list[Task]:
    """One :class:`Task` per recording and motor of the config."""
    return [Task(path=r.path, robot=r.robot, size=r.size, mtime_ns=r.mtime_ns, motor=m,
                 fit=config.fit, analyze=analyze, settings=config.settings_hash(m, analyze))
            for r in recordings for m in config.motors]


def run_fleet(paths: Sequence[str], config: FleetConfig, out_dir: str,
              workers: int | None = None, scheduler: str | None = None,
              analyze: bool = False, robot_from: str = 'parent', retry_failed: bool = False,
              progress: Progress | None = None, engine: DaskEngine | None = None,
              report: bool = True) -> FleetRun:
    """Fit every motor of every new recording on the engine; write the results.

    Parameters
    ----------
    paths : sequence of str
        Files, folders, globs (:func:`motor_id.fleet.discover.find_recordings`); empty:
        only recompute drift and the report from ``out_dir``.
    config : motor_id.fleet.config.FleetConfig
    out_dir : str
    workers, scheduler : see :class:`motor_id.fleet.engine.DaskEngine`
    analyze : bool
        Also run the discrepancy analysis per task (its verdict goes in the row).
    robot_from : str
    retry_failed : bool
        Try again the tasks that failed on their data or fit before.
    progress : callable, optional
        ``progress(done, failed, left, result)`` after each task (result None at start).
    engine : DaskEngine, optional
        An engine already entered (benchmarks); default: one made and closed here.
    report : bool
        Write report.html.

    Returns
    -------
    FleetRun
    """
    started = time.perf_counter()
    store = ResultStore(out_dir)
    run = FleetRun()
    if paths:
        tasks = plan(find_recordings(paths, robot_from), config, analyze)
        todo = [t for t in tasks if not store.is_done(t, retry_failed)]
        run.tasks, run.skipped = len(tasks), len(tasks) - len(todo)
        if todo:
            _execute(todo, store, run, workers, scheduler, progress, engine)
    store.flush(force=True)
    found = fleet_findings(store.rows.values(), config.drift, config.groups())
    run.drift, run.siblings = found.drift, found.siblings
    run.files = {'estimates': str(store.parquet_path), 'csv': str(store.csv_path),
                 'failed': str(store.failed_path)}
    for name, rows in (('drift', found.drift), ('siblings', found.siblings)):
        path = store.out / f'{name}.json'
        with open(path, 'w', encoding='utf-8') as fh:
            json.dump([r.to_dict() for r in rows], fh, indent=1)
        run.files[name] = str(path)
    if report:
        from motor_id.fleet.report_page import write_report
        path = store.out / 'report.html'
        write_report(path, store.sorted_rows(), store.sorted_failures(), found,
                     config.drift)
        run.files['report'] = str(path)
    run.seconds = time.perf_counter() - started
    return run


def _execute(todo: list[Task], store: ResultStore, run: FleetRun, workers: int | None,
             scheduler: str | None, progress: Progress | None,
             engine: DaskEngine | None) -> None:
    if progress:
        progress(0, 0, len(todo), None)
    own = engine is None
    if engine is None:
        engine = DaskEngine(workers=workers, scheduler=scheduler).__enter__()
    try:
        left = len(todo)
        for task, got, error in engine.map(run_task, todo):
            result: TaskResult | None = got
            if result is None:
                result = TaskFailure(robot=task.robot, motor=task.motor.name,
                                     recording=task.path, size=task.size,
                                     mtime_ns=task.mtime_ns, settings=task.settings,
                                     stage='engine', reason=error or 'no result')
            store.add(result)
            left -= 1
            if isinstance(result, EstimateRow):
                run.done += 1
            else:
                run.failed += 1
            if progress:
                progress(run.done, run.failed, left, result)
    finally:
        store.flush(force=True)
        if own:
            engine.__exit__(None, None, None)
