"""Discrepancy discovery: what the linear model misses, which named effect explains it, the gain.

The analysis fits the linear model, diagnoses its residuals, fits every candidate effect of
:data:`motor_id.model.EFFECTS` warm-started from the linear fit, and keeps the extension
that cuts the simulation error on held-out data the most (greedy, up to three effects).

Held-out data are interleaved blocks: the record is cut into ``n_blocks`` blocks and every
third block (from the third on) is left out of the fit; the simulation still runs through
it, so a model is scored on its free-run prediction of inputs it was not fitted to. The
error measure is the RMS simulation error of each measured channel divided by that
channel's standard deviation, combined as the root mean square over channels; the
*gain* of a model is the relative cut of this held-out error against the linear model.
A model counts as significant when its gain is at least ``min_gain`` and it improves
the majority of held-out sub-blocks; candidates whose held-out error is within
``ambiguity`` of the winner's cannot be told apart by this excitation.
"""

import contextlib
import dataclasses
from dataclasses import dataclass, field
import math
import time

import numpy as np

from motor_id.errors import ConfigError, DataError
from motor_id.identify import Identifier
from motor_id.metrics import residual_diagnostics
from motor_id.model import EFFECTS
from motor_id.simulate import simulate_batch

CANDIDATES = tuple(EFFECTS)
"""Candidate effects, in catalogue order."""

FIXED_PARAMS = {'input_delay': ('d',), 'speed_quantization': ('q',)}
"""Effect parameters found by a grid (integer or non-smooth), never by the refinement."""

EXPERIMENTS = {
    frozenset(('coulomb_friction', 'load_torque')):
        'reverse the motor (bipolar_steps with rests): Coulomb friction changes sign '
        'with the speed, a constant load torque does not',
    frozenset(('coulomb_friction', 'brush_drop')):
        'measure the current and brake hard (steps down) so that the current reverses '
        'while the speed keeps its sign: friction follows the speed, the brush drop the '
        'current',
    frozenset(('coulomb_friction', 'dead_zone')):
        'measure the current and decelerate with the input still positive: friction '
        'raises the current needed at a given speed, a dead zone lowers the voltage '
        'that reaches the motor',
    frozenset(('brush_drop', 'dead_zone')):
        'braking steps in which the current reverses while the input keeps its sign: '
        'a brush drop follows the current sign, a dead zone the input sign',
    frozenset(('load_torque', 'brush_drop')):
        'reverse the motor: a brush drop changes sign with the current, a load torque '
        'keeps its sign',
    frozenset(('load_torque', 'dead_zone')):
        'reverse the input: a dead zone is symmetric, a constant load is not',
    frozenset(('quadratic_load', 'voltage_saturation')):
        'a staircase of input levels below and above the suspected limit: a quadratic '
        'load bends the steady-state map smoothly, saturation cuts it flat',
    frozenset(('quadratic_load', 'coulomb_friction')):
        'a staircase of several steady speeds: friction offsets the speed-input map by '
        'a constant, a quadratic load bends it',
    frozenset(('sensor_lag', 'input_delay')):
        'fast steps or a PRBS with the current measured: a delay shifts the whole '
        'response, a sensor lag smooths only the speed reading',
    frozenset(('sensor_lag', 'resonance')):
        'a multisine through the suspected resonance: a lag only attenuates, a '
        'compliant shaft rings',
    frozenset(('input_delay', 'resonance')):
        'a multisine through the suspected resonance: a delay only shifts the phase, '
        'a compliant shaft rings',
}
TORQUE_EXPERIMENTS = {
    frozenset(('coulomb_friction', 'dead_zone')):
        'log the current with its sign and brake with the torque reversed while the '
        'shaft still turns: friction follows the speed sign, a dead zone the torque sign '
        '(a torque whose sign is inferred from the speed makes both act alike)',
    frozenset(('coulomb_friction', 'load_torque')):
        'reverse the motion: friction changes sign with the speed, a constant load or '
        'force offset does not',
}
"""Experiments for torque-input plants where they differ from :data:`EXPERIMENTS`."""
GENERIC_EXPERIMENT = ('an excitation that visits more operating points: bipolar steps with '
                      'rests at several amplitudes, a PRBS, and the current measured')


# --------------------------------------------------------------------------- helpers
def heldout_mask(n, n_blocks=10, every=3, first=2):
    """Boolean mask of held-out samples: blocks ``first, first + every, ...``.

    Parameters
    ----------
    n : int
        Number of samples.
    n_blocks : int
        Number of equal blocks the record is cut into.
    every, first : int
        Every ``every``-th block from block ``first`` on is held out (defaults: blocks
        2, 5, 8 of 10, i.e. 30 %).

    Returns
    -------
    mask : ndarray of bool, shape (n,)
        True on held-out samples.
    blocks : list of (start, stop)
        The held-out blocks.
    """
    if n_blocks < 2 or not 0 <= first < n_blocks or every < 1:
        raise ConfigError('held-out blocks need n_blocks >= 2, 0 <= first < n_blocks, '
                          'every >= 1')
    edges = np.linspace(0, n, n_blocks + 1).astype(int)
    mask = np.zeros(n, dtype=bool)
    blocks = []
    for b in range(first, n_blocks, every):
        mask[edges[b]:edges[b + 1]] = True
        blocks.append((int(edges[b]), int(edges[b + 1])))
    return mask, blocks


def noise_floor(y):
    """Robust white-noise level of a smooth signal from its second differences.

    For white noise of variance s^2 the second difference has variance 6 s^2; the median
    absolute deviation ignores the few large differences at steps. A quantised signal
    (most differences exactly zero) falls back to a trimmed RMS.
    """
    y = np.asarray(y, dtype=float)
    if y.size < 5:
        return 0.0
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    mad = np.median(np.abs(d2 - np.median(d2)))
    if mad > 0:
        return float(1.4826 * mad / math.sqrt(6.0))
    cut = np.percentile(np.abs(d2), 99)
    keep = d2[np.abs(d2) <= cut]
    return float(np.sqrt(np.mean(keep * keep) / 6.0)) if keep.size else 0.0


