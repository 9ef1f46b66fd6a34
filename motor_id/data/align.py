"""Commands zero-order held onto measurement times: the rule, batch and streaming."""

import collections

import numpy as np
from numpy.typing import ArrayLike, NDArray

from motor_id.contracts import SAMPLE_COLUMNS
from motor_id.errors import ConfigError

ALIGN_RULES = ('hold', 'next')
"""``hold``: a sample takes the last command at or before its own time (the command in
force when it was measured). ``next``: the last command before the next sample's time
(the command in force over the interval that starts at the sample), for robots that
publish the command just after reading the state."""


def _check_rule(align: str) -> None:
    if align not in ALIGN_RULES:
        raise ConfigError(f'align must be one of {", ".join(ALIGN_RULES)}, got {align!r}')


def held_command_index(t_meas: ArrayLike, t_cmd: ArrayLike,
                       align: str = 'hold') -> NDArray[np.intp]:
    """Index of the command each measurement takes (-1: no command yet).

    Parameters
    ----------
    t_meas : array_like, shape (n,)
        Measurement times [s], increasing.
    t_cmd : array_like, shape (m,)
        Command times [s], non-decreasing.
    align : {'hold', 'next'}
        See :data:`ALIGN_RULES`. With ``next`` the last measurement has no next time
        and gets -1 (it cannot be aligned yet).

    Returns
    -------
    ndarray of int, shape (n,)
    """
    _check_rule(align)
    t_meas = np.asarray(t_meas, dtype=float)
    t_cmd = np.asarray(t_cmd, dtype=float)
    if align == 'hold':
        return np.searchsorted(t_cmd, t_meas, side='right') - 1
    idx = np.full(t_meas.shape, -1, dtype=np.intp)
    idx[:-1] = np.searchsorted(t_cmd, t_meas[1:], side='left') - 1
    return idx


def interval_mean_command(t_meas: ArrayLike, t_cmd: ArrayLike, values: ArrayLike
                          ) -> NDArray[np.float64]:
    """The mean of the held command over each measurement's interval.

    The commands hold from their times (0 before the first); sample ``k`` gets their
    time average over ``[t_meas[k], t_meas[k+1])``, the last sample over an interval as
    long as the one before it. A command that changed a third of the way into an interval
    counts two thirds there: the input a zero-order-hold model needs where commands
    leave at any time between samples (a robot's states and a host's commands on their
    own clocks), which the rules of :data:`ALIGN_RULES` round to a whole sample.

    Parameters
    ----------
    t_meas : array_like, shape (n,)
        Measurement times [s], increasing, ``n >= 2``.
    t_cmd : array_like, shape (m,)
        Command times [s], non-decreasing.
    values : array_like, shape (m,)
    """
    t = np.asarray(t_meas, dtype=float)
    tc = np.asarray(t_cmd, dtype=float)
    v = np.asarray(values, dtype=float)
    edges = np.append(t, t[-1] + (t[-1] - t[-2]))
    if tc.size == 0:
        return np.zeros(t.size)
    # the integral of the held command from the first command's time to each edge
    area = np.concatenate([[0.0], np.cumsum(v[:-1] * np.diff(tc))])
    j = np.searchsorted(tc, edges, side='right') - 1
    integral = np.where(j >= 0, area[np.maximum(j, 0)]
                        + v[np.maximum(j, 0)] * (edges - tc[np.maximum(j, 0)]), 0.0)
    return np.asarray(np.diff(integral) / np.diff(edges), dtype=float)


class StreamAligner:
    """Builds sample rows from a measurement stream and a command stream, as they arrive.

    Rows are released in measurement order once no command that could still change
    them is expected: when a command at or after the time that decides the row
    (the sample's own time for ``hold``, the next sample's time for ``next``) has
    arrived, or ``max_delay_s`` after that time. Measurements before the first command,
    or out of order, are dropped and counted.

    Parameters
    ----------
    align : {'hold', 'next'}
    max_delay_s : float
        Longest expected delay of a command message [s].
    """

    def __init__(self, align: str = 'hold', max_delay_s: float = 0.2) -> None:
        _check_rule(align)
        self.align = align
        self.max_delay_s = float(max_delay_s)
        # (time, value), time non-decreasing; (time, speed, current)
        self._cmd: collections.deque[tuple[float, float]] = collections.deque()
        self._meas: collections.deque[tuple[float, float, float]] = collections.deque()
        self.seq = 0
        self.dropped_no_command = 0
        self.dropped_out_of_order = 0
        self._last_meas_t = -np.inf

    def add_command(self, t: float, value: float) -> None:
        """A command ``value`` that took effect at time ``t`` [s]."""
        if self._cmd and t < self._cmd[-1][0]:
            t = self._cmd[-1][0]   # keep the held value well defined
        self._cmd.append((float(t), float(value)))

    def add_measurement(self, t: float, speed: float, current: float = np.nan) -> None:
        """A measurement at time ``t`` [s]: speed [rad/s], current [A] or the torque."""
        if t <= self._last_meas_t:
            self.dropped_out_of_order += 1
            return
        self._last_meas_t = t
        self._meas.append((float(t), float(speed), float(current)))

    def _decided_at(self, k: int) -> float | None:
        """The time that decides measurement ``k``'s command (None: not known yet)."""
        if self.align == 'hold':
            return self._meas[k][0]
        return self._meas[k + 1][0] if k + 1 < len(self._meas) else None

    def _command_at(self, t_ref: float) -> float | None:
        """The held command for deciding time ``t_ref``, or None before the first."""
        value = None
        strict = self.align == 'next'
        for t, v in self._cmd:
            if t < t_ref or (not strict and t == t_ref):
                value = v
            else:
                break
        return value

    def ready_rows(self, now: float) -> NDArray[np.float64]:
        """Release the rows that can be aligned at time ``now`` [s].

        Returns
        -------
        ndarray, shape (n, 6)
            Columns seq, t, input, speed, current, flags (0); ``seq`` counts released
            rows from 0.
        """
        out = []
        last_cmd = self._cmd[-1][0] if self._cmd else -np.inf
        while self._meas:
            t_ref = self._decided_at(0)
            if t_ref is None or (last_cmd < t_ref and now - t_ref < self.max_delay_s):
                break
            t, speed, current = self._meas.popleft()
            value = self._command_at(t_ref)
            if value is None:
                self.dropped_no_command += 1
                continue
            out.append((self.seq, t, value, speed, current, 0.0))
            self.seq += 1
            # commands older than the one just used are never needed again
            while len(self._cmd) > 1 and self._cmd[1][0] <= t_ref:
                self._cmd.popleft()
        if not out:
            return np.zeros((0, len(SAMPLE_COLUMNS)))
        return np.array(out, dtype=float)
