"""A gap-aware ring buffer of sample rows (seq, t, voltage, speed, current, flags)."""

from dataclasses import dataclass
import threading
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from motor_id.contracts import (
    CURRENT,
    FLAGS,
    INPUT,
    profile_span,
    SAMPLE_COLUMNS,
    SEQ,
    seq_step,
    SPEED,
    T,
)
from motor_id.errors import ConfigError, DataError
from motor_id.recording import MIN_SAMPLES, Recording

COLUMNS = SAMPLE_COLUMNS


@dataclass(frozen=True)
class Gap:
    """A break in the stream between two consecutive stored rows.

    Attributes
    ----------
    index : int
        Row (in the snapshot) that starts the segment after the gap.
    kind : {'lost', 'backwards', 'time', 'marked'}
        ``lost``: sequence numbers skipped (frames lost); ``backwards``: the sequence
        restarted or went back (card reset, out-of-order frame); ``time``: the sequence
        is contiguous but card time did not increase; ``marked``: the producer said so
        (device reopened).
    seq_before, seq_after : int
    t_before, t_after : float
    """

    index: int
    kind: str
    seq_before: int
    seq_after: int
    t_before: float
    t_after: float

    def describe(self) -> str:
        """One line for people."""
        if self.kind == 'lost':
            what = f'{self.seq_after - self.seq_before - 1} frame(s) lost'
        elif self.kind == 'backwards':
            what = 'sequence went backwards (card reset or reordering)'
        elif self.kind == 'time':
            what = 'card time did not increase'
        else:
            what = 'stream interrupted (device reopened)'
        return (f'{what} between seq {self.seq_before} (t={self.t_before:.4f} s) and '
                f'seq {self.seq_after} (t={self.t_after:.4f} s)')


@dataclass(frozen=True)
class Snapshot:
    """A copy of the buffer's window, oldest row first.

    Attributes
    ----------
    rows : ndarray, shape (n, 6)
        Columns as :data:`COLUMNS`.
    gaps : tuple of Gap
        Breaks inside the window (a gap before the first row is not listed).
    received, duplicates : int
        Buffer counters at the time of the snapshot.
    """

    rows: np.ndarray
    gaps: tuple = ()
    received: int = 0
    duplicates: int = 0

    def __len__(self) -> int:
        return self.rows.shape[0]

    @property
    def span(self) -> float:
        """Card time covered by the window [s] (0 when fewer than two rows)."""
        return float(self.rows[-1, T] - self.rows[0, T]) if len(self) > 1 else 0.0

    def latest_segment(self) -> 'Snapshot':
        """The most recent gap-free part of the window, as a Snapshot without gaps."""
        start = self.gaps[-1].index if self.gaps else 0
        return Snapshot(self.rows[start:], (), self.received, self.duplicates)

    def profile_segment(self) -> 'Snapshot':
        """The latest complete excitation profile (rows flagged by the card).

        See :func:`motor_id.contracts.profile_span` for the flags.

        Returns
        -------
        Snapshot
            The run's rows, with the gaps that fall inside it.

        Raises
        ------
        DataError
            No run has ended in the window, or the latest one started before it.
        """
        span = profile_span(self.rows[:, FLAGS])
        if span is None:
            raise DataError('no complete excitation profile in the window (none has ended '
                            'yet, or the window is too short)')
        start, end = span[0], span[1] - 1
        if start == 0:
            raise DataError(f'the latest excitation profile started before the window '
                            f'({len(self)} rows, {self.span:.3g} s); make the window longer')
        gaps = tuple(Gap(g.index - start, g.kind, g.seq_before, g.seq_after, g.t_before,
                         g.t_after) for g in self.gaps if start < g.index <= end)
        return Snapshot(self.rows[start:end + 1], gaps, self.received, self.duplicates)

    def to_recording(self, input_kind: str = 'voltage',
                     meta: dict[str, Any] | None = None) -> Recording:
        """The rows as a :class:`motor_id.recording.Recording` (no validation).

        The current channel is dropped when it is NaN throughout (a card without a
        current sensor); partial NaN stays so that validation reports it.
        """
        r = self.rows
        current: NDArray[np.float64] | None = r[:, CURRENT]
        if current is None or current.size == 0 or np.all(np.isnan(current)):
            current = None
        info = {'source': 'samples stream', 'samples': len(self)}
        if len(self):
            info.update(seq_first=int(r[0, SEQ]), seq_last=int(r[-1, SEQ]))
        info.update(meta or {})
        t, u, w = r[:, T].copy(), r[:, INPUT].copy(), r[:, SPEED].copy()
        if current is None:
            return Recording(t, u, w, input_kind=input_kind, meta=info)
        return Recording(t, u, w, current.copy(), input_kind, info)

    def recording(self, min_samples: int = MIN_SAMPLES, allow_gaps: bool = False,
                  input_kind: str = 'voltage', meta: dict[str, Any] | None = None) -> Recording:
        """A validated recording of the window, or :class:`DataError` saying why not.

        Parameters
        ----------
        min_samples : int
            Fewer rows than this is an error.
        allow_gaps : bool
            False: any gap in the window is an error. True: use the latest gap-free
            segment (which must itself hold ``min_samples`` rows).
        input_kind : {'voltage', 'torque'}
        meta : dict, optional

        Raises
        ------
        DataError
            Empty window, a gap, too few samples, NaN/inf, non-increasing time or a
            constant input, each with a one-line reason.
        """
        if len(self) == 0:
            raise DataError('no samples received yet: the buffer is empty '
                            '(is the driver publishing on samples?)')
        snap = self
        if self.gaps:
            last = self.gaps[-1]
            if not allow_gaps:
                raise DataError(f'{len(self.gaps)} gap(s) in the window, latest: '
                                f'{last.describe()}; {len(self) - last.index} sample(s) '
                                'since then (wait until the window is gap-free, or allow '
                                'gaps to fit the latest segment)')
            snap = self.latest_segment()
        if len(snap) < min_samples:
            raise DataError(f'too few samples: {len(snap)} in the window '
                            f'(need at least {min_samples})')
        rec = snap.to_recording(input_kind, meta)
        rec.validate(min_samples)
        return rec


