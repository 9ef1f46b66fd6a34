"""Drift in a parameter's history: a change-point test over the whole history at each recording.

The rule (:class:`DriftRule`), per robot, motor and parameter, on the estimates in time
order (undetermined ones left out), in logs, so that every change is relative. Each
estimate ``y_i`` has its own error bar ``s_i`` (the fit's relative standard error) and
the motor scatters from day to day by ``tau`` beyond it
(:mod:`motor_id.fleet.scatter`: pooled over the motor and its siblings, robust to the
changes themselves), so ``var(y_i) = tau^2 + s_i^2`` while nothing changes.

1. **Every split.** For each split of the history into the estimates before and from
   recording k on, the weighted two-sample statistic ``T_k = (m_after - m_before) /
   sqrt(1/W_before + 1/W_after)`` (weighted means, weights ``1 / (tau^2 + s_i^2)``,
   W their sums): N(0, 1) at every k while nothing changed. The largest ``|T_k|`` is
   the likelihood-ratio statistic of one change at an unknown recording against none;
   the k that reaches it dates the change.
2. **Threshold.** ``|T|`` becomes the normal score with the same tail probability
   under Student t with the scatter's degrees of freedom (a scatter from few
   differences pays for its uncertainty), and the history drifts when that score
   exceeds ``threshold``. A constant threshold holds the false-alarm rate per
   recording about constant over the history's length (the max over more splits of
   a longer history is offset by its splits being more alike; measured by simulation
   in benchmarks/fleet_drift.py, which also gives the false alarms per motor-year of
   the default).
3. **Persistence.** The test runs from the 3rd recording on. The recordings after a
   change must be at least 2 (one recording, however far off, is never a drift), the
   first regime may be one recording (a change at the 2nd recording is found). An
   estimate off from both neighbours by more than ``outlier`` standard deviations of a
   difference, in the same direction, is a gross error left out (``outliers``); the
   latest estimate, off from the one before by as much, waits for the next recording.
4. **The first week.** The splits with at most ``early`` recordings before them are also
   held to ``early_threshold``: their first regime is fixed, so each one's statistic
   settles as the history grows, and these few need no allowance for the many splits
   and looks of a long history. A change at the 2nd recording (one recording before it)
   is found when it is a few day-to-day scatters, not only beyond ``threshold``.
5. **More changes.** Binary segmentation: each side of a change is tested again with
   the same threshold, so a later second change (or an earlier one) is found too.
   Changes in the same direction with at most ``ramp_gap`` recordings between them are
   one ramp: ``since`` its first recording after the change began, ``until`` the
   first at the new level.

``since`` is the first recording after the change; ``flagged_at`` is the first
recording at which the test (on the data known then) flagged it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from motor_id.errors import ConfigError
from motor_id.fleet.scatter import Scatter, ScatterPool
from motor_id.fleet.segment import best_split, change_groups, level_of, shape_change
from motor_id.records import Record

MIN_RECORDINGS = 3
"""Recordings before the test runs: 1 before a change and 2 after it."""
@dataclass(frozen=True)
class Series:
    """One parameter's history prepared for the test: kept estimates only.

    Attributes
    ----------
    times : tuple
        Time of each kept estimate.
    y : ndarray
        Log of each kept estimate.
    rel : ndarray
        Its relative standard error (0 when unknown).
    index : ndarray of int
        Position of each kept estimate in the history given.
    held : bool
        Every estimate the same with no error bar: held at one value, not estimated.
    """

    times: tuple[Any, ...]
    y: NDArray[np.float64]
    rel: NDArray[np.float64]
    index: NDArray[np.intp]
    held: bool = False


def series(times: Sequence[Any], values: Sequence[float | None],
           stds: Sequence[float | None] | None = None) -> Series:
    """Keep the finite positive estimates of a history, in logs.

    Parameters
    ----------
    times : sequence
        Time of each estimate, in order (sortable; ISO text of one format or datetimes).
    values : array_like
        Estimates (> 0; None or NaN: left out).
    stds : array_like, optional
        Their standard errors (None or NaN: 0).
    """
    x = np.array([np.nan if v is None else float(v) for v in values], dtype=float)
    s = np.zeros_like(x) if stds is None else np.array(
        [np.nan if v is None else float(v) for v in stds], dtype=float)
    keep = np.flatnonzero(np.isfinite(x) & (x > 0))
    rel = np.nan_to_num(s[keep] / x[keep], nan=0.0, posinf=0.0)
    held = bool(keep.size) and bool(np.all(x[keep] == x[keep[0]])) and \
        not bool(np.any(rel > 0))
    return Series(times=tuple(times[int(i)] for i in keep), y=np.log(x[keep]), rel=rel,
                  index=keep, held=held)


@dataclass(frozen=True)
class ChangePoint(Record):
    """One change found in a history.

    Attributes
    ----------
    index : int
        Position (in the history given) of the first recording after the change.
    since : str or None
        Its time.
    until_index : int
        First recording at the new level (``index`` for a step).
    until : str or None
        Its time.
    kind : {'step', 'ramp'}
    flagged_index : int
        First recording at which the test flagged this change.
    flagged_at : str or None
        Its time.
    before, after : float
        Level before and after (weighted geometric means of the recordings between the
        neighbouring changes).
    change : float
        ``after / before - 1``.
    z : float
        ``log(after / before)`` in day-to-day scatters.
    score : float
        The test's normal score for this change on the whole history.
    """

    index: int
    since: str | None
    until_index: int
    until: str | None
    kind: str
    flagged_index: int
    flagged_at: str | None
    before: float
    after: float
    change: float
    z: float
    score: float


@dataclass(frozen=True)
class DriftFinding(Record):
    """What :meth:`DriftRule.scan` found in one history.

    Attributes
    ----------
    detected : bool
    n : int
        Estimates used.
    change : float or None
        Relative change of the latest regime over the level before it (detected), or of
        the latest estimate over the history's level.
    since : str or None
        First recording after the last change.
    z : float or None
        ``change`` (in logs) in day-to-day scatters.
    baseline, latest : float or None
        Level before the last change and after it (or the history's level and the latest
        estimate).
    level, level_std : float or None
        The latest regime's level and its relative standard error.
    scatter, dof : float or None
        The day-to-day scatter tau (relative) the test used and its degrees of freedom.
    score : float or None
        The test's normal score on the whole history (largest over the splits).
    threshold : float
    early_score : float or None
        The normal score of the largest split with at most ``DriftRule.early``
        recordings before it (a change in the first week).
    early_threshold : float
    change_points : tuple of ChangePoint
    outliers : tuple of int
        Positions left out as gross errors (or the latest, waiting for the next).
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
    level: float | None = None
    level_std: float | None = None
    scatter: float | None = None
    dof: float | None = None
    score: float | None = None
    threshold: float = 0.0
    early_score: float | None = None
    early_threshold: float = 0.0
    change_points: tuple[ChangePoint, ...] = ()
    outliers: tuple[int, ...] = ()
    reason: str | None = None


