"""Sequence numbers of the card's frames: lost, duplicated, late and restarted streams.

Link state, not wire format: the link keeps one :class:`SequenceTracker` per card and
asks it what each received sequence number means. The arithmetic (a wrap-aware signed
step) is :func:`motor_id.contracts.seq_step`, shared with the ring buffer and the bag
reader.
"""

from collections import deque
from dataclasses import dataclass

from motor_id.card.protocol import check_uint
from motor_id.contracts import SEQ_MODULUS, seq_step
from motor_id.errors import ConfigError


@dataclass(frozen=True)
class SeqEvent:
    """What one sequence number means relative to the ones before it.

    Attributes
    ----------
    kind : {'first', 'ok', 'gap', 'duplicate', 'late', 'reset'}
        ``first``: the first number seen; ``ok``: the previous + 1; ``gap``: numbers
        were skipped (``lost`` of them); ``duplicate``: seen recently; ``late``: an
        older number not seen before (out of order; it had been counted lost);
        ``reset``: the sequence restarted (startup flag, jump back beyond the window or
        forward beyond ``max_gap``).
    seq : int
    lost : int
        Frames missing before this one (``gap`` only).
    """

    kind: str
    seq: int
    lost: int = 0


class SequenceTracker:
    """Classify successive uint32 sequence numbers; count lost, duplicated, late frames.

    Parameters
    ----------
    window : int
        How many recent numbers are remembered to recognise duplicates and late frames.
    max_gap : int
        A forward jump larger than this is a reset, not a loss.
    modulus : int
        Sequence numbers wrap at this value.

    Attributes
    ----------
    received, lost, duplicates, late, resets : int
        Counters. ``lost`` is net: a late frame that arrives after all is taken off.
    """

    def __init__(self, window: int = 256, max_gap: int = 2 ** 24,
                 modulus: int = SEQ_MODULUS) -> None:
        if window < 1 or max_gap < 1 or modulus < 2 * (window + 1):
            raise ConfigError('SequenceTracker needs window >= 1, max_gap >= 1 and '
                              'modulus > 2 * window')
        self.window = int(window)
        self.max_gap = int(max_gap)
        self.modulus = int(modulus)
        self.received = self.lost = self.duplicates = self.late = self.resets = 0
        self.last: int | None = None
        self._first = 0   # the first number since the last (re)start; set with last
        self._seen: deque[int] = deque()
        self._seen_set: set[int] = set()

    def _signed(self, d: int) -> int:
        return int(seq_step(0, d, self.modulus))

    def _remember(self, seq: int) -> None:
        self._seen.append(seq)
        self._seen_set.add(seq)
        if len(self._seen) > self.window:
            self._seen_set.discard(self._seen.popleft())

    def _restart(self, seq: int) -> None:
        self.last = self._first = seq
        self._seen.clear()
        self._seen_set.clear()
        self._remember(seq)

    def update(self, seq: int, restart: bool = False) -> SeqEvent:
        """Account for one received sequence number.

        Parameters
        ----------
        seq : int
            The frame's sequence number, 0 <= seq < modulus.
        restart : bool
            The card says it restarted (:data:`FLAG_STARTUP`).

        Returns
        -------
        SeqEvent
        """
        seq = check_uint('seq', seq, self.modulus)
        self.received += 1
        if self.last is None or restart:
            kind = 'first' if self.last is None else 'reset'
            self.resets += kind == 'reset'
            self._restart(seq)
            return SeqEvent(kind, seq)
        d = self._signed(seq - self.last)
        if d == 1:
            self.last = seq
            self._remember(seq)
            return SeqEvent('ok', seq)
        if 1 < d <= self.max_gap:
            self.lost += d - 1
            self.last = seq
            self._remember(seq)
            return SeqEvent('gap', seq, d - 1)
        if seq in self._seen_set:
            self.duplicates += 1
            return SeqEvent('duplicate', seq)
        if -self.window <= d < 0:
            self.late += 1
            if self._signed(seq - self._first) > 0:
                self.lost -= 1
            self._remember(seq)
            return SeqEvent('late', seq)
        self.resets += 1
        self._restart(seq)
        return SeqEvent('reset', seq)
