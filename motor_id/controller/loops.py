"""Loop checks: a designed cascade's loops on the full identified model, as polynomials in s.

The loop gains are rational functions built from the model's state-space matrices
(Faddeev-LeVerrier), a sample delay enters as a Pade approximant, and the stability
margins, crossovers and closed-loop bandwidth are found on a log frequency grid refined
by brentq. numpy polynomials only; the tests hold the results to python-control.
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from motor_id.records import Record

# With a sample period T a loop sees about 1.5 T of delay: half a sample of ZOH plus one
# sample of computation.
DELAY_SAMPLES = 1.5

# The checks' sample delay as a 3rd-order Pade approximant (as python-control's pade).
PADE_ORDER = 3

# Crossings are bracketed on a log grid this dense, reaching this many decades beyond the
# loop's slowest and fastest pole or zero, then refined by brentq.
GRID_POINTS_PER_DECADE = 50
GRID_MARGIN_DECADES = 3


def _trim(p: ArrayLike) -> NDArray[np.float64]:
    """Drop a polynomial's leading exact zeros (keeps ``[0.]`` for the zero polynomial)."""
    p = np.atleast_1d(np.asarray(p, dtype=float))
    nz = np.flatnonzero(p)
    return p[nz[0]:] if nz.size else p[-1:]


def pade_delay(delay: float,
               order: int = PADE_ORDER) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pade approximant of a pure delay ``exp(-s delay)`` as a numerator/denominator pair.

    Parameters
    ----------
    delay : float
        The delay [s], >= 0.
    order : int
        Degree of numerator and denominator.

    Returns
    -------
    num, den : ndarray
        Coefficients in s, highest power first; ``den`` is ``sum c_k (s delay)^k`` and
        ``num`` the same with ``-s``, ``c_k = C(n, k) (2n - k)! / (2n)!`` (``n = order``).
    """
    n = order
    c = np.array([math.comb(n, k) * math.factorial(2 * n - k) / math.factorial(2 * n)
                  * delay ** k for k in range(n + 1)])
    sign = (-1.0) ** np.arange(n + 1)
    return _trim((sign * c)[::-1]), _trim(c[::-1])


def _state_transfer_functions(F: np.ndarray,
                              g: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Input -> each state of ``dx/dt = F x + g u``: ``([num_row, ...], den)`` in s.

    Faddeev-LeVerrier: ``adj(sI - F) = sum_k M_k s^(n-k)`` and the characteristic
    polynomial follow from traces, so structural zeros stay exact zeros.
    """
    n = F.shape[0]
    den = np.ones(n + 1)
    m = np.zeros_like(F)
    adj = np.zeros((n, n))  # adj[k - 1] = M_k g, the coefficient of s^(n-k)
    for k in range(1, n + 1):
        m = F @ m + den[k - 1] * np.eye(n)
        adj[k - 1] = m @ g
        den[k] = -np.trace(F @ m) / k
    return [_trim(adj[:, row]) for row in range(n)], den


def loop_transfer_functions(
        values: Mapping[str, float], input_kind: str, gains: Mapping[str, float],
        sample_period: float | None = None,
) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Loop transfer functions of the cascade on the full identified model.

    Parameters
    ----------
    values : dict
        Plant parameters in SI units.
    input_kind : {'voltage', 'torque'}
        The plant kind (see :func:`design_controller`).
    gains : dict
        ``current_kp, current_ki, speed_kp, speed_ki`` as from :func:`controller_constants`.
    sample_period : float, optional
        If given, each loop includes a delay of 1.5 sample periods (3rd-order Pade).

    Returns
    -------
    dict of (ndarray, ndarray)
        ``{name: (num, den)}``, polynomial coefficients in s (highest power first, as
        ``numpy.polyval``) of ``'current'`` (V -> i with the PI, voltage plant only) and
        ``'speed'`` (i_ref or torque command -> w with the PI; for a voltage plant the
        inner current loop is closed around the full two-state model, back-EMF
        included). The loops are negative-feedback loop gains ``L``: closed loop
        ``L / (1 + L)``.
    """
    from motor_id.model import continuous_matrices  # the one model; lazy: cheap import

    d_num, d_den = np.ones(1), np.ones(1)
    if sample_period is not None:
        d_num, d_den = pade_delay(DELAY_SAMPLES * sample_period)
    F, G = continuous_matrices({k: [x] for k, x in values.items()}, input_kind)
    nums, den = _state_transfer_functions(F[0], G[0][:, 0])
    integrator = np.array([1.0, 0.0])
    # speed PI with the delay: (kp s + ki) d_num / (s d_den)
    cs_num = np.polymul([gains['speed_kp'], gains['speed_ki']], d_num)
    cs_den = np.polymul(integrator, d_den)
    if input_kind == 'torque':
        return {'speed': (_trim(np.polymul(cs_num, nums[0])), _trim(np.polymul(cs_den, den)))}
    ci_num = np.polymul([gains['current_kp'], gains['current_ki']], d_num)
    ci_den = np.polymul(integrator, d_den)
    # inner: w / i_ref = P_w C / (1 + C P_i) = N_w N_c / (D_c D + N_c N_i) (D cancels)
    inner_num = np.polymul(nums[0], ci_num)
    inner_den = np.polyadd(np.polymul(ci_den, den), np.polymul(ci_num, nums[1]))
    return {'current': (_trim(np.polymul(ci_num, nums[1])), _trim(np.polymul(ci_den, den))),
            'speed': (_trim(np.polymul(cs_num, inner_num)),
                      _trim(np.polymul(cs_den, inner_den)))}


def _grid(*polys: np.ndarray) -> np.ndarray:
    """Log-spaced frequencies [rad/s] covering every pole and zero by some decades."""
    mags = np.concatenate([np.abs(np.roots(p)) for p in polys if len(p) > 1] + [[]])
    mags = mags[(mags > 0) & np.isfinite(mags)]
    if not mags.size:
        mags = np.array([1.0])
    lo = math.floor(math.log10(mags.min())) - GRID_MARGIN_DECADES
    hi = math.ceil(math.log10(mags.max())) + GRID_MARGIN_DECADES
    return np.logspace(lo, hi, (hi - lo) * GRID_POINTS_PER_DECADE + 1)


def _extend(w: np.ndarray, response: Callable[[np.ndarray], np.ndarray], target: float,
            num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Extend the grid by decades until ``|response|`` has crossed ``target`` at its ends.

    Upwards while it is still above ``target`` (strictly proper: it falls as w grows),
    downwards while it is still below (an integrator: it grows as w falls).
    """
    decades = np.logspace(0, 3, 3 * GRID_POINTS_PER_DECADE + 1)
    for _ in range(10):
        if len(den) <= len(num) or abs(response(w[-1:]))[0] < target:
            break
        w = np.concatenate([w, w[-1] * decades[1:]])
    for _ in range(10):
        if den[-1] != 0 or abs(response(w[:1]))[0] > target:
            break
        w = np.concatenate([w[0] / decades[:0:-1], w])
    return w


