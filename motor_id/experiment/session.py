"""One experiment's record: the guard's decisions, the samples, the bag and the run log.

The node hands every state sample to :meth:`ExperimentSession.on_state` and every
message it sends or receives, serialised, to :meth:`ExperimentSession.record_message`;
the session writes them to ``DIR/recording.mcap`` as they come (a killed process loses
at most a second of them) and, at :meth:`ExperimentSession.close`, adds the project's
``/samples`` stream, the position and ``/motor_id/meta`` (one run per test), so that
``motor-id fit|analyze|validate DIR/recording.mcap`` read it as it is, and writes
``DIR/experiment.json``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import math
from pathlib import Path
from typing import Any

import numpy as np

from motor_id.bag.writer import BagWriter, write_recording_into
from motor_id.contracts import channel_units
from motor_id.data.align import interval_mean_command
from motor_id.errors import BagError, ConfigError
from motor_id.experiment.guard import Guard, StateSample
from motor_id.experiment.plan import build_plan, Plan
from motor_id.experiment.settings import ExperimentSettings
from motor_id.experiment.speed import central_speed, SPEED_ESTIMATE, SpeedFromPosition
from motor_id.output import write_json
from motor_id.recording import MIN_SAMPLES, Recording

RECORDING = 'recording.mcap'
PINNED_WIDTH = 1e-3
"""An elevator within this fraction of its travel of where it rested sits on its
support (and within this much per sample period of rest)."""
MIN_PIECE = 20
"""Fewest samples of a run's free piece (fewer: left out)."""
REPORT = 'report.json'
EXPERIMENT = 'experiment.json'


@dataclass(frozen=True)
class Row:
    """One recorded sample: the state, the command decided on it, the run it is in."""

    t: float
    command: float
    position: float
    velocity: float
    effort: float
    run: int


