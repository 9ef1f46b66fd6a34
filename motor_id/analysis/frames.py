"""Held readings: a channel that is logged faster than its sensor reports.

A motor controller on a bus (a CAN status frame every 20 ms, say) updates its speed and
position readings once a frame; a robot that logs every 5 ms writes the last value it
received until the next frame arrives, so each reading repeats for a few samples and then
jumps. Between frames the log says nothing new, and a model compared with every sample
is judged on stale copies (the repeated value against a motion that went on).

The evidence is in the values themselves, as for a grid (:mod:`.measurement`):

1. while the channel moves, consecutive samples repeat *exactly* far more often than a
   continuous or even a finely quantised sensor repeats (``min_repeated``: a quantised
   speed at a steady level flickers between grid points; it does not freeze while the
   motion changes);
2. the changes come at a steady rhythm: the time between consecutive changes has a clear
   typical value, the frame period, at least 1.5 sample periods, with a small spread
   (``max_spread``: the interquartile range over the median).

A channel with held readings is scored at its *fresh* samples only: the sample at which
a new value arrived, and, while the value stays put for longer than a frame (at rest),
one sample per frame period (a frame arrived and said the same).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from motor_id.records import finite, internal, Record, written

if TYPE_CHECKING:
    from motor_id.recording import Recording

MIN_CHANGES = 20
"""Value changes the rhythm test needs."""


@dataclass(kw_only=True)
class FrameEvidence(Record):
    """What one channel's repeats say about held readings."""

    channel: str
    found: bool
    repeated_moving: float = written(finite)
    """Share of the moving samples whose value equals the previous sample's."""
    frame_period: float = written(finite)
    """Median time between value changes [s] (nan when there are too few)."""
    frame_samples: float = written(finite)
    """The frame period in median sample periods."""
    spread: float = written(finite)
    """Interquartile range of the times between changes over their median."""
    fresh_share: float = written(finite)
    """Share of the samples that carry a new reading."""
    reason: str
    fresh: np.ndarray = internal(default_factory=lambda: np.ones(0, dtype=bool))
    """Per sample: it carries a new reading (:func:`fresh_mask`; all True when no held
    readings were found). Not part of :meth:`to_dict`."""



def _moving(y: np.ndarray, frac: float = 0.05) -> np.ndarray:
    """Samples taken while the channel moves: within a short window of a change of more
    than ``frac`` of the channel's spread (a motion, not a flicker at rest)."""
    spread = float(np.ptp(y)) or 1.0
    big = np.abs(np.diff(y, prepend=y[0])) > 1e-3 * spread
    # a change at k says the channel was moving around k: mark +-8 samples
    idx = np.flatnonzero(big)
    mask = np.zeros(y.size, dtype=bool)
    for off in range(-8, 9):
        j = idx + off
        mask[j[(j >= 0) & (j < y.size)]] = True
    level = np.abs(y - np.median(y)) > frac * spread
    return mask & level if y.size else mask


def frame_evidence(time: np.ndarray, y: np.ndarray, channel: str = 'speed',
                   segments: list[tuple[int, int]] | None = None,
                   min_repeated: float = 0.5, max_spread: float = 0.35) -> FrameEvidence:
    """Test one channel for held readings (see the module notes).

    Parameters
    ----------
    time, y : ndarray
        Sample times [s] and the channel's values.
    channel : str
    segments : list of (start, stop), optional
        Separate runs (changes are not counted across their joins).
    min_repeated : float
        Share of repeated moving samples above which readings count as held.
    max_spread : float
        Largest interquartile range of the times between changes, over their median.
    """
    segments = segments or [(0, y.size)]
    rep: list[np.ndarray] = []
    gaps: list[np.ndarray] = []
    dts: list[np.ndarray] = []
    for a, b in segments:
        yy, tt = y[a:b], time[a:b]
        if yy.size < 3:
            continue
        same = np.diff(yy) == 0
        mov = _moving(yy)[1:]
        rep.append(same[mov])
        ch = np.flatnonzero(~same) + 1
        gaps.append(np.diff(tt[ch]))
        dts.append(np.diff(tt))
    r = np.concatenate(rep) if rep else np.zeros(0, dtype=bool)
    g = np.concatenate(gaps) if gaps else np.zeros(0)
    dt = float(np.median(np.concatenate(dts))) if dts else float('nan')
    repeated = float(np.mean(r)) if r.size else 0.0
    if g.size < MIN_CHANGES or not np.isfinite(dt) or dt <= 0:
        return FrameEvidence(channel=channel, found=False, repeated_moving=repeated,
                             frame_period=float('nan'), frame_samples=float('nan'),
                             spread=float('nan'), fresh_share=1.0,
                             reason=f'fewer than {MIN_CHANGES} value changes',
                             fresh=np.ones(y.size, dtype=bool))
    period = float(np.median(g))
    q1, q3 = np.percentile(g, [25, 75])
    spread = float((q3 - q1) / period) if period > 0 else float('inf')
    frames = period / dt
    reason = ''
    if repeated < min_repeated:
        reason = (f'{100 * repeated:.0f} % of the moving samples repeat '
                  f'(held readings: at least {100 * min_repeated:.0f} %)')
    elif frames < 1.5:
        reason = f'values change every {frames:.2f} samples'
    elif spread > max_spread:
        reason = (f'the times between changes spread {spread:.2f} of their median '
                  f'(a frame rhythm: at most {max_spread})')
    found = not reason
    fresh = fresh_mask(time, y, period, segments) if found else np.ones(y.size, bool)
    return FrameEvidence(channel=channel, found=found, repeated_moving=repeated,
                         frame_period=period, frame_samples=frames, spread=spread,
                         fresh_share=float(np.mean(fresh)), reason=reason or
                         f'{100 * repeated:.0f} % of the moving samples repeat; a new '
                         f'value every {1e3 * period:.1f} ms ({frames:.1f} samples)',
                         fresh=fresh)


def fresh_mask(time: np.ndarray, y: np.ndarray, period: float,
               segments: list[tuple[int, int]] | None = None) -> np.ndarray:
    """True at the samples carrying a new reading: where the value changed (and a run's
    first sample), and while it stays put, one sample per frame ``period``."""
    segments = segments or [(0, y.size)]
    out = np.zeros(y.size, dtype=bool)
    for a, b in segments:
        yy, tt = y[a:b], time[a:b]
        starts = np.concatenate([[0], np.flatnonzero(np.diff(yy) != 0) + 1])
        stops = np.append(starts[1:], yy.size)
        for s, e in zip(starts, stops, strict=True):
            out[a + s] = True
            if e - s > 1:
                # a frame that repeated the value: one mark per period after the change
                n = np.floor((tt[s:e] - tt[s]) / period + 0.15).astype(int)
                keep = np.flatnonzero(np.diff(n) > 0) + 1
                out[a + s + keep] = True
    return out


def held_channels(rec: Recording, channels: tuple[str, ...]) -> dict[str, FrameEvidence]:
    """The evidence for each of ``channels`` of ``rec``."""
    return {ch: frame_evidence(rec.time, np.asarray(getattr(rec, ch), dtype=float), ch,
                               rec.segment_ranges)
            for ch in channels}
