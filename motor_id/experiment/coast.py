"""Where the joint goes if it is commanded 0 now: an on-line model of its acceleration and
the coast it predicts (the guard ends a test while that coast stays inside the travel).

The model is linear least squares on the samples so far, in integral form (the speed
change over a few samples against the integrals of the regressors, which averages the
speed noise instead of differentiating it)::

    dw/dt = a_u u + a_w w + a_s s(w) [+ a_g]               (simple [elevator])
    dw/dt = a_u u + a_w w + a_s s(w) + a_c cos x + a_n sin x   (arm)

with ``s(w) = tanh(w / w_eps)`` a smoothed sign (Coulomb friction). It is only a safety
model: the identification proper is the analysis of the recording.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

WINDOW = 5
"""Samples per speed difference of the integral form."""
MIN_ROWS = 40
"""Rows before the model may be used."""
MAX_RELATIVE_STD = 0.3
"""The damping (and an arm's gravity) must be known to this relative error."""
HOLD_MAX = 0.5
"""An elevator's tests are centred on the command that holds it (:func:`test_centre`),
at most this fraction of the command limit."""
FALLBACK_COAST = 1.0
"""Without a usable model the joint is taken to coast at its speed this long [s]."""


@dataclass(frozen=True)
class CoastModel:
    """A fitted acceleration model (coefficients of :func:`regressors`)."""

    mechanism: str
    theta: tuple[float, ...]
    w_eps: float

    def acceleration(self, u: float, x: float, w: float) -> float:
        """dw/dt [rad/s^2, or m/s^2] at command ``u``, position ``x``, speed ``w``."""
        th = self.theta
        return (th[0] * u + th[1] * w + th[2] * math.tanh(w / self.w_eps)
                + self.load(x))

    def load(self, x: float) -> float:
        """The acceleration of gravity alone at position ``x`` (0 without gravity)."""
        th = self.theta
        if self.mechanism == 'elevator':
            return th[3]
        if self.mechanism == 'arm':
            return th[3] * math.cos(x) + th[4] * math.sin(x)
        return 0.0

    def hold(self) -> float:
        """The command that balances an elevator's gravity (0 for other mechanisms)."""
        if self.mechanism != 'elevator' or self.theta[0] == 0:
            return 0.0
        return -self.theta[3] / self.theta[0]

    def friction(self) -> float:
        """The Coulomb friction's deceleration |a_s| (0 if it came out driving)."""
        return max(0.0, -self.theta[2])

    def time_constant(self) -> float:
        """-1 / a_w [s]: how fast a coast slows down."""
        return -1.0 / self.theta[1]


def n_regressors(mechanism: str) -> int:
    """Coefficients of the model of ``mechanism``."""
    return {'simple': 3, 'elevator': 4, 'arm': 5}[mechanism]


def regressors(mechanism: str, u: float, x: float, w: float, w_eps: float) -> np.ndarray:
    """The row ``[u, w, s(w), (1 | cos x, sin x)]`` of the model."""
    row = [u, w, math.tanh(w / w_eps)]
    if mechanism == 'elevator':
        row.append(1.0)
    elif mechanism == 'arm':
        row += [math.cos(x), math.sin(x)]
    return np.array(row)


class OnlineModel:
    """Least squares of the acceleration model, updated one sample at a time.

    Parameters
    ----------
    mechanism : {'simple', 'arm', 'elevator'}
    w_eps : float
        Speed scale of the smoothed sign (a few speed-noise levels); a window whose
        speeds all stay within it is left out (the joint at rest, held by friction or
        by a stop, which the model does not have).
    """

    def __init__(self, mechanism: str, w_eps: float) -> None:
        self.mechanism = mechanism
        self.w_eps = max(float(w_eps), 1e-9)
        n = n_regressors(mechanism)
        self._A = np.zeros((n, n))
        self._b = np.zeros(n)
        self._yy = 0.0
        self.rows = 0
        self._hist: list[tuple[float, float, np.ndarray]] = []   # (t, w, phi dt)

    def add(self, t: float, x: float, w: float, u_applied: float) -> None:
        """Add the sample at time ``t`` [s]: position ``x``, speed ``w``, and the command
        in effect from it to the next sample."""
        phi = regressors(self.mechanism, u_applied, x, w, self.w_eps)
        hist = self._hist
        if hist:
            t_prev, w_prev, phi_prev = hist[-1]
            dt = t - t_prev
            if dt <= 0:
                return
            hist[-1] = (t_prev, w_prev, phi_prev * dt)
        hist.append((t, w, phi))
        if len(hist) > WINDOW and max(abs(h[1]) for h in hist) <= self.w_eps:
            hist.pop(0)   # at rest: held by friction or a stop, which the model has not
        elif len(hist) > WINDOW:
            t0, w0, _ = hist[0]
            integral = sum(p for _, _, p in hist[:-1])
            y = w - w0
            self._A += np.outer(integral, integral)
            self._b += integral * y
            self._yy += y * y
            self.rows += 1
            hist.pop(0)

    def fitted(self) -> CoastModel | None:
        """The model if the data determine it well enough to predict a coast, else None.

        Usable means: :data:`MIN_ROWS` rows, a damping coefficient ``a_w < 0`` known to
        :data:`MAX_RELATIVE_STD`, and for an arm the gravity amplitude as well.
        """
        if self.rows < MIN_ROWS:
            return None
        A, b = self._A, self._b
        scale = np.sqrt(np.maximum(np.diag(A), 1e-300))
        An = A / np.outer(scale, scale) + 1e-9 * np.eye(len(b))
        try:
            inv = np.linalg.inv(An)
        except np.linalg.LinAlgError:
            return None
        theta = inv @ (b / scale) / scale
        dof = max(self.rows - len(b), 1)
        s2 = max(self._yy - float(theta @ b), 0.0) / dof
        std = np.sqrt(np.maximum(np.diag(inv), 0.0) * s2) / scale
        if not theta[1] < 0 or std[1] > MAX_RELATIVE_STD * abs(theta[1]):
            return None
        if self.mechanism == 'arm':
            g = math.hypot(theta[3], theta[4])
            if g == 0 or math.hypot(std[3], std[4]) > MAX_RELATIVE_STD * g:
                return None
        return CoastModel(self.mechanism, tuple(float(v) for v in theta), self.w_eps)


def test_centre(model: CoastModel | None, max_command: float) -> float:
    """The command an elevator's test is centred on: the one that holds it against
    gravity, from the on-line model (0 before the model is known, and for other
    mechanisms). Centred so, a test down is a slow descent as a test up is a slow climb,
    and their speeds alike tell friction from gravity (a test down from 0 is a fall)."""
    if model is None:
        return 0.0
    return max(-HOLD_MAX * max_command, min(HOLD_MAX * max_command, model.hold()))


@dataclass(frozen=True)
class Coast:
    """The positions a coast visits: ``[low, high]``, and whether a model predicted it."""

    low: float
    high: float
    modelled: bool


def predict_coast(model: CoastModel | None, x: float, w: float, u: float, latency: float,
                  support: float | None = None, horizon: float = 6.0) -> Coast:
    """The range of positions the joint visits if it is commanded 0 now.

    The command ``u`` acts for ``latency`` more seconds, then 0 until the joint stops
    (its speed crosses zero with friction or gravity unable to move it on), for an arm
    until its second turn (the swing back through the hanging position and up the other
    side), or ``horizon`` seconds.

    Parameters
    ----------
    model : CoastModel or None
        None: the joint coasts at speed ``w`` for ``latency`` + :data:`FALLBACK_COAST`.
    x, w : float
        Position and speed now.
    u : float
        The command in effect now.
    latency : float
        [s]
    support : float, optional
        A position the joint cannot fall below (an elevator resting on its bottom): the
        coast ends there.
    horizon : float
        [s]

    Returns
    -------
    Coast
    """
    if model is None:
        end = x + w * (latency + FALLBACK_COAST)
        if support is not None:
            end = max(end, min(support, x))
        return Coast(min(x, end), max(x, end), False)
    tau = model.time_constant()
    h = min(0.01, max(tau / 8.0, 1e-4))
    horizon = min(horizon, max(2.0, 8.0 * tau) + latency)
    lo = hi = x
    t = 0.0
    turns = 0
    max_turns = 2 if model.mechanism == 'arm' else 1
    a_w = model.theta[1]
    n_lat = math.ceil(latency / h) if latency > 0 else 0
    h_lat = latency / n_lat if n_lat else h
    steps = 0
    while t < horizon:
        cmd, step = (u, h_lat) if steps < n_lat else (0.0, h)
        steps += 1
        # exact over the step for the damping, the rest of the acceleration held
        c = model.acceleration(cmd, x, w) - a_w * w
        w_inf = -c / a_w
        decay = math.exp(a_w * step)
        w_new = w_inf + (w - w_inf) * decay
        x += (w - w_inf) * (decay - 1.0) / a_w + w_inf * step
        t += step
        if support is not None and x < support:
            x = support
            lo = min(lo, x)
            break
        lo, hi = min(lo, x), max(hi, x)
        if steps > n_lat:
            turned = w != 0 and w_new * w <= 0
            turns += turned
            if turns >= max_turns or ((turned or abs(w_new) < 0.5 * model.w_eps)
                                      and abs(model.load(x)) <= model.friction()):
                break
        w = w_new
    return Coast(lo, hi, True)
