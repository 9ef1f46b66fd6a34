"""The event-located RK4 integrator of the independent simulator (numpy and numba only).

The equations and their events are described in :mod:`motor_id.testing.independent_physics`,
which builds the parameter vector and calls :func:`advance` and :func:`integrate_held`; this
module holds only the compiled kernel. Like that module it shares no code with ``motor_id``.
"""

import math
from typing import Any

import numpy as np

try:  # numba is a dependency of the project; the plain-Python path is only a fallback
    import numba
    _jit = numba.njit(cache=False, nogil=True)
except ImportError:  # pragma: no cover
    def _jit(f: Any) -> Any:
        return f

# indices of the state vector and of the parameter vector of the integrator kernel
W, I, TH, DT, WL, PHI, Y = range(7)  # noqa: E741 (I: the current)
NX = 7
(P_JM, P_JL, P_KS, P_CS, P_RES, P_B, P_K, P_R0, P_L, P_ALPHA, P_CTH, P_RTH,
 P_TS, P_TC, P_TL, P_KQ, P_VB, P_TAUS, P_TG, P_GOFF, P_GARM, P_LO, P_HI, P_TORQUE,
 P_TAUI) = range(25)
NP = 25
_MAX_EVENTS = 8
_N_KINDS = 5
"""Events: 0 w crosses zero, 1 i crosses zero, 2 the held shaft breaks away, 3 the blocked
brushes start to conduct, 4 the joint reaches a hard stop."""


def parameters() -> np.ndarray:
    """A parameter vector with no effect: zeros, no gravity, the stops at -+infinity."""
    p = np.zeros(NP)
    p[P_LO] = -math.inf
    p[P_HI] = math.inf
    return p


@_jit
def _gravity(theta: float, p: np.ndarray) -> float:
    """Gravity load [N m or N]: T_g (elevator) or T_g cos(theta + offset) (arm)."""
    if p[P_GARM] > 0.0:
        return p[P_TG] * math.cos(theta + p[P_GOFF])
    return p[P_TG]


@_jit
def _deriv(x: np.ndarray, v: float, w_stuck: bool, sw: float, i_stuck: bool, si: float,
           p: np.ndarray, dx: np.ndarray) -> None:
    w = x[W]
    i = x[I]
    R = p[P_R0] * (1.0 + p[P_ALPHA] * x[DT])
    if p[P_TORQUE] > 0.0:  # a current-controlled drive: i follows v / K (v a torque)
        dx[I] = (v / p[P_K] - i) / p[P_TAUI]
    elif i_stuck:
        dx[I] = 0.0
    else:
        dx[I] = (v - R * i - p[P_K] * w - p[P_VB] * si) / p[P_L]
    if p[P_RES] > 0.0:
        wl = x[WL]
        shaft = p[P_KS] * x[PHI] + p[P_CS] * (w - wl)
        dx[WL] = (shaft - p[P_TL] - p[P_KQ] * wl * abs(wl)) / p[P_JL]
        dx[PHI] = w - wl
        load = shaft
    else:
        dx[WL] = 0.0
        dx[PHI] = 0.0
        load = p[P_TL] + p[P_KQ] * w * abs(w) + _gravity(x[TH], p)
    if w_stuck:
        dx[W] = 0.0
    else:
        dx[W] = (p[P_K] * i - p[P_B] * w - p[P_TC] * sw - load) / p[P_JM]
    dx[TH] = w
    if p[P_CTH] > 0.0:
        dx[DT] = (i * i * R - x[DT] / p[P_RTH]) / p[P_CTH]
    else:
        dx[DT] = 0.0
    if p[P_TAUS] > 0.0:
        dx[Y] = (w - x[Y]) / p[P_TAUS]
    else:
        dx[Y] = 0.0


@_jit
def _rk4(x: np.ndarray, v: float, h: float, w_stuck: bool, sw: float, i_stuck: bool,
         si: float, p: np.ndarray, out: np.ndarray, k1: np.ndarray, k2: np.ndarray,
         k3: np.ndarray, k4: np.ndarray, xt: np.ndarray) -> None:
    _deriv(x, v, w_stuck, sw, i_stuck, si, p, k1)
    for j in range(NX):
        xt[j] = x[j] + 0.5 * h * k1[j]
    _deriv(xt, v, w_stuck, sw, i_stuck, si, p, k2)
    for j in range(NX):
        xt[j] = x[j] + 0.5 * h * k2[j]
    _deriv(xt, v, w_stuck, sw, i_stuck, si, p, k3)
    for j in range(NX):
        xt[j] = x[j] + h * k3[j]
    _deriv(xt, v, w_stuck, sw, i_stuck, si, p, k4)
    for j in range(NX):
        out[j] = x[j] + h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    if p[P_TAUS] <= 0.0:
        out[Y] = out[W]


