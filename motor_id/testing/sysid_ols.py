"""WPILib SysId's own feedforward fit, re-implemented from its method for comparisons.

SysId (the 2022-2023 application that writes ``sysid_data.json``) fits
``V = kS sgn(v) + kV v + kA a`` by ordinary least squares after its own data
preparation; this module follows that method step by step (written from reading WPILib's
sysid sources, ``AnalysisManager``, ``FilteringUtils`` and ``FeedforwardAnalysis``; no
code copied) so that a benchmark can set the project's model beside the fit a SysId user
gets:

1. Each test's rows become prepared points ``(t, V, position, v, dt)`` with
   ``dt = t[k+1] - t[k]`` (the last row has none and is dropped) and the voltage's sign
   set to the velocity's (``copysign(V, v)``).
2. The motion threshold is the smallest noise floor of the quasistatic velocities: the
   RMS of ``v[k-4]`` about the causal 9-point moving mean at ``k`` (zeros before the
   start). Quasistatic points with ``V = 0`` or ``|v|`` below it are dropped.
3. Accelerations are central differences ``(v[k+1] - v[k-1]) / 2h`` with ``h`` the mean
   ``dt`` (within 0-0.5 s) of the test's kept points; the first point uses ``v[0]`` for
   ``v[-1]`` and the last gets 0.
4. A step test starts at its largest ``|a|``; it is cut at a duration found on the first
   step test: 1 s past its last ``|a|`` above the acceleration noise floor, at most the
   longest raw step test.
5. Points with ``a == 0`` exactly are dropped (frame-held readings make many).
6. OLS of ``a = alpha v + beta V + gamma sgn(v)`` on the four tests together:
   ``kS = -gamma / beta``, ``kV = -alpha / beta``, ``kA = 1 / beta``.

SysId before 2022 fitted the discrete form ``v[k+1] = a v[k] + b V[k] + c sgn(v[k])``
instead (:func:`fit_discrete`). For ``dv/dt = (V - kS sgn v - kV v) / kA`` held over a
step ``T`` (sgn v constant), the exact solution is ``a = exp(-kV T / kA)``,
``b = (1 - a) / kV``, ``c = -kS b``; hence ``kS = -c / b``, ``kV = (1 - a) / b`` and
``kA = -kV T / ln a = (a - 1) T / (b ln a)``, with ``T`` the mean sample interval.

SysId's plots simulate the fitted model per test from its first measured velocity with
the exact discretisation of each interval (:func:`simulate_feedforward`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import math
from typing import Any, TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from motor_id.recording import Recording

__all__ = ['fit_acceleration', 'fit_discrete', 'noise_floor', 'prepare', 'Prepared',
           'simulate_feedforward', 'SysIdFit']

NOISE_WINDOW = 9
"""SysId's ``kNoiseMeanWindow``."""
TESTS = ('slow-forward', 'slow-backward', 'fast-forward', 'fast-backward')


@dataclass
class Prepared:
    """The points of each test SysId fits, and the settings its preparation found."""

    tests: dict[str, dict[str, np.ndarray]]
    motion_threshold: float
    step_test_duration: float
    max_step_time: float

    def rows(self) -> dict[str, int]:
        """Points kept per test."""
        return {k: int(v['t'].size) for k, v in self.tests.items()}


@dataclass(frozen=True)
class PrepSummary:
    """How the tests were prepared: SysId's thresholds and the points kept per test."""

    motion_threshold: float
    step_test_duration: float
    max_step_time: float
    rows: dict[str, int]


@dataclass
class SysIdFit:
    """Feedforward constants in the recording's SI units and the OLS statistics."""

    method: str
    kS: float  # noqa: N815 - kS, kV, kA: WPILib's symbols
    kV: float  # noqa: N815
    kA: float  # noqa: N815
    r_squared: float
    rmse: float
    samples: int
    dt_mean: float
    prepared: PrepSummary | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)

    def simulate(self, time: np.ndarray, voltage: np.ndarray, v0: float) -> np.ndarray:
        """This model's velocity over one test (:func:`simulate_feedforward`)."""
        return simulate_feedforward(self.kS, self.kV, self.kA, time, voltage, v0)


def noise_floor(x: np.ndarray, window: int = NOISE_WINDOW) -> float:
    """SysId's noise floor: RMS of ``x[k - w//2]`` about the causal ``w``-point mean."""
    x = np.asarray(x, dtype=float)
    step = window // 2
    if x.size <= step:
        return math.nan
    mean = np.convolve(x, np.ones(window) / window)[:x.size]
    dev = x[:x.size - step] - mean[step:]
    return float(np.sqrt(np.sum(dev ** 2) / (x.size - step)))


def _points(t: np.ndarray, u: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray]:
    """Prepared points of one test: all rows but the last, with ``dt`` and next speed."""
    return {'t': t[:-1], 'V': np.copysign(u[:-1], v[:-1]), 'v': v[:-1],
            'dt': np.diff(t), 'v_next': v[1:]}


def _mean_dt(dt: np.ndarray) -> float:
    ok = dt[(dt > 0) & (dt < 0.5)]
    return float(np.mean(ok)) if ok.size else math.nan


def _acceleration(p: dict[str, np.ndarray]) -> None:
    """Central differences of the speed over the mean interval, in place (``'a'``)."""
    v = p['v']
    h = _mean_dt(p['dt'])
    a = np.zeros(v.size)
    if v.size >= 3:
        prev = np.concatenate([[v[0]], v[:-2]])
        a[:-1] = (v[1:] - prev) / (2.0 * h)
    p['a'] = a