@dataclass(frozen=True)
class DriftRule(Record):
    """Settings of the drift test (see the module docstring).

    Attributes
    ----------
    threshold : float
        Normal score beyond which a history drifts (the default holds false alarms to
        under 1 per 100 motor-years of daily recordings: docs/fleet.md).
    floor : float
        Smallest relative day-to-day scatter assumed (0.002: 0.2 %).
    outlier : float
        An estimate this many standard deviations of a difference off from both
        neighbours, the same way, is a gross error left out.
    ramp_gap : int
        Changes in the same direction with at most this many recordings between them
        are one ramp.
    sibling_threshold : float
        Normal score beyond which a motor is reported against its siblings
        (:mod:`motor_id.fleet.siblings`).
    early : int
        The splits with at most this many recordings before them (a change by the
        ``early + 1``-th recording: the first week) are also held to ``early_threshold``.
    early_threshold : float
        Normal score beyond which the largest of those early splits flags a change. A
        split's statistic with k recordings before it settles as the history grows (its
        first regime is fixed), so these few splits need no allowance for the many splits
        and looks of a long history, and a change in the first week, with one or two
        recordings before it, is found (docs/fleet.md: the false alarms it costs).
    """

    threshold: float = 5.3
    floor: float = 0.002
    outlier: float = 4.0
    ramp_gap: int = 3
    sibling_threshold: float = 3.5
    early: int = 6
    early_threshold: float = 4.0

    def __post_init__(self) -> None:
        for name in ('ramp_gap', 'early'):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ConfigError(f'drift: {name} must be a whole number >= 0, got {v!r}')
        for name in ('threshold', 'floor', 'outlier', 'sibling_threshold',
                     'early_threshold'):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v)
                                           and v > 0):
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

    def pool(self, histories: Sequence[Series], units: Sequence[str] | None = None
             ) -> ScatterPool:
        """The scatter pooled over histories of one parameter (a motor and its siblings;
        ``units``: the robot of each, see :class:`~motor_id.fleet.scatter.ScatterPool`)."""
        return ScatterPool([(h.times, h.y, h.rel) for h in histories], self.floor, units)

    def scan(self, times: Sequence[Any], values: Sequence[float | None],
             stds: Sequence[float | None] | None = None,
             pool: ScatterPool | None = None) -> DriftFinding:
        """Test one history (at its latest recording).

        Parameters
        ----------
        times, values, stds : see :func:`series`
        pool : ScatterPool, optional
            The scatter pooled over this history and its siblings' (default: this
            history's own).

        Returns
        -------
        DriftFinding
        """
        return self.scan_series(series(times, values, stds), pool)

    def scan_series(self, h: Series, pool: ScatterPool | None = None) -> DriftFinding:
        """:meth:`scan` of a prepared history."""
        n = int(h.y.size)
        if h.held:
            x = float(np.exp(h.y[0]))
            return DriftFinding(detected=False, n=n, reason='held at one value (not '
                                'estimated)', baseline=x, latest=x, change=0.0,
                                threshold=self.threshold,
                                early_threshold=self.early_threshold)
        sc = (pool or self.pool([h])).at(h.times[-1] if n else None)
        if n < MIN_RECORDINGS or sc.dof <= 0:
            return _untested(h, sc, self, f'{n} estimate(s); the test needs '
                             f'{MIN_RECORDINGS}')
        used = _screen(h.y, h.rel, sc.tau, self.outlier)
        return _segment(self, h, used, sc, pool)

    def alarms(self, h: Series, pool: ScatterPool | None = None
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The test's normal scores at each recording, on the data known then.

        Parameters
        ----------
        h : Series
        pool : ScatterPool, optional

        Returns
        -------
        score, early_score : ndarray
            One per kept estimate: the scores (:attr:`DriftFinding.score` and
            ``early_score``) of the test run when it arrived (NaN before the 3rd).
        """
        pool = pool or self.pool([h])
        n = int(h.y.size)
        out = np.full((2, n), np.nan)
        looks = np.arange(MIN_RECORDINGS - 1, n)
        scs = [pool.at(h.times[last]) for last in looks]
        tau = np.array([sc.tau for sc in scs])
        dof = np.array([sc.dof for sc in scs])
        for lo in range(0, looks.size, 256):      # blocks of looks: n x n arrays
            sl = slice(lo, lo + 256)
            got = _look_scores(h.y, h.rel, looks[sl], tau[sl], dof[sl], self.outlier,
                               self.early)
            out[0, looks[sl]], out[1, looks[sl]] = got
        return out[0], out[1]

    def flags(self, h: Series, pool: ScatterPool | None = None) -> NDArray[np.bool_]:
        """Whether the test flags a change at each recording, on the data known then
        (:meth:`alarms` against ``threshold`` and ``early_threshold``)."""
        score, early = self.alarms(h, pool)
        with np.errstate(invalid='ignore'):
            return (score > self.threshold) | (early > self.early_threshold)


def _look_scores(y: NDArray[np.float64], rel: NDArray[np.float64], looks: NDArray[np.intp],
                 tau: NDArray[np.float64], dof: NDArray[np.float64], outlier: float,
                 early: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The first stage's normal scores at each look (row), all splits at once: what
    :func:`_screen` and :func:`~motor_id.fleet.segment.best_split` give on each prefix
    ``y[:look + 1]``, over every split and over the splits with at most ``early``
    estimates before them."""
    from scipy import special
    n = int(looks.max()) + 1
    y, rel = y[:n], rel[:n]
    t2 = (tau * tau)[:, None]
    inside = np.arange(n)[None, :] <= looks[:, None]
    d = np.diff(y)[None, :] / np.sqrt(2 * t2 + (rel[1:] ** 2 + rel[:-1] ** 2)[None, :])
    keep = inside.copy()
    up = (d[:, :-1] > outlier) & (d[:, 1:] < -outlier)
    down = (d[:, :-1] < -outlier) & (d[:, 1:] > outlier)
    interior = np.arange(1, n - 1)[None, :] < looks[:, None]
    keep[:, 1:-1] &= ~((up | down) & interior)
    rows = np.arange(looks.size)
    last_d = d[rows, looks - 1]
    keep[rows, looks] &= ~((np.abs(last_d) > outlier) & keep[rows, looks - 1])
    w = np.where(keep, 1.0 / (t2 + (rel ** 2)[None, :]), 0.0)
    cw, cs, cn = np.cumsum(w, 1), np.cumsum(w * y[None, :], 1), np.cumsum(keep, 1)
    tot_w, tot_s, tot_n = cw[rows, looks][:, None], cs[rows, looks][:, None], \
        cn[rows, looks][:, None]
    # split before position k (1..n-1): the kept estimates before k, and from k on
    wb, sb, nb = cw[:, :-1], cs[:, :-1], cn[:, :-1]
    wa, sa, na = tot_w - wb, tot_s - sb, tot_n - nb
    ok = keep[:, 1:] & (nb >= 1) & (na >= 2)
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (sa / wa - sb / wb) / np.sqrt(1.0 / wa + 1.0 / wb)
    t = np.where(ok, np.abs(t), -np.inf)
    scores = []
    for best in (t.max(axis=1), np.where(nb <= early, t, -np.inf).max(axis=1)):
        p = np.where(np.isfinite(best), special.stdtr(dof, -np.maximum(best, 0.0)), np.nan)
        score = -special.ndtri(np.maximum(p, 1e-300))
        scores.append(np.where((dof > 0) & np.isfinite(best), score, np.nan))
    return scores[0], scores[1]


def normal_score(t: float, dof: float) -> float:
    """The normal score with the tail probability of ``|t|`` under Student t (``dof``)."""
    from scipy import special
    p = float(special.stdtr(dof, -abs(t))) if math.isfinite(dof) else \
        float(special.ndtr(-abs(t)))
    return float(-special.ndtri(max(p, 1e-300)))


def _untested(h: Series, sc: Scatter, rule: DriftRule, reason: str) -> DriftFinding:
    n = int(h.y.size)
    if not n:
        return DriftFinding(detected=False, n=0, reason=reason, threshold=rule.threshold,
                            early_threshold=rule.early_threshold)
    w = 1.0 / (sc.tau ** 2 + h.rel ** 2)
    m = float(np.sum(w * h.y) / np.sum(w))
    base, last = math.exp(m), math.exp(float(h.y[-1]))
    return DriftFinding(detected=False, n=n, reason=reason, baseline=base, latest=last,
                        change=last / base - 1.0, level=base,
                        level_std=float(1.0 / math.sqrt(np.sum(w))), scatter=sc.tau,
                        dof=sc.dof, threshold=rule.threshold,
                        early_threshold=rule.early_threshold)


def _screen(y: NDArray[np.float64], rel: NDArray[np.float64], tau: float,
            outlier: float) -> NDArray[np.intp]:
    """Positions kept by the test: not a gross error between agreeing neighbours, and
    the latest not waiting for the next recording."""
    n = y.size
    keep = np.ones(n, dtype=bool)
    if n < 2:
        return np.flatnonzero(keep)
    d = np.diff(y) / np.sqrt(2 * tau * tau + rel[1:] ** 2 + rel[:-1] ** 2)
    if n >= 3:
        up = (d[:-1] > outlier) & (d[1:] < -outlier)
        down = (d[:-1] < -outlier) & (d[1:] > outlier)
        keep[1:-1] = ~(up | down)
    if abs(d[-1]) > outlier and keep[-2]:
        keep[-1] = False
    return np.flatnonzero(keep)


def _binseg(y: NDArray[np.float64], w: NDArray[np.float64], dof: float, rule: DriftRule
            ) -> tuple[list[tuple[int, float]], float | None, float | None]:
    """Change points (position in ``y``, score) by binary segmentation; and the first
    stage's score over every split and over the early splits."""
    found: list[tuple[int, float]] = []
    first_score: float | None = None
    early_score: float | None = None
    todo = [(0, int(y.size))]
    while todo:
        a, b = todo.pop()
        best = best_split(y, w, a, b, first=a == 0)
        if best is None:
            continue
        score = normal_score(best[1], dof)
        whole = a == 0 and b == y.size     # the early splits: the first stage only
        early = best_split(y, w, a, b, first=True, most=rule.early) if whole else None
        escore = normal_score(early[1], dof) if early is not None else None
        if whole:
            first_score, early_score = score, escore
        if score > rule.threshold:
            cut = best[0]
        elif early is not None and escore is not None and escore > rule.early_threshold:
            cut, score = early[0], escore
        else:
            continue
        found.append((cut, score))
        todo += [(a, cut), (cut, b)]
    return sorted(found), first_score, early_score


def _segment(rule: DriftRule, h: Series, used: NDArray[np.intp], sc: Scatter,
             pool: ScatterPool | None) -> DriftFinding:
    """Binary segmentation of the kept estimates, changes grouped, shaped and dated."""
    y, rel = h.y[used], h.rel[used]
    n = int(y.size)
    w = 1.0 / (sc.tau ** 2 + rel ** 2)
    cps, first_score, early_score = _binseg(y, w, sc.dof, rule)
    groups = change_groups(cps, y, w, rule.ramp_gap)
    times = [h.times[i] for i in used]
    pos = [int(h.index[i]) for i in used]
    firsts = [0] + [g[0][0] for g in groups] + [n]
    lasts = [0] + [g[-1][0] for g in groups] + [n]
    shapes = [(0, 0)]
    for j, g in enumerate(groups):    # each change starts after the one before has ended
        shapes.append(shape_change(y, w, lasts[j], g[0][0], g[-1][0], firsts[j + 2],
                                   shapes[-1][1] + 1))
    shapes.append((n, n))
    changes = []
    pool = pool or rule.pool([h])
    for j, g in enumerate(groups):
        onset, end = shapes[j + 1]
        before = level_of(y, w, shapes[j][1], onset)[0]
        after = level_of(y, w, end, shapes[j + 2][0])[0]
        flag = _flagged(rule, h, used, lasts[j], min(onset, g[0][0]), firsts[j + 2], pool)
        changes.append(ChangePoint(
            index=pos[onset], since=_iso(times[onset]), until_index=pos[end],
            until=_iso(times[end]), kind='ramp' if end > onset else 'step',
            flagged_index=pos[flag], flagged_at=_iso(times[flag]),
            before=math.exp(before), after=math.exp(after),
            change=math.exp(after - before) - 1.0, z=(after - before) / sc.tau,
            score=max(s for _, s in g)))
    level, level_se = level_of(y, w, shapes[-2][1], n)
    outliers = tuple(int(h.index[i]) for i in np.setdiff1d(np.arange(h.y.size), used))
    base = DriftFinding(detected=False, n=int(h.y.size), level=math.exp(level),
                        level_std=level_se, scatter=sc.tau, dof=sc.dof, score=first_score,
                        threshold=rule.threshold, early_score=early_score,
                        early_threshold=rule.early_threshold, change_points=tuple(changes),
                        outliers=outliers)
    if changes:
        last = changes[-1]
        return replace(base, detected=True, change=last.change, since=last.since, z=last.z,
                       baseline=last.before, latest=last.after)
    m = level_of(y, w, 0, n)[0]
    latest = float(h.y[-1])
    return replace(base, change=math.exp(latest - m) - 1.0, z=(latest - m) / sc.tau,
                   baseline=math.exp(m), latest=math.exp(latest))


def _flagged(rule: DriftRule, h: Series, used: NDArray[np.intp], a: int, c: int, b: int,
             pool: ScatterPool) -> int:
    """Position (in ``used``) of the first recording at which the test on the regime
    ``a..`` flagged the change at ``c`` (the next change at ``b`` bounds it)."""
    y, rel = h.y[used], h.rel[used]
    for last in range(c + 1, int(y.size)):
        sc = pool.at(h.times[used[last]])
        if sc.dof <= 0:
            continue
        end = min(last + 1, b)
        w = 1.0 / (sc.tau ** 2 + rel[a:end] ** 2)
        best = best_split(y[a:end], w, 0, end - a, first=a == 0)
        if best is not None and normal_score(best[1], sc.dof) > rule.threshold:
            return last
        early = best_split(y[a:end], w, 0, end - a, True, rule.early) if a == 0 else None
        if early is not None and normal_score(early[1], sc.dof) > rule.early_threshold:
            return last
    return int(y.size) - 1


def _iso(t: object) -> str | None:
    """An ISO text of a time value (strings pass through)."""
    if t is None or isinstance(t, str):
        return t
    iso = getattr(t, 'isoformat', None)
    return iso() if iso is not None else str(t)
