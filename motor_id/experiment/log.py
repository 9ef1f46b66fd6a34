"""The plan as run: each test's times, why it ended, the limits it reached, the stop reason
(``experiment.json``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import math
from typing import Any

END_REASONS = {
    'complete': 'ran its full length',
    'travel_high': "the coast with 0 commanded would have passed the travel's HI",
    'travel_low': "the coast with 0 commanded would have passed the travel's LO",
    'max_speed': 'the speed passed --max-speed',
    'no_room': 'no room toward its edge of the travel from where the joint was',
    'stopped': 'the experiment stopped during it',
}
"""Why a test ends."""
TRAVEL_REASONS = ('travel_high', 'travel_low')
"""End reasons at the travel's edges."""
LIMIT_REASONS = TRAVEL_REASONS + ('max_speed',)
"""End reasons that are a limit reached."""


@dataclass
class TestLog:
    """One test as run (times in seconds since the experiment started)."""

    __test__ = False   # not a pytest test class

    name: str
    kind: str
    direction: int
    start: float
    end: float | None = None
    end_reason: str | None = None
    peak_command: float = 0.0
    peak_speed: float = 0.0
    position_low: float = math.inf
    position_high: float = -math.inf
    samples: int = 0
    centre: float = 0.0
    """The command the test is centred on (an elevator's: the one that holds it)."""

    def update(self, command: float, position: float, speed: float) -> None:
        """Account one sample of the test."""
        self.peak_command = max(self.peak_command, abs(command))
        self.peak_speed = max(self.peak_speed, abs(speed))
        self.position_low = min(self.position_low, position)
        self.position_high = max(self.position_high, position)
        self.samples += 1

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (positions null before any sample)."""
        d = asdict(self)
        for key in ('position_low', 'position_high'):
            if not math.isfinite(d[key]):
                d[key] = None
        d['limit_reached'] = self.end_reason if self.end_reason in LIMIT_REASONS else None
        if self.end_reason in END_REASONS:
            d['why'] = END_REASONS[self.end_reason]
        return d


@dataclass
class RunLog:
    """The experiment as run.

    Attributes
    ----------
    tests : list of TestLog
    stop_reason : str
        ``complete`` (the plan ran to its end), or what stopped it (the watchdog, a
        signal, a limit, an error), in words.
    safety_stop : bool
        The experiment was stopped by a safety rule (watchdog, stale stamps, the joint
        outside its travel).
    start_position : float or None
    noise : dict
        Position and speed noise measured at rest before the first test.
    timing : dict
        Median sample period, state latency (receive time - stamp) and the latency the
        guard allowed for; the states that arrived late and the longest delay.
    clamped : int
        Commands the limit clamped (the plan never asks more than the limit, so 0).
    """

    tests: list[TestLog] = field(default_factory=list)
    stop_reason: str | None = None
    safety_stop: bool = False
    start_position: float | None = None
    noise: dict[str, float] = field(default_factory=dict)
    timing: dict[str, float] = field(default_factory=dict)
    clamped: int = 0
    ignored_samples: int = 0

    @property
    def complete(self) -> bool:
        """The plan ran to its end."""
        return self.stop_reason == 'complete'

    def limits_reached(self) -> list[str]:
        """``'<test>: <reason>'`` of every test that ended at a limit."""
        return [f'{t.name}: {t.end_reason}' for t in self.tests
                if t.end_reason in LIMIT_REASONS]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'stop_reason': self.stop_reason, 'complete': self.complete,
                'safety_stop': self.safety_stop, 'start_position': self.start_position,
                'limits_reached': self.limits_reached(),
                'tests': [t.to_dict() for t in self.tests], 'noise': dict(self.noise),
                'timing': dict(self.timing), 'clamped_commands': self.clamped,
                'ignored_samples': self.ignored_samples}
