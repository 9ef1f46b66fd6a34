"""Candidate fits on several processes: the same results as one after the other, sooner.

The candidates of one step of the search (every effect alone, the runners-up restarted
from the leader, the extensions of the chosen model) are independent fits of one
:class:`.candidates.CandidateFitter`. With ``jobs > 1`` they run on forked worker
processes that inherit the fitter (its record and split are not copied per task); each
task carries the fitter's few settings that change after the linear fit, so a worker
never fits with stale ones. Results come back in task order. Fork is used only where
the platform offers it; a caller in a multi-threaded process (a ROS node) keeps the
default of one job.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
import multiprocessing
import multiprocessing.pool
import os
import signal
from typing import Any, TYPE_CHECKING

from motor_id.effects import EFFECTS
from motor_id.lifeline import set_parent_death_signal

if TYPE_CHECKING:
    from motor_id.analysis.candidates import CandidateFitter
    from motor_id.analysis.report import ModelScore

SETTINGS = ('scales', 'extra_starts', 'physical_bounds', 'spread', 'reading')
"""The fitter's attributes that the linear fit sets; sent with every task."""

_FITTER: CandidateFitter | None = None
"""The fitter a worker process inherited when it was forked."""


@dataclass(frozen=True)
class FitTask:
    """One call of :meth:`.candidates.CandidateFitter.fit`."""

    name: str
    ref: ModelScore
    prior: ModelScore | None = None
    seed: ModelScore | None = None


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform tells)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # no sched_getaffinity (macOS, Windows)
        return os.cpu_count() or 1


class FitPool:
    """Runs :class:`FitTask` lists on ``jobs`` processes (one: in this process).

    Parameters
    ----------
    fitter : CandidateFitter
    jobs : int
        Worker processes; 1 fits in the calling process. The workers start at the
        first list of two or more tasks and stop at :meth:`close`.
    """

    def __init__(self, fitter: CandidateFitter, jobs: int = 1) -> None:
        self.fitter = fitter
        self.jobs = jobs if 'fork' in multiprocessing.get_all_start_methods() else 1
        self._pool: multiprocessing.pool.Pool | None = None

    def map(self, tasks: Sequence[FitTask]) -> Iterator[ModelScore]:
        """The fitted candidates of ``tasks``, in order, each as soon as it is done.

        The workers take the tasks largest start grid first (a three-parameter
        resonance costs several one-parameter effects): a long fit handed out last
        would leave the other workers idle at the end of the step.
        """
        if self.jobs <= 1 or len(tasks) < 2:
            for t in tasks:
                yield self.fitter.fit(t.name, t.ref, prior=t.prior, seed=t.seed)
            return
        settings = {k: getattr(self.fitter, k) for k in SETTINGS}
        yield from longest_first(self._workers(), _fit, [(settings, t) for t in tasks],
                                 [self._grid_size(t.name) for t in tasks])

    def _grid_size(self, name: str) -> int:
        """Start points of effect ``name`` on this record: how long its fit takes."""
        grid = EFFECTS[name].start_grid(self.fitter.scales)
        return int(next(iter(grid.values())).size) if grid else 0

    def _workers(self) -> multiprocessing.pool.Pool:
        global _FITTER
        if self._pool is None:
            _FITTER = self.fitter   # inherited by the workers forked from now on
            self._pool = multiprocessing.get_context('fork').Pool(self.jobs,
                                                                   initializer=_worker_start)
        return self._pool

    def close(self, abort: bool = False) -> None:
        """Stop the workers (if any were started); ``abort``: at once, mid-task (an
        exception or Ctrl-C is on its way), instead of after their last task."""
        global _FITTER
        if self._pool is not None:
            if abort:
                self._pool.terminate()
            else:
                self._pool.close()
            self._pool.join()
            self._pool = None
            _FITTER = None

    def __enter__(self) -> FitPool:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self.close(abort=exc_type is not None)


def longest_first(pool: multiprocessing.pool.Pool, fn: Callable[[Any], Any],
                  jobs: Sequence[Any], cost: Sequence[float]) -> Iterator[Any]:
    """``fn(job)`` of every job on ``pool``, handed out in order of falling ``cost`` (a
    long job handed out last would leave the other workers idle at the end), the results
    yielded in job order, each as soon as it and those before it are done."""
    pending = {k: pool.apply_async(fn, (jobs[k],))
               for k in sorted(range(len(jobs)), key=lambda k: -cost[k])}
    for k in range(len(jobs)):
        yield pending[k].get()


def _worker_start() -> None:
    """A worker leaves Ctrl-C to the caller, which stops the pool (no worker traceback);
    SIGTERM and SIGHUP (the pool's terminate, a caller that made them raise
    KeyboardInterrupt) end it at once; and it dies with its caller: a killed caller's
    workers would wait for tasks for ever."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
    set_parent_death_signal(signal.SIGKILL)   # a fit worker has nothing to clean up


def _fit(job: tuple[dict[str, Any], FitTask]) -> ModelScore:
    """A worker's task: the inherited fitter, brought up to date, fits one candidate."""
    settings, t = job
    if _FITTER is None:   # pragma: no cover - only reached in a forked worker
        raise RuntimeError('a fit worker without its fitter (not started by fork)')
    for k, v in settings.items():
        setattr(_FITTER, k, v)
    return _FITTER.fit(t.name, t.ref, prior=t.prior, seed=t.seed)
