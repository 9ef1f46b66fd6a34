"""Shared pieces of the benchmarks: test data, the Identifier's objective, tables, timing."""

from contextlib import contextmanager, nullcontext
import os
import time

import numpy as np

from motor_id.excitation import paper_steps
from motor_id.identify import Identifier
from motor_id.model import PAPER_MOTOR
from motor_id.recording import Recording
from motor_id.simulate import simulate_batch

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
"""The repository root (for child processes' PYTHONPATH)."""


class Skip(Exception):  # noqa: N818 - a section's "cannot run here", not an error
    """Raised by a section that cannot run here; the message says why."""


PAPER_PERIOD = 40.0
"""Length of the paper's Eq. 14 experiment [s]; longer records repeat it."""

PAPER_SETUP = {'R_m': PAPER_MOTOR.R_m, 'tie': False,
               'fixed': {'J': PAPER_MOTOR.J, 'R_m': PAPER_MOTOR.R_m}}
"""Identifier settings for the paper's motor: it has K_T != K_b, so no K_T = K_b tie;
R_m and J are given (explicit assumptions); K_T, K_b, B, L_m are fitted."""


def paper_recording(n=4000, dt=0.01, params=PAPER_MOTOR, noise=0.005, seed=0):
    """The paper's experiment: Eq. 14 steps, speed and current with white noise.

    Parameters
    ----------
    n : int
        Number of samples.
    dt : float
        Sample period [s]; records longer than 40 s repeat the Eq. 14 steps.
    params : motor_id.model.MotorParams
        The true motor.
    noise : float
        Standard deviation of the additive white Gaussian noise on each channel, as a
        fraction of that channel's noise-free standard deviation.
    seed : int
        Seed of the noise (``np.random.default_rng``).

    Returns
    -------
    Recording
        With ``meta['truth']`` and ``meta['noise_std']`` (absolute, per channel).
    """
    t = np.arange(n) * dt
    u = paper_steps(np.mod(t, PAPER_PERIOD))
    out = simulate_batch(params.to_dict(), t, u)
    rng = np.random.default_rng(seed)
    speed, current = out['speed'][0], out['current'][0]
    s_speed = noise * float(np.std(speed))
    s_current = noise * float(np.std(current))
    meta = {'truth': params.to_dict(), 'noise': noise,
            'noise_std': {'speed': s_speed, 'current': s_current}, 'seed': seed}
    return Recording(t, u, speed + s_speed * rng.standard_normal(n),
                     current + s_current * rng.standard_normal(n), 'voltage', meta)


class CountingIdentifier(Identifier):
    """An :class:`Identifier` with the number of parameter sets it simulated.

    The count is the public ``problem_.evaluations`` (GA, refinement, uncertainty).
    """

    @property
    def evaluations(self):
        """Parameter sets simulated so far (0 before ``fit``)."""
        problem = getattr(self, 'problem_', None)
        return 0 if problem is None else problem.evaluations