def binned_means(residual, variables, n_bins=8):
    """Mean residual per bin of each explanatory variable.

    Parameters
    ----------
    residual : ndarray, shape (N,)
    variables : dict of ndarray
        Name -> values; names starting with ``sign(`` are binned by sign.
    n_bins : int
        Quantile bins for continuous variables.

    Returns
    -------
    dict
        Name -> ``{'centers', 'means', 'counts', 'explained'}``; ``explained`` is the
        share of the residual variance that the binned means account for (0..1).
    """
    r = np.asarray(residual, dtype=float)
    var = float(np.var(r))
    out = {}
    for name, x in variables.items():
        x = np.asarray(x, dtype=float)
        if name.startswith('sign('):
            labels = np.sign(x).astype(int) + 1
            centers = np.array([-1.0, 0.0, 1.0])
            nb = 3
        else:
            edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
            if edges.size < 2:
                continue
            labels = np.clip(np.searchsorted(edges, x, side='right') - 1, 0, edges.size - 2)
            nb = edges.size - 1
            centers = 0.5 * (edges[:-1] + edges[1:])
        counts = np.bincount(labels, minlength=nb)
        sums = np.bincount(labels, weights=r, minlength=nb)
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        fitted = np.nan_to_num(means)[labels]
        explained = float(np.var(fitted) / var) if var > 0 else 0.0
        keep = counts > 0
        out[name] = {'centers': centers[keep].tolist(), 'means': means[keep].tolist(),
                     'counts': counts[keep].tolist(), 'explained': explained}
    return out


