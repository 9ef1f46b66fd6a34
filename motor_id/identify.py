"""The estimator: GA fit of the constrained Elman net, refinement, covariance, identifiability.

Methods
-------
``zoh`` (recommended)
    Exact zero-order-hold model, the paper's GA, then a bounded least-squares refinement
    from the GA's best individuals; every measured channel is used.
``euler``
    As ``zoh`` but with the paper's first-order discretisation (to show its bias).
``paper``
    The paper as published: Euler, GA only, speed channel only.

Uncertainty is the Gauss-Newton (Cramer-Rao) covariance with each channel's noise level
estimated from its residuals. Identifiability comes from the singular values of the
weighted output sensitivities: directions in parameter space that the data cannot see
are reported, and parameters along them are reported as not determined.
"""

from dataclasses import dataclass, field
import time

import numpy as np
from scipy.optimize import least_squares

from motor_id.errors import ConfigError
from motor_id.ga import Bounds, GeneticAlgorithm
from motor_id.metrics import channel_metrics
from motor_id.model import EFFECTS, PARAM_NAMES, transfer_coefficients
from motor_id.simulate import simulate_batch

METHODS = ('zoh', 'euler', 'paper')
VOLTAGE_FREE = ('J', 'K_T', 'K_b', 'B', 'L_m')
TORQUE_FREE = ('J', 'B')
DEFAULT_BOUNDS = {
    'J': (1e-6, 10.0), 'K_T': (1e-3, 10.0), 'K_b': (1e-3, 10.0), 'B': (1e-7, 1.0),
    'L_m': (1e-5, 1.0),
}
TORQUE_BOUNDS = {'J': (1e-7, 1e4), 'B': (1e-8, 1e5)}
NULL_TOL = 1e-7     # singular value ratio below which a direction is structurally unseen
DETERMINED_TOL = 1e-6  # max projection of a parameter on the unseen directions


def parse_fixed(items, option='--fix'):
    """Parse ``NAME=VALUE`` items: motor parameters known in advance.

    Parameters
    ----------
    items : iterable of str
    option : str
        How the user gave them (``--fix``, ``parameter fix``), for the messages.

    Returns
    -------
    dict
        ``{name: value}``.

    Raises
    ------
    ConfigError
        A malformed item, a name not in :data:`motor_id.model.PARAM_NAMES`, or a value
        that is not a finite positive number.
    """
    out = {}
    for item in items or ():
        name, sep, value = (x.strip() for x in item.partition('='))
        if not (sep and name):
            raise ConfigError(f'{option} takes NAME=VALUE, got {item!r}')
        if name not in PARAM_NAMES:
            raise ConfigError(f'{option}: unknown parameter {name!r}; use '
                              f'{", ".join(PARAM_NAMES)}')
        try:
            v = float(value)
        except ValueError:
            raise ConfigError(f'{option} {item!r}: {value!r} is not a number') from None
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f'{option} {item!r}: a physical parameter must be finite and '
                              '> 0')
        out[name] = v
    return out


def parse_bounds(items, option='--bounds'):
    """Parse ``NAME=LOW:HIGH`` items: search ranges.

    Parameters
    ----------
    items : iterable of str
    option : str
        How the user gave them, for the messages.

    Returns
    -------
    dict
        ``{name: (low, high)}``.

    Raises
    ------
    ConfigError
        A malformed item, a range that is not finite with LOW < HIGH, or, for the motor
        parameters (searched on a log scale), LOW <= 0. Other names (effect parameters)
        are checked by :class:`Identifier` against what it fits.
    """
    out = {}
    for item in items or ():
        name, sep, rng = (x.strip() for x in item.partition('='))
        lo, sep2, hi = rng.partition(':')
        try:
            low, high = float(lo), float(hi)
        except ValueError:
            low = high = None
        if not (sep and sep2 and name) or low is None:
            raise ConfigError(f'{option} takes NAME=LOW:HIGH, got {item!r}')
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ConfigError(f'{option} {item!r}: need finite LOW < HIGH')
        if name in PARAM_NAMES and not low > 0:
            raise ConfigError(f'{option} {item!r}: {name} is searched on a log scale, '
                              'LOW must be > 0')
        out[name] = (low, high)
    return out