class Objective:
    """The Identifier's normalised output-error cost on one recording, for any optimiser.

    The Identifier is prepared by a warm-start fit (no GA) so that its data, channel
    weights (1/std of each channel) and initial state are exactly what ``fit`` uses;
    afterwards only its public problem (``Identifier.problem_``: ``cost``, ``residuals``,
    ``bounds``) is used. Every simulated parameter set
    is counted in :attr:`evaluations`.

    Parameters
    ----------
    rec : Recording
    start : dict
        Any parameter set inside the bounds (used only for the preparation).
    **identifier_kwargs
        Passed to :class:`Identifier` (``R_m``, ``tie``, ``fixed``, ...).
    """

    def __init__(self, rec, start, **identifier_kwargs):
        self.rec = rec
        self.kwargs = dict(identifier_kwargs)
        idf = CountingIdentifier(**self.kwargs).warm_start(start).fit(rec)
        self.identifier = idf
        self.problem = idf.problem_
        self.bounds = self.problem.bounds
        self.names = list(self.bounds.names)
        self.reset()

    @property
    def evaluations(self):
        """Model evaluations since the last :meth:`reset`."""
        return self.identifier.evaluations - self._base

    def reset(self):
        """Zero the evaluation counter."""
        self._base = self.identifier.evaluations

    @property
    def dim(self):
        """Number of free parameters."""
        return self.bounds.dim

    def cost(self, X):
        """Cost of parameter vectors ``X`` (P, d) in physical units -> (P,)."""
        return self.problem.cost(np.atleast_2d(X))

    def unit_cost(self, G):
        """Cost of unit-cube genes ``G`` (P, d), mapped by :class:`motor_id.ga.Bounds`."""
        return self.cost(self.bounds.decode(np.atleast_2d(G)))

    def residuals(self, x):
        """Weighted residual vector at one parameter vector (physical units).

        ``sum(r**2) / r.size`` equals :meth:`cost`.
        """
        return self.problem.residuals(x)

    def polish(self, x):
        """The project's standard least-squares refinement from ``x`` (a warm-start fit).

        Returns
        -------
        x : ndarray
            The refined free parameters.
        seconds : float
        evaluations : int
        """
        start = dict(zip(self.names, np.asarray(x, dtype=float), strict=True))
        t0 = time.perf_counter()
        idf = CountingIdentifier(**self.kwargs).warm_start(start).fit(self.rec)
        seconds = time.perf_counter() - t0
        values = idf.result_.values()
        return np.array([values[n] for n in self.names]), seconds, idf.evaluations

    def truth_vector(self, truth):
        """The true free parameters, in the order of :attr:`names`."""
        return np.array([truth[n] for n in self.names], dtype=float)


def blas_limit(threads):
    """Context limiting BLAS threads (threadpoolctl), or a no-op for ``None``."""
    if threads is None:
        return nullcontext()
    from threadpoolctl import threadpool_limits
    return threadpool_limits(int(threads))


@contextmanager
def stopwatch(out, key='seconds'):
    """Store the wall time of the ``with`` block in ``out[key]``."""
    t0 = time.perf_counter()
    try:
        yield out
    finally:
        out[key] = time.perf_counter() - t0


def rel_errors(x, truth):
    """Relative errors ``x / truth - 1``."""
    return np.asarray(x, dtype=float) / np.asarray(truth, dtype=float) - 1.0


def fmt(value, spec):
    """Format a table cell; None and NaN print as '-'."""
    if value is None:
        return '-'
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return 'yes' if value else 'no'
    if isinstance(value, float) and not np.isfinite(value):
        return '-' if np.isnan(value) else str(value)
    if spec == '%':
        return f'{100 * value:.0f} %'
    return format(value, spec)


def render_table(columns, rows, markdown=False):
    """Render rows (dicts) as an aligned text table or a markdown table.

    Parameters
    ----------
    columns : list of (key, header, format spec)
    rows : list of dict
    markdown : bool
    """
    head = [h for _, h, _ in columns]
    body = [[fmt(r.get(k), f) for k, _, f in columns] for r in rows]
    if markdown:
        head = [h.replace('|', '\\|') for h in head]
        body = [[c.replace('|', '\\|') for c in row] for row in body]
        lines = ['| ' + ' | '.join(head) + ' |',
                 '|' + '|'.join('---' if i == 0 else '---:' for i in range(len(head))) + '|']
        lines += ['| ' + ' | '.join(row) + ' |' for row in body]
        return '\n'.join(lines)
    widths = [max(len(h), *(len(row[i]) for row in body)) if body else len(h)
              for i, h in enumerate(head)]
    out = ['  '.join(h.ljust(w) if i == 0 else h.rjust(w)
                     for i, (h, w) in enumerate(zip(head, widths, strict=True)))]
    out.append('  '.join('-' * w for w in widths))
    for row in body:
        out.append('  '.join(c.ljust(w) if i == 0 else c.rjust(w)
                             for i, (c, w) in enumerate(zip(row, widths, strict=False))))
    return '\n'.join(out)


def target(name, value, threshold, passed, unit=''):
    """One pass/fail target record."""
    return {'name': name, 'value': None if value is None else float(value),
            'threshold': threshold, 'unit': unit,
            'pass': None if passed is None else bool(passed)}