@_jit
def _sign(a: float) -> float:
    return 1.0 if a > 0.0 else (-1.0 if a < 0.0 else 0.0)


@_jit
def _shaft_drive(x: np.ndarray, p: np.ndarray) -> float:
    """Torque that would accelerate the motor at w = 0, friction excluded [N m]."""
    if p[P_RES] > 0.0:
        load = p[P_KS] * x[PHI] - p[P_CS] * x[WL]
    else:
        load = p[P_TL] + _gravity(x[TH], p)
    return p[P_K] * x[I] - load


@_jit
def _hold_margin(x: np.ndarray, p: np.ndarray) -> float:
    """How far the shaft at w = 0 is from moving (>= 0: held) [N m].

    Friction holds it while |drive| <= T_s; at a hard stop the stop also takes any drive
    into it, so it leaves the stop only once the drive away from it exceeds T_s.
    """
    drive = _shaft_drive(x, p)
    if x[TH] >= p[P_HI]:
        return drive + p[P_TS]
    if x[TH] <= p[P_LO]:
        return p[P_TS] - drive
    return p[P_TS] - abs(drive)


@_jit
def _stop_gap(x: np.ndarray, p: np.ndarray) -> float:
    """Distance to the nearer hard stop (negative beyond it) [rad or m]."""
    return min(p[P_HI] - x[TH], x[TH] - p[P_LO])


@_jit
def _event_value(kind: int, x: np.ndarray, v: float, sw: float, si: float,
                 p: np.ndarray) -> float:
    """Positive before the event, negative after (kinds: see ``_N_KINDS``)."""
    if kind == 0:
        return x[W] * sw
    if kind == 1:
        return x[I] * si
    if kind == 2:
        return _hold_margin(x, p)
    if kind == 3:
        return p[P_VB] - abs(v - p[P_K] * x[W])
    return _stop_gap(x, p)


@_jit
def _modes(x: np.ndarray, v: float, p: np.ndarray, force_w: float,
           force_i: float) -> tuple[bool, float, bool, float]:
    """Modes of the next piece: (w stuck, sign of w's motion, i stuck, sign of i)."""
    w_stuck = False
    sw = _sign(x[W])
    at_stop = x[TH] >= p[P_HI] or x[TH] <= p[P_LO]
    if (p[P_TS] > 0.0 or p[P_TC] > 0.0 or at_stop) and x[W] == 0.0:
        if force_w != 0.0:
            sw = force_w
        elif _hold_margin(x, p) >= 0.0:
            w_stuck = True
            sw = 0.0
        else:
            sw = _sign(_shaft_drive(x, p))
    i_stuck = False
    si = _sign(x[I])
    if p[P_VB] > 0.0 and x[I] == 0.0:
        drive_v = v - p[P_K] * x[W]
        if force_i != 0.0:
            si = force_i
        elif abs(drive_v) <= p[P_VB]:
            i_stuck = True
            si = 0.0
        else:
            si = _sign(drive_v)
    return w_stuck, sw, i_stuck, si


@_jit
def _armed(kind: int, w_stuck: bool, i_stuck: bool, p: np.ndarray) -> bool:
    if kind == 0:
        return (p[P_TS] > 0.0 or p[P_TC] > 0.0) and not w_stuck
    if kind == 1:
        return p[P_VB] > 0.0 and not i_stuck
    if kind == 2:
        return w_stuck
    if kind == 3:
        return i_stuck
    return (p[P_HI] < math.inf or p[P_LO] > -math.inf) and not w_stuck


@_jit
def _first_event(x: np.ndarray, xn: np.ndarray, v: float, w_stuck: bool, sw: float,
                 i_stuck: bool, si: float, p: np.ndarray) -> tuple[float, int]:
    """The earliest event between x and xn: (linear estimate of its fraction, kind or -1)."""
    frac = 2.0
    kind = -1
    for kk in range(_N_KINDS):
        if not _armed(kk, w_stuck, i_stuck, p):
            continue
        g1 = _event_value(kk, xn, v, sw, si, p)
        if g1 < 0.0:
            g0 = _event_value(kk, x, v, sw, si, p)
            f = g0 / (g0 - g1) if g0 > 0.0 else 0.0
            if f < frac:
                frac = f
                kind = kk
    return frac, kind


