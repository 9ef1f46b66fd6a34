"""The distributed engine: Dask distributed, an embedded local cluster or an existing one.

Why Dask and not Ray (docs/fleet.md has the long form): its wheels are pure Python
(nothing to build or download at run time, and it installs on every Python the project
supports); ``LocalCluster`` runs in-process so ``motor-id fleet`` works on a laptop
with nothing else started; ``as_completed`` streams results back in completion order,
which is what the progress line and the incremental result files need; and
``Client(address)`` runs the very same code on a cluster. Workers are processes with one
thread each (the fit is numpy/numba work under the GIL), so N workers use N cores.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
import logging
import os
from types import ModuleType
from typing import Any, TypeVar

from motor_id.errors import ConfigError

T = TypeVar('T')
R = TypeVar('R')

WORKER_CONFIG = {'distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_': None,
                 'distributed.worker.profile.enabled': False}
"""Dask settings of the embedded cluster's workers (set the same on a cluster's,
docs/fleet.md). Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also fixes
glibc's mmap threshold: every large numpy array is then mapped and unmapped anew and a
fit takes 2.3x as long (0.30 s instead of 0.13 s); it is left unset. The statistical
profiler (a sample every 10 ms) keeps an hour of call trees: a worker grew 45 MiB over
1,000 fits with it and 1.6 MiB over 400 without."""


def _distributed() -> ModuleType:
    try:
        import distributed
    except ImportError:
        raise ConfigError('motor-id fleet runs on Dask distributed: pip install '
                          '"motor_id[fleet]" (dask[distributed], pyarrow)') from None
    return distributed


class DaskEngine:
    """Run tasks on Dask and hand back each result as it completes.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the embedded cluster (default: the machine's cores).
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``); then ``workers`` is not
        used and the cluster's workers must have motor_id installed.
    in_flight : int, optional
        Tasks submitted ahead of the results (default 4 per worker thread): the
        scheduler holds a bounded window, never the whole fleet.

    Use as a context manager; :meth:`map` yields ``(item, result, error)``.
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 in_flight: int | None = None) -> None:
        if workers is not None and (isinstance(workers, bool) or int(workers) < 1):
            raise ConfigError(f'workers must be >= 1, got {workers}', params=('workers',))
        self.workers = workers
        self.scheduler = scheduler
        self.in_flight = in_flight
        self.client: Any = None
        self.cluster: Any = None

    def __enter__(self) -> DaskEngine:
        dist = _distributed()
        if self.scheduler:
            try:
                self.client = dist.Client(self.scheduler, timeout='20s')
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f'scheduler {self.scheduler}: cannot connect ({exc})',
                                  params=('scheduler',)) from None
        else:
            import dask
            n = int(self.workers or os.cpu_count() or 1)
            with dask.config.set(WORKER_CONFIG):
                self.cluster = dist.LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, host='127.0.0.1',
                    dashboard_address='127.0.0.1:0', silence_logs=logging.ERROR)
            self.client = dist.Client(self.cluster)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    @property
    def threads(self) -> int:
        """Worker threads the scheduler knows now."""
        info = self.client.scheduler_info()
        return sum(w.get('nthreads', 1) for w in info.get('workers', {}).values()) or 1

    def map(self, fn: Callable[[T], R], items: Iterable[T]
            ) -> Iterator[tuple[T, R | None, str | None]]:
        """Run ``fn(item)`` for every item on the workers.

        Yields
        ------
        (item, result, error)
            ``result`` is ``fn(item)`` (None when the engine failed); ``error`` is None,
            or the text of an exception the engine raised for the task (a worker that
            died, a task that could not be shipped).
        """
        dist = _distributed()
        items = iter(items)
        window = self.in_flight or 4 * self.threads
        pending: dict[Any, T] = {}
        done = dist.as_completed()

        def submit() -> bool:
            for item in items:
                fut = self.client.submit(fn, item, pure=False)
                pending[fut.key] = item
                done.add(fut)
                return True
            return False
        for _ in range(window):
            if not submit():
                break
        for fut in done:
            item = pending.pop(fut.key)
            result: R | None = None
            error: str | None = None
            try:
                result = fut.result()
            except Exception as exc:   # noqa: BLE001  the engine's failure of one task
                error = f'{type(exc).__name__}: {exc}'
            fut.release()
            submit()
            yield item, result, error

    def worker_memory(self) -> dict[str, int]:
        """``{worker address: resident memory [bytes]}`` of every worker process."""
        memory: dict[str, int] = self.client.run(_rss)
        return memory


def _rss() -> int:
    """Resident memory of this process [bytes] (Linux /proc, else the peak)."""
    try:
        with open('/proc/self/statm') as fh:
            return int(fh.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')
    except OSError:
        import resource
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
