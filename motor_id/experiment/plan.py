"""The test plan: quasistatic ramps and dynamic steps each way (WPILib SysId's routine, with
steps at two levels), or PRBS / multisine segments, sized from the command limit, with
rests between them.

A test is a command as a function of the time since it began; the guard
(:mod:`motor_id.experiment.guard`) decides when it actually ends (its duration, the
travel window, the speed limit). Every command a test gives is within ``max_command``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math

import numpy as np

from motor_id.errors import ConfigError
from motor_id.excitation import multisine, prbs
from motor_id.experiment.settings import PLANS

RAMP_SECONDS = 10.0
"""A quasistatic ramp reaches the command limit after this long (WPILib: 1 V/s to 12 V)."""
STEP_FRACTION = 0.6
"""Dynamic steps go to this fraction of the command limit (WPILib: 7 V of 12)."""
LOW_STEP_FRACTION = 0.3
"""A second pair of dynamic steps at this fraction: speeds between the ramps' and the
steps' (on the simulated arm, whose stick-slip friction the analysis may take as
Stribeck's, kS came out undetermined in 3 of 5 runs with one step level and determined
in 3 of 3 with two, within 0.005 V)."""
STEP_SECONDS = 4.0
"""Longest dynamic step."""
SEGMENT_SECONDS = 10.0
"""Length of one PRBS or multisine segment."""
SEGMENTS = 3
"""PRBS / multisine segments of a plan (one ended at the travel edge loses only itself)."""
PRBS_DWELL = 0.25
"""Shortest PRBS level [s]."""
TABLE_STEP = 0.002
"""Grid of the tabulated multisine [s] (looked up with linear interpolation)."""
KINDS = ('ramp', 'step', 'prbs', 'multisine')


@dataclass(frozen=True)
class TestSpec:
    """One test of the plan.

    Attributes
    ----------
    name : str
        E.g. ``quasistatic-forward``.
    kind : {'ramp', 'step', 'prbs', 'multisine'}
    direction : int
        +1 toward the travel's HI, -1 toward LO, 0 both ways.
    amplitude : float
        Ramp: the command reached at ``duration``; step: its level; PRBS / multisine:
        the peak (all magnitudes, within the command limit).
    duration : float
        The test's longest time [s].
    rest_before : bool
        Rest at 0 until the joint settles before it starts (False: it follows the
        previous test at once, as an elevator's way down follows its way up).
    table : tuple of float
        PRBS: one level per dwell; multisine: values on a :data:`TABLE_STEP` grid.
    table_step : float
        [s]
    """

    __test__ = False   # not a pytest test class

    name: str
    kind: str
    direction: int
    amplitude: float
    duration: float
    rest_before: bool = True
    table: tuple[float, ...] = ()
    table_step: float = 0.0

    def command(self, t: float) -> float:
        """The command ``t`` seconds after the test began (0 before it and after it)."""
        if not 0.0 <= t < self.duration:
            return 0.0
        if self.kind == 'ramp':
            return self.direction * self.amplitude * t / self.duration
        if self.kind == 'step':
            return self.direction * self.amplitude
        k = t / self.table_step
        i = min(int(k), len(self.table) - 1)
        if self.kind == 'prbs':
            return self.table[i]
        j = min(i + 1, len(self.table) - 1)
        return self.table[i] + (k - i) * (self.table[j] - self.table[i])

    def peak(self) -> float:
        """The largest command magnitude the test asks for."""
        if self.table:
            return float(max(abs(v) for v in self.table))
        return abs(self.amplitude)


@dataclass(frozen=True)
class Plan:
    """The tests in order and how long the rests between them may take.

    Attributes
    ----------
    name : str
    tests : tuple of TestSpec
    rest_min, rest_max : float
        A rest lasts at least ``rest_min`` [s] and ends when the joint has settled, or
        after ``rest_max`` [s] whether it has or not.
    settle_time : float
        The speed must stay below the settling level this long [s].
    """

    name: str
    tests: tuple[TestSpec, ...]
    rest_min: float
    rest_max: float
    settle_time: float

    def peak(self) -> float:
        """The largest command magnitude of any test."""
        return max((t.peak() for t in self.tests), default=0.0)

    def seconds(self) -> float:
        """The longest the tests take, without the rests [s]."""
        return sum(t.duration for t in self.tests)


def build_plan(kind: str, max_command: float, time_scale: float = 1.0,
               seed: int = 0) -> Plan:
    """The plan ``kind`` sized from the command limit.

    Parameters
    ----------
    kind : {'sysid', 'prbs', 'multisine'}
        ``sysid``: quasistatic ramps (to ``max_command`` in :data:`RAMP_SECONDS`) and
        dynamic steps (:data:`STEP_FRACTION` of it, then :data:`LOW_STEP_FRACTION`),
        forward then reverse; ``prbs`` and
        ``multisine``: :data:`SEGMENTS` segments of :data:`SEGMENT_SECONDS` at
        :data:`STEP_FRACTION` of the limit, each its own seed.
    max_command : float
        [V, or N m / N]
    time_scale : float
        Multiplies every duration (a ramp keeps its end value: it gets steeper).
    seed : int

    Returns
    -------
    Plan
    """
    if kind not in PLANS:
        raise ConfigError(f'plan must be one of {", ".join(PLANS)}, got {kind!r}')
    if not (math.isfinite(max_command) and max_command > 0):
        raise ConfigError(f'max command must be > 0, got {max_command}')
    s = float(time_scale)
    step = STEP_FRACTION * max_command
    tests: tuple[TestSpec, ...]
    if kind == 'sysid':
        tests = (
            TestSpec('quasistatic-forward', 'ramp', 1, max_command, RAMP_SECONDS * s),
            TestSpec('quasistatic-reverse', 'ramp', -1, max_command, RAMP_SECONDS * s),
            TestSpec('dynamic-forward', 'step', 1, step, STEP_SECONDS * s),
            TestSpec('dynamic-reverse', 'step', -1, step, STEP_SECONDS * s),
            TestSpec('dynamic-forward-low', 'step', 1, LOW_STEP_FRACTION * max_command,
                     STEP_SECONDS * s),
            TestSpec('dynamic-reverse-low', 'step', -1, LOW_STEP_FRACTION * max_command,
                     STEP_SECONDS * s))
    else:
        tests = tuple(_segment(kind, k, step, SEGMENT_SECONDS * s, seed + k)
                      for k in range(SEGMENTS))
    return Plan(kind, tests, rest_min=max(0.3, 1.0 * s), rest_max=max(2.0, 6.0 * s),
                settle_time=max(0.2, 0.4 * s))


def arrange(plan: Plan, room_low: bool, room_high: bool) -> Plan:
    """The plan ordered for where the joint rests.

    A joint resting at one edge of its travel (an elevator on its bottom, an arm hanging
    near a stop) cannot start a test toward that edge: each such test follows the test
    away from it at once (``rest_before`` False), from where that one ended, and is put
    after it. With room both ways (or neither) the plan is unchanged.

    Parameters
    ----------
    plan : Plan
    room_low, room_high : bool
        Whether a test toward LO (HI) can start from the rest position.
    """
    if room_low == room_high:
        return plan
    blocked = -1 if not room_low else 1
    tests = list(plan.tests)
    k = 0
    while k < len(tests) - 1:
        a, b = tests[k], tests[k + 1]
        if {a.direction, b.direction} == {1, -1} and a.kind == b.kind:
            first, second = (a, b) if b.direction == blocked else (b, a)
            tests[k:k + 2] = [replace(first, rest_before=True),
                              replace(second, rest_before=False)]
            k += 2
        else:
            k += 1
    return replace(plan, tests=tuple(tests))


def repeat_later(plan: Plan, index: int) -> Plan:
    """``plan`` with test ``index`` and the chained tests that follow it run again at the
    end (a test cut short before the guard knew the joint, run once it does)."""
    k = index + 1
    while k < len(plan.tests) and not plan.tests[k].rest_before:
        k += 1
    again = (replace(plan.tests[index], rest_before=True),) + plan.tests[index + 1:k]
    return replace(plan, tests=plan.tests + again)


def _segment(kind: str, k: int, amplitude: float, duration: float, seed: int) -> TestSpec:
    """A PRBS or multisine segment, tabulated from :mod:`motor_id.excitation`."""
    if kind == 'prbs':
        grid = np.arange(0.0, duration + PRBS_DWELL, PRBS_DWELL)
        values = prbs(grid, amplitude, dwell=PRBS_DWELL, random_state=seed)
        step = PRBS_DWELL
    else:
        grid = np.arange(0.0, duration + TABLE_STEP, TABLE_STEP)
        values = multisine(grid, amplitude, f_min=0.1, f_max=4.0, random_state=seed)
        step = TABLE_STEP
    values = np.clip(values, -amplitude, amplitude)
    return TestSpec(f'{kind}-{k + 1}', kind, 0, amplitude, duration,
                    table=tuple(float(v) for v in values), table_step=step)