class ExperimentSession:
    """The guard and the record of one experiment.

    Parameters
    ----------
    settings : ExperimentSettings
    plan : Plan, optional
        Default: :func:`motor_id.experiment.plan.build_plan` of the settings.
    """

    def __init__(self, settings: ExperimentSettings, plan: Plan | None = None) -> None:
        self.settings = settings
        self.guard = Guard(settings, plan or build_plan(
            settings.plan, settings.max_command, settings.time_scale, settings.seed))
        self.rows: list[Row] = []
        self.sent: list[tuple[float, float]] = []
        self.bag: BagWriter | None = None
        self.out = Path(settings.out)
        self._first_ns: int | None = None
        self._speed = SpeedFromPosition()
        self.write_error: str | None = None
        """Why the recording could not be written (the experiment then stops)."""
        self._t0 = 0.0
        self.speed_derived = False
        """The state gave no velocity: the speed is derived from the position."""

    def open(self, topics: Mapping[str, str] | None = None) -> None:
        """Create the output folder and start ``recording.mcap``.

        Parameters
        ----------
        topics : mapping of str to str, optional
            Topic -> message type (``'sensor_msgs/msg/JointState'``) of the messages
            that will be recorded: declared now, so that the first message of each
            costs no schema work where it arrives (the first JointState's took 0.4 s
            alone, 0.63 s with every core busy: the message type store loads).
        """
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f'{self.out}: cannot create the output folder '
                              f'({exc.strerror})') from exc
        self.bag = BagWriter(self.out / RECORDING)
        for topic, msgtype in (topics or {}).items():
            self.bag.add_topic(topic, msgtype)

    def record_message(self, topic: str, msgtype: str, data: bytes, log_time_ns: int) -> None:
        """Write one serialised (CDR) message as sent or received."""
        if self.bag is None:
            return
        if self._first_ns is None:
            self._first_ns = int(log_time_ns)
        try:
            self.bag.write_serialized(topic, msgtype, data, int(log_time_ns))
        except BagError:
            pass   # closed at the end while a late message came in
        except OSError as exc:   # a full disk, a file size limit: the caller stops
            self.write_error = (f'cannot write {self.out / RECORDING}: '
                                f'{exc.strerror or exc}')
            bag, self.bag = self.bag, None
            try:
                bag.close()
            except (OSError, BagError):
                pass

    def note_sent(self, t: float, value: float) -> None:
        """A command left at time ``t`` [s, the clock of the receive times]."""
        self.sent.append((float(t), float(value)))
        self.guard.sent.add(t, value)

    def start(self, now: float) -> float:
        """Start the plan; the first command (0)."""
        return self.guard.start(now)

    def on_state(self, s: StateSample) -> float | None:
        """The command for this sample (None: nothing to send); the sample is recorded.
        A sample without a velocity (NaN) gets the speed derived from the positions."""
        if not math.isfinite(s.velocity):
            self.speed_derived = True
            s = replace(s, velocity=self._speed.update(s.t, s.position))
        cmd = self.guard.on_state(s)
        if cmd is not None and self.guard.phase != 'idle':
            self.rows.append(Row(s.t, cmd, s.position, s.velocity, s.effort,
                                 self.guard.run_index))
        return cmd

    def recording(self) -> Recording | None:
        """The samples as a :class:`~motor_id.recording.Recording` (one run per test and
        the rest after it, less the samples pinned on a support: :meth:`pinned`), or None
        with fewer than the fit needs."""
        if len(self.rows) < MIN_SAMPLES:
            return None
        s = self.settings
        t = np.array([r.t for r in self.rows])
        effort = np.array([r.effort for r in self.rows])
        current = None
        if s.input_kind == 'voltage' and s.resistance is not None and \
                np.all(np.isfinite(effort)) and np.any(effort != 0):
            current = effort
        position = np.array([r.position for r in self.rows])
        speed = central_speed(t, position) if self.speed_derived else \
            np.array([r.velocity for r in self.rows])
        runs = np.array([r.run for r in self.rows])
        keep, pieces = free_pieces(runs, self.pinned(position, speed))
        if int(np.sum(keep)) < MIN_SAMPLES:
            return None
        names = self._run_names(int(runs.max()) + 1)
        meta: dict[str, Any] = {
            'source': str(self.out / RECORDING), 'joint': s.joint,
            'mechanism': s.mechanism, 'experiment': self.guard.plan.name,
            'units': channel_units(s.input_kind, s.linear, position=True),
            'segment_names': [names[runs[a]] for a, _ in pieces]}
        if self.speed_derived:
            meta['speed_estimate'] = SPEED_ESTIMATE
        if len(pieces) > 1:   # tests back to back: one input stream, a delay reaches back
            meta['runs_follow'] = [k > 0 and pieces[k][0] == pieces[k - 1][1]
                                   for k in range(len(pieces))]
        if not np.all(keep):
            meta['pinned_samples'] = int(np.sum(~keep))
        index = np.cumsum(keep) - 1   # row -> kept sample
        segments = [(int(index[a]), int(index[b - 1]) + 1) for a, b in pieces]
        t_kept = t[keep]
        self._t0 = float(t_kept[0])
        return Recording(t_kept - t_kept[0], self._inputs(t)[keep], speed[keep],
                         None if current is None else current[keep], s.input_kind, meta,
                         segments if len(segments) > 1 else None, position[keep])

    def pinned(self, position: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """The samples where an elevator sits on the support it rested on at the start
        (gravity holds it there: the free model would fall through it), at rest within
        the noise of the baseline. Nothing is pinned for other mechanisms."""
        g = self.guard
        travel = self.settings.travel
        if self.settings.mechanism != 'elevator' or travel is None or \
                not np.isfinite(g.rest_position):
            return np.zeros(len(position), dtype=bool)
        tol_x = max(3.0 * g.noise_position, PINNED_WIDTH * travel.width)
        tol_w = max(4.0 * g.noise_speed, PINNED_WIDTH * travel.width / g.stats.period())
        return np.asarray((np.abs(position - g.rest_position) <= tol_x) &
                          (np.abs(speed) <= tol_w), bool)

    def _inputs(self, t: np.ndarray) -> np.ndarray:
        """The input over each sample's interval: the mean of the commands over it, each
        from when it left (:func:`interval_mean_command`: a late decision counts as late,
        and a command sent a third of the way into an interval counts two thirds there),
        or, without send times, the command decided on the sample. Rounded to a whole
        interval instead, the commands of a robot whose states come 20 ms late at 50 Hz
        acted 1.03 to 1.9 samples after the sample, as the send times fell; an input
        delay of a whole sample then matches the interval means to 0.6 % of the steps."""
        decided = np.array([r.command for r in self.rows])
        if not self.sent:
            return decided
        # a robot on another clock: its stamps are offset by about the smallest lag
        lag = self.guard.stats.min_lag if self.guard.stats.other_clock else 0.0
        t_sent = np.array([ts for ts, _ in self.sent]) - lag
        values = np.array([v for _, v in self.sent])
        return interval_mean_command(t, t_sent, values)

    def _run_names(self, n: int) -> list[str]:
        names = [t.name for t in self.guard.log.tests][:n]
        return names + ['rest'] * (n - len(names))

    def close(self) -> Recording | None:
        """Finish ``recording.mcap`` (the samples, position and metadata added) and write
        ``experiment.json``; return the recording (None if too short to fit)."""
        rec = self.recording()
        if self.bag is not None:
            try:
                if rec is not None:
                    start_ns = int(round(self._t0 * 1e9)) if self._t0 > 0 \
                        else (self._first_ns or 0)
                    write_recording_into(self.bag, rec, start_ns=max(start_ns, 0))
            finally:
                self.bag.close()
        write_json(self.experiment_dict(), self.out / EXPERIMENT)
        return rec

    def experiment_dict(self) -> dict[str, Any]:
        """``experiment.json``: the settings, the plan and the run log."""
        s = self.settings
        log = self.guard.log.to_dict()
        log['timing'] = self.guard.stats.timing()
        plan = self.guard.plan
        return {
            'joint': s.joint, 'command_topic': s.command_topic,
            'command_type': s.command_type, 'state_topic': s.state_topic,
            'input_kind': s.input_kind, 'mechanism': s.mechanism,
            'max_command': s.max_command,
            'travel': None if s.travel is None else [s.travel.low, s.travel.high],
            'max_speed': s.max_speed, 'watchdog': s.watchdog,
            'plan': {'name': plan.name, 'rest_min': plan.rest_min, 'rest_max': plan.rest_max,
                     'tests': [{'name': t.name, 'kind': t.kind, 'direction': t.direction,
                                'amplitude': t.amplitude, 'duration': t.duration,
                                'rest_before': t.rest_before} for t in plan.tests]},
            'samples': len(self.rows),
            'recording': str(self.out / RECORDING),
            **log}



def free_pieces(runs: np.ndarray, pinned: np.ndarray
                ) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """The samples kept and the runs' pieces ``(start, stop)`` (row indices) between the
    pinned samples, each at least :data:`MIN_PIECE` long.

    Parameters
    ----------
    runs : ndarray of int
        Each row's run (non-decreasing).
    pinned : ndarray of bool
    """
    keep = ~pinned
    pieces = []
    n = len(runs)
    a = 0
    while a < n:
        if not keep[a]:
            a += 1
            continue
        b = a
        while b < n and keep[b] and runs[b] == runs[a]:
            b += 1
        if b - a >= MIN_PIECE:
            pieces.append((a, b))
        else:
            keep[a:b] = False
        a = b
    return keep, pieces
