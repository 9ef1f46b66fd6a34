"""A time shift between input and output: detect it with quick ARX fits, apply a fix."""

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from motor_id.errors import ConfigError, DataError
from motor_id.recording import Recording


def shift_input(rec: Recording, samples: int) -> Recording:
    """A recording whose input is advanced by ``samples`` (delayed when negative).

    ``out.input[k] = rec.input[k + samples]``; the samples without a partner are dropped.

    Parameters
    ----------
    rec : Recording
    samples : int

    Returns
    -------
    Recording
    """
    s = int(samples)
    if s == 0:
        return rec
    n = len(rec)
    if abs(s) >= n:
        raise ConfigError(f'shift {s} is not smaller than the recording ({n} samples)',
                          params=('shift',))
    keep = slice(0, n - s) if s > 0 else slice(-s, n)
    moved = slice(s, n) if s > 0 else slice(0, n + s)
    meta = dict(rec.meta)
    meta['input_shift_samples'] = s
    cur = None if rec.current is None else rec.current[keep]
    return Recording(rec.time[keep], rec.input[moved], rec.speed[keep], cur, rec.input_kind,
                     meta)


@dataclass
class ShiftCheck:
    """Result of :func:`detect_shift`.

    Attributes
    ----------
    samples : int
        Best shift: ``shift_input(rec, samples)`` explains the data best; 0 when no shift
        is clearly better than none.
    seconds : float
        ``samples`` times the median sample period [s].
    channel : str
        The output used (``current`` when measured on a voltage plant, else ``speed``).
    relative_rss : dict
        Residual sum of squares of the quick ARX fit per shift, relative to shift 0.
    """

    samples: int
    seconds: float
    channel: str
    relative_rss: dict = field(default_factory=dict)

    def message(self) -> str:
        """One line for people: what is shifted and how to fix it ('' when nothing)."""
        s = self.samples
        if s == 0:
            return ''
        ms = abs(self.seconds) * 1e3
        n = f'{abs(s)} sample{"s" if abs(s) > 1 else ""} ({ms:.3g} ms)'
        if s > 0:
            return (f'the {self.channel} responds {n} before the recorded input could cause '
                    f'it (the input is stamped late, e.g. a command published just after '
                    f'reading the state): re-run with --align next or --shift {s}')
        return (f'the {self.channel} responds {n} later than the model expects (a dead time '
                f'or an input stamped early): re-run with --shift {s}')

    def to_dict(self) -> dict[str, Any]:
        """Plain values for JSON."""
        return {'samples': self.samples, 'seconds': self.seconds, 'channel': self.channel,
                'relative_rss': {str(k): v for k, v in self.relative_rss.items()},
                'message': self.message()}


def detect_shift(rec: Recording, max_shift: int = 3, min_gain: float = 0.5,
                 max_samples: int = 200_000) -> ShiftCheck:
    """Find a time shift between the input and the output with quick linear ARX fits.

    For each shift ``s`` in ``-max_shift..max_shift`` a least-squares ARX model of the
    output one step ahead is fitted with the input shifted by ``s``. With a current
    channel on a voltage plant the current is used (it responds to the voltage within
    one sample): ``i[k+1] ~ i[k], w[k], u[k+s], 1``; otherwise the speed
    ``w[k+1] ~ w[k], w[k-1], u[k+s], u[k+s-1], 1``.

    Parameters
    ----------
    rec : Recording
        Validated (finite values); the runs of a joined recording are fitted together,
        but no regression row spans two runs.
    max_shift : int
        Largest shift tried [samples].
    min_gain : float
        The best shift is reported only when its residual sum of squares is below
        ``(1 - min_gain)`` times that of shift 0.
    max_samples : int
        Only the first ``max_samples`` samples are used (speed on long recordings).

    Returns
    -------
    ShiftCheck

    Notes
    -----
    In closed loop a controller that reacts to the speed makes a later input look
    informative about the speed; the current-based test is much less affected.
    """
    n = min(len(rec), int(max_samples))
    if n < 4 * max_shift + 20:
        raise DataError(f'too few samples ({n}) to check for a shift of up to {max_shift}')
    use_current = rec.has_current and rec.input_kind == 'voltage'
    channel = 'current' if use_current else 'speed'

    def norm(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x[:n], dtype=float)
        sd = np.std(x)
        return (x - np.mean(x)) / (sd if sd > 0 else 1.0)

    u, w = norm(rec.input), norm(rec.speed)
    i = norm(rec.current) if use_current and rec.current is not None else None
    k = np.arange(max_shift + 1, n - max_shift - 1)
    # separate runs of a joined recording: no regression row reaches across a boundary
    run = rec.segment_index()[:n]
    k = k[run[k - max_shift - 1] == run[k + max_shift + 1]]
    ones = np.ones(k.size)
    rss = {}
    for s in range(-max_shift, max_shift + 1):
        if i is not None:
            X = np.column_stack([i[k], w[k], u[k + s], ones])
            y = i[k + 1]
        else:
            X = np.column_stack([w[k], w[k - 1], u[k + s], u[k + s - 1], ones])
            y = w[k + 1]
        coef = np.linalg.lstsq(X, y, rcond=None)[0]
        rss[s] = float(np.sum((y - X @ coef) ** 2))
    base = rss[0] if rss[0] > 0 else np.finfo(float).tiny
    rel = {s: r / base for s, r in rss.items()}
    best = min(rel, key=rel.__getitem__)
    if best != 0 and rel[best] >= 1.0 - min_gain:
        best = 0
    period = rec.sample_period
    return ShiftCheck(samples=int(best), seconds=float(best * period), channel=channel,
                      relative_rss=rel)
