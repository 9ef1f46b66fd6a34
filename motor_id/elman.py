"""The linear Elman network: its weights, and the free n-order net of the order selection.

The paper's network is ``X(k) = W_xc X(k-1) + W_xu U(k-1)``, ``Y(k) = W_yx X(k)`` with
the context weights tied to the discrete motor model: ``W_xc = A``, ``W_xu = b``,
``W_yx = [1 0]`` (:func:`motor_id.model.discretize`, which the fitter simulates). Under
the paper's Euler discretisation ``b = [0, T/L_m]``, which is where its fixed
``w11_xu = 0`` comes from; under exact zero-order hold ``b[0]`` is small but not zero,
and it too is a function of the physical parameters, not a free weight.

The *free* net has n hidden units and unconstrained weights. Any minimal linear Elman
net is, up to a change of basis of its hidden state, equal to its observable canonical
form, so the free net is trained in that form (2n numbers; the other n^2 weights are
exactly the basis freedom the data cannot see) and exported as full weight matrices.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from motor_id.errors import ConfigError, DataError
from motor_id.ga import Bounds, GeneticAlgorithm
from motor_id.records import Record


@dataclass
class ElmanWeights:
    """The weights of a linear Elman net (one hidden layer of n context units)."""

    W_xc: np.ndarray
    W_xu: np.ndarray
    W_yx: np.ndarray

    def forward(self, u: ArrayLike, x0: ArrayLike | None = None) -> NDArray[np.float64]:
        """Run the net on an input sequence; returns the output sequence Y."""
        u = np.asarray(u, dtype=float)
        n = self.W_xc.shape[0]
        x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).copy()
        y = np.empty(u.size)
        for k in range(u.size):
            y[k] = self.W_yx @ x
            x = self.W_xc @ x + self.W_xu * u[k]
        return y

    def to_dict(self) -> dict[str, list[float] | list[list[float]]]:
        """JSON-ready: the weight matrices as nested lists."""
        return {'W_xc': self.W_xc.tolist(), 'W_xu': self.W_xu.tolist(),
                'W_yx': self.W_yx.tolist()}


def canonical_weights(a: Sequence[float] | NDArray[np.float64], b: ArrayLike) -> ElmanWeights:
    """Observable canonical weights for ``y(k) = sum a_i y(k-i) + sum b_i u(k-i)``."""
    n = len(a)
    W_xc = np.zeros((n, n))
    W_xc[:, 0] = a
    W_xc[:-1, 1:] = np.eye(n - 1)
    return ElmanWeights(W_xc, np.asarray(b, dtype=float), np.eye(n)[0])


def _simulate_free(theta: ArrayLike, u: np.ndarray, n: int, y0: float) -> np.ndarray:
    """Outputs of free nets; theta (P, 2n) = [a_1..a_n, b_1..b_n]."""
    from scipy.signal import lfilter  # lazy: scipy.signal costs ~0.5 s to import

    theta = np.atleast_2d(theta)
    out = np.empty((theta.shape[0], u.size))
    for p, th in enumerate(theta):
        a, b = th[:n], th[n:]
        den = np.concatenate([[1.0], -a])
        num = np.concatenate([[0.0], b])
        with np.errstate(all='ignore'):
            out[p] = lfilter(num, den, u) + y0
    return out


def _arx(u: np.ndarray, y: np.ndarray, n: int) -> np.ndarray:
    """Equation-error (ARX) start for the output-error fit."""
    N = y.size
    rows = [y[n - i - 1:N - i - 1] for i in range(n)] + [u[n - i - 1:N - i - 1]
                                                         for i in range(n)]
    Phi = np.column_stack(rows)
    theta, *_ = np.linalg.lstsq(Phi, y[n:], rcond=None)
    return theta


@dataclass(frozen=True)
class OrderEvidence(Record):
    """Evidence for one net order (``to_dict()``: these keys in this order)."""

    order: int
    n_params: int
    train_rmse: float
    validation_rmse: float
    aic: float
    bic: float
    weights: dict[str, list[float] | list[list[float]]] = field(default_factory=dict)


class FreeElmanOrderSelection:
    """Find the smallest free linear Elman net that explains the data.

    Each order n = 1..``max_order`` is trained by the same GA (bounds around the
    equation-error estimate) and refined by least squares on the first
    ``1 - validation`` share of the record; its output error is then scored on the
    held-out rest. The chosen order is the smallest whose training BIC is within 10 of
    the lowest and whose held-out error is within ``tolerance`` of the best.

    Parameters
    ----------
    max_order : int
    validation : float
        Share of samples held out at the end.
    tolerance : float
        Relative validation-error slack that favours the smaller order.
    population, generations, random_state
        GA settings.
    """

    def __init__(self, max_order: int = 4, validation: float = 0.3, tolerance: float = 0.05,
                 population: int = 20, generations: int = 160,
                 random_state: int | np.random.Generator | None = None) -> None:
        if not 1 <= max_order <= 8:
            raise ConfigError(f'max_order must be in 1..8, got {max_order}')
        if not 0.05 <= validation <= 0.8:
            raise ConfigError(f'validation share must be in [0.05, 0.8], got {validation}')
        self.max_order = max_order
        self.validation = validation
        self.tolerance = tolerance
        self.population = population
        self.generations = generations
        self.random_state = random_state

    def fit(self, u: ArrayLike, y: ArrayLike) -> 'FreeElmanOrderSelection':
        """Train every order on (u, y) and choose one; returns self.

        Sets ``order_`` (int), ``evidence_`` (list of OrderEvidence), ``weights_``
        (ElmanWeights of the chosen order) and ``seconds_``.
        """
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        if u.shape != y.shape or u.ndim != 1:
            raise DataError('u and y must be 1-D arrays of the same length')
        if u.size < 50:
            raise DataError(f'too few samples for order selection: {u.size} (need 50)')
        from scipy.optimize import least_squares  # lazy: only the order selection needs it

        t0 = time.perf_counter()
        rng = np.random.default_rng(self.random_state)
        n_tr = int(round(u.size * (1 - self.validation)))
        y0 = y[0]
        scale = np.std(y[:n_tr]) or 1.0
        evidence = []
        fitted = {}
        for n in range(1, self.max_order + 1):
            start = _arx(u[:n_tr], y[:n_tr] - y0, n)
            half = np.maximum(np.abs(start), 1e-3)
            bounds = Bounds(tuple(f'a{i + 1}' for i in range(n)) +
                            tuple(f'b{i + 1}' for i in range(n)),
                            tuple(start - 2 * half), tuple(start + 2 * half),
                            (False,) * (2 * n))

            def cost(X: np.ndarray, n: int = n) -> np.ndarray:
                with np.errstate(all='ignore'):
                    e = _simulate_free(X, u[:n_tr], n, y0) - y[:n_tr]
                    c = np.mean(e * e, axis=1) / scale ** 2
                return np.where(np.isfinite(c), c, np.inf)

            ga = GeneticAlgorithm(bounds, self.population, self.generations, x0=start,
                                  random_state=rng).run(cost)

            def resid(th: np.ndarray, n: int = n) -> np.ndarray:
                r = (_simulate_free(th, u[:n_tr], n, y0)[0] - y[:n_tr]) / scale
                return np.where(np.isfinite(r), r, 1e6)

            sol = least_squares(resid, ga.best_, method='lm', max_nfev=200 * 2 * n)
            th = sol.x
            y_hat = _simulate_free(th, u, n, y0)[0]
            e_tr = y_hat[:n_tr] - y[:n_tr]
            e_va = y_hat[n_tr:] - y[n_tr:]
            k = 2 * n
            mse = float(np.mean(e_tr ** 2))
            aic = n_tr * np.log(mse) + 2 * k
            bic = n_tr * np.log(mse) + k * np.log(n_tr)
            w = canonical_weights(th[:n], th[n:])
            fitted[n] = w
            evidence.append(OrderEvidence(n, k, float(np.sqrt(mse)),
                                          float(np.sqrt(np.mean(e_va ** 2))),
                                          float(aic), float(bic), w.to_dict()))
        best_bic = min(e.bic for e in evidence)
        best_val = min(e.validation_rmse for e in evidence)
        # the smallest order that both the information criterion (within 10, "strong
        # evidence" on Kass-Raftery's scale) and the held-out error accept
        order = next(e.order for e in evidence
                     if (e.bic <= best_bic + 10.0
                         and e.validation_rmse <= best_val * (1 + self.tolerance))
                     or e.bic == best_bic)
        self.order_ = order
        self.evidence_ = evidence
        self.weights_ = fitted[order]
        self.seconds_ = time.perf_counter() - t0
        return self

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary of the selection."""
        return {'order': self.order_, 'evidence': [e.to_dict() for e in self.evidence_],
                'rule': 'smallest order with training BIC within 10 of the lowest and '
                        f'held-out RMS error within {self.tolerance:.0%} of the best',
                'seconds': self.seconds_}