def _keep(p: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    return {k: x[mask] for k, x in p.items()}


def _trim_step(p: dict[str, np.ndarray], duration: float | None,
               max_step_time: float) -> tuple[dict[str, np.ndarray], float]:
    """Start at the largest |a|, cut after the step-test duration (found when None)."""
    start = int(np.argmax(np.abs(p['a'])))
    p = {k: x[start:] for k, x in p.items()}
    if duration is None:
        floor = noise_floor(p['a'])
        above = np.flatnonzero(np.abs(p['a']) > floor)
        if above.size:
            duration = min(float(p['t'][above[-1]] - p['t'][0]) + 1.0, max_step_time)
        else:
            duration = max_step_time
    return _keep(p, p['t'] - p['t'][0] <= duration), duration


def prepare(rec: Recording) -> Prepared:
    """SysId's preparation of the four tests of a recording from a SysId log.

    Parameters
    ----------
    rec : Recording
        From :func:`motor_id.data.sysid.load_sysid` or
        :func:`motor_id.data.wpilog.load_wpilog` (runs named in ``meta['segment_names']``:
        ``slow-*``/``fast-*`` or ``quasistatic-*``/``dynamic-*``).

    Returns
    -------
    Prepared
    """
    names = rec.meta.get('segment_names') or list(TESTS[:len(rec.segment_ranges)])
    raw = {}
    for name, (a, b) in zip(names, rec.segment_ranges, strict=True):
        raw[name] = _points(rec.time[a:b], rec.input[a:b], rec.speed[a:b])
    slow = [n for n in raw if n.startswith(('slow', 'quasistatic'))]
    fast = [n for n in raw if n.startswith(('fast', 'dynamic'))]
    threshold = min((noise_floor(raw[n]['v']) for n in slow), default=0.0)
    max_step = max((float(raw[n]['t'][-1] - raw[n]['t'][0]) for n in fast), default=0.0)
    duration: float | None = None
    tests = {}
    for name, p in raw.items():
        if name in slow:
            p = _keep(p, (np.abs(p['V']) > 0) & (np.abs(p['v']) >= threshold))
        _acceleration(p)
        if name in fast and p['t'].size:
            p, duration = _trim_step(p, duration, max_step)
        tests[name] = _keep(p, p['a'] != 0.0)
    return Prepared(tests=tests, motion_threshold=threshold,
                    step_test_duration=math.nan if duration is None else duration,
                    max_step_time=max_step)


def _stack(prep: Prepared, target: str) -> tuple[np.ndarray, np.ndarray, float]:
    pts = [p for p in prep.tests.values() if p['t'].size]
    v = np.concatenate([p['v'] for p in pts])
    X = np.column_stack([v, np.concatenate([p['V'] for p in pts]), np.copysign(1.0, v)])
    y = np.concatenate([p[target] for p in pts])
    return X, y, _mean_dt(np.concatenate([p['dt'] for p in pts]))


def _ols(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float, float]:
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ beta
    sst = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(res @ res) / sst if sst > 0 else math.nan
    return beta, r2, float(np.sqrt(np.mean(res ** 2)))


def fit_acceleration(prep: Prepared) -> SysIdFit:
    """SysId 2022-2023: OLS of ``a = alpha v + beta V + gamma sgn(v)``."""
    X, y, dt = _stack(prep, 'a')
    (alpha, beta, gamma), r2, rmse = _ols(X, y)
    return SysIdFit(method='SysId 2022-2023 (acceleration OLS)', kS=-gamma / beta,
                    kV=-alpha / beta, kA=1.0 / beta, r_squared=r2, rmse=rmse,
                    samples=int(y.size), dt_mean=dt, prepared=_summary(prep))


def fit_discrete(prep: Prepared) -> SysIdFit:
    """SysId 2021: OLS of ``v[k+1] = a v[k] + b V[k] + c sgn(v[k])`` (module notes)."""
    X, y, dt = _stack(prep, 'v_next')
    (a, b, c), r2, rmse = _ols(X, y)
    kV = (1.0 - a) / b
    kA = (a - 1.0) * dt / (b * math.log(a)) if 0 < a < 1 else math.nan
    return SysIdFit(method='SysId 2021 (discrete OLS)', kS=-c / b, kV=kV, kA=kA,
                    r_squared=r2, rmse=rmse, samples=int(y.size), dt_mean=dt,
                    prepared=_summary(prep))


def _summary(prep: Prepared) -> PrepSummary:
    return PrepSummary(prep.motion_threshold, prep.step_test_duration, prep.max_step_time,
                       prep.rows())


def simulate_feedforward(kS: float, kV: float, kA: float, time: np.ndarray,
                         voltage: np.ndarray, v0: float) -> np.ndarray:
    """Velocity of ``kA dv/dt = V - kS sgn(v) - kV v`` over one test, as SysId plots it.

    Each voltage is held to the next sample; each interval is discretised exactly with
    the sign of the velocity at its start (``sgn(0) = 0``).

    Returns
    -------
    ndarray
        NaN throughout when ``kV`` or ``kA`` is not positive.
    """
    t = np.asarray(time, dtype=float)
    u = np.asarray(voltage, dtype=float)
    out = np.full(t.size, math.nan)
    if not (kV > 0 and kA > 0) or t.size == 0:
        return out
    decay = np.exp(-kV / kA * np.diff(t))
    v = float(v0)
    out[0] = v
    for k in range(t.size - 1):
        v = decay[k] * v + (1.0 - decay[k]) * (u[k] - kS * float(np.sign(v))) / kV
        out[k + 1] = v
    return out