@dataclass
class Estimate:
    """One parameter's estimate."""

    value: float = None
    std: float = None
    determined: bool = False
    assumed: bool = False
    particular_value: float = None
    ci95: tuple = None

    def to_dict(self):
        """JSON-ready; undetermined parameters have value and std null."""
        d = {'value': self.value, 'std': self.std, 'determined': self.determined}
        if self.assumed:
            d['assumed'] = True
        if self.particular_value is not None:
            d['particular_value'] = self.particular_value
        if self.ci95 is not None:
            d['bootstrap_ci95'] = list(self.ci95)
        return d


@dataclass
class IdentificationResult:
    """Everything a fit produced; serialises to the documented JSON shape."""

    method: str
    input_kind: str
    channels: tuple
    parameters: dict
    identifiable_combinations: list
    undetermined_directions: list
    identifiability: dict
    fit: dict
    ga: dict
    refinement: dict
    assumptions: dict
    effects: dict = field(default_factory=dict)
    prediction: dict = field(default_factory=dict, repr=False)
    seconds: float = 0.0

    def to_dict(self):
        """The JSON shape documented in the README (extra keys beyond the contract)."""
        return {
            'parameters': {k: v.to_dict() for k, v in self.parameters.items()},
            'identifiable_combinations': self.identifiable_combinations,
            'undetermined_directions': self.undetermined_directions,
            'identifiability': self.identifiability,
            'fit': self.fit,
            'method': self.method,
            'input_kind': self.input_kind,
            'channels': list(self.channels),
            'assumptions': self.assumptions,
            'effects': self.effects,
            'ga': self.ga,
            'refinement': self.refinement,
            'seconds': self.seconds,
        }

    def values(self):
        """``{name: value}`` of every parameter, using the particular value if undetermined."""
        out = {}
        for k, e in self.parameters.items():
            out[k] = e.value if e.value is not None else e.particular_value
        return out

    def summary(self):
        """A plain-text table for people."""
        lines = [f'method: {self.method}   channels: {", ".join(self.channels)}   '
                 f'plant: {self.input_kind} input']
        lines.append(f'{"parameter":<12}{"estimate":>14}{"std":>12}  note')
        for name, e in self.parameters.items():
            if e.value is None:
                lines.append(f'{name:<12}{"-":>14}{"-":>12}  not determined by this data')
            else:
                std = '-' if e.std is None else f'{e.std:.4g}'
                note = 'assumed (given)' if e.assumed else ''
                if e.ci95 is not None:
                    note += f' bootstrap 95%: [{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]'
                lines.append(f'{name:<12}{e.value:>14.6g}{std:>12}  {note}'.rstrip())
        idf = self.identifiability
        lines.append(f'identifiability: rank {idf["rank"]} of {idf["n_free"]} free '
                     f'parameter(s), condition {idf["condition"]:.3g}')
        if self.undetermined_directions:
            pivots = [d['free'] for d in self.undetermined_directions]
            lines.append(f'{len(pivots)} direction(s) in parameter space leave the output '
                         f'unchanged: {", ".join(pivots)} can take any value, and the '
                         'others follow:')
            for d in self.undetermined_directions:
                lines.append('  ' + d['description'])
            lines.append('  add a measured channel (current), the K_T = K_b tie, or a known '
                         'value (--fix NAME=VALUE) to determine them')
        if self.identifiable_combinations:
            lines.append('determined combinations:')
            for c in self.identifiable_combinations:
                std = '' if c.get('std') is None else f' +- {c["std"]:.4g}'
                lines.append(f'  {c["name"]:<28} = {c["value"]:.6g}{std}')
        for ch, m in self.fit['channels'].items():
            lines.append(f'fit {ch}: {m["fit_percent"]:.2f} %  RMS {m["rms"]:.4g}  '
                         f'residual white: {m["white"]}  independent of input: '
                         f'{m["independent"]}')
        lines.append(f'GA: {self.ga["generations"]} generations, {self.ga["evaluations"]} '
                     f'evaluations, {self.ga["seconds"]:.3f} s; total {self.seconds:.2f} s')
        return '\n'.join(lines)