def steady_state_map(rec, min_len=None):
    """Steady-state points (input, speed[, current]) from plateaus of the recording.

    Plateaus are runs of a constant input at least ``min_len`` samples long (the last
    40 % of each run is averaged, after the transient); when they hold fewer than three
    distinct input levels (a noisy measured input, say), quasi-steady windows of
    ``min_len`` samples (speed varying by less than 5 % of its spread) are used.

    Returns
    -------
    list of dict
        ``{'start', 'stop', 'input', 'speed'[, 'current']}`` per point; start/stop are
        the averaged sample range.
    """
    u = rec.input
    n = u.size
    min_len = int(min_len or max(10, n // 100))
    scale = float(np.max(np.abs(u))) or 1.0
    change = np.flatnonzero(np.abs(np.diff(u)) > 1e-9 * scale) + 1
    edges = np.concatenate([[0], change, [n]])
    ranges = []
    for a, b in zip(edges[:-1], edges[1:]):
        if b - a >= min_len:
            ranges.append((int(b - max(3, int(0.4 * (b - a)))), int(b)))
    levels = np.unique(np.round(np.array([u[a] for a, _ in ranges]) / (1e-6 * scale)))
    if levels.size < 3:
        ranges = []
        spread = float(np.std(rec.speed)) or 1.0
        for a in range(0, n - min_len + 1, min_len):
            seg = rec.speed[a:a + min_len]
            if np.std(seg) < 0.05 * spread:
                ranges.append((a, a + min_len))
    points = []
    for a, b in ranges:
        p = {'start': a, 'stop': b, 'input': float(np.mean(u[a:b])),
             'speed': float(np.mean(rec.speed[a:b]))}
        if rec.has_current:
            p['current'] = float(np.mean(rec.current[a:b]))
        points.append(p)
    return points


def map_summary(points):
    """Straight-line fits ``speed = a input + b`` to the positive and negative plateaus.

    Returns the slope, intercept and the input at which the fitted speed is zero (an
    offset there points to friction, a brush drop or a dead zone) for each side with at
    least two points, and the quadratic coefficient over all points (curvature points to
    a quadratic load or saturation).
    """
    out = {'n_points': len(points)}
    if not points:
        return out
    u = np.array([p['input'] for p in points])
    w = np.array([p['speed'] for p in points])
    tol = 1e-6 * (float(np.max(np.abs(u))) or 1.0)
    for side, sel in (('positive', u > 0), ('negative', u < 0)):
        if np.unique(np.round(u[sel] / tol)).size >= 2:
            a, b = np.polyfit(u[sel], w[sel], 1)
            out[side] = {'slope': float(a), 'intercept': float(b),
                         'zero_speed_input': float(-b / a) if a != 0 else None}
    if np.unique(np.round(u / tol)).size >= 3:
        c2, c1, c0 = np.polyfit(u, w, 2)
        out['quadratic'] = {'c2': float(c2), 'c1': float(c1), 'c0': float(c0)}
    return out


def inverse_dynamics(rec, terms=('coulomb_friction', 'load_torque'), cutoff=None,
                     delay=0, min_speed=0.02):
    """Equation-error (inverse dynamics) least squares for a torque-input plant.

    Fits ``u = J dw/dt + B w + T_c sgn(w) + T_L + k_q w|w|`` (the terms asked for) with
    the speed, its derivative and the input all low-pass filtered by the same zero-phase
    Butterworth filter (parallel filtering, as in IDIM-LS); the first and last 2 % of
    samples are dropped, and with Coulomb friction the samples near rest.

    Parameters
    ----------
    rec : Recording
        ``input_kind == 'torque'``.
    terms : sequence of str
        Any of coulomb_friction, load_torque, quadratic_load.
    cutoff : float, optional
        Filter cut-off [Hz]; default a tenth of the Nyquist frequency.
    delay : int
        Input delay in samples (from an ``input_delay`` effect).
    min_speed : float
        With Coulomb friction, samples slower than this fraction of the top speed are
        left out (at rest the friction takes any value up to T_c).

    Returns
    -------
    dict
        ``parameters`` (J, B and ``effect.param`` values), ``relative_error`` (norm of the
        equation residual over norm of the filtered input), ``cutoff``.
    """
    from scipy.signal import butter, filtfilt

    if rec.input_kind != 'torque':
        raise ConfigError('inverse dynamics needs a torque-input recording')
    t = rec.time
    dt = float(np.mean(np.diff(t)))
    cutoff = float(cutoff or 0.05 / dt)
    wn = min(cutoff * 2 * dt, 0.99)
    b, a = butter(4, wn)
    u = rec.input
    if delay > 0:
        u = np.concatenate([np.full(delay, u[0]), u[:-delay]])
    w = filtfilt(b, a, rec.speed)
    acc = np.gradient(w, t)
    uf = filtfilt(b, a, u)
    cols = {'J': acc, 'B': w}
    if 'coulomb_friction' in terms:
        cols['coulomb_friction.T_c'] = np.sign(w)
    if 'load_torque' in terms:
        cols['load_torque.T_L'] = np.ones_like(w)
    if 'quadratic_load' in terms:
        cols['quadratic_load.k_q'] = w * np.abs(w)
    trim = max(1, int(0.02 * t.size))
    keep = np.zeros(t.size, dtype=bool)
    keep[trim:-trim] = True
    if 'coulomb_friction' in terms:
        # at rest the friction is anything up to T_c, not T_c sgn(w): leave out the
        # samples near zero speed
        keep &= np.abs(w) > min_speed * np.max(np.abs(w))
    X = np.column_stack(list(cols.values()))[keep]
    y = uf[keep]
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ theta
    dof = max(y.size - theta.size, 1)
    cov = np.linalg.pinv(X.T @ X) * float(res @ res) / dof
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    params = {k: {'value': float(v), 'std': float(s)} for k, v, s in zip(cols, theta, std)}
    physical = bool(theta[0] > 0 and theta[1] >= 0 and all(
        params[k]['value'] >= 0 for k in params if k in ('coulomb_friction.T_c',
                                                         'quadratic_load.k_q')))
    return {'parameters': params, 'cutoff': cutoff, 'delay': int(delay),
            'physical': physical,
            'relative_error': float(np.linalg.norm(res) / (np.linalg.norm(y) or 1.0)),
            'model': 'u = J dw/dt + B w' + ''.join(
                {'coulomb_friction': ' + T_c sgn(w)', 'load_torque': ' + T_L',
                 'quadratic_load': ' + k_q w|w|'}[k] for k in terms
                if k in ('coulomb_friction', 'load_torque', 'quadratic_load'))}


# --------------------------------------------------------------------------- results
@dataclass
class ModelScore:
    """One candidate model (one effect or a combination) and how it did."""

    name: str
    effects: dict
    parameters: dict
    gain: float
    heldout_error: float
    train_error: float
    block_wins: float
    n_extra: int
    delta_bic: float
    significant: bool = False
    at_bound: list = field(default_factory=list)
    implausible: str = ''
    physical: dict = field(default_factory=dict, repr=False)
    x0: dict = field(default_factory=dict, repr=False)
    prediction: dict = field(default_factory=dict, repr=False)
    seconds: float = 0.0

    def to_dict(self):
        """The report's ``effects`` entry: name, parameters, gain, evidence."""
        return {'name': self.name, 'parameters': self.parameters, 'gain': self.gain,
                'evidence': {'heldout_error': self.heldout_error,
                             'train_error': self.train_error,
                             'heldout_blocks_improved': self.block_wins,
                             'extra_parameters': self.n_extra,
                             'delta_bic': self.delta_bic,
                             'at_search_limit': self.at_bound,
                             'implausible': self.implausible,
                             'significant': self.significant,
                             'seconds': self.seconds}}


@dataclass
class DiscrepancyReport:
    """The analysis result; :meth:`to_dict` is the ``--json`` shape."""

    verdict: str
    effects: list
    unexplained: bool
    ambiguous_with: list
    parameters: dict
    baseline: dict
    chosen: dict
    diagnostics: dict
    heldout: dict
    input_kind: str
    channels: tuple
    inverse_dynamics: dict = None
    plot_data: dict = field(default_factory=dict, repr=False)
    seconds: float = 0.0

    def to_dict(self):
        """JSON-ready dict (the documented keys first)."""
        d = {'verdict': self.verdict,
             'effects': [e.to_dict() for e in self.effects],
             'unexplained': self.unexplained,
             'ambiguous_with': self.ambiguous_with,
             'parameters': self.parameters,
             'baseline': self.baseline,
             'chosen': self.chosen,
             'diagnostics': self.diagnostics,
             'heldout': self.heldout,
             'input_kind': self.input_kind,
             'channels': list(self.channels),
             'seconds': self.seconds}
        if self.inverse_dynamics is not None:
            d['inverse_dynamics'] = self.inverse_dynamics
        return d

    def summary(self):
        """A readable report for people."""
        lines = []
        h = self.heldout
        lines.append(f'linear model: held-out error {h["base_error"]:.4g} '
                     f'(noise floor {h["noise_floor"]:.4g}; errors are RMS / channel std)')
        for ch, m in self.baseline['fit']['channels'].items():
            after = ''
            if self.chosen.get('fit'):
                after = (f' -> {self.chosen["fit"]["channels"][ch]["fit_percent"]:.2f} % '
                         f'with {self.verdict}')
            lines.append(f'  {ch} fit on all data: {m["fit_percent"]:.2f} %{after}')
        diag = self.diagnostics
        for ch, dd in diag['residual'].items():
            lines.append(f'  {ch} residual: {100 * dd["autocorrelation_outside"]:.0f} % of '
                         f'autocorrelation lags and {100 * dd["cross_correlation_outside"]:.0f}'
                         f' % of input cross-correlation lags outside the 99 % band')
            top = sorted(diag['binned'][ch].items(), key=lambda kv: -kv[1]['explained'])[:3]
            lines.append('    binned means explain ' + ', '.join(
                f'{k} {100 * v["explained"]:.0f} %' for k, v in top) + ' of its variance')
        ms = diag['steady_state']
        if ms.get('n_points'):
            parts = []
            for side in ('positive', 'negative'):
                if side in ms:
                    z = ms[side]['zero_speed_input']
                    parts.append(f'{side} side: speed = {ms[side]["slope"]:.4g} u '
                                 f'{ms[side]["intercept"]:+.4g}' +
                                 ('' if z is None else f' (zero at u = {z:.4g})'))
            lines.append(f'  steady-state map: {ms["n_points"]} plateau(s)' +
                         (('; ' + '; '.join(parts)) if parts else ''))
        lines.append(f'{"candidate":<42}{"gain":>8}{"held-out":>11}  parameters')
        for e in self.effects:
            pv = ', '.join(f'{k.split(".")[-1]}={v["value"]:.4g}'
                           for k, v in e.parameters.items())
            flag = '' if e.significant else '  (not significant)'
            lines.append(f'{e.name:<42}{100 * e.gain:>7.1f}%{e.heldout_error:>11.4g}  '
                         f'{pv}{flag}')
        lines.append(f'verdict: {self.verdict}')
        for a in self.ambiguous_with:
            lines.append(f'  cannot be told apart from {a["name"]} with this excitation '
                         f'(gain {100 * a["gain"]:.1f} %); to separate them: '
                         f'{a["experiment"]}')
        ratio = h['final_error'] / h['noise_floor'] if h['noise_floor'] > 0 else float('inf')
        lines.append(f'unexplained structure: {"yes" if self.unexplained else "no"} '
                     f'(held-out error {ratio:.2f} x noise floor)')
        lines.append('parameters under the chosen model:')
        for k, v in self.parameters.items():
            if v.get('value') is None:
                lines.append(f'  {k:<24}{"-":>14}  not determined')
            else:
                std = '' if v.get('std') is None else f' +- {v["std"]:.3g}'
                lines.append(f'  {k:<24}{v["value"]:>14.6g}{std}')
        if self.inverse_dynamics:
            idm = self.inverse_dynamics
            lines.append(f'inverse dynamics (equation error, {idm["model"]}, filter '
                         f'{idm["cutoff"]:.3g} Hz): relative error '
                         f'{100 * idm["relative_error"]:.2f} %' +
                         ('' if idm['physical'] else
                          '; NOT physical (negative inertia or friction): the derivative '
                          'of this speed is too noisy or too coarsely sampled'))
            for k, v in idm['parameters'].items():
                lines.append(f'  {k:<24}{v["value"]:>14.6g} +- {v["std"]:.3g}')
        lines.append(f'analysis time {self.seconds:.2f} s')
        return '\n'.join(lines)


# --------------------------------------------------------------------------- analysis
class DiscrepancyAnalysis:
    """Find the named effect that the linear model misses.

    Parameters
    ----------
    R_m : float, optional
        Known armature resistance [Ohm] (voltage plants).
    candidates : sequence of str, optional
        Effects to try; default every effect of the catalogue that applies.
    random_state : int or None
        Seed of the base model's GA.
    min_gain : float
        Smallest held-out gain (relative cut of the held-out error) that counts.
    ambiguity : float
        Candidates whose held-out error is within this fraction of the winner's are
        reported as indistinguishable.
    max_effects : int
        Largest number of effects combined (greedy forward selection).
    structure_ratio : float
        Held-out error above this multiple of the noise floor counts as unexplained
        structure.
    n_blocks : int
        Number of blocks for the held-out split.
    max_delay : int, optional
        Largest input delay tried [samples]; default min(40, N / 25).
    generations : int
        GA generations of the base fit.
    pool_size : int
        Combinations are formed from this many best single effects (positive gain).
    starts : int
        Distinct grid points each candidate's refinement starts from.
    """

    def __init__(self, R_m=None, candidates=None, random_state=0, min_gain=0.05,
                 ambiguity=0.03, max_effects=3, structure_ratio=1.5, n_blocks=10,
                 max_delay=None, generations=160, pool_size=4, starts=2):
        self.R_m = R_m
        self.candidates = candidates
        self.random_state = random_state
        self.min_gain = min_gain
        self.ambiguity = ambiguity
        self.max_effects = max_effects
        self.structure_ratio = structure_ratio
        self.n_blocks = n_blocks
        self.max_delay = max_delay
        self.generations = generations
        self.pool_size = pool_size
        self.starts = starts

    # ------------------------------------------------------------------ set-up
    def _say(self, msg):
        if self._progress is not None:
            self._progress(msg)

    def _prepare(self, rec):
        kind = rec.input_kind
        names = self.candidates if self.candidates is not None else CANDIDATES
        for n in names:
            if n not in EFFECTS:
                raise ConfigError(f'unknown candidate effect {n!r}; known: {sorted(EFFECTS)}')
        self._cands = [n for n in names if kind in EFFECTS[n].kinds]
        self._rec = rec
        self._kind = kind
        self._channels = rec.channels()
        self._ys = [getattr(rec, c) for c in self._channels]
        self._scales = [float(np.std(y)) or 1.0 for y in self._ys]
        n = len(rec)
        self._test, blocks = heldout_mask(n, self.n_blocks)
        self._train = ~self._test
        subs = []
        for a, b in blocks:
            e = np.linspace(a, b, 5).astype(int)
            subs.extend(zip(e[:-1], e[1:]))
        self._subblocks = subs
        self._blocks = blocks
        floors = [noise_floor(y) / s for y, s in zip(self._ys, self._scales)]
        self._floor = float(np.sqrt(np.mean(np.square(floors))))
        dt = np.diff(rec.time)
        self._dt = float(np.median(dt))
        self._T = float(rec.time[-1] - rec.time[0])

    def _identifier(self, **kw):
        return Identifier(R_m=self.R_m, random_state=self.random_state, **kw)

    # --------------------------------------------------------------- scoring
    def _errors(self, preds):
        """(train error, held-out error, per-sub-block SSE) of channel predictions."""
        tr, te = [], []
        sub = np.zeros(len(self._subblocks))
        for y, p, s in zip(self._ys, preds, self._scales):
            r2 = ((y - p) / s) ** 2
            tr.append(np.mean(r2[self._train]))
            te.append(np.mean(r2[self._test]))
            sub += [np.sum(r2[a:b]) for a, b in self._subblocks]
        return float(np.sqrt(np.mean(tr))), float(np.sqrt(np.mean(te))), sub

    def _score(self, name, est, effects, n_extra, t0, quant=None):
        """A :class:`ModelScore` from a fitted Identifier (``quant``: a speed grid)."""
        res = est.result_
        preds = [np.asarray(res.prediction[c]) for c in self._channels]
        if quant is not None:
            k = self._channels.index('speed')
            preds[k] = _quantize(preds[k], quant)
        e_tr, e_te, sub = self._errors(preds)
        params = {}
        for e, vals in res.effects.items():
            for p, v in vals.items():
                key = f'{e}.{p}'
                if isinstance(v, dict):
                    params[key] = {'value': v['value'], 'std': v['std'],
                                   'determined': v['determined']}
                elif e in effects and (e in FIXED_PARAMS and p in FIXED_PARAMS[e]):
                    params[key] = {'value': float(v), 'std': None, 'determined': True,
                                   'grid': True}
        eff = {e: {p: (v['value'] if isinstance(v, dict) else float(v))
                   for p, v in vals.items()} for e, vals in res.effects.items()}
        if quant is not None:
            eff['speed_quantization'] = {'q': float(quant)}
        at_bound = []
        for key, (lo, hi) in (est.bounds or {}).items():
            e, _, p = key.partition('.')
            if e not in eff or p not in eff[e]:
                continue
            v, tol = eff[e][p], 1e-3 * (hi - lo)
            if (lo != 0.0 and v <= lo + tol) or v >= hi - tol:
                at_bound.append(key)
        return ModelScore(name, eff, params, 0.0, e_te, e_tr, 0.0, n_extra, 0.0,
                          at_bound=at_bound, physical=dict(est.params_),
                          x0=dict(res.fit.get('initial_state', {})),
                          prediction={'preds': preds, 'sub': sub},
                          seconds=time.perf_counter() - t0)

    def _finish(self, score, ref):
        """Gain, block wins and BIC of ``score`` against the reference model ``ref``."""
        score.gain = float(1.0 - score.heldout_error / ref.heldout_error) \
            if ref.heldout_error > 0 else 0.0
        a, b = score.prediction['sub'], ref.prediction['sub']
        score.block_wins = float(np.mean(a < b))
        n_tr = int(np.sum(self._train)) * len(self._channels)
        r = self._rec.speed - score.prediction['preds'][self._channels.index('speed')]
        r = r[self._train]
        rho = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.999)) \
            if r.size > 3 and np.std(r) > 0 else 0.0
        n_eff = max(n_tr * (1 - rho) / (1 + rho), 2.0)
        k = score.n_extra - ref.n_extra
        if score.train_error > 0 and ref.train_error > 0:
            score.delta_bic = float(n_eff * 2 * math.log(score.train_error / ref.train_error)
                                    + k * math.log(n_eff))
        score.significant = bool(score.gain >= self.min_gain and score.delta_bic < 0
                                 and not score.at_bound and not score.implausible)
        return score

    # ------------------------------------------------------------- grids
    def _scales_for_grid(self, base):
        u = self._rec.input
        u_max = float(np.max(np.abs(u))) or 1.0
        w_max = float(np.max(np.abs(self._rec.speed))) or 1.0
        if self._kind == 'voltage':
            tau = base['K_T'] * u_max / base['R_m']
        else:
            tau = u_max
        i_rms = float(np.sqrt(np.mean(self._rec.current ** 2))) if self._rec.has_current \
            else u_max / base.get('R_m', 1.0)
        return {'u_max': u_max, 'w_max': w_max, 'tau': tau, 'i_rms': i_rms or 1.0}

    def _grid(self, name, sc):
        """Start values ``{param: array}`` for a candidate."""
        g = np.geomspace
        tau, u_max, w_max = sc['tau'], sc['u_max'], sc['w_max']
        T, dt = self._T, self._dt
        if name == 'coulomb_friction':
            return {'T_c': g(1e-4, 0.5, 16) * tau}
        if name == 'load_torque':
            v = g(1e-4, 0.5, 12) * tau
            return {'T_L': np.concatenate([v, -v])}
        if name == 'quadratic_load':
            return {'k_q': g(1e-4, 1.0, 16) * tau / w_max ** 2}
        if name == 'brush_drop':
            return {'V_b': g(1e-3, 0.3, 14) * u_max}
        if name == 'dead_zone':
            return {'V_dz': g(5e-3, 0.6, 14) * u_max}
        if name == 'voltage_saturation':
            return {'V_max': np.linspace(0.15, 0.98, 16) * u_max}
        if name == 'sensor_lag':
            return {'tau_s': g(0.5 * dt, max(0.1 * T, dt), 16)}
        if name == 'resistance_drift':
            taus = np.array([0.05, 0.2, 0.8]) * T
            frac = np.array([0.02, 0.1, 0.3, 0.8])
            tt, ff = np.meshgrid(taus, frac)
            R = self.R_m or 1.0
            kh = ff * R / (sc['i_rms'] ** 2 * tt)
            return {'k_h': kh.ravel(), 'tau_th': tt.ravel()}
        if name == 'resonance':
            f = g(max(3.0 / T, 0.01), 0.2 / dt, 10)
            ff, rr, zz = np.meshgrid(f, [0.25, 1.0, 4.0], [0.03, 0.15])
            return {'r': rr.ravel(), 'f_r': ff.ravel(), 'zeta': zz.ravel()}
        raise ConfigError(f'no start grid for {name!r}')

    def _grid_best(self, base_fit, name, grid, fixed_effects=None, top=1):
        """Evaluate a start grid at the base parameters; best ``top`` rows by train cost."""
        P = next(iter(grid.values())).size
        effects = {e: dict(v) for e, v in (fixed_effects or {}).items()}
        effects[name] = {**{p: np.full(P, v) for p, v in
                            EFFECTS[name].defaults().items()}, **grid}
        phys = {k: v for k, v in base_fit.physical.items()}
        x0 = np.array(list(base_fit.x0.values())) if base_fit.x0 else None
        with np.errstate(all='ignore'):
            out = simulate_batch(phys, self._rec.time, self._rec.input, self._kind, 'zoh',
                                 effects, x0)
        cost = np.zeros(P)
        with np.errstate(all='ignore'):
            for c, y, s in zip(self._channels, self._ys, self._scales):
                r = (out[c] - y[None, :]) / s
                cost += np.mean(r[:, self._train] ** 2, axis=1)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        picked = []
        for k in np.argsort(cost):
            if len(picked) >= top:
                break
            if all(_distinct(grid, k, j) for j in picked):
                picked.append(k)
        return [{p: float(v[k]) for p, v in grid.items()} for k in picked], cost

    # --------------------------------------------------------------- fitting
    def _fit_model(self, effects, free, start, weight=True):
        kw = {}
        if effects:
            kw['effects'] = effects
            kw['free_effects'] = free
        est = self._identifier(start=start, use_ga=False, **kw)
        bounds = {fe: self._bounds_for(fe) for fe in free}
        if bounds:
            est.bounds = bounds
        with np.errstate(all='ignore'):
            est.fit(self._rec, sample_weight=self._train.astype(float) if weight else None)
        return est

    def _bounds_for(self, key):
        """Search range of an effect parameter on the scale of this recording.

        The catalogue ranges span decades beyond any one motor; a range on the data's own
        scale keeps the refinement's steps and its start (pulled into the interior)
        meaningful for a 1e-6 kg m^2 motor and a 100 kg axis alike.
        """
        e, _, p = key.partition('.')
        spec = {q.name: q for q in EFFECTS[e].params}[p]
        tau, u_max, w_max = self._sc['tau'], self._sc['u_max'], self._sc['w_max']
        T, dt = self._T, self._dt
        R = self.R_m or 1.0
        rng = {
            'T_c': (0.0, 2 * tau), 'T_L': (-2 * tau, 2 * tau),
            'k_q': (0.0, 2 * tau / w_max ** 2), 'V_b': (0.0, u_max),
            'V_dz': (0.0, u_max), 'V_max': (0.01 * u_max, 2 * u_max),
            'tau_s': (0.0, max(0.2 * T, 10 * dt)),
            'k_h': (0.0, 10 * R / (self._sc['i_rms'] ** 2 * max(0.01 * T, dt))),
            'tau_th': (max(spec.low, dt), 10 * T), 'f_r': (3.0 / T, 0.5 / dt),
        }.get(p, (spec.low, spec.high))
        return (max(rng[0], spec.low), min(rng[1], spec.high))

    def _start(self, base_like, effects_start):
        start = dict(base_like.physical)
        for e, vals in effects_start.items():
            for p, v in vals.items():
                start[f'{e}.{p}'] = v
        return start

    def _fit_candidate(self, name, base, prior=None, seed=None):
        """Fit one effect (on top of the effects of ``prior``, a ModelScore or None).

        ``seed`` (a ModelScore) supplies the starting physical parameters and initial
        state instead of ``prior`` or the linear fit.
        """
        t0 = time.perf_counter()
        ref = prior or base
        if seed is not None:
            ref = dataclasses.replace(ref, physical=dict(seed.physical), x0=dict(seed.x0))
        fixed_eff = {e: dict(v) for e, v in (prior.effects if prior else {}).items()}
        quant = fixed_eff.pop('speed_quantization', {}).get('q')
        if name == 'speed_quantization':
            return self._fit_quantization(ref, t0)
        free_prior = [f'{e}.{p}' for e, v in fixed_eff.items() for p in v
                      if not (e in FIXED_PARAMS and p in FIXED_PARAMS[e])]
        if name == 'input_delay':
            d_max = self.max_delay if self.max_delay is not None else \
                int(min(40, max(2, len(self._rec) // 25)))
            grid = {'d': np.arange(1, d_max + 1, dtype=float)}
            rows, _ = self._grid_best(ref, name, grid, _batchable(fixed_eff), top=2)
            tried = {}

            def fit_delay(d):
                if d not in tried and 1 <= d <= d_max:
                    eff = {**fixed_eff, name: {'d': float(d)}}
                    est = self._fit_model(eff, free_prior, self._start(ref, fixed_eff))
                    tried[d] = self._score(name, est, eff, ref.n_extra + 1, t0, quant)
                return tried.get(d)

            for row in rows:
                fit_delay(int(row['d']))
            while True:  # the grid ran at the linear fit's parameters: climb to the best d
                d_best = min(tried, key=lambda d: tried[d].train_error)
                for d in (d_best - 1, d_best + 1):
                    fit_delay(d)
                if min(tried, key=lambda d: tried[d].train_error) == d_best:
                    break
            best = tried[d_best]
            best.seconds = time.perf_counter() - t0
            return best
        grid = self._grid(name, self._sc)
        rows, _ = self._grid_best(ref, name, grid, _batchable(fixed_eff), top=self.starts)
        best = None
        for row in rows:  # a few distinct starts: some effects have local minima
            eff = {**fixed_eff, name: row}
            free = free_prior + [f'{name}.{p}' for p in row]
            est = self._fit_model(eff, free, self._start(ref, eff))
            s = self._score(name, est, eff, ref.n_extra + len(row), t0, quant)
            if best is None or s.train_error < best.train_error:
                best = s
        return best

    def _fit_quantization(self, ref, t0):
        """Quantisation is an output map: grid its step on the reference prediction."""
        k = self._channels.index('speed')
        w_hat = ref.prediction['preds'][k]
        y = self._rec.speed
        w_max = float(np.max(np.abs(y))) or 1.0
        qs = np.geomspace(1e-3 * w_max, 0.2 * w_max, 600)
        tr = self._train
        best_q, best_c = None, np.inf
        for chunk in np.array_split(qs, 12):
            Q = np.round(w_hat[None, tr] / chunk[:, None]) * chunk[:, None]
            c = np.mean((Q - y[None, tr]) ** 2, axis=1)
            j = int(np.argmin(c))
            if c[j] < best_c:
                best_c, best_q = float(c[j]), float(chunk[j])
        # local refinement of q around the grid optimum
        fine = np.linspace(best_q * 0.985, best_q * 1.015, 61)
        Q = np.round(w_hat[None, tr] / fine[:, None]) * fine[:, None]
        c = np.mean((Q - y[None, tr]) ** 2, axis=1)
        q = float(fine[int(np.argmin(c))])
        # a real quantiser puts the measured speed on the grid while it moves, too (on
        # plateaus any grid can be made to fit a few levels)
        moving = np.zeros(y.size, dtype=bool)
        moving[1:-1] = np.abs(w_hat[2:] - w_hat[:-2]) > 0.2 * q
        coherence = float(np.abs(np.mean(np.exp(2j * np.pi * y[moving] / q)))) \
            if np.sum(moving) >= 30 else 0.0
        implausible = '' if coherence >= 0.3 else (
            f'the moving speed does not sit on a grid of {q:.4g} (coherence '
            f'{coherence:.2f} over {int(np.sum(moving))} samples)')
        preds = [np.array(p) for p in ref.prediction['preds']]
        preds[k] = _quantize(preds[k], q)
        e_tr, e_te, sub = self._errors(preds)
        eff = {e: dict(v) for e, v in ref.effects.items()}
        eff['speed_quantization'] = {'q': q}
        params = {**ref.parameters,
                  'speed_quantization.q': {'value': q, 'std': None, 'determined': True,
                                           'grid': True}}
        return ModelScore('speed_quantization', eff, params, 0.0, e_te, e_tr, 0.0,
                          ref.n_extra + 1, 0.0, implausible=implausible,
                          physical=dict(ref.physical),
                          x0=dict(ref.x0), prediction={'preds': preds, 'sub': sub},
                          seconds=time.perf_counter() - t0)

    def _structure(self, model):
        """True when the model's held-out error is well above the noise floor."""
        return model.heldout_error > self.structure_ratio * self._floor

    def _combine(self, base, prior, name):
        """Fit ``name`` on top of the model ``prior``; gain against the linear model."""
        s = self._fit_candidate(name, base, prior=prior)
        s.name = '+'.join(prior.name.split('+') + [name])
        s = self._finish(s, base)
        self._say(f'  {s.name:<40} gain {100 * s.gain:6.1f} %  ({s.seconds:.2f} s)')
        return s

    def _accept(self, chosen, trials):
        """The best trial if it cuts the held-out error of ``chosen`` by ``min_gain``
        (and has no parameter at a search limit); otherwise ``chosen``."""
        for s in trials:
            s.significant = False
        best = min(trials, key=lambda s: s.heldout_error)
        cut = 1.0 - best.heldout_error / chosen.heldout_error
        if (cut >= self.min_gain and best.gain >= self.min_gain and not best.at_bound
                and not best.implausible):
            best.significant = True
            return best
        return chosen

    # -------------------------------------------------------------------- fit
    def fit(self, rec, progress=None):
        """Run the analysis.

        Parameters
        ----------
        rec : Recording
        progress : callable, optional
            ``progress(message)`` for each step (the CLI prints them to stderr).

        Returns
        -------
        self
            With ``report_`` (:class:`DiscrepancyReport`).
        """
        with _single_blas_thread():
            return self._fit(rec, progress)

    def _fit(self, rec, progress):
        t_start = time.perf_counter()
        self._progress = progress
        rec.validate()
        if rec.input_kind == 'voltage' and self.R_m is None:
            raise ConfigError('the armature resistance R_m is required for voltage-input '
                              'data (--resistance R)')
        if len(rec) < 10 * self.n_blocks:
            raise DataError(f'too few samples for a held-out analysis: {len(rec)} '
                            f'(need at least {10 * self.n_blocks})')
        self._prepare(rec)

        # ---- the linear model, fitted on the training blocks
        self._say(f'fitting the linear model ({len(rec)} samples, '
                  f'{100 * np.mean(self._test):.0f} % held out)')
        t0 = time.perf_counter()
        est = self._identifier(generations=self.generations)
        with np.errstate(all='ignore'):
            est.fit(rec, sample_weight=self._train.astype(float))
        base = self._score('linear', est, {}, 0, t0)
        base.significant = False
        self._sc = self._scales_for_grid(base.physical)
        self._say(f'  held-out error {base.heldout_error:.4g} '
                  f'(noise floor {self._floor:.4g})')

        # ---- every candidate alone
        singles = []
        for name in self._cands:
            s = self._finish(self._fit_candidate(name, base), base)
            singles.append(s)
            self._say(f'  {name:<20} gain {100 * s.gain:6.1f} %  '
                      f'({s.seconds:.2f} s){"  *" if s.significant else ""}')
        singles.sort(key=lambda s: s.heldout_error)
        if singles and singles[0].significant:
            # a poor start must not decide the verdict: refit the runners-up from the
            # physical parameters of the best (the linear fit may sit at a bound)
            lead = singles[0]
            for k, s in enumerate(singles[1:self.pool_size + 1], 1):
                if s.name == 'speed_quantization' or s.gain < self.min_gain:
                    continue
                r = self._finish(self._fit_candidate(s.name, base, seed=lead), base)
                if r.train_error < s.train_error:
                    singles[k] = r
                    self._say(f'  {s.name:<20} gain {100 * r.gain:6.1f} %  (restarted '
                              f'from {lead.name}, {r.seconds:.2f} s)'
                              f'{"  *" if r.significant else ""}')
            singles.sort(key=lambda s: s.heldout_error)
        ranked = list(singles)

        # ---- combinations while structure remains: every pair of the best singles
        # (effects can act together: an offset and friction, say), then greedy additions
        chosen = base
        sig = [s for s in singles if s.significant]
        if sig:
            chosen = sig[0]
            if self._structure(chosen):
                # the best still misfits: error differences within the ambiguity band
                # reflect the misfit, not the effect, so the more common effect (the
                # catalogue's order) is named and the others are listed as ambiguous
                ties = [s for s in sig
                        if s.heldout_error <= (1 + self.ambiguity) * chosen.heldout_error]
                chosen = min(ties, key=lambda s: CANDIDATES.index(s.name))
        pool = [s for s in singles if s.gain > 0][:self.pool_size]
        if len(pool) >= 2 and self.max_effects >= 2 and self._structure(chosen):
            trials = []
            for i, first in enumerate(pool):
                for second in pool[i + 1:]:
                    trials.append(self._combine(base, first, second.name))
            ranked.extend(trials)
            chosen = self._accept(chosen, trials)
            while (chosen is not base and '+' in chosen.name and
                   len(chosen.effects) < self.max_effects and self._structure(chosen)):
                trials = [self._combine(base, chosen, s.name) for s in pool
                          if s.name not in chosen.effects]
                if not trials:
                    break
                ranked.extend(trials)
                nxt = self._accept(chosen, trials)
                if nxt is chosen:
                    break
                chosen = nxt
        # best first: the chosen model, then the significant ones, then the rest
        ranked.sort(key=lambda s: (s is not chosen, not s.significant, s.heldout_error))
        verdict = 'none' if chosen is base else chosen.name

        # ---- ambiguity: other significant models as good as the winner
        ambiguous = []
        if chosen is not base:
            for s in ranked:
                if s is chosen or not s.significant or '+' in s.name:
                    continue
                if s.name in chosen.name.split('+'):
                    continue
                if s.heldout_error <= (1 + self.ambiguity) * chosen.heldout_error:
                    main = chosen.name.split('+')[0]
                    key = frozenset((main, s.name))
                    exp = (TORQUE_EXPERIMENTS.get(key) if self._kind == 'torque' else None) \
                        or EXPERIMENTS.get(key, GENERIC_EXPERIMENT)
                    ambiguous.append({'name': s.name, 'gain': s.gain, 'experiment': exp})

        unexplained = bool(chosen.heldout_error > self.structure_ratio * self._floor)

        # ---- final fits on all data
        self._say('refitting the linear and the chosen model on all data')
        full_base = self._fit_model({}, [], dict(base.physical), weight=False)
        if chosen is base:
            full = full_base
        else:
            eff = {e: dict(v) for e, v in chosen.effects.items()
                   if e != 'speed_quantization'}
            free = [f'{e}.{p}' for e, v in eff.items() for p in v
                    if not (e in FIXED_PARAMS and p in FIXED_PARAMS[e])]
            full = self._fit_model(eff, free, self._start(chosen, eff), weight=False)
        params = full.result_.to_dict()['parameters']
        chosen_d = {'name': verdict, 'effects': chosen.effects,
                    'fit': full.result_.fit if chosen is not base else None}
        if chosen is not base:
            fe = full.result_.effects
            chosen_d['effects'] = {e: {p: (v['value'] if isinstance(v, dict) else v)
                                       for p, v in vals.items()} for e, vals in fe.items()}
            if 'speed_quantization' in chosen.effects:
                chosen_d['effects']['speed_quantization'] = chosen.effects[
                    'speed_quantization']
            for e, vals in fe.items():
                for p, v in vals.items():
                    if isinstance(v, dict):
                        params[f'{e}.{p}'] = dict(v)
                    else:
                        params[f'{e}.{p}'] = {'value': float(v), 'std': None,
                                              'determined': True, 'grid': True}
            if 'speed_quantization' in chosen.effects:
                params['speed_quantization.q'] = {
                    'value': chosen.effects['speed_quantization']['q'], 'std': None,
                    'determined': True, 'grid': True}

        # ---- diagnostics of the linear model's residuals
        bres = full_base.result_
        diag = {'residual': {}, 'binned': {}, 'noise_floor': self._floor}
        variables = {'speed': rec.speed, 'input': rec.input,
                     'sign(speed)': rec.speed, 'sign(input)': rec.input}
        if rec.has_current:
            variables.update({'current': rec.current, 'sign(current)': rec.current})
        for c in self._channels:
            r = np.asarray(bres.prediction[c + '_measured']) - np.asarray(bres.prediction[c])
            dd = residual_diagnostics(r, rec.input)
            diag['residual'][c] = {k: dd[k] for k in (
                'autocorrelation_outside', 'cross_correlation_outside', 'white',
                'independent', 'band', 'autocorrelation', 'cross_correlation')}
            diag['binned'][c] = binned_means(r, variables)
        points = steady_state_map(rec)
        for p in points:
            a, b = p['start'], p['stop']
            p['speed_linear'] = float(np.mean(bres.prediction['speed'][a:b]))
            if chosen is not base:
                p['speed_chosen'] = float(np.mean(
                    chosen.prediction['preds'][self._channels.index('speed')][a:b]))
        diag['steady_state'] = {**map_summary(points), 'points': points}
        if chosen is not base:
            after = {}
            fres = full.result_
            for c in self._channels:
                r = np.asarray(fres.prediction[c + '_measured']) - \
                    np.asarray(fres.prediction[c])
                if c == 'speed' and 'speed_quantization' in chosen.effects:
                    r = np.asarray(fres.prediction[c + '_measured']) - _quantize(
                        np.asarray(fres.prediction[c]),
                        chosen.effects['speed_quantization']['q'])
                dd = residual_diagnostics(r, rec.input)
                after[c] = {k: dd[k] for k in ('autocorrelation_outside',
                                               'cross_correlation_outside', 'white',
                                               'independent')}
            diag['residual_after'] = after

        idyn = None
        if rec.input_kind == 'torque':
            terms = [e for e in chosen.effects
                     if e in ('coulomb_friction', 'load_torque', 'quadratic_load')]
            delay = int(chosen.effects.get('input_delay', {}).get('d', 0))
            idyn = inverse_dynamics(rec, terms, delay=delay)

        held = list(range(2, self.n_blocks, 3))
        heldout = {'scheme': f'{self.n_blocks} blocks, blocks {held} held out (the '
                             'simulation runs through them)',
                   'fraction': float(np.mean(self._test)), 'blocks': self._blocks,
                   'base_error': base.heldout_error, 'final_error': chosen.heldout_error,
                   'noise_floor': self._floor, 'min_gain': self.min_gain}
        baseline = {'parameters': bres.to_dict()['parameters'], 'fit': bres.fit,
                    'heldout_error': base.heldout_error}
        plot_data = {'time': rec.time, 'channels': self._channels, 'ys': self._ys,
                     'base': base.prediction['preds'],
                     'chosen': chosen.prediction['preds'], 'test': self._test,
                     'points': points}
        self.report_ = DiscrepancyReport(
            verdict, [s for s in ranked], unexplained, ambiguous, params, baseline,
            chosen_d, diag, heldout, rec.input_kind, self._channels, idyn, plot_data)
        self.report_.seconds = time.perf_counter() - t_start
        return self


def _single_blas_thread():
    """Limit BLAS to one thread: the analysis does many small solves, where threads only
    contend (a no-op without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1)


def _distinct(grid, a, b):
    """True when grid rows a and b differ by more than a factor 2 in some parameter."""
    for v in grid.values():
        x, y = abs(v[a]), abs(v[b])
        if np.sign(v[a]) != np.sign(v[b]) or max(x, y) > 2 * min(x, y):
            return True
    return False


def _quantize(w, q):
    return np.round(np.asarray(w) / q) * q if q and q > 0 else np.asarray(w)


def _batchable(effects):
    """Effects of a fitted model as scalars, minus output maps (for grid evaluation)."""
    return {e: dict(v) for e, v in effects.items() if e != 'speed_quantization'}


# --------------------------------------------------------------------------- plots
def plot_report(report, path, title=None):
    """Residuals before/after, the steady-state map and the gain per candidate, as PNG."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    pd = report.plot_data
    chans = list(pd['channels'])
    fig, axes = plt.subplots(2, 2, figsize=(13, 9), squeeze=False)
    t = pd['time']
    for k, ch in enumerate(chans[:2]):
        ax = axes[0, k]
        rb = pd['ys'][k] - pd['base'][k]
        rc = pd['ys'][k] - pd['chosen'][k]
        ax.plot(t, rb, lw=0.7, label='linear model')
        if report.verdict != 'none':
            ax.plot(t, rc, lw=0.7, label=report.verdict)
        test = pd['test']
        ylo, yhi = ax.get_ylim()
        ax.fill_between(t, ylo, yhi, where=test, color='0.9', zorder=0, label='held out')
        ax.set_ylim(ylo, yhi)
        ax.set_title(f'{ch} residual (measured - simulated)')
        ax.set_xlabel('time [s]')
        ax.legend(loc='best', fontsize=8)
    ax = axes[0, 1] if len(chans) < 2 else axes[1, 1]
    pts = pd['points']
    if pts:
        u = [p['input'] for p in pts]
        ax.plot(u, [p['speed'] for p in pts], 'o', label='measured plateaus')
        ax.plot(u, [p['speed_linear'] for p in pts], 'x', label='linear model')
        if 'speed_chosen' in pts[0]:
            ax.plot(u, [p['speed_chosen'] for p in pts], '+', ms=10, label=report.verdict)
        ax.legend(loc='best', fontsize=8)
    ax.set_title('steady-state map')
    ax.set_xlabel('input')
    ax.set_ylabel('speed')
    ax = axes[1, 0]
    singles = [e for e in report.effects if '+' not in e.name]
    combos = [e for e in report.effects if '+' in e.name]
    items = singles + combos
    names = [e.name for e in items]
    gains = [100 * e.gain for e in items]
    colors = ['tab:blue' if e.name == report.verdict else
              'tab:green' if e.significant else 'tab:gray' for e in items]
    ax.barh(range(len(items)), gains, color=colors)
    ax.set_yticks(range(len(items)))
    ax.set_yticklabels(names, fontsize=7)
    ax.invert_yaxis()
    ax.axvline(100 * report.heldout['min_gain'], color='k', ls='--', lw=0.8)
    ax.set_xlabel('held-out gain [%] (blue: chosen, green: significant)')
    ax.set_title(f'gain per candidate; verdict: {report.verdict}')
    if len(chans) < 2:
        ax = axes[1, 1]
        ax.plot(t, pd['ys'][0], lw=0.8, color='k', label='measured')
        ax.plot(t, pd['base'][0], lw=0.8, label='linear model')
        if report.verdict != 'none':
            ax.plot(t, pd['chosen'][0], lw=0.8, ls='--', label=report.verdict)
        ax.set_title(f'{chans[0]}: measured and simulated')
        ax.set_xlabel('time [s]')
        ax.legend(loc='best', fontsize=8)
    fig.suptitle(title or 'motor_id discrepancy analysis')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
