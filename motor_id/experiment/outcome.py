"""From the experiment's recording to ``report.json`` and the exit code.

The recording is analysed as ``motor-id analyze`` does (:class:`DiscrepancyAnalysis`);
``report.json`` is its report with the data block and ``controller.feedforward`` constants
carrying their units. A voltage plant measured without current cannot tell the armature
resistance: without ``-R`` the analysis runs on the internal one of speed-only records
(:data:`~motor_id.identify.space.SPEED_ONLY_R_M`), which the feedforward constants do not
depend on, and the report says so.
"""

from __future__ import annotations

from collections.abc import Callable
import contextlib
from dataclasses import dataclass, replace
from pathlib import Path
import signal
import sys
from typing import Any

from motor_id.analysis import DiscrepancyAnalysis, DiscrepancyReport
from motor_id.analysis.feedforward import FeedforwardConstant
from motor_id.analysis.workers import usable_cores
from motor_id.errors import MotorIdError
from motor_id.experiment.session import ExperimentSession
from motor_id.experiment.settings import ExperimentSettings
from motor_id.identify.space import SPEED_ONLY_R_M
from motor_id.lifeline import STOP_SIGNALS, stop_signals_as_interrupt
from motor_id.output import write_json
from motor_id.recording import Recording
from motor_id.records import optional, Record

EXIT_OK = 0
EXIT_CONFIG = 2
EXIT_SAFETY = 3
"""A safety rule stopped the experiment (watchdog, stale states, outside the travel)."""
EXIT_NOT_IDENTIFIED = 4
"""The plan ran, but the analysis could not determine the feedforward constants."""
EXIT_ERROR = 5
"""An unexpected error stopped the experiment (0 was commanded)."""


@dataclass(frozen=True, kw_only=True)
class DataBlock(Record):
    """The recording the report comes from: its source, samples and runs."""

    source: str | None
    samples: int
    runs: int
    run_names: list[str] | None


@dataclass(frozen=True, kw_only=True)
class ExperimentBlock(Record):
    """The joint, its mechanism and plant kind, and how R_m was set (left out of a
    failure report: ``''``)."""

    joint: str
    mechanism: str
    input_kind: str
    R_m: str | None = optional('', when=lambda value, _record: value == '')


@dataclass(frozen=True, kw_only=True)
class ExperimentReport:
    """``report.json``: the analysis of the experiment's recording with the data and the
    experiment blocks, or, without an analysis, why nothing was identified.
    The feedforward constants are the analysis' (``controller``)."""

    experiment: ExperimentBlock
    analysis: DiscrepancyReport | None = None
    data: DataBlock | None = None
    identified: bool = False
    reason: str = ''

    @property
    def feedforward(self) -> dict[str, FeedforwardConstant]:
        """The feedforward constants by name (none without a simulation-error model)."""
        block = self.analysis.controller() if self.analysis else None
        return block.feedforward if block is not None else {}

    def to_dict(self) -> dict[str, Any]:
        """The JSON of ``report.json``: the analyze report, then ``data``, ``experiment``
        and ``identified``."""
        if self.analysis is None:
            return {'identified': self.identified, 'reason': self.reason,
                    'experiment': self.experiment.to_dict()}
        out = self.analysis.to_dict()
        out['data'] = self.data.to_dict() if self.data is not None else None
        out['experiment'] = self.experiment.to_dict()
        out['identified'] = self.identified
        return out


def analyze_experiment(rec: Recording, settings: ExperimentSettings, jobs: int = 1,
                       progress: Callable[[str], object] | None = None) -> ExperimentReport:
    """The analysis report of the experiment's recording, as ``report.json`` holds it.

    Parameters
    ----------
    rec : Recording
    settings : ExperimentSettings
    jobs : int
        Processes for the candidate fits.
    progress : callable, optional

    Returns
    -------
    ExperimentReport
        The analyze report plus ``data`` (source, samples, runs), ``experiment`` (the
        joint, the mechanism, how R_m was set) and units on the feedforward constants.
    """
    nominal = settings.input_kind == 'voltage' and settings.resistance is None
    R = SPEED_ONLY_R_M if nominal else settings.resistance
    ana = DiscrepancyAnalysis(R_m=R, random_state=settings.seed, jobs=jobs,
                             mechanism=settings.mechanism)
    ana.fit(rec, progress=progress)
    report = ana.report_
    data = DataBlock(source=rec.meta.get('source'), samples=len(rec),
                     runs=len(rec.segment_ranges), run_names=rec.meta.get('segment_names'))
    experiment = ExperimentBlock(
        joint=settings.joint, mechanism=settings.mechanism, input_kind=settings.input_kind,
        R_m=(f'nominal {SPEED_ONLY_R_M:g} Ohm: speed alone cannot tell the armature '
             'resistance; kS, kV, kA do not depend on it') if nominal else
        (f'{R:g} Ohm as given' if R is not None else None))
    return ExperimentReport(experiment=experiment, analysis=report, data=data)


def identified(report: ExperimentReport) -> bool:
    """The report determines kS, kV and kA."""
    ff = report.feedforward
    return all(k in ff and ff[k].value is not None for k in ('kS', 'kV', 'kA'))


