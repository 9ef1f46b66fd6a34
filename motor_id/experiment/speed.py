"""The joint's speed from its position, for robots whose ``JointState`` has no velocity.

On line (the guard's coast and rests) the speed is the least-squares slope of the
position over the last samples spanning at least :data:`SPAN` seconds (at least
:data:`MIN_POINTS` of them): a quantised encoder read at 1 kHz differs by one count
between samples, which a two-point difference would turn into a large speed noise. For
the recording the speed is the central difference (:func:`central_speed`), which has no
lag; the analysis then scores the position, not that derived speed
(:data:`SPEED_ESTIMATE` in the recording's metadata).
"""

from __future__ import annotations

from collections import deque

import numpy as np

SPAN = 0.03
"""Seconds of samples the on-line slope takes at least."""
MIN_POINTS = 3
"""Samples the on-line slope takes at least."""
MAX_POINTS = 64
"""Samples the on-line slope takes at most."""
SPEED_ESTIMATE = ('central difference of the position over the sample times; the state '
                  'gave no velocity')
"""``meta['speed_estimate']`` of a recording whose speed was derived from its position."""


class SpeedFromPosition:
    """The on-line speed of a joint from its positions (see the module notes)."""

    def __init__(self) -> None:
        self._t: deque[float] = deque(maxlen=MAX_POINTS)
        self._x: deque[float] = deque(maxlen=MAX_POINTS)

    def update(self, t: float, x: float) -> float:
        """Take the position ``x`` at time ``t`` [s]; return the speed now (0 before two
        samples). A sample not newer than the last one is not taken."""
        if self._t and not t > self._t[-1]:
            return self.speed()
        self._t.append(float(t))
        self._x.append(float(x))
        return self.speed()

    def speed(self) -> float:
        """The least-squares slope over the newest samples spanning :data:`SPAN`."""
        n = len(self._t)
        if n < 2:
            return 0.0
        t_end = self._t[-1]
        k = n - 1
        while k > 0 and (n - k < MIN_POINTS or t_end - self._t[k] < SPAN):
            k -= 1
        t = np.fromiter(self._t, float)[k:]
        x = np.fromiter(self._x, float)[k:]
        dt = t - t.mean()
        return float(np.dot(dt, x - x.mean()) / np.dot(dt, dt))


def central_speed(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The speed at every sample from positions ``x`` at times ``t`` (central
    differences, one-sided at the ends; ``t`` strictly increasing)."""
    if len(t) < 2:
        return np.zeros(len(t))
    return np.asarray(np.gradient(np.asarray(x, float), np.asarray(t, float)), float)