@_jit
def _land(kind: int, x: np.ndarray, p: np.ndarray) -> None:
    """Put the state exactly on the event just reached (a zero crossing, a hard stop)."""
    if kind == 0 or kind == 4:
        x[W] = 0.0
        if p[P_TAUS] <= 0.0:
            x[Y] = 0.0
        if kind == 4:
            x[TH] = p[P_HI] if p[P_HI] - x[TH] < x[TH] - p[P_LO] else p[P_LO]
    elif kind == 1:
        x[I] = 0.0


@_jit
def _substep(x: np.ndarray, v: float, h: float, p: np.ndarray, xn: np.ndarray,
             k1: np.ndarray, k2: np.ndarray, k3: np.ndarray, k4: np.ndarray,
             xt: np.ndarray) -> None:
    """Advance x by h in place, locating the events of friction, brushes and stops in it.

    Each piece runs with fixed modes up to the earliest event (regula falsi on the event
    function, re-integrating from the piece's start), then the modes are decided anew.
    """
    remaining = h
    force_w = 0.0   # direction of a break-away located at the end of the previous piece
    force_i = 0.0
    for event in range(_MAX_EVENTS + 1):
        w_stuck, sw, i_stuck, si = _modes(x, v, p, force_w, force_i)
        force_w = 0.0
        force_i = 0.0
        _rk4(x, v, remaining, w_stuck, sw, i_stuck, si, p, xn, k1, k2, k3, k4, xt)
        frac, kind = _first_event(x, xn, v, w_stuck, sw, i_stuck, si, p)
        if kind < 0 or event == _MAX_EVENTS:
            for j in range(NX):
                x[j] = xn[j]
            if kind == 0 or kind == 1 or kind == 4:
                _land(kind, x, p)
            return
        f_lo, g_lo = 0.0, _event_value(kind, x, v, sw, si, p)
        f_hi, g_hi = 1.0, _event_value(kind, xn, v, sw, si, p)
        f = frac
        for _ in range(3):
            _rk4(x, v, f * remaining, w_stuck, sw, i_stuck, si, p, xn, k1, k2, k3, k4, xt)
            g = _event_value(kind, xn, v, sw, si, p)
            if g > 0.0:
                f_lo, g_lo = f, g
            else:
                f_hi, g_hi = f, g
            if g_lo - g_hi <= 0.0:
                break
            f = f_lo + (f_hi - f_lo) * g_lo / (g_lo - g_hi)
        _rk4(x, v, f * remaining, w_stuck, sw, i_stuck, si, p, xn, k1, k2, k3, k4, xt)
        for j in range(NX):
            x[j] = xn[j]
        if kind == 2:
            force_w = _sign(_shaft_drive(x, p))
        elif kind == 3:
            force_i = _sign(v - p[P_K] * x[W])
        else:
            _land(kind, x, p)
        remaining -= f * remaining
        if remaining <= 0.0:
            return


@_jit
def advance(x: np.ndarray, v: float, duration: float, n_sub: int, p: np.ndarray) -> None:
    """Advance the state x in place by ``duration`` [s] under the held input v, in n_sub
    RK4 sub-steps."""
    xn = np.empty(NX)
    k1 = np.empty(NX)
    k2 = np.empty(NX)
    k3 = np.empty(NX)
    k4 = np.empty(NX)
    xt = np.empty(NX)
    h = duration / n_sub
    for _ in range(n_sub):
        _substep(x, v, h, p, xn, k1, k2, k3, k4, xt)


@_jit
def integrate_held(v: np.ndarray, dt: float, n_sub: int, p: np.ndarray,
                   x0: np.ndarray) -> np.ndarray:
    """States at the sample instants under the zero-order-held inputs v (one per sample)."""
    n = v.shape[0]
    out = np.empty((n, NX))
    x = x0.copy()
    xn = np.empty(NX)
    k1 = np.empty(NX)
    k2 = np.empty(NX)
    k3 = np.empty(NX)
    k4 = np.empty(NX)
    xt = np.empty(NX)
    h = dt / n_sub
    for k in range(n):
        for j in range(NX):
            out[k, j] = x[j]
        for _ in range(n_sub):
            _substep(x, v[k], h, p, xn, k1, k2, k3, k4, xt)
    return out
