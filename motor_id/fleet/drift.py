"""Drift in a parameter's history: a CUSUM on predictive scores from the motor's own baseline.

The rule (:class:`DriftRule`), per robot, motor and parameter, on the estimates in time
order (undetermined ones left out), in logs, so that every change is relative. It is a
self-starting CUSUM (Hawkins 1987) with the estimates' error bars folded in:

1. **Baseline.** A regime's first ``min_base`` estimates start its baseline untested;
   every later estimate joins it (unless it scores beyond ``outlier``: a gross error),
   but only ``guard`` estimates after its own test, so that the first estimates after a
   change cannot hide it. The baseline's mean m and sample std S give the motor's own
   day-to-day scatter ``tau^2 = max(S^2 - mean(s_b^2), floor^2)``: the scatter of the
   values less what the estimates' own error bars (s_b, relative std of each fit)
   already explain.
2. **Score.** Each later estimate y with error bar s gets the predictive t statistic
   ``t = (y - m) / sqrt(tau^2 + s^2 + (tau^2 + mean(s_b^2)) / n)``, Student-t with
   n - 1 degrees of freedom when nothing changed (n baseline estimates), mapped to the
   normal score z with the same tail probability (a short baseline pays for its own
   uncertainty) and clipped to +-``cap``.
3. **Decision.** A two-sided CUSUM, ``C+ = max(0, C+ + z - k)``, ``C- = max(0, C- - z -
   k)``, flags a change when either exceeds ``h``. With ``cap - k < h`` one estimate,
   however far off, never flags alone: a bad recording is not a drift.
4. **Change point.** Between the estimate where the flagging sum last left zero and the
   flagged one, the split that best separates the means before and after (least
   squares); the regime restarts there, so a second change is found too.

``change`` is the median of the estimates since the last change point over the baseline
mean, minus 1. The false-alarm rate of the defaults, measured on the fleet generator
(:mod:`motor_id.testing.fleet_gen`, R_m +-2 % from day to day), is in docs/fleet.md.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from motor_id.errors import ConfigError


@dataclass(frozen=True)
class DriftRule:
    """Settings of the drift test (see the module docstring).

    Attributes
    ----------
    min_base : int
        Estimates that start a regime's baseline untested (at least 3).
    guard : int
        An estimate joins the baseline this many tests after its own.
    k : float
        CUSUM allowance per estimate, in normal scores.
    h : float
        CUSUM decision threshold.
    cap : float
        Largest score one estimate can contribute.
    floor : float
        Smallest relative day-to-day scatter assumed (0.002: 0.2 %).
    outlier : float
        An estimate scoring beyond this does not join the baseline.
    """

    min_base: int = 5
    guard: int = 2
    k: float = 1.0
    h: float = 7.0
    cap: float = 6.0
    floor: float = 0.002
    outlier: float = 5.0

    def __post_init__(self) -> None:
        for name, low in (('min_base', 3), ('guard', 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ConfigError(f'drift: {name} must be a whole number >= {low}, '
                                  f'got {v!r}')
        for name in ('k', 'h', 'cap', 'floor', 'outlier'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f'drift: {name} must be a number > 0, got {v!r}')

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> DriftRule:
        """A rule from a profile's ``drift:`` mapping (unknown keys refused)."""
        d = dict(d or {})
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(f'drift: unknown key(s) {", ".join(unknown)} (known: '
                              f'{", ".join(sorted(known))})')
        return cls(**d)

    def to_dict(self) -> dict[str, Any]:
        """The settings, for the outputs."""
        return asdict(self)

    def scan(self, times: Sequence[Any], values: Sequence[float | None],
             stds: Sequence[float | None] | None = None) -> DriftFinding:
        """Run the rule over one history.

        Parameters
        ----------
        times : sequence
            Time of each estimate (any sortable value; ISO strings or datetimes), in order.
        values : array_like
            Estimates (> 0; None or NaN: left out).
        stds : array_like, optional
            Their standard errors (None or NaN: 0).

        Returns
        -------
        DriftFinding
        """
        times = list(times)
        x = np.array([np.nan if v is None else float(v) for v in values], dtype=float)
        s = np.zeros_like(x) if stds is None else np.array(
            [np.nan if v is None else float(v) for v in stds], dtype=float)
        keep = np.flatnonzero(np.isfinite(x) & (x > 0))
        if keep.size and np.all(x[keep] == x[keep[0]]) and \
                not np.any(np.nan_to_num(s[keep]) > 0):
            return DriftFinding(detected=False, n=int(keep.size),
                                reason='held at one value (not estimated)',
                                baseline=float(x[keep[0]]), latest=float(x[keep[-1]]),
                                change=0.0)
        t_kept = [times[i] for i in keep]
        y = np.log(x[keep])
        rel = np.nan_to_num(s[keep] / x[keep], nan=0.0, posinf=0.0)
        return self._scan(t_kept, y, rel, keep)

    def _scan(self, times: list[Any], y: NDArray[np.float64], rel: NDArray[np.float64],
              index: NDArray[np.intp]) -> DriftFinding:
        from scipy import stats
        n = y.size
        finding = DriftFinding(detected=False, n=int(n), scores=[None] * n)
        if n < self.min_base + self.guard + 1:
            finding.reason = (f'{n} estimate(s); the rule needs '
                              f'{self.min_base + self.guard + 1}')
            if n:
                finding.baseline = float(np.exp(np.mean(y)))
                finding.latest = float(np.exp(y[-1]))
                finding.change = finding.latest / finding.baseline - 1.0
            return finding
        members: list[int] = []   # the regime's estimates that count as in control
        c_pos = c_neg = 0.0
        start_pos = start_neg = 0
        for j in range(n):
            if len(members) < self.min_base + self.guard:
                members.append(j)
                continue
            m, tau2, sb2, nb = self._baseline(y, rel, members[:len(members) - self.guard])
            scale = math.sqrt(tau2 + rel[j] ** 2 + (tau2 + sb2) / nb)
            t = (y[j] - m) / scale
            p = stats.t.sf(abs(t), nb - 1)
            z = math.copysign(float(stats.norm.isf(max(p, 1e-300))), t) if t else 0.0
            z = max(-self.cap, min(self.cap, z))
            finding.scores[j] = z
            if c_pos == 0.0:
                start_pos = j
            if c_neg == 0.0:
                start_neg = j
            c_pos = max(0.0, c_pos + z - self.k)
            c_neg = max(0.0, c_neg - z - self.k)
            if c_pos > self.h or c_neg > self.h:
                c = _split(y, members[:len(members) - self.guard],
                           start_pos if c_pos > self.h else start_neg, j)
                finding.change_points.append({
                    'index': int(index[c]), 'since': _iso(times[c]),
                    'flagged_index': int(index[j]), 'flagged_at': _iso(times[j]),
                    'before': float(np.exp(m)), 'scatter': float(math.sqrt(tau2)),
                    '_pos': c})
                members = list(range(c, j + 1))
                c_pos = c_neg = 0.0
                continue
            if abs(z) < self.outlier:
                members.append(j)
        return self._finish(finding, y, rel, members)

    def _baseline(self, y: NDArray[np.float64], rel: NDArray[np.float64], base: list[int]
                  ) -> tuple[float, float, float, int]:
        """(mean, tau^2, mean s_b^2, n) of the baseline points."""
        yb = y[base]
        nb = len(base)
        sb2 = float(np.mean(rel[base] ** 2))
        var = float(np.var(yb, ddof=1))
        tau2 = max(var - sb2, self.floor ** 2)
        return float(np.mean(yb)), tau2, sb2, nb

    def _finish(self, finding: DriftFinding, y: NDArray[np.float64], rel: NDArray[np.float64],
                members: list[int]) -> DriftFinding:
        f = finding
        cps = f.change_points
        for a, cp in enumerate(cps):
            lo = cp.pop('_pos')
            hi = cps[a + 1]['_pos'] if a + 1 < len(cps) else y.size
            after = float(np.exp(np.median(y[lo:hi])))
            cp['after'] = after
            cp['change'] = after / cp['before'] - 1.0
            cp['z'] = math.log(after / cp['before']) / max(cp['scatter'], 1e-12)
        if cps:
            last = cps[-1]
            f.detected = True
            f.baseline, f.latest = last['before'], last['after']
            f.change, f.since, f.z = last['change'], last['since'], last['z']
            return f
        m = self._baseline(y, rel, members)[0]
        f.baseline = float(np.exp(m))
        f.latest = float(np.exp(y[-1]))
        f.change = f.latest / f.baseline - 1.0
        f.z = f.scores[-1] if f.scores[-1] is not None else 0.0
        return f


