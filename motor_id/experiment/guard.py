"""The guard: from each state sample and the time, the command to send and why a test
ends. A pure state machine (no ROS, no clock of its own), so every rule is unit-tested.

Phases: ``idle`` (nothing is sent before :meth:`Guard.start`), ``baseline`` (0 commanded:
the rest position, the noise and the sample period are measured), then for each test a
``rest`` (0 until the joint has settled; before a chained test, only until it no longer
moves against the test) and the ``test``; ``done`` after the last test's rest, or
``stopped`` by a safety rule or a request.

Rules, checked on every sample of a test:

- the command is the plan's, within the command limit (:func:`limit_command`);
- the test ends at its duration, at ``--max-speed``, or when the joint's coast with 0
  commanded after the latency (:func:`motor_id.experiment.coast.predict_coast`) would
  leave the travel window less a margin; an arm's fall is part of that coast (before
  the on-line model knows the arm, its swing to the mirror of its angle about the
  hanging position), an elevator's fall ends on the bottom it rested on;
- the joint found outside the travel stops the experiment.

And at any time: no fresh state for ``watchdog`` seconds (:meth:`Guard.tick`), or states
stamped ``watchdog`` seconds later than the smallest lag seen, stop it with 0.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
import math
import statistics

from motor_id.experiment.coast import Coast, OnlineModel, predict_coast, test_centre
from motor_id.experiment.log import RunLog, TestLog, TRAVEL_REASONS
from motor_id.experiment.plan import arrange, Plan, repeat_later, TestSpec
from motor_id.experiment.settings import ExperimentSettings

MARGIN = 0.05
"""The coast must stay this fraction of the travel width inside each edge."""
ROOM = 0.15
"""A test toward an edge needs this fraction of the width between the joint and it."""
EXTRA_LATENCY = 0.05
"""Seconds allowed for a command to act, beyond the state's measured latency and two
sample periods."""
BASELINE_SAMPLES = 20
"""Samples at rest before the first test."""
SPEED_MEAN = 3
"""The coast starts from the mean of the last few speeds (noise averaged)."""
OTHER_CLOCK = 0.5
"""States stamped this far [s] from their receive times at the least are stamped on
another clock (the robot's own): only the lag's changes then tell a latency."""
SETTLE_FRACTION = 0.02
"""A rest ends when the speed is below this fraction of the last test's peak (and a few
noise levels)."""


def limit_command(value: float, max_command: float) -> float:
    """``value`` clamped to ``[-max_command, max_command]`` (not a number: 0)."""
    if not math.isfinite(value):
        return 0.0
    return max(-max_command, min(max_command, float(value)))


@dataclass(frozen=True)
class StateSample:
    """One state of the joint.

    Attributes
    ----------
    t : float
        Measurement time [s] (the header stamp; the receive time where it is unset).
    received : float
        Receive time on the guard's monotonic clock [s].
    position, velocity : float
    effort : float
    lag : float
        Receive time - stamp on the publisher's clock [s] (0 where the stamp is unset).
    """

    t: float
    received: float
    position: float
    velocity: float
    effort: float = math.nan
    lag: float = 0.0


class Guard:
    """The experiment's state machine (see the module notes).

    Parameters
    ----------
    settings : ExperimentSettings
    plan : Plan
    """

    def __init__(self, settings: ExperimentSettings, plan: Plan) -> None:
        self.settings = settings
        self.plan = plan
        self.log = RunLog()
        self.phase = 'idle'
        self.command = 0.0
        self.test_index = -1
        self.run_index = 0
        self.model: OnlineModel | None = None
        self._phase_start = 0.0
        self._t0: float | None = None
        self._last: StateSample | None = None
        self._last_rx: float | None = None
        self.stats = StreamStats()
        self._modelled = False
        self._repeated: set[str] = set()
        self._baseline: list[StateSample] = []
        self._settled_since: float | None = None
        self.sent = SentCommands()
        """The commands sent (:meth:`ExperimentSession.note_sent` adds them)."""
        self._peak_speed = 0.0
        self.rest_position = math.nan
        self.noise_position = 0.0
        self.noise_speed = 0.0

    # ------------------------------------------------------------------ requests
    @property
    def active(self) -> bool:
        """Started and neither done nor stopped."""
        return self.phase not in ('idle', 'done', 'stopped')

    @property
    def finished(self) -> bool:
        """Done or stopped."""
        return self.phase in ('done', 'stopped')

    def start(self, now: float) -> float:
        """Begin: 0 until the baseline is measured. Returns the command (0)."""
        if self.phase == 'idle':
            self.phase = 'baseline'
            self._last_rx = now
        return self._set(0.0)

    def stop(self, reason: str, safety: bool = False) -> float:
        """Stop now (a signal, an error, a safety rule): returns 0."""
        if not self.finished:
            if self.phase == 'test':
                self._end_test('stopped')
            self.phase = 'stopped'
            self.log.stop_reason = reason
            self.log.safety_stop = safety
        return self._set(0.0)

    def tick(self, now: float) -> float | None:
        """The watchdog: 0 (and the stop) if no fresh state came for ``watchdog`` s."""
        if not self.active or self._last_rx is None:
            return None
        silent = now - self._last_rx
        if silent > self.settings.watchdog:
            return self.stop(f'watchdog: no state of joint {self.settings.joint} for '
                             f'{silent:.2f} s', safety=True)
        return None

    # ------------------------------------------------------------------ samples
    def on_state(self, s: StateSample) -> float | None:
        """Take one state sample; return the command to send, or None to ignore it (not
        started, finished, or not newer than the last sample)."""
        if not self.active:
            return None
        if self._last is not None and not s.t > self._last.t:
            self.log.ignored_samples += 1
            return None
        late = self.stats.lateness(s)
        if late > self.settings.watchdog:
            return self.stop(f'stale state: joint {self.settings.joint} stamped '
                             f'{late:.2f} s later than usual', safety=True)
        self._account(s)
        outside = self._outside_travel(s.position) if self.phase != 'baseline' else None
        if outside is not None:
            return self.stop(outside, safety=True)
        if self.phase == 'baseline':
            return self._on_baseline(s)
        if self.phase == 'rest':
            return self._on_rest(s)
        return self._on_test(s)

    def _account(self, s: StateSample) -> None:
        last = self._last
        if self._t0 is None:
            self._t0 = s.t
        if last is not None:
            if self.model is not None:
                offset = self.stats.min_lag if self.stats.other_clock else 0.0
                self.model.add(s.t, s.position, s.velocity,
                               self.sent.at(s.t + offset, self.command))
        self.stats.add(s, last)
        self._last = s
        self._last_rx = s.received
        if self.phase == 'test':
            self.log.tests[-1].update(self.command, s.position, s.velocity)

    def elapsed(self, t: float) -> float:
        """Seconds since the first sample after the start."""
        return t - (self._t0 if self._t0 is not None else t)

    # ------------------------------------------------------------------ phases
    def _on_baseline(self, s: StateSample) -> float:
        self._baseline.append(s)
        if len(self._baseline) < BASELINE_SAMPLES or \
                self.elapsed(s.t) < self.plan.rest_min:
            return self._set(0.0)
        if self.elapsed(s.t) < self.plan.rest_max and \
                drifting([b.position for b in self._baseline]):
            del self._baseline[:len(self._baseline) // 2]   # still moving: wait on
            return self._set(0.0)
        pos = [b.position for b in self._baseline]
        vel = [b.velocity for b in self._baseline]
        self.rest_position = statistics.fmean(pos)
        self.noise_position = statistics.pstdev(pos)
        self.noise_speed = max(statistics.pstdev(vel), 1e-9)
        self.model = OnlineModel(self.settings.mechanism, 3.0 * self.noise_speed)
        self.log.start_position = self.rest_position
        self.log.noise = {'position': self.noise_position, 'speed': self.noise_speed}
        travel = self.settings.travel
        tol = 3.0 * self.noise_position
        if travel is not None and \
                not travel.low - tol <= self.rest_position <= travel.high + tol:
            return self.stop(f'the joint rests at {self.rest_position:.4g}, outside the '
                             f'travel {travel.text()}: give a window that holds it',
                             safety=True)
        if travel is not None:
            lo, hi = self.window()
            room = ROOM * travel.width
            self.plan = arrange(self.plan, self.rest_position - lo >= room,
                                hi - self.rest_position >= room)
        return self._next_test(s)

    def _on_rest(self, s: StateSample) -> float:
        waited = s.t - self._phase_start
        nxt = self.test_index + 1
        if nxt < len(self.plan.tests) and not self.plan.tests[nxt].rest_before:
            # a chained test starts once the joint no longer moves against it
            if self.speed() * self.plan.tests[nxt].direction >= 0 or \
                    waited >= self.plan.rest_max:
                return self._begin_test(s)
            return self._set(0.0)
        level = max(4.0 * self.noise_speed, SETTLE_FRACTION * self._peak_speed)
        if abs(s.velocity) > level:
            self._settled_since = None
        elif self._settled_since is None:
            self._settled_since = s.t
        settled = self._settled_since is not None and \
            s.t - self._settled_since >= self.plan.settle_time
        if waited >= self.plan.rest_max or (settled and waited >= self.plan.rest_min):
            if self.test_index + 1 >= len(self.plan.tests):
                self.phase = 'done'
                self.log.stop_reason = 'complete'
                return self._set(0.0)
            return self._begin_test(s)
        return self._set(0.0)

    def _next_test(self, s: StateSample) -> float:
        """After the baseline or a test: the rest before the next test (for a chained
        test only until the joint turns its way), or the final rest."""
        self.phase = 'rest'
        self._phase_start = s.t
        self._settled_since = None
        return self._set(0.0)

    def _begin_test(self, s: StateSample) -> float:
        self.test_index += 1
        spec = self.plan.tests[self.test_index]
        if self.test_index > 0:
            self.run_index += 1
        centre = test_centre(self.model.fitted() if self.model is not None else None,
                             self.settings.max_command)
        self.log.tests.append(TestLog(spec.name, spec.kind, spec.direction,
                                      self.elapsed(s.t), centre=centre))
        self.phase = 'test'
        self._phase_start = s.t
        self._peak_speed = 0.0
        if not self._has_room(spec, s.position):
            return self._end_test('no_room', s)
        return self._on_test(s)

    def _on_test(self, s: StateSample) -> float:
        spec = self.plan.tests[self.test_index]
        t = s.t - self._phase_start
        self._peak_speed = max(self._peak_speed, abs(s.velocity))
        if t >= spec.duration:
            return self._end_test('complete', s)
        if self.settings.max_speed is not None and abs(s.velocity) > self.settings.max_speed:
            return self._end_test('max_speed', s)
        reason = self._travel_reason(s)
        if reason is not None:
            return self._end_test(reason, s)
        c = self.log.tests[-1].centre   # the command limit is kept around the centre
        return self._set(c + spec.command(t) * (1.0 - abs(c) / self.settings.max_command))

    def _end_test(self, reason: str, s: StateSample | None = None) -> float:
        test = self.log.tests[-1]
        test.end_reason = reason
        test.end = self.elapsed(s.t) if s is not None else \
            self.elapsed(self._last.t) if self._last is not None else test.start
        if reason == 'stopped' or s is None:
            return self._set(0.0)
        if reason in TRAVEL_REASONS and not self._modelled and \
                test.name not in self._repeated:
            # cut short on the cautious coast, before the model knew the joint: again
            # at the end, once it does
            self._repeated.add(test.name)
            self.plan = repeat_later(self.plan, self.test_index)
        self._set(0.0)
        return self._next_test(s)

    # ------------------------------------------------------------------ travel
    def window(self) -> tuple[float, float]:
        """Where the coast may go: the travel less the margin, widened to hold the rest
        position (where the joint goes by itself)."""
        travel = self.settings.travel
        if travel is None:
            return -math.inf, math.inf
        m = MARGIN * travel.width + 3.0 * self.noise_position
        tol = 3.0 * self.noise_position + 1e-3 * travel.width
        return (min(travel.low + m, self.rest_position - tol),
                max(travel.high - m, self.rest_position + tol))

    def _outside_travel(self, x: float) -> str | None:
        travel = self.settings.travel
        tol = 0.0 if travel is None else 6.0 * self.noise_position + 1e-3 * travel.width
        if travel is None or min(travel.low, self.rest_position) - tol <= x <= \
                max(travel.high, self.rest_position) + tol:
            return None
        return f'position {x:.4g} outside the travel {travel.text()}'

    def _has_room(self, spec: TestSpec, x: float) -> bool:
        travel = self.settings.travel
        if travel is None or spec.direction == 0:
            return True
        lo, hi = self.window()
        room = hi - x if spec.direction > 0 else x - lo
        return room >= ROOM * travel.width

    def coast(self, s: StateSample) -> Coast:
        """The positions the joint visits if it is commanded 0 now (see the module
        notes)."""
        w = self.speed()
        model = self.model.fitted() if self.model is not None else None
        support = self.rest_position if self.settings.mechanism == 'elevator' else None
        c = predict_coast(model, s.position, w, self.command, self.stats.latency(s.lag),
                          support)
        if model is None and self.settings.mechanism == 'arm':
            mirror = 2.0 * self.rest_position - s.position
            c = Coast(min(c.low, mirror), max(c.high, mirror), False)
        return c

    def speed(self) -> float:
        """The speed a coast starts from (:meth:`StreamStats.speed`)."""
        return self.stats.speed(self.noise_speed)

    def _travel_reason(self, s: StateSample) -> str | None:
        if self.settings.travel is None:
            return None
        lo, hi = self.window()
        c = self.coast(s)
        self._modelled = c.modelled
        if c.high > hi:
            return 'travel_high'
        if c.low < lo:
            return 'travel_low'
        # moving toward an edge (an elevator's way down to its bottom, where the
        # predicted fall ends on the support): the position a latency ahead
        travel = self.settings.travel
        m = MARGIN * travel.width
        w = self.speed()
        ahead = s.position + w * self.stats.latency(s.lag)
        if w > 0 and ahead > travel.high - m:
            return 'travel_high'
        if w < 0 and ahead < travel.low + m:
            return 'travel_low'
        return None

    # ------------------------------------------------------------------ output
    def _set(self, value: float) -> float:
        limited = limit_command(value, self.settings.max_command)
        if limited != value and math.isfinite(value):
            self.log.clamped += 1
        self.command = limited
        return limited


class SentCommands:
    """The commands sent and their send times: which one drove the joint at a stamp."""

    def __init__(self) -> None:
        self._t: list[float] = []
        self._v: list[float] = []

    def add(self, t: float, value: float) -> None:
        """A command left at ``t`` [s, the clock of the receive times]."""
        if not self._t or t >= self._t[-1]:
            self._t.append(float(t))
            self._v.append(float(value))

    def at(self, t: float, unsent: float) -> float:
        """The command in effect at ``t`` (the receive times' clock): the last one sent
        before it, 0 before the first; ``unsent`` where none was sent.

        A state that arrives late (a busy machine) was measured under the command sent
        before it was measured, not under the one decided on the state before it: so
        taken, the on-line model learns the joint from what drove it.
        """
        if not self._t:
            return unsent
        k = bisect.bisect_left(self._t, t) - 1
        return self._v[k] if k >= 0 else 0.0


class StreamStats:
    """The state stream's timing and recent speeds: sample period, latency (receive
    time - stamp) and its smallest value, the last few speeds."""

    def __init__(self) -> None:
        self._min_lag = math.inf
        self._periods: list[float] = []
        self._lags: list[float] = []
        self._speeds: list[float] = []
        self.late = 0
        """States that arrived over :data:`EXTRA_LATENCY` later than the smallest lag."""
        self.latest = 0.0
        """The most any state arrived later than the smallest lag [s]."""

    def lateness(self, s: StateSample) -> float:
        """How much later than the smallest lag so far ``s`` is stamped [s]."""
        late = s.lag - self._min_lag if math.isfinite(self._min_lag) else 0.0
        self._min_lag = min(self._min_lag, s.lag)
        self.late += int(late > EXTRA_LATENCY)
        self.latest = max(self.latest, late)
        return late

    def add(self, s: StateSample, last: StateSample | None) -> None:
        """Account a fresh sample (``last``: the one before it)."""
        if last is not None:
            self._periods.append(s.t - last.t)
        self._lags.append(s.lag)
        self._speeds.append(s.velocity)
        del self._periods[:-200], self._lags[:-200], self._speeds[:-SPEED_MEAN]

    @property
    def min_lag(self) -> float:
        """The smallest receive time - stamp seen [s] (0 before any sample)."""
        return self._min_lag if math.isfinite(self._min_lag) else 0.0

    @property
    def other_clock(self) -> bool:
        """The stamps are on another clock than the receive times."""
        return abs(self.min_lag) > OTHER_CLOCK

    def period(self) -> float:
        """Median sample period [s] (0.01 before two samples)."""
        return statistics.median(self._periods) if self._periods else 0.01

    def latency(self, lag_now: float | None = None) -> float:
        """Seconds a command may take to act: the state's latency (its excess over the
        smallest for stamps on another clock, :data:`OTHER_CLOCK`), two sample periods
        (and half the speed mean's), and :data:`EXTRA_LATENCY`.

        ``lag_now``: the lag of the state the coast starts from. A state that arrives
        late (a busy machine: 0.28 s, where the median was 5 ms) shows the joint where
        it was that long ago, and it has moved on since: the larger lag counts."""
        floor = self.min_lag if self.other_clock else min(self.min_lag, 0.0)
        lag = max(0.0, statistics.median(self._lags) - floor) if self._lags else 0.0
        if lag_now is not None and math.isfinite(lag_now):
            lag = max(lag, lag_now - floor)
        return lag + (2.0 + SPEED_MEAN / 2.0) * self.period() + EXTRA_LATENCY

    def speed(self, noise: float) -> float:
        """The speed a coast starts from: the mean of the last :data:`SPEED_MEAN`
        samples, less two noise levels (0 inside that band)."""
        if not self._speeds:
            return 0.0
        return _deadband(statistics.fmean(self._speeds), 2.0 * noise)

    def timing(self) -> dict[str, float]:
        """Median sample period and state latency, and the latency allowed for [s]; the
        states that arrived late (a busy machine or network: their stamps still hold,
        and the command each was measured under is the one sent before it) and the
        longest such delay [s]."""
        lag = statistics.median(self._lags) if self._lags else 0.0
        return {'sample_period': statistics.median(self._periods) if self._periods else 0.0,
                'state_latency': lag - self.min_lag if self.other_clock else lag,
                'allowed_latency': self.latency(), 'late_states': float(self.late),
                'latest_state': self.latest}


def drifting(positions: list[float]) -> bool:
    """The positions move: their halves' means differ by more than three times the
    spread within the later half (a joint still falling, or coasting, when the
    experiment started)."""
    half = len(positions) // 2
    drift = abs(statistics.fmean(positions[half:]) - statistics.fmean(positions[:half]))
    return drift > 3.0 * statistics.pstdev(positions[half:]) + 1e-12


def _deadband(w: float, level: float) -> float:
    """``w`` with ``level`` taken off its magnitude (0 inside the band)."""
    return math.copysign(max(0.0, abs(w) - level), w)
