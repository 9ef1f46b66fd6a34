"""The fleet's results on disk: estimates.parquet and .csv (one row per recording and motor)
and failed.json, rewritten atomically as results arrive; read back to skip finished work.

A (recording, motor) is finished when a row (or a failure of the data or the fit) has the
same recording key (path, size, mtime) and the same settings hash; failures of the
engine (a worker that died) are always tried again.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import csv
import datetime as dt
import json
import os
from pathlib import Path
import time
from types import ModuleType
from typing import Any, TYPE_CHECKING

from motor_id.errors import ConfigError
from motor_id.fleet.rows import COLUMNS, EstimateRow, TaskFailure, TaskResult

if TYPE_CHECKING:
    from motor_id.fleet.task import Task

_INT = {'size', 'mtime_ns', 'samples'}
_BOOL = {c for c in COLUMNS if c.endswith('_determined')} | {'adequate', 'unexplained'}
_STR = {'robot', 'motor', 'recording', 'settings', 'warnings', 'verdict', 'worker'}


def _pa() -> ModuleType:
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise ConfigError('motor-id fleet writes Parquet with pyarrow: pip install '
                          '"motor_id[fleet]" (dask[distributed], pyarrow)') from None
    module: ModuleType = pyarrow   # pyarrow has no type information: Any to mypy
    return module


def schema() -> Any:
    """The Parquet schema of the estimates."""
    pa = _pa()
    fields = []
    for c in COLUMNS:
        if c == 'start_time':
            t = pa.timestamp('ms', tz='UTC')
        elif c in _INT:
            t = pa.int64()
        elif c in _BOOL:
            t = pa.bool_()
        elif c in _STR:
            t = pa.string()
        else:
            t = pa.float64()
        fields.append(pa.field(c, t))
    return pa.schema(fields)


def _parse_time(text: str) -> dt.datetime:
    return dt.datetime.fromisoformat(text.replace('Z', '+00:00'))


def _iso(t: dt.datetime | str | None) -> str | None:
    if t is None or isinstance(t, str):
        return t
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    return t.astimezone(dt.timezone.utc).isoformat(timespec='milliseconds').replace(
        '+00:00', 'Z')


class ResultStore:
    """Rows and failures of a fleet run in ``out_dir``, with what was there before.

    Parameters
    ----------
    out_dir : str or Path
        Created if missing.
    flush_every : float
        Smallest time between two rewrites of the files while results arrive [s].
    """

    def __init__(self, out_dir: str | Path, flush_every: float = 2.0) -> None:
        self.out = Path(out_dir)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f'out_dir {out_dir}: cannot create ({exc.strerror})',
                              params=('out_dir',)) from None
        self.flush_every = flush_every
        self.rows: dict[tuple[str, str], EstimateRow] = {}
        self.failures: dict[tuple[str, str], TaskFailure] = {}
        self._dirty = False
        self._flushed = time.monotonic()
        self._load()

    @property
    def parquet_path(self) -> Path:
        return self.out / 'estimates.parquet'

    @property
    def csv_path(self) -> Path:
        return self.out / 'estimates.csv'

    @property
    def failed_path(self) -> Path:
        return self.out / 'failed.json'

    def _load(self) -> None:
        if self.parquet_path.exists():
            import pyarrow.parquet as pq
            _pa()
            try:
                table = pq.read_table(self.parquet_path)
            except (OSError, ValueError) as exc:
                raise ConfigError(f'{self.parquet_path}: unreadable ({exc}); move it away '
                                  'to start afresh') from None
            for cols in table.to_pylist():
                cols['start_time'] = _iso(cols.get('start_time'))
                r = EstimateRow.from_dict(cols)
                self.rows[(r.recording, r.motor)] = r
        if self.failed_path.exists():
            try:
                with open(self.failed_path, encoding='utf-8') as fh:
                    for d in json.load(fh):
                        f = TaskFailure.from_dict(d)
                        self.failures[(f.recording, f.motor)] = f
            except (OSError, ValueError, KeyError, TypeError) as exc:
                raise ConfigError(f'{self.failed_path}: unreadable ({exc})') from None

    def is_done(self, task: Task, retry_failed: bool = False) -> bool:
        """True when ``task`` has a result (or a data/fit failure) for the same key."""
        def same(r: TaskResult | None) -> bool:
            return (r is not None and r.size == task.size and
                    r.mtime_ns == task.mtime_ns and r.settings == task.settings)
        if same(self.rows.get(task.ident)):
            return True
        f = self.failures.get(task.ident)
        return f is not None and same(f) and not retry_failed and f.stage != 'engine'

    def add(self, result: TaskResult) -> None:
        """Keep one task's result row or failure; rewrite the files when due."""
        ident = (result.recording, result.motor)
        if isinstance(result, EstimateRow):
            self.rows[ident] = result
            self.failures.pop(ident, None)
        else:
            self.failures[ident] = result
            self.rows.pop(ident, None)
        self._dirty = True
        if time.monotonic() - self._flushed >= self.flush_every:
            self.flush()

    def sorted_rows(self) -> list[EstimateRow]:
        """The rows by robot, motor, start time."""
        return sorted(self.rows.values(), key=lambda r: (r.robot, r.motor,
                                                         r.start_time or '', r.recording))

    def sorted_failures(self) -> list[TaskFailure]:
        """The failures by robot, motor, recording."""
        return sorted(self.failures.values(), key=lambda f: (f.robot, f.motor, f.recording))

    def flush(self, force: bool = False) -> None:
        """Rewrite estimates.parquet, estimates.csv and failed.json (atomic replaces)."""
        if not (self._dirty or force):
            return
        rows = [r.to_dict() for r in self.sorted_rows()]
        self._write_parquet(rows)
        self._write_csv(rows)
        failures = [f.to_dict() for f in self.sorted_failures()]
        _atomic_text(self.failed_path, json.dumps(failures, indent=1))
        self._dirty = False
        self._flushed = time.monotonic()

    def _write_parquet(self, rows: Sequence[Mapping[str, object]]) -> None:
        pa = _pa()
        import pyarrow.parquet as pq
        cols = {c: [r.get(c) for r in rows] for c in COLUMNS}
        cols['start_time'] = [None if t is None else _parse_time(str(t))
                              for t in cols['start_time']]
        table = pa.Table.from_pydict(cols, schema=schema())
        tmp = self.parquet_path.with_suffix('.parquet.tmp')
        pq.write_table(table, tmp)
        os.replace(tmp, self.parquet_path)

    def _write_csv(self, rows: Sequence[Mapping[str, object]]) -> None:
        tmp = self.csv_path.with_suffix('.csv.tmp')
        with open(tmp, 'w', newline='', encoding='utf-8') as fh:
            w = csv.writer(fh)
            w.writerow(COLUMNS)
            for r in rows:
                w.writerow([_cell(r.get(c)) for c in COLUMNS])
        os.replace(tmp, self.csv_path)


def _cell(v: object) -> object:
    if v is None:
        return ''
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return repr(v)
    return v


def _atomic_text(path: str | os.PathLike[str], text: str) -> None:
    tmp = Path(str(path) + '.tmp')
    with open(tmp, 'w', encoding='utf-8') as fh:
        fh.write(text)
    os.replace(tmp, path)
