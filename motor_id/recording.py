"""One in-memory recording (time + channels) and its validation."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from motor_id.contracts import channel_units
from motor_id.errors import DataError

MIN_SAMPLES = 20


@dataclass
class Recording:
    """Samples of one experiment.

    Attributes
    ----------
    time : ndarray
        Sample times [s], strictly increasing (may be irregular).
    input : ndarray
        The plant input: armature voltage [V] for a voltage plant, or applied torque
        [N m] (force [N] for a linear axis) when ``input_kind == 'torque'``.
    speed : ndarray
        Measured speed [rad/s] (or [m/s] for a linear axis).
    current : ndarray or None
        Measured armature current [A], when the card has it.
    input_kind : {'voltage', 'torque'}
    meta : dict
        Provenance and notes, carried into reports and bags.
    segments : list of (int, int), optional
        Sample ranges ``[start, stop)`` of separate runs joined into one recording
        (:meth:`concatenate`): each starts from its own initial state and the model is
        never simulated across a boundary. None: one run.
    position : ndarray or None
        Measured position [rad] (or [m] for a linear axis), when the source logs it
        (encoder counts scaled by the counts per revolution, the EMPS ``qm``, a SysId
        log's position). A model that integrates speed holds it too.

    Examples
    --------
    From arrays (SI units; the fit needs at least 20 samples, :meth:`validate`):

    >>> import numpy as np
    >>> from motor_id import Recording
    >>> t = np.arange(5) * 0.01
    >>> rec = Recording(t, input=np.full(5, 6.0), speed=[0.0, 1.2, 2.1, 2.8, 3.3])
    >>> len(rec), rec.channels(), rec.has_current
    (5, ('speed',), False)
    >>> round(rec.sample_period, 6)
    0.01
    """

    time: np.ndarray
    input: np.ndarray
    speed: np.ndarray
    current: np.ndarray | None = None
    input_kind: str = 'voltage'
    meta: dict = field(default_factory=dict)
    segments: list[tuple[int, int]] | None = None
    position: np.ndarray | None = None

    MAX_MAGNITUDE = 1e200
    """Largest accepted magnitude of any value. The fit rescales each channel and copes
    with values up to about 1e250 (tested); beyond, its arithmetic overflows."""
    OUTLIER_RATIO = 1e12
    """A value this many times the channel's typical magnitude is a corrupt cell."""
    MIN_MOVING_FRACTION = 0.01
    """Fewer samples than this fraction off the output's median is a constant output."""

    def __post_init__(self) -> None:
        self.time = np.asarray(self.time, dtype=float)
        self.input = np.asarray(self.input, dtype=float)
        self.speed = np.asarray(self.speed, dtype=float)
        if self.current is not None:
            self.current = np.asarray(self.current, dtype=float)
        if self.position is not None:
            self.position = np.asarray(self.position, dtype=float)

    def __len__(self) -> int:
        return self.time.size

    @property
    def has_current(self) -> bool:
        """True when a current channel is present."""
        return self.current is not None

    @property
    def has_position(self) -> bool:
        """True when a position channel is present."""
        return self.position is not None

    @property
    def linear(self) -> bool:
        """True for a linear axis: the reader gave the speed in m/s (``meta['units']``)."""
        units = self.meta.get('units') or {}
        return bool(units.get('speed') == channel_units(linear=True)['speed'])

    @property
    def sample_period(self) -> float:
        """Median sample interval [s]."""
        return float(np.median(np.diff(self.time)))

    @property
    def is_regular(self) -> bool:
        """True when all intervals are equal to within 1 ppm."""
        dt = np.diff(self.time)
        return bool(np.ptp(dt) <= 1e-6 * np.mean(dt))

    @property
    def segment_ranges(self) -> list[tuple[int, int]]:
        """``[(start, stop), ...]``: the runs of this recording (one unless joined)."""
        return list(self.segments) if self.segments else [(0, len(self))]

    @property
    def input_streams(self) -> list[tuple[int, int]]:
        """``[(start, stop), ...]``: the ranges whose input is one stream, which an input
        map that reaches back in time (a delay) takes whole. They are the runs, but runs
        the source marks as following the previous one with no sample left out between
        are joined to it (``meta['runs_follow']``, a flag per run: ``motor-id
        experiment`` records its tests back to back). Runs joined from separate records
        (:meth:`concatenate`, a SysId JSON log's tests) stay apart."""
        runs = self.segment_ranges
        follow = self.meta.get('runs_follow')
        if not isinstance(follow, list) or len(follow) != len(runs):
            return runs
        out = [runs[0]]
        for (a, b), joined in zip(runs[1:], follow[1:], strict=True):
            if joined is True and a == out[-1][1]:
                out[-1] = (out[-1][0], b)
            else:
                out.append((a, b))
        return out

    def segment_index(self) -> np.ndarray:
        """The run each sample belongs to (0, 1, ...)."""
        out = np.zeros(len(self), dtype=int)
        for k, (a, b) in enumerate(self.segment_ranges):
            out[a:b] = k
        return out

    @classmethod
    def concatenate(cls, recordings: Iterable[Recording]) -> Recording:
        """Join separate runs of one motor into one recording with :attr:`segments`.

        Each run keeps its samples; its times are shifted to follow the previous run by
        one median sample period (a run's own time origin is kept in
        ``meta['segment_offsets']``, one entry per run). A recording that is itself
        several runs (a SysId log's four tests) keeps them as runs; the caller names the
        joined runs (``meta['segment_names']`` is not carried over). All runs must have
        the same input kind and channels.

        Raises
        ------
        DataError
            Mixed plant kinds or channels.
        """
        recordings = list(recordings)
        if len(recordings) == 1:
            return recordings[0]
        first = recordings[0]
        for r in recordings[1:]:
            if (r.input_kind != first.input_kind or r.has_current != first.has_current
                    or r.has_position != first.has_position):
                raise DataError(
                    f'cannot fit {r.meta.get("source", "a recording")} together with '
                    f'{first.meta.get("source", "the first")}: one has '
                    f'{first.input_kind} input and channels {first.channels(True)}, the '
                    f'other {r.input_kind} input and {r.channels(True)}')
        times: list[np.ndarray] = []
        segs: list[tuple[int, int]] = []
        offsets: list[float] = []
        t_end: float | None = None
        n = 0
        for r in recordings:
            t = np.asarray(r.time, dtype=float)
            shift = 0.0 if t_end is None else t_end + r.sample_period - t[0]
            times.append(t + shift)
            inner = r.segment_ranges
            offsets += [shift] * len(inner)
            t_end = float(times[-1][-1])
            segs += [(n + a, n + b) for a, b in inner]
            n += t.size
        cur = np.concatenate([r.current for r in recordings]) if first.has_current \
            else None
        pos = np.concatenate([r.position for r in recordings]) if first.has_position \
            else None
        meta = dict(first.meta)
        meta.pop('segment_names', None)
        meta.pop('runs_follow', None)
        meta['sources'] = [r.meta.get('source') for r in recordings]
        meta['segment_offsets'] = offsets
        return cls(np.concatenate(times), np.concatenate([r.input for r in recordings]),
                   np.concatenate([r.speed for r in recordings]), cur,
                   first.input_kind, meta, segs, pos)

    def channels(self, with_position: bool = False) -> tuple[str, ...]:
        """Names of the output channels present: speed, and current if measured.

        ``with_position`` adds 'position' when it is measured (the channels a model
        is compared with in simulation; the equation-error fit uses speed and current).
        """
        out = ('speed', 'current') if self.has_current else ('speed',)
        return out + ('position',) if with_position and self.has_position else out

    def slice(self, start: int | None, stop: int | None) -> Recording:
        """A new recording with samples ``start:stop``."""
        cur = None if self.current is None else self.current[start:stop]
        pos = None if self.position is None else self.position[start:stop]
        start, stop, _ = slice(start, stop).indices(len(self))
        segs: list[tuple[int, int]] | None = None
        if self.segments:
            segs = [(max(a, start) - start, min(b, stop) - start)
                    for a, b in self.segments if min(b, stop) > max(a, start)]
            segs = segs if len(segs) > 1 else None
        return Recording(self.time[start:stop], self.input[start:stop],
                         self.speed[start:stop], cur, self.input_kind, dict(self.meta),
                         segs, pos)

    def validate(self, min_samples: int = MIN_SAMPLES) -> Recording:
        """Raise :class:`DataError` with a one-line reason if the data cannot be fitted.

        Checks equal lengths, enough samples, finite values of sane magnitude (see
        :func:`bad_magnitude`), strictly increasing time, an input that varies and a speed
        that varies (not constant, and off its median in at least
        :attr:`MIN_MOVING_FRACTION` of the samples).
        """
        n = self.time.size
        names = (('time', 'input', 'speed') + (('current',) if self.has_current else ())
                 + (('position',) if self.has_position else ()))
        for name in names[1:]:
            arr = getattr(self, name)
            if arr.shape != self.time.shape:
                raise DataError(f'channel {name!r} has {arr.size} samples but time has {n}')
        if n < min_samples:
            raise DataError(f'too few samples: {n} (need at least {min_samples})')
        for name in names:
            arr = getattr(self, name)
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise DataError(f'channel {name!r} has {bad.size} NaN/inf value(s), '
                                f'first at sample {bad[0]}')
            found = bad_magnitude(arr, relative=name != 'time')
            if found:
                raise DataError(f'channel {name!r} at sample {found[0]}: {found[1]}')
        dt = np.diff(self.time)
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            k = bad[0] + 1
            raise DataError(f'time is not strictly increasing at sample {k} '
                            f'(t = {self.time[k - 1]:g} then {self.time[k]:g})')
        if _is_constant(self.input):
            raise DataError('no excitation: the input is constant '
                            f'({self.input[0]:g} throughout); use a varying input')
        self._check_output_moves()
        return self

    def _check_output_moves(self) -> None:
        """DataError when the speed is constant or nearly so (nothing to fit)."""
        speed = self.speed
        if _is_constant(speed):
            raise DataError(f'no response: the speed is constant ({speed[0]:g} throughout); '
                            'check the speed column/topic and that the motor moved')
        median = np.median(speed)
        moving = int(np.count_nonzero(np.abs(speed - median)
                                      > 1e-9 * max(1.0, float(np.max(np.abs(speed))))))
        if moving < max(3, self.MIN_MOVING_FRACTION * speed.size):
            raise DataError(f'no response: the speed is nearly constant ({median:g} in '
                            f'{speed.size - moving} of {speed.size} samples); check the speed '
                            'column/topic and that the motor moved')

    def sample_rows(self) -> np.ndarray:
        """The recording as sample rows (:data:`motor_id.contracts.SAMPLE_COLUMNS`).

        Sequence numbers count from 0, flags are 0 and a missing current is NaN: the
        form in which a bag stores, and a replay publishes, a recording.
        """
        n = len(self)
        cur = self.current if self.current is not None else np.full(n, np.nan)
        return np.column_stack([np.arange(n, dtype=float), self.time, self.input, self.speed,
                                cur, np.zeros(n)])

    def to_dict(self) -> dict[str, Any]:
        """Plain lists for JSON."""
        d = {'time': self.time.tolist(), 'input': self.input.tolist(),
             'speed': self.speed.tolist(), 'input_kind': self.input_kind, 'meta': self.meta}
        if self.current is not None:
            d['current'] = self.current.tolist()
        if self.position is not None:
            d['position'] = self.position.tolist()
        return d


def _is_constant(values: np.ndarray) -> bool:
    """True when the values vary by no more than rounding (relative 1e-12)."""
    return bool(np.ptp(values) <= 1e-12 * max(1.0, float(np.max(np.abs(values)))))


def bad_magnitude(values: np.ndarray, relative: bool = True) -> tuple[int, str] | None:
    """The first value no measurement can have, and why; None when all are sane.

    Parameters
    ----------
    values : ndarray
        Finite values of one channel.
    relative : bool
        Also flag a value above :attr:`Recording.OUTLIER_RATIO` times the channel's
        typical magnitude (the 90th percentile of ``|values|``, or the median of the
        non-zero ones when that is 0): one corrupt cell among sane ones.

    Returns
    -------
    (int, str) or None
        Index of the first offending value and a one-line reason.
    """
    mag = np.abs(values)
    if mag.size == 0:
        return None
    huge = np.flatnonzero(mag > Recording.MAX_MAGNITUDE)
    if huge.size:
        k = int(huge[0])
        return k, (f'{values[k]:g} is above {Recording.MAX_MAGNITUDE:g} in magnitude '
                   "(the fit's arithmetic overflows): check the units or the column")
    if not relative:
        return None
    typical = float(np.percentile(mag, 90))
    if typical == 0.0:
        nonzero = mag[mag > 0]
        typical = float(np.median(nonzero)) if nonzero.size else 0.0
    if typical == 0.0:
        return None
    out = np.flatnonzero(mag > Recording.OUTLIER_RATIO * typical)
    if out.size:
        k = int(out[0])
        return k, (f'{values[k]:g} is {mag[k] / typical:.2g} times the typical magnitude '
                   f'{typical:.3g} of the channel: a corrupt value?')
    return None