class Identifier:
    """Estimate physical motor parameters from a recording.

    Parameters
    ----------
    method : {'zoh', 'euler', 'paper'}
    R_m : float
        Known armature resistance [Ohm]; required for a voltage plant.
    tie : bool or None
        Impose K_T = K_b (SI units). ``None``: on when a current channel is present and
        the method is not ``paper``.
    population, generations, crossover, mutation : GA settings (the paper's defaults).
    random_state : int, Generator or None
    fixed : dict, optional
        Known values ``{name: value}``: an explicit extra assumption; those parameters are
        not fitted.
    bounds : dict, optional
        ``{name: (low, high)}`` search ranges overriding the defaults; effect
        parameters are named ``effect.param``.
    channels : tuple, optional
        Output channels to fit; default all measured (``paper``: speed only).
    effects : dict, optional
        ``{effect: {param: value}}`` terms included in the model (from
        :data:`motor_id.model.EFFECTS`).
    free_effects : sequence of str, optional
        ``'effect.param'`` entries of ``effects`` to estimate.
    start : dict, optional
        A starting parameter set; seeds the GA and the refinement.
    use_ga : bool
        False skips the GA and refines from ``start`` only (warm starts).
    bootstrap : int
        Number of residual-bootstrap refits for percentile intervals (0 = off).
    refine_starts : int
        Number of distinct GA individuals the refinement starts from.
    """

    def __init__(self, method='zoh', R_m=None, tie=None, population=20, generations=160,
                 crossover=0.75, mutation=0.04, random_state=None, fixed=None, bounds=None,
                 channels=None, effects=None, free_effects=None, start=None, use_ga=True,
                 bootstrap=0, refine_starts=3):
        self.method = method
        self.R_m = R_m
        self.tie = tie
        self.population = population
        self.generations = generations
        self.crossover = crossover
        self.mutation = mutation
        self.random_state = random_state
        self.fixed = fixed
        self.bounds = bounds
        self.channels = channels
        self.effects = effects
        self.free_effects = free_effects
        self.start = start
        self.use_ga = use_ga
        self.bootstrap = bootstrap
        self.refine_starts = refine_starts

    # ----------------------------------------------------------------- set-up
    def _setup(self, rec):
        if self.method not in METHODS:
            raise ConfigError(f'method must be one of {METHODS}, got {self.method!r}')
        kind = rec.input_kind
        fixed = {k: float(v) for k, v in (self.fixed or {}).items()}
        if kind == 'voltage':
            if self.R_m is None:
                raise ConfigError('the armature resistance R_m is required '
                                  '(--resistance R)')
            if not self.R_m > 0:
                raise ConfigError(f'R_m must be > 0 Ohm, got {self.R_m}')
            names = list(VOLTAGE_FREE)
            fixed['R_m'] = float(self.R_m)
            bounds = dict(DEFAULT_BOUNDS)
        else:
            names = list(TORQUE_FREE)
            bounds = dict(TORQUE_BOUNDS)
        unknown = set(fixed) - set(names) - {'R_m'}
        if unknown:
            raise ConfigError(f'cannot fix {sorted(unknown)}: the parameters of a {kind} '
                              f'plant are {names}')
        if self.channels is not None:
            channels = tuple(self.channels)
        elif self.method == 'paper':
            channels = ('speed',)
        else:
            channels = rec.channels()
        for ch in channels:
            if ch not in rec.channels():
                raise ConfigError(f'channel {ch!r} is not in the recording '
                                  f'(it has {", ".join(rec.channels())})')
        tie = self.tie
        if tie is None:
            tie = kind == 'voltage' and 'current' in channels and self.method != 'paper'
        if tie and kind != 'voltage':
            tie = False
        free = [n for n in names if n not in fixed and not (tie and n == 'K_b')]
        effects = {k: dict(v) for k, v in (self.effects or {}).items()}
        for e in effects:
            if e not in EFFECTS:
                raise ConfigError(f'unknown effect {e!r}')
            effects[e] = {**EFFECTS[e].defaults(), **effects[e]}
        free_eff = list(self.free_effects or ())
        for fe in free_eff:
            e, _, p = fe.partition('.')
            if e not in effects or p not in effects[e]:
                raise ConfigError(f'free effect parameter {fe!r} is not in the effects '
                                  f'{sorted(effects)}')
        for key, (lo, hi) in (self.bounds or {}).items():
            if key not in bounds and key not in free_eff:
                raise ConfigError(f'bounds given for {key!r}, which is not fitted '
                                  f'(fitted: {free + free_eff})')
            bounds[key] = (float(lo), float(hi))
        for fe in free_eff:
            if fe not in bounds:
                e, _, p = fe.partition('.')
                spec = {q.name: q for q in EFFECTS[e].params}[p]
                bounds[fe] = (spec.low, spec.high)
        lows, highs, logs = [], [], []
        for n in free + free_eff:
            lo, hi = bounds[n]
            lows.append(lo)
            highs.append(hi)
            logs.append(n in PARAM_NAMES)
        self._kind = kind
        self._tie = tie
        self._fixed = fixed
        self._free = free
        self._free_eff = free_eff
        self._effects = effects
        self._channels = channels
        self._disc = 'zoh' if self.method == 'zoh' else 'euler'
        self._bounds = Bounds(tuple(free + free_eff), tuple(lows), tuple(highs), tuple(logs))

    def _expand(self, X):
        """Parameter vectors (P, d) -> (theta dict, effects dict) batches."""
        X = np.atleast_2d(X)
        P = X.shape[0]
        theta = {k: np.full(P, v) for k, v in self._fixed.items()}
        for j, n in enumerate(self._free):
            theta[n] = X[:, j]
        if self._tie:
            theta['K_b'] = theta['K_T']
        effects = {e: {p: np.full(P, v) for p, v in vals.items()}
                   for e, vals in self._effects.items()}
        for j, fe in enumerate(self._free_eff):
            e, _, p = fe.partition('.')
            effects[e][p] = X[:, len(self._free) + j]
        return theta, effects

    def _simulate_channels(self, X):
        """Outputs per channel for parameter rows X (trailing columns: initial state)."""
        X = np.atleast_2d(X)
        d = self._bounds.dim
        x0 = X[:, d:] if X.shape[1] > d else self._x0
        theta, effects = self._expand(X[:, :d])
        with np.errstate(all='ignore'):
            out = simulate_batch(theta, self._t, self._u, self._kind, self._disc, effects,
                                 x0)
        return [out[c] for c in self._channels]

    def _simulate(self, X):
        """All channels side by side, shape (P, n_channels * N)."""
        return np.concatenate(self._simulate_channels(X), axis=1)

    def _cost(self, X):
        """The GA's fitness: weighted mean squared output error per row of X."""
        ys = self._simulate_channels(X)
        c = np.zeros(ys[0].shape[0])
        n = ys[0].shape[1]
        with np.errstate(all='ignore'):
            for k, y in enumerate(ys):
                sl = slice(k * n, (k + 1) * n)
                e = y - self._y[sl]
                e *= self._w[sl]
                c += np.einsum('ij,ij->i', e, e)
        c /= n * len(ys)
        return np.where(np.isfinite(c), c, np.inf)

    # ------------------------------------------------------------- transforms
    def _log_mask(self, size):
        """Which of ``size`` coordinates are on a log scale (initial states never are)."""
        lg = np.zeros(size, dtype=bool)
        lg[:self._bounds.dim] = self._bounds.log
        return lg

    def _to_z(self, x):
        lg = self._log_mask(np.shape(x)[-1])
        return np.where(lg, np.log(np.where(lg, np.maximum(x, 1e-300), 1.0)), x)

    def _from_z(self, z):
        lg = self._log_mask(np.shape(z)[-1])
        return np.where(lg, np.exp(z), z)

    def _z_bounds(self, size=None):
        lo = self._to_z(np.array(self._bounds.low))
        hi = self._to_z(np.array(self._bounds.high))
        if size is not None and size > lo.size:
            lo = np.concatenate([lo, self._x0_bounds[0]])
            hi = np.concatenate([hi, self._x0_bounds[1]])
        return lo, hi

    def _jacobian_z(self, z, weights):
        """Central-difference Jacobian of weighted residuals w.r.t. z, one batch."""
        d = z.size
        h = 1e-5 * np.maximum(1.0, np.abs(z))
        # linear coordinates whose range is narrow (effect parameters of a small motor,
        # given bounds) step by a fraction of that range, never by more than before
        lo, hi = self._z_bounds(d)
        h = np.minimum(h, 1e-5 * np.maximum(np.abs(z), 1e-3 * (hi - lo)))
        h = np.where(self._log_mask(d), 1e-5, h)
        Z = np.repeat(z[None, :], 2 * d, axis=0)
        Z[np.arange(d), np.arange(d)] += h
        Z[d + np.arange(d), np.arange(d)] -= h
        Y = self._simulate(self._from_z(Z)) * weights[None, :]
        Jt = (Y[:d] - Y[d:]) / (2 * h[:, None])
        return Jt.T

    def _refine(self, z0, weights, max_nfev=60):
        lo, hi = self._z_bounds(z0.size)
        z0 = np.clip(z0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

        def fun(z):
            return self._weighted_residuals(z, weights)

        def jac(z):
            J = self._jacobian_z(z, weights)
            return np.where(np.isfinite(J), J, 0.0)

        return least_squares(fun, z0, jac=jac, bounds=(lo, hi), method='trf',
                             x_scale='jac', max_nfev=max_nfev, xtol=1e-10, ftol=1e-12)

    # -------------------------------------------------------------------- fit
    def fit(self, rec, progress=None, sample_weight=None):
        """Fit the model to a recording.

        Parameters
        ----------
        rec : motor_id.recording.Recording
        progress : callable, optional
            ``progress(generation, generations, best_cost)``; returning True cancels
            the GA (the best so far is then refined and reported).
        sample_weight : array_like, shape (N,), optional
            Non-negative weight of each sample in the cost (every channel); 0 leaves a
            sample out of the fit while the simulation still runs through it (held-out
            blocks for validation).

        Returns
        -------
        self
            With ``result_`` (:class:`IdentificationResult`), ``params_`` (dict),
            ``covariance_`` (ndarray over the free parameters, log scale where the
            parameter is positive) and ``history_`` (GA generations).
        """
        t_start = time.perf_counter()
        rec.validate()
        self._setup(rec)
        self._t = rec.time
        self._u = rec.input
        x0 = [rec.speed[0]]
        if self._kind == 'voltage':
            x0.append(rec.current[0] if rec.has_current else 0.0)
        self._x0 = np.array(x0)
        ys0 = [rec.speed] + ([rec.current] if self._kind == 'voltage' and rec.has_current
                             else [np.zeros(1)] if self._kind == 'voltage' else [])
        span = np.array([np.max(np.abs(y)) * 2 + 1.0 for y in ys0])
        self._x0_bounds = (self._x0 - span, self._x0 + span)
        ys = [getattr(rec, c) for c in self._channels]
        self._y = np.concatenate(ys)
        scales = [np.std(y) if np.std(y) > 0 else 1.0 for y in ys]
        self._w = np.concatenate([np.full(y.size, 1.0 / s) for y, s in zip(ys, scales)])
        n_per = [y.size for y in ys]
        self._sw = np.ones(self._y.size)
        if sample_weight is not None:
            sw = np.asarray(sample_weight, dtype=float)
            if sw.shape != rec.time.shape or not np.all(np.isfinite(sw) & (sw >= 0)) \
                    or not np.any(sw > 0):
                raise ConfigError(f'sample_weight must hold {len(rec)} finite values >= 0, '
                                  'not all zero')
            self._sw = np.tile(sw, len(ys))
            self._w = self._w * self._sw

        # ---- GA (the paper's network training)
        t_ga = time.perf_counter()
        rng = (self.random_state if isinstance(self.random_state, np.random.Generator)
               else np.random.default_rng(self.random_state))
        x_start = None
        if self.start is not None:
            x_start = self._start_vector(self.start)
        ga = None
        if self.use_ga:
            ga = GeneticAlgorithm(self._bounds, self.population, self.generations,
                                  self.crossover, self.mutation, x0=x_start,
                                  random_state=rng)
            while not ga.stop():
                ga.tell(self._cost(ga.ask()))
                if progress is not None and progress(ga.generation_, ga.generations,
                                                     ga.best_cost_):
                    ga.cancel()
            best = ga.best_
        else:
            if x_start is None:
                raise ConfigError('use_ga=False needs a start parameter set')
            best = x_start
        ga_seconds = time.perf_counter() - t_ga

        # ---- refinement
        refine_info = {'used': False}
        z_best = self._to_z(best)
        if self.method != 'paper':
            # the refinement also estimates the initial state (nuisance parameters):
            # starting from a noisy first sample would bias the fit
            z_best = np.concatenate([z_best, self._x0])
            starts = [z_best]
            if ga is not None and self.refine_starts > 1:
                order = np.argsort(ga.costs_)
                pop = self._to_z(ga.bounds.decode(ga.genes_))
                for k in order:
                    if len(starts) >= self.refine_starts:
                        break
                    zk = np.concatenate([pop[k], self._x0])
                    if all(np.max(np.abs(zk - s)) > 0.05 for s in starts):
                        starts.append(zk)
            sols = [self._refine(s, self._w) for s in starts]
            sol = min(sols, key=lambda s: s.cost)
            z_best = sol.x
            # re-weight by the estimated noise levels and restart until the cost settles
            # (a trust-region run can stall on a tiny step far from the optimum)
            for _ in range(4):
                w = self._noise_weights(z_best, n_per)
                prev = np.sum(self._weighted_residuals(z_best, w) ** 2)
                sol = self._refine(z_best, w)
                z_best = sol.x
                if prev - 2 * sol.cost <= 1e-9 * prev:
                    break
            refine_info = {'used': True, 'starts': len(starts), 'nfev': int(sol.nfev),
                           'status': int(sol.status), 'message': str(sol.message)}
        x_best = self._from_z(z_best)

        # ---- uncertainty and identifiability
        sigma, w = self._noise_levels(z_best, n_per)
        J = self._jacobian_z(z_best, w)
        result = self._build_result(rec, x_best, z_best, J, sigma, n_per, ga, ga_seconds,
                                    refine_info)
        if self.bootstrap and self.method != 'paper':
            self._bootstrap(result, z_best, w, n_per, rng)
        result.seconds = time.perf_counter() - t_start
        self.result_ = result
        self.params_ = result.values()
        self.history_ = [] if ga is None else [h.to_dict() for h in ga.history_]
        return self

    def _start_vector(self, start):
        vals = []
        for n in self._bounds.names:
            if '.' in n:
                e, _, p = n.partition('.')
                vals.append(self._effects[e][p] if n not in start else start[n])
            else:
                if n not in start:
                    raise ConfigError(f'start values lack {n!r}')
                vals.append(start[n])
        lo = np.array(self._bounds.low)
        hi = np.array(self._bounds.high)
        return np.clip(np.array(vals, dtype=float), lo, hi)

    def _weighted_residuals(self, z, w):
        with np.errstate(all='ignore'):
            r = (self._simulate(self._from_z(z[None, :]))[0] - self._y) * w
        return np.where(np.isfinite(r), r, 1e6)

    def _residuals(self, z):
        return self._simulate(self._from_z(z[None, :]))[0] - self._y

    def _noise_levels(self, z, n_per):
        r = self._residuals(z)
        sig, w = [], []
        i = 0
        d = z.size
        for n in n_per:
            rc = r[i:i + n]
            swc = self._sw[i:i + n]
            dof = max(np.sum(swc) - d / len(n_per), 1.0)
            s = float(np.sqrt(np.sum(swc * rc * rc) / dof))
            s = s if s > 0 else 1e-12 * (np.std(self._y[i:i + n]) or 1.0)
            sig.append(s)
            w.append(swc / s)
            i += n
        return sig, np.concatenate(w)

    def _noise_weights(self, z, n_per):
        return self._noise_levels(z, n_per)[1]

    def _build_result(self, rec, x_best, z_best, J, sigma, n_per, ga, ga_seconds,
                      refine_info):
        names = list(self._bounds.names)
        state_names = ['x0:speed', 'x0:current'][:z_best.size - len(names)]
        names = names + state_names
        rank, Vr, Vn, determined = self._structural(z_best)
        Jr = J @ Vr  # output sensitivities along the identifiable directions
        fisher_r = Jr.T @ Jr
        sr = np.linalg.svd(fisher_r, compute_uv=False) if rank else np.zeros(0)
        cov = Vr @ np.linalg.pinv(fisher_r, rcond=1e-15) @ Vr.T
        cond = float(sr[0] / sr[-1]) if rank and sr[-1] > 0 else float('inf')
        lg = self._log_mask(len(names))
        params = {}
        values = dict(self._fixed)
        for j, n in enumerate(names):
            values[n] = float(x_best[j])
        if self._tie:
            values['K_b'] = values['K_T']
        all_names = list(PARAM_NAMES) if self._kind == 'voltage' else list(TORQUE_FREE)
        std_z = np.sqrt(np.maximum(np.diag(cov), 0.0))
        for n in all_names:
            if n in self._fixed:
                params[n] = Estimate(self._fixed[n], 0.0, True, assumed=True)
                continue
            src = 'K_T' if (self._tie and n == 'K_b') else n
            j = names.index(src)
            if determined[j]:
                std = std_z[j] * x_best[j] if lg[j] else std_z[j]
                params[n] = Estimate(float(x_best[j]), float(std), True)
            else:
                params[n] = Estimate(None, None, False, particular_value=float(x_best[j]))
        eff_out = {e: dict(v) for e, v in self._effects.items()}
        for j, fe in enumerate(self._free_eff):
            e, _, p = fe.partition('.')
            k = len(self._free) + j
            eff_out[e][p] = {'value': float(x_best[k]),
                             'std': float(std_z[k]) if determined[k] else None,
                             'determined': bool(determined[k])}
        undetermined = []
        if Vn.size:
            # a basis with one free "pivot" parameter per direction (QR column pivoting)
            from scipy.linalg import qr
            _, _, piv = qr(Vn.T, pivoting=True)
            piv = np.sort(piv[:Vn.shape[1]])
            basis = Vn @ np.linalg.inv(Vn[piv])
            pivots = [names[j] for j in piv]
            others = [n for j, n in enumerate(names) if j not in piv and not determined[j]]
            for k, v in enumerate(basis.T):
                comp = {names[j]: round(float(c), 4) for j, c in enumerate(v)
                        if abs(c) > 1e-6}
                desc = ' '.join(f'{n}^{c:+.3g}' if lg[names.index(n)] else f'{n}{c:+.3g}'
                                for n, c in comp.items() if abs(c) >= 1e-3)
                undetermined.append({'free': pivots[k], 'exponents': comp,
                                     'description': f'multiply {desc} by any common factor'})
            self._free_choice = (pivots, others)
        else:
            self._free_choice = ([], [])
        combos = self._combinations(values, z_best, cov, rank, len(names))
        pred_full = self._simulate(x_best[None, :])[0]
        fit = {'channels': {}, 'noise_std': {}}
        i = 0
        for ch, n, sg in zip(self._channels, n_per, sigma):
            fit['channels'][ch] = channel_metrics(self._y[i:i + n], pred_full[i:i + n],
                                                  self._u)
            fit['noise_std'][ch] = sg
            i += n
        fit['cost'] = float(np.mean(((pred_full - self._y) * self._w) ** 2))
        fit['initial_state'] = {n: float(x_best[names.index(n)]) for n in state_names}
        prediction = {'time': rec.time, 'input': rec.input}
        i = 0
        for ch, n in zip(self._channels, n_per):
            prediction[ch] = pred_full[i:i + n]
            prediction[ch + '_measured'] = self._y[i:i + n]
            i += n
        n_model = len(names) - len(state_names)
        idf = {'rank': rank - len(state_names), 'n_free': n_model, 'free': names[:n_model],
               'nuisance': state_names,
               'condition': cond,
               'basis': 'transfer-function coefficients (structural); covariance from '
                        'output sensitivities on the identifiable subspace',
               'fully_determined': rank == len(names),
               'tie_K_T_eq_K_b': bool(self._tie), 'channels': list(self._channels)}
        gad = {'generations': 0, 'evaluations': 0, 'seconds': ga_seconds, 'history': []}
        if ga is not None:
            gad = {'generations': ga.generation_, 'evaluations': ga.evaluations_,
                   'seconds': ga_seconds, 'best_cost': ga.best_cost_,
                   'stop': {k: v for k, v in ga.stop().items()},
                   'population': ga.population, 'crossover': ga.crossover,
                   'mutation': ga.mutation,
                   'history': [h.to_dict() for h in ga.history_]}
        assumptions = {'R_m': self._fixed.get('R_m'), 'K_T_eq_K_b': bool(self._tie),
                       'fixed': {k: v for k, v in self._fixed.items() if k != 'R_m'},
                       'discretisation': self._disc}
        self.covariance_ = cov
        return IdentificationResult(self.method, self._kind, self._channels, params, combos,
                                    undetermined, idf, fit, gad, refine_info, assumptions,
                                    eff_out, prediction)

    def _values_at(self, z):
        """Full ``{name: value}`` of the physical parameters at free vector z."""
        x = self._from_z(z)
        v = dict(self._fixed)
        for j, n in enumerate(self._free):
            v[n] = x[j]
        if self._tie:
            v['K_b'] = v['K_T']
        return v

    def _coefficients(self, z):
        return transfer_coefficients(self._values_at(z), self._kind, self._channels)

    def _structural_jacobian(self, z):
        """d log|c| / dz of the transfer coefficients; effect parameters get unit rows."""
        d = z.size
        n_phys = len(self._free)
        base = np.log(np.abs(np.array(list(self._coefficients(z).values()))))
        rows = np.zeros((base.size + d - n_phys, d))
        for j in range(n_phys):
            h = 1e-6
            zp = z.copy()
            zm = z.copy()
            zp[j] += h
            zm[j] -= h
            cp = np.log(np.abs(np.array(list(self._coefficients(zp).values()))))
            cm = np.log(np.abs(np.array(list(self._coefficients(zm).values()))))
            rows[:base.size, j] = (cp - cm) / (2 * h)
        for j in range(n_phys, d):
            rows[base.size + j - n_phys, j] = 1.0
        return rows

    def _structural(self, z):
        """Generic structural rank, bases and per-parameter verdict near z.

        The rank of the coefficient map is evaluated at z and at three random points
        inside the bounds (fixed seed): a parameter counts as determined only if it is at
        all of them, so an estimate sitting on a special point (B at its lower bound,
        say) does not make a parameter look determined.
        """
        rng = np.random.default_rng(20261122)
        lo, hi = self._z_bounds(z.size)
        points = [z] + [lo + rng.uniform(0.2, 0.8, z.size) * (hi - lo) for _ in range(3)]
        best = None
        determined = np.ones(z.size, dtype=bool)
        for zz in points:
            Jc = self._structural_jacobian(zz)
            _, sc, Vt = np.linalg.svd(Jc, full_matrices=True)
            smax = sc[0] if sc.size and sc[0] > 0 else 1.0
            rank = int(np.sum(sc > NULL_TOL * smax))
            Vn = Vt[rank:].T
            proj = np.linalg.norm(Vn, axis=1) if Vn.size else np.zeros(z.size)
            determined &= proj < DETERMINED_TOL
            if best is None or rank > best[0]:
                best = (rank, Vt[:rank].T, Vn)
        return best[0], best[1], best[2], determined

    def _combinations(self, values, z_best, cov, rank, d):
        """The transfer-function coefficients, with delta-method standard errors."""
        base = self._coefficients(z_best)
        out = []
        for key, val in base.items():
            g = np.zeros(d)
            for j in range(len(self._free)):
                h = 1e-6
                zp = z_best.copy()
                zp[j] += h
                g[j] = (self._coefficients(zp)[key] - val) / h
            std = float(np.sqrt(max(g @ cov @ g, 0.0)))
            out.append({'name': key, 'value': float(val), 'std': std, 'determined': True})
        return out

    def _bootstrap(self, result, z_best, w, n_per, rng):
        """Residual moving-block bootstrap: refit B times from the estimate."""
        y_true = self._y.copy()
        r = y_true - self._simulate(self._from_z(z_best[None, :]))[0]
        y_hat = y_true - r
        block = 50
        samples = []
        for _ in range(int(self.bootstrap)):
            r_star = np.empty_like(r)
            i = 0
            for n in n_per:
                seg = r[i:i + n]
                starts = rng.integers(0, max(n - block, 1), n // block + 1)
                rs = np.concatenate([seg[s:s + block] for s in starts])[:n]
                r_star[i:i + n] = rs
                i += n
            self._y = y_hat + r_star
            sol = self._refine(z_best, w, max_nfev=20)
            samples.append(self._from_z(sol.x))
        self._y = y_true
        samples = np.array(samples)
        names = list(self._bounds.names)
        for n, e in result.parameters.items():
            src = 'K_T' if (self._tie and n == 'K_b') else n
            if e.determined and not e.assumed and src in names:
                col = samples[:, names.index(src)]
                e.ci95 = (float(np.percentile(col, 2.5)), float(np.percentile(col, 97.5)))
        result.refinement['bootstrap'] = int(self.bootstrap)