@dataclass
class DriftFinding:
    """What :meth:`DriftRule.scan` found in one history.

    Attributes
    ----------
    detected : bool
    change : float
        Relative change of the latest regime over its baseline (or of the latest estimate
        over the baseline when nothing was detected).
    since : str or None
        ISO time of the last change point.
    z : float
        The change in units of the baseline's day-to-day scatter (detected), or the
        latest estimate's score.
    baseline, latest : float
        Level before the change and after it (or the latest estimate).
    change_points : list of dict
        Every change found: ``index`` (into the history given), ``since``,
        ``flagged_index``, ``flagged_at``, ``before``, ``after``, ``change``, ``z``.
    scores : list
        The clipped normal score of each estimate kept (None: baseline, untested).
    n : int
        Estimates used.
    reason : str or None
        Why nothing could be tested.
    """

    detected: bool
    n: int = 0
    change: float | None = None
    since: str | None = None
    z: float | None = None
    baseline: float | None = None
    latest: float | None = None
    change_points: list[dict[str, Any]] = field(default_factory=list)
    scores: list[float | None] = field(default_factory=list)
    reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``scores`` left out)."""
        d = asdict(self)
        d.pop('scores')
        return d


def _split(y: NDArray[np.float64], base: list[int], start: int, end: int) -> int:
    """The change point in ``start..end``: the split that best separates the means of the
    estimates before it (with the baseline) and from it on (least squares)."""
    best, best_stat = start, -1.0
    for c in range(start, end + 1):
        before = np.concatenate([y[base], y[start:c]])
        after = y[c:end + 1]
        stat = abs(after.mean() - before.mean()) * math.sqrt(
            before.size * after.size / (before.size + after.size))
        if stat > best_stat:
            best, best_stat = c, stat
    return best


def _iso(t: object) -> str | None:
    """An ISO text of a time value (strings pass through)."""
    if t is None or isinstance(t, str):
        return t
    iso = getattr(t, 'isoformat', None)
    return iso() if iso is not None else str(t)
