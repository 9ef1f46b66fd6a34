"""Measurement effects judged by their own evidence: the lattice a measured channel sits on.

An encoder that counts per sample period reports the speed on a grid of step
``q = 2 pi / (counts_per_rev T)``; an ADC reports the current on a grid of its step. Such a
grid is a property of the measured values, not of the motion, so it is found from the
values themselves (never from a simulation-error gain):

1. a candidate step: the spacing between the distinct values, when values repeat (at
   most half as many distinct values as samples: a counter or an ADC reports a finite
   set of values; values that do not repeat are continuous, even when a staircase input
   makes their histogram look like a comb);
2. the coherence at the refined step over the *moving* samples only (the value changed
   by at least half a step since the previous sample: a signal at rest sits on any
   grid), and its largest multiple that keeps the coherence (a finer grid through the
   same values is not the sensor's);
3. the null: values that do not sit on a grid of step q have phases spread over the
   circle, and ``n C^2`` of the coherence ``C(q) = |mean exp(2 pi i y / q)|`` is then
   exponentially distributed (Rayleigh test); with n the moving samples, the grid counts
   when
   ``p < alpha`` and ``C >= min_coherence``, and the moving samples occupy at least
   ``MIN_LEVELS`` grid levels. Continuous noisy data give p of order one.

A grid that is fine against the signal is a logging resolution, not a measurement
effect: it is reported only when ``q / sqrt(12)`` (the rounding error's standard
deviation) is at least ``min_share`` of the channel's standard deviation (EMPS: the
differentiated 12500-line encoder is on a grid of 2.5e-5 m/s, 1.4e-4 of the speed's
spread, far below any model error).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
from typing import Any, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.effects import EFFECTS
from motor_id.records import optional, Record

if TYPE_CHECKING:
    from motor_id.recording import Recording

MIN_MOVING = 20
"""Moving samples the test needs."""

MIN_LEVELS = 10
"""Grid levels the moving samples must occupy: a few clusters of values (the plateaus
of a square wave) line up with some step by chance."""


@dataclass(frozen=True)
class LatticeEvidence(Record):
    """What the values of one channel say about a grid (see the module notes)."""

    channel: str
    found: bool
    q: float
    offset: float
    coherence: float
    p_value: float
    n_moving: int
    n_distinct: int
    n_samples: int
    method: str
    relative_to_spread: float
    reason: str = ''
    note: str = optional('', when='empty')
    """Why a grid found cannot be a model effect (the input's)."""


@dataclass
class MeasurementEffect:
    """A measurement effect found from its own evidence (an ``effects`` entry)."""

    name: str
    q: float
    evidence: LatticeEvidence
    extra: dict

    significant: bool = True
    gain = 0.0
    heldout_error = math.nan
    failed = ''

    @property
    def parameters(self) -> dict[str, dict[str, Any]]:
        """``{effect.param: {value, std, determined, grid}}`` as the fitted effects."""
        pname = EFFECTS[self.name].params[0].name
        out: dict[str, dict[str, Any]] = {
            f'{self.name}.{pname}': {'value': self.q, 'std': None, 'determined': True,
                                     'grid': True}}
        if 'counted' in self.extra:  # the speed reading chosen by the linear model
            out[f'{self.name}.counted'] = {'value': float(self.extra['counted']),
                                           'std': None, 'determined': True, 'grid': True}
        return out

    def to_dict(self) -> dict[str, Any]:
        """The report's ``effects`` entry: name, parameters, gain (none), evidence."""
        ev = {'kind': 'measurement', 'significant': True, **self.evidence.to_dict(),
              **self.extra}
        return {'name': self.name, 'parameters': self.parameters, 'gain': None,
                'evidence': ev}


def _phases(y: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """exp(2 pi i y / q) for each q (rows)."""
    return np.exp(2j * np.pi * y[None, :] / qs[:, None])


def _slope(y: np.ndarray) -> np.ndarray:
    """Per sample: the size of the change from the previous sample."""
    return np.abs(np.diff(y, prepend=y[0]))


def _moving(slope: np.ndarray, q: ArrayLike) -> np.ndarray:
    """Samples that move: the value changed by half a step or more since the previous
    sample (a value at rest sits on any grid)."""
    q = np.asarray(q, dtype=float)[..., None]
    return slope[None, :] >= 0.5 * q


def _coherence(y: np.ndarray, slope: np.ndarray, qs: ArrayLike
               ) -> tuple[np.ndarray, np.ndarray]:
    """Coherence and moving-sample count of each step in ``qs`` (arrays)."""
    qs = np.atleast_1d(np.asarray(qs, dtype=float))
    out_c = np.zeros(qs.size)
    out_n = np.zeros(qs.size, dtype=int)
    for j0 in range(0, qs.size, 64):
        q = qs[j0:j0 + 64]
        mask = _moving(slope, q)
        n = mask.sum(axis=1)
        s = np.abs(np.sum(_phases(y, q) * mask, axis=1))
        out_c[j0:j0 + 64] = np.where(n > 0, s / np.maximum(n, 1), 0.0)
        out_n[j0:j0 + 64] = n
    return out_c, out_n


def _distinct(y: np.ndarray) -> np.ndarray:
    """Sorted distinct values (values closer than 1e-9 of the range merged)."""
    u = np.unique(y)
    tol = 1e-9 * (float(np.max(np.abs(y))) or 1.0)
    if u.size > 1:
        u = u[np.concatenate([[True], np.diff(u) > tol])]
    return u


def _candidates(u: np.ndarray, n_all: int) -> np.ndarray:
    """Candidate step from the spacing of the distinct values, when values repeat.

    A sensor's counter or ADC reports a finite set of values, each many times; values
    that (almost) never repeat are continuous, whatever their histogram looks like (a
    staircase input makes equally spaced speed levels without any quantiser).
    """
    if u.size < 3 or u.size > 0.5 * n_all:
        return np.zeros(0)
    gaps = np.diff(u)
    small = gaps[gaps <= 1.5 * np.percentile(gaps, 10)]
    return np.array([float(np.median(small))])


def _levels(y: np.ndarray, slope: np.ndarray, q: float) -> int:
    """Grid levels the moving samples occupy."""
    return int(np.unique(np.round(y[_moving(slope, q).ravel()] / q)).size)


def _refine(y: np.ndarray, slope: np.ndarray, q0: float) -> float:
    """The step of largest coherence within 3 % of q0, then its largest coherent multiple."""
    fine = q0 * np.concatenate([[1.0], np.linspace(0.97, 1.03, 241)])
    c, _ = _coherence(y, slope, fine)
    q = float(fine[int(np.argmax(c))])
    c_q = float(np.max(c))
    for k in (5, 4, 3, 2):
        ck, nk = _coherence(y, slope, [k * q])
        if nk[0] >= MIN_MOVING and ck[0] >= 0.9 * c_q and \
                _levels(y, slope, k * q) >= MIN_LEVELS:
            return k * q
    return q


def lattice_evidence(y: ArrayLike, channel: str = 'speed', alpha: float = 1e-3,
                     min_coherence: float = 0.5, min_share: float = 2e-3,
                     max_samples: int = 4000) -> LatticeEvidence:
    """Test whether the values of one channel sit on a grid, and find its step.

    Parameters
    ----------
    y : array_like
        Measured values of one channel.
    channel : str
        Its name (reported).
    alpha : float
        Significance level of the Rayleigh test (after the Bonferroni factor).
    min_coherence : float
        Smallest coherence that counts as a grid (effect size).
    min_share : float
        The grid is reported only when ``q / sqrt(12)`` is at least this share of the
        channel's standard deviation.
    max_samples : int
        Longer records are tested on an evenly spaced subset of this many samples.

    Returns
    -------
    LatticeEvidence
    """
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    n_all = int(y.size)
    u = _distinct(y)
    none = LatticeEvidence(channel, False, 0.0, 0.0, 0.0, 1.0, 0, int(u.size), n_all, '',
                           0.0)
    if y.size < 50 or u.size < 3:
        return replace(none, reason='too few samples or distinct values to test')
    slope = _slope(y)
    std = float(np.std(y))
    if y.size > max_samples:
        keep = np.linspace(0, y.size - 1, max_samples).astype(int)
        y, slope = y[keep], slope[keep]
    qs = _candidates(u, n_all)
    method, n_tried = 'distinct values', 1
    best = None
    for q0 in qs:
        q = _refine(y, slope, q0)
        c, n = _coherence(y, slope, [q])
        if best is None or c[0] > best[1]:
            best = (q, float(c[0]), int(n[0]))
    if best is None:
        return replace(none, reason=f'{u.size} distinct values in {n_all} samples: the '
                       'values do not repeat, so they sit on no grid')
    q, c, n_mov = best
    p = float(min(1.0, n_tried * math.exp(-n_mov * c * c)))
    phase = np.angle(np.mean(np.exp(2j * np.pi * y / q)))
    share = (q / math.sqrt(12.0)) / std if std > 0 else 0.0
    found, reason = _decide(q, c, p, n_mov, _levels(y, slope, q), share, alpha,
                            min_coherence, min_share)
    return LatticeEvidence(channel, found, float(q), float(q * phase / (2 * np.pi)), c, p,
                           n_mov, int(u.size), n_all, method, float(min(share, 1e12)),
                           reason)


def _decide(q: float, c: float, p: float, n_mov: int, levels: int, share: float, alpha: float,
            min_coherence: float, min_share: float) -> tuple[bool, str]:
    """Whether the evidence makes a grid a measurement effect, and why not."""
    if n_mov < MIN_MOVING:
        return False, f'only {n_mov} samples change by half a step of {q:.4g} or more'
    if p >= alpha or c < min_coherence:
        return False, f'coherence {c:.2f} (p = {p:.2g}) over {n_mov} moving samples: no grid'
    if levels < MIN_LEVELS:
        return False, (f'the moving samples occupy only {levels} levels of a grid of '
                       f'{q:.4g}: too few to tell a grid from clusters of values')
    if share < min_share:
        return False, (f'a grid of {q:.4g}, fine against the signal (rounding error '
                       f'{share:.2g} of its spread): a logging resolution, not a '
                       'measurement effect')
    return True, ''


def find_measurement_effects(rec: Recording, **kw: Any
                             ) -> tuple[list[MeasurementEffect], dict[str, LatticeEvidence]]:
    """Grids of the recording's output channels (effects) and of its input (a note).

    Parameters
    ----------
    rec : Recording
    **kw
        Passed to :func:`lattice_evidence`.

    Returns
    -------
    effects : list of MeasurementEffect
        ``speed_quantization`` / ``current_quantization`` for the output channels on a
        grid; for the speed also the implied counts per revolution ``2 pi / (q T)``.
    evidence : dict
        ``{channel: LatticeEvidence}`` for every channel and the input, with a note where
        a grid cannot be a model effect.
    """
    effects: list[MeasurementEffect] = []
    evidence: dict[str, LatticeEvidence] = {}
    T = rec.sample_period
    for name, spec in EFFECTS.items():
        if spec.category != 'measurement' or rec.input_kind not in spec.kinds:
            continue
        if spec.channel not in rec.channels():
            continue
        ev = lattice_evidence(getattr(rec, spec.channel), spec.channel, **kw)
        evidence[spec.channel] = ev
        if not ev.found:
            continue
        extra: dict[str, float] = {}
        if spec.channel == 'speed':
            extra['counts_per_revolution'] = float(2 * math.pi / (ev.q * T))
            extra['position_step'] = float(ev.q * T)
        effects.append(MeasurementEffect(name, ev.q, ev, extra))
    ev = lattice_evidence(rec.input, 'input', **kw)
    if ev.found:
        ev = replace(ev, note=(
            'the input is measured on a grid: its rounding acts as input noise of '
            f'variance q^2/12 = {ev.q ** 2 / 12:.3g} (errors in variables), not as a term '
            'of the model'))
    evidence['input'] = ev
    return effects, evidence