class SampleBuffer:
    """Thread-safe ring buffer of sample rows that notices gaps as rows arrive.

    Parameters
    ----------
    capacity : int
        Rows kept (the window in samples).
    window_s : float or None
        If set, snapshots hold at most the last ``window_s`` seconds of card time.
    seq_modulus : int
        Sequence numbers wrap modulo this (the card's counter width).

    Notes
    -----
    A row is appended after the previous one with a gap mark when its sequence number
    is not the previous plus one (modulo ``seq_modulus``) or its time does not
    increase. A row with the same sequence number as the previous one is a duplicate
    and dropped; a row without a finite sequence number or time is dropped (counted in
    ``invalid``) and the next row starts a new segment.
    """

    def __init__(self, capacity: int = 100000, window_s: float | None = None,
                 seq_modulus: int = 2 ** 32) -> None:
        if int(capacity) < 2:
            raise ConfigError(f'capacity must be >= 2 rows, got {capacity}')
        if window_s is not None and not window_s > 0:
            raise ConfigError(f'window_s must be > 0 s, got {window_s}')
        if int(seq_modulus) < 2:
            raise ConfigError(f'seq_modulus must be >= 2, got {seq_modulus}')
        self.capacity = int(capacity)
        self.window_s = window_s
        self.seq_modulus = int(seq_modulus)
        self._lock = threading.Lock()
        self._rows = np.zeros((self.capacity, len(COLUMNS)))
        self._gap = np.zeros(self.capacity, dtype=bool)
        self._kind = np.zeros(self.capacity, dtype='<U9')
        self._next = 0       # write position
        self._count = 0      # rows stored (<= capacity)
        self._last: NDArray[np.float64] | None = None    # last stored row
        self._mark = False
        self.received = 0
        self.duplicates = 0
        self.invalid = 0
        self.gaps = 0

    def __len__(self) -> int:
        with self._lock:
            return self._count

    def mark_gap(self) -> None:
        """Declare that the next row does not continue the previous one."""
        with self._lock:
            self._mark = True

    def clear(self) -> None:
        """Drop every row (counters are kept)."""
        with self._lock:
            self._count = 0
            self._next = 0
            self._last = None
            self._mark = False

    def extend(self, rows: ArrayLike) -> int:
        """Append rows (array-like, shape (n, 6)); returns the number stored."""
        rows = np.asarray(rows, dtype=float)
        if rows.size == 0:
            return 0
        if rows.ndim != 2 or rows.shape[1] != len(COLUMNS):
            raise DataError(f'sample rows must have shape (n, {len(COLUMNS)}), '
                            f'got {rows.shape}')
        stored = 0
        with self._lock:
            for row in rows:
                self.received += 1
                if not (np.isfinite(row[SEQ]) and np.isfinite(row[T])):
                    self.invalid += 1
                    self._mark = True
                    continue
                kind = self._classify(row)
                if kind == 'duplicate':
                    self.duplicates += 1
                    continue
                if kind:
                    self.gaps += 1
                k = self._next
                self._rows[k] = row
                self._gap[k] = bool(kind)
                self._kind[k] = kind
                self._next = (k + 1) % self.capacity
                self._count = min(self._count + 1, self.capacity)
                self._last = row
                stored += 1
        return stored

    def _classify(self, row: NDArray[np.float64]) -> str:
        """'' (continues), 'duplicate', or the gap kind; consumes a pending mark."""
        last = self._last
        if last is None:
            self._mark = False
            return ''
        step = seq_step(int(last[SEQ]), int(row[SEQ]), self.seq_modulus)
        if step == 0:
            return 'duplicate'
        if step == 1:
            kind = ''
        elif step > 1:
            kind = 'lost'
        else:
            kind = 'backwards'
        if not kind and not row[T] > last[T]:
            kind = 'time'
        if self._mark:
            kind = kind or 'marked'
            self._mark = False
        return kind

    def snapshot(self) -> Snapshot:
        """Copy the window under the lock and describe its gaps.

        Returns
        -------
        Snapshot
        """
        with self._lock:
            n = self._count
            idx = (self._next - n + np.arange(n)) % self.capacity
            rows = self._rows[idx].copy()
            gap = self._gap[idx].copy()
            kinds = self._kind[idx].copy()
            received, duplicates = self.received, self.duplicates
        if n and self.window_s is not None:
            age = rows[-1, T] - rows[:, T]
            outside = np.flatnonzero(~((age >= 0) & (age <= self.window_s)))
            if outside.size:
                start = outside[-1] + 1
                rows, gap, kinds = rows[start:], gap[start:], kinds[start:]
        gaps = tuple(Gap(int(k), str(kinds[k]), int(rows[k - 1, SEQ]), int(rows[k, SEQ]),
                         float(rows[k - 1, T]), float(rows[k, T]))
                     for k in np.flatnonzero(gap) if k > 0)
        return Snapshot(rows, gaps, received, duplicates)