def _roots_on_grid(fun: Callable[[np.ndarray], np.ndarray], w: np.ndarray) -> np.ndarray:
    """Every root of ``fun`` between sign changes on the grid ``w``, refined by brentq."""
    from scipy.optimize import brentq  # lazy: a fit has imported it already

    y = fun(w)
    idx = np.flatnonzero(np.sign(y[:-1]) * np.sign(y[1:]) <= 0)
    roots = []
    for i in idx:
        if y[i] == 0:
            roots.append(w[i])
        elif y[i + 1] != 0 and np.isfinite(y[i]) and np.isfinite(y[i + 1]):
            roots.append(brentq(fun, w[i], w[i + 1], xtol=1e-14 * w[i], rtol=1e-13))
    return np.unique(roots)


def _response(num: np.ndarray, den: np.ndarray, w: ArrayLike) -> np.ndarray:
    """``num / den`` at ``s = j w`` (an infinite or undefined value where ``den`` is 0)."""
    s = 1j * np.asarray(w)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.polyval(num, s) / np.polyval(den, s)


@dataclass(frozen=True)
class LoopCheck(Record):
    """A loop's check on the full model (:func:`margins`): None where it has none."""

    phase_margin_deg: float | None = None
    crossover_hz: float | None = None
    gain_margin_db: float | None = None
    closed_loop_stable: bool | None = None
    closed_loop_bandwidth_hz: float | None = None


def margins(num: NDArray[np.float64], den: NDArray[np.float64]) -> LoopCheck:
    """Phase margin [deg], crossover [Hz], gain margin [dB] and closed-loop facts of a loop.

    ``num / den`` is the loop gain L(s). The crossover is where ``|L(jw)| = 1`` (of
    several, the one with the smallest ``|phase margin|``), the gain margin is taken where
    the phase crosses -180 deg (the one closest to 0 dB), as ``control.stability_margins``
    does; the closed loop ``L / (1 + L)`` is stable when every root of ``den + num`` lies in
    the open left half plane, and its bandwidth is the first frequency where its gain
    falls 3 dB below the DC gain.
    """
    def loop(w: ArrayLike) -> np.ndarray:
        return _response(num, den, w)

    w = _extend(_grid(num, den), loop, 1.0, num, den)
    with np.errstate(divide='ignore'):
        wc = _roots_on_grid(lambda x: np.log(np.abs(loop(x))), w)
        w180 = _roots_on_grid(lambda x: loop(x).imag, w)
    w180 = w180[loop(w180).real < 0]
    pm = np.remainder(np.angle(loop(wc), deg=True), 360.0) - 180.0
    with np.errstate(divide='ignore'):
        gm = 1.0 / np.abs(loop(w180))
    gm = gm[np.isfinite(gm)]  # |L| = 0 on the negative real axis: no finite gain margin
    pm_deg = crossover = gm_db = bandwidth = None
    if wc.size:
        j = np.argmin(np.abs(pm))
        pm_deg, crossover = float(pm[j]), float(wc[j] / (2 * np.pi))
    if gm.size:
        gm_db = float(20 * np.log10(gm[np.argmin(np.abs(np.log(gm)))]))
    closed_den = np.polyadd(den, num)
    stable = bool(np.all(np.roots(closed_den).real < 0))
    if stable:
        bw = _bandwidth(num, closed_den)
        bandwidth = None if bw is None else float(bw / (2 * np.pi))
    return LoopCheck(phase_margin_deg=pm_deg, crossover_hz=crossover, gain_margin_db=gm_db,
                     closed_loop_stable=stable, closed_loop_bandwidth_hz=bandwidth)


def _bandwidth(num: np.ndarray, den: np.ndarray, drop_db: float = -3.0) -> float | None:
    """First frequency [rad/s] where ``|num/den (jw)|`` falls ``drop_db`` below DC; or None."""
    dc = abs(np.polyval(num, 0.0) / np.polyval(den, 0.0))
    if not np.isfinite(dc) or dc == 0:
        return None
    level = float(dc * 10 ** (drop_db / 20))

    def excess(w: ArrayLike) -> np.ndarray:
        gap: np.ndarray = np.abs(_response(num, den, w)) - level
        return gap

    w = _extend(_grid(num, den), lambda x: excess(x) + level, level, num, den)
    if excess(w[:1])[0] < 0:  # below the level already at the lowest frequency
        return None
    drops = _roots_on_grid(excess, w)
    return float(drops[0]) if drops.size else None