def write_report(report: ExperimentReport, out: str | Path) -> Path:
    """Write ``report.json`` into ``out``; return its path."""
    path = Path(out) / 'report.json'
    write_json(report.to_dict(), path)
    return path


def feedforward_line(report: ExperimentReport) -> str:
    """``kS 0.21 +- 0.01 V, kV ...``: the constants in one line (or why there are none)."""
    ff = report.feedforward
    if not ff:
        sim = report.analysis.simulation if report.analysis else None
        return ('no feedforward constants (the analysis found no simulation-error model'
                + (f': {sim.failed})' if sim is not None and sim.failed else ')'))
    parts = []
    for name, e in ff.items():
        if e.value is None:
            parts.append(f'{name} not determined')
        elif e.std is None:   # a constant the model holds (no Coulomb friction: kS 0)
            parts.append(f'{name} {e.value:.4g} {e.unit or ""} ({e.note or "no error bar"})'
                         .replace('  (', ' ('))
        else:
            parts.append(f'{name} {e.value:.4g} +- {e.std:.2g} {e.unit or ""}'.rstrip())
    return ', '.join(parts)


def failure_report(reason: str, settings: ExperimentSettings) -> ExperimentReport:
    """``report.json`` when nothing could be identified: why."""
    return ExperimentReport(reason=reason, experiment=ExperimentBlock(
        joint=settings.joint, mechanism=settings.mechanism, input_kind=settings.input_kind))


def try_analyze(rec: Recording | None, settings: ExperimentSettings, jobs: int = 1,
                progress: Callable[[str], object] | None = None) -> ExperimentReport:
    """:func:`analyze_experiment`, or a :func:`failure_report` naming why it could not run."""
    if rec is None:
        return failure_report('too few samples were recorded to identify anything',
                              settings)
    try:
        report = analyze_experiment(rec, settings, jobs, progress)
    except MotorIdError as exc:
        return failure_report(f'the analysis failed: {exc}', settings)
    return replace(report, identified=identified(report))


def finish(session: ExperimentSession, failure: str | None, signum: int | None,
           errored: bool = False, jobs: int | None = None,
           say: Callable[[str], object] | None = None) -> int:
    """After the motion: finish the recording and ``experiment.json``, identify, write
    ``report.json``; return the exit code.

    Parameters
    ----------
    session : ExperimentSession
    failure : str or None
        Why the experiment never started (no state, no controller joints).
    signum : int or None
        The signal that ended it: the outputs are written, the analysis skipped.
    errored : bool
        An exception ended it.
    jobs : int, optional
        Processes for the analysis (default: every usable core).
    say : callable, optional
        Where progress lines go (default: stderr).

    Returns
    -------
    int
        :data:`EXIT_OK`, :data:`EXIT_CONFIG`, :data:`EXIT_SAFETY`,
        :data:`EXIT_NOT_IDENTIFIED`, :data:`EXIT_ERROR`, or 128 + the signal number.
    """
    say = say or (lambda text: print(text, file=sys.stderr, flush=True))
    stopping: contextlib.AbstractContextManager[None]
    if signum is None:
        # from here on a stop signal interrupts the analysis (its workers are stopped)
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        stopping = stop_signals_as_interrupt(STOP_SIGNALS)
    else:
        # a signal ended it (no analysis): its repeats, the parent-death signal once per
        # thread of a dying parent, must not cut the outputs short; the signal thread
        # still ends the process on a second Ctrl-C or at its deadline
        stopping = contextlib.nullcontext()
    try:
        with stopping:
            return _finish(session, failure, signum, errored, jobs, say)
    except OSError as exc:   # the outputs cannot be written (a full disk)
        say(f'experiment: cannot write the outputs in {session.out}: {exc}')
        return EXIT_ERROR
    except KeyboardInterrupt as exc:
        name = exc.args[0] if exc.args and isinstance(exc.args[0], str) else 'SIGINT'
        say('experiment: interrupted')
        return 128 + int(signal.Signals[name])


def _finish(session: ExperimentSession, failure: str | None, signum: int | None,
            errored: bool, jobs: int | None, say: Callable[[str], object]) -> int:
    rec = session.close()
    log = session.guard.log
    say(f'experiment: {log.stop_reason}; tests: ' + ', '.join(
        f'{t.name} ({t.end_reason})' for t in log.tests) + f'; wrote {session.out}')
    stats = session.guard.stats
    if stats.late:
        say(f'experiment: {stats.late} states arrived late, up to {stats.latest:.2f} s (a '
            'busy machine or network); each is recorded at its stamp, under the command '
            'sent before it')
    if signum is not None:
        return 128 + signum
    if failure is not None:
        write_report(failure_report(failure, session.settings), session.out)
        return EXIT_CONFIG
    if not session.settings.identify:
        return EXIT_ERROR if errored else EXIT_SAFETY if log.safety_stop else EXIT_OK
    report = try_analyze(rec, session.settings, jobs or usable_cores(), say)
    write_report(report, session.out)
    if report.identified:
        say('feedforward: ' + feedforward_line(report))
    else:
        say(f'not identified: {report.reason or feedforward_line(report)}')
    if errored:
        return EXIT_ERROR
    if log.safety_stop:
        return EXIT_SAFETY
    return EXIT_OK if report.identified else EXIT_NOT_IDENTIFIED
