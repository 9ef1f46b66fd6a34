"""The numba kernels of :mod:`motor_id.simulate`: the loops that step a batch of parameter
sets through one input record, and their compilation on first use.

The loops are plain Python here; :func:`compiled` hands out their numba form
(``cache=True``: the machine code is kept on disk, see :func:`motor_id.simulate.warm_up`).
Only :mod:`motor_id.simulate` calls them, with C-contiguous arrays of fixed dtypes, so each
kernel has one compiled signature.
"""

from __future__ import annotations

from collections.abc import Callable
import threading
from typing import Any

import numpy as np

_HEAP_PRIME_BYTES = 16 << 20
"""Size of the block :func:`_prime_allocator` allocates and frees once (16 MiB)."""


def _kernel(A, Bd, idx, dts, u, x0, voltage, fr, T_L, k_q, V_b, k_h, tau_th, tau_s,  # noqa: C901
            T_G, G_cos, G_off, R0, Hm, Hq, ipos, theta_m):
    P, N = u.shape
    n = A.shape[2]
    X = np.zeros((P, N, n))
    Y = np.zeros((P, N))
    xn = np.zeros(n)
    for p in range(P):
        x = x0[p].copy()
        dR = 0.0
        y = x[0]
        for k in range(N):
            for j in range(n):
                X[p, k, j] = x[j]
            Y[p, k] = y
            if k == N - 1:
                break
            c = idx[k]
            dt = dts[c]
            w = x[0]
            v = u[p, k]
            si = 0.0   # the direction of the current that carries the brush drop
            if voltage and V_b[p] != 0.0:
                if x[1] > 0.0:
                    si = 1.0
                elif x[1] < 0.0:
                    si = -1.0
                v -= V_b[p] * si
            tau = -T_L[p] - T_G[p] - k_q[p] * w * abs(w)
            if G_cos[p] != 0.0:
                # an arm's gravity held over the interval at its midpoint (its mean to
                # second order): between the measured positions (exogenous, like the
                # input), else half the interval on at the integrated speed. At the
                # interval's start it lagged the motion by half an interval, a term in
                # w sin(theta) that a heavy arm at a 20 ms loop took for 1.6 % more kV
                if theta_m.shape[0] > 0:
                    th = 0.5 * (theta_m[k] + theta_m[k + 1])
                else:
                    th = x[ipos] + 0.5 * w * dt if ipos >= 0 else 0.0
                tau -= G_cos[p] * np.cos(th + G_off[p])
            if w < 0.0:
                tau -= fr[p, 2] * w   # extra viscous friction in the negative direction
            heat = 0.0
            if voltage and k_h[p] != 0.0:
                # the extra resistance drops dR i(t): held at dR times the interval's mean
                # current, which itself depends on the drop (solved for it); the mean of
                # i^2 over the interval is exact for the held input (Van Loan integrals)
                s_i = Hm[p, c, n] * v + Hm[p, c, n + 1] * tau
                for j in range(n):
                    s_i += Hm[p, c, j] * x[j]
                v -= dR * s_i / (dt + Hm[p, c, n] * dR)
                for j in range(n + 2):
                    zj = x[j] if j < n else (v if j == n else tau)
                    for m in range(n + 2):
                        zm = x[m] if m < n else (v if m == n else tau)
                        heat += zj * Hq[p, c, j, m] * zm
                heat /= dt
            for j in range(n):
                acc = Bd[p, c, j, 0] * v + Bd[p, c, j, 1] * tau
                for m in range(n):
                    acc += A[p, c, j, m] * x[m]
                xn[j] = acc
            if voltage and V_b[p] != 0.0:
                # the brushes conduct only while the drive beats the drop (dry friction
                # at the current level): from zero current the drop of the drive's
                # direction is applied if the current still flows with it; a current
                # that reverses within the interval goes on only if it beats the other
                # direction's drop too. Else it ends at zero: the winding sees the
                # voltage that leaves it there, the drop takes the rest.
                dv = 0.0
                s = 0.0
                if si == 0.0 and xn[1] != 0.0:
                    s = 1.0 if xn[1] > 0.0 else -1.0
                    dv = -V_b[p] * s
                elif xn[1] * si < 0.0:
                    s = -si
                    dv = 2.0 * V_b[p] * si
                if s != 0.0:
                    g = Bd[p, c, 1, 0]
                    held = (xn[1] + g * dv) * s <= 0.0 and g != 0.0
                    if held:
                        dv = -xn[1] / g
                    for j in range(n):
                        xn[j] += Bd[p, c, j, 0] * dv
                    if held:
                        xn[1] = 0.0
            if heat != 0.0:
                # copper loss i^2 R: the heating rate grows with the resistance itself
                dR += dt * (k_h[p] * heat * (1.0 + dR / R0[p]) - dR / tau_th[p])
            if fr[p, 0] > 0.0 or fr[p, 1] > 0.0 or fr[p, 3] > 0.0:
                if w != 0.0:
                    s = 1.0 if w > 0.0 else -1.0
                    # the Coulomb level of this direction, raised towards the static
                    # level near zero speed (Stribeck)
                    tc = fr[p, 0] if s > 0.0 else fr[p, 1]
                    if fr[p, 3] > tc and fr[p, 4] > 0.0:
                        z = w / fr[p, 4]
                        tc += (fr[p, 3] - tc) * np.exp(-z * z)
                    for j in range(n):
                        xn[j] -= Bd[p, c, j, 1] * tc * s
                    if xn[0] * s < 0.0:  # it stops within the interval; a drive that
                        # beats the other direction's friction carries it on (which then
                        # opposes -s)
                        to = max(fr[p, 1] if s > 0.0 else fr[p, 0], fr[p, 3])
                        back = xn[0] + Bd[p, c, 0, 1] * (tc + to) * s
                        if back * s < 0.0:
                            for j in range(n):
                                xn[j] += Bd[p, c, j, 1] * (tc + to) * s
                        else:
                            xn[0] = 0.0
                            if ipos >= 0:   # it stopped part-way: half the free travel
                                xn[ipos] = x[ipos] + 0.5 * (xn[ipos] - x[ipos])
                elif xn[0] != 0.0:
                    s = 1.0 if xn[0] > 0.0 else -1.0
                    # break-away: the static level of the drive's direction
                    tc = max(fr[p, 0] if s > 0.0 else fr[p, 1], fr[p, 3])
                    for j in range(n):
                        xn[j] -= Bd[p, c, j, 1] * tc * s
                    if xn[0] * s <= 0.0:
                        xn[0] = 0.0
                        if ipos >= 0:
                            xn[ipos] = x[ipos]   # held at rest
            for j in range(n):
                x[j] = xn[j]
            if tau_s[p] > 0.0:
                # the sensor filters the continuous speed, taken as linear between the
                # samples (first-order hold): exact for a ramp, trapezoid for tau_s >> dt
                a = np.exp(-dt / tau_s[p])
                b1 = 1.0 - tau_s[p] * (1.0 - a) / dt
                y = a * y + (1.0 - a - b1) * w + b1 * x[0]
            else:
                y = x[0]
    return X, Y


def _linear_kernel(A, Bd, idx, u, x0):
    """Fast path without effects: the first two states, shape (2, P, N) (state first)."""
    P, N = u.shape
    n = A.shape[2]
    out = np.zeros((2, P, N))
    for p in range(P):
        x = x0[p].copy()
        xn = np.zeros(n)
        for k in range(N):
            out[0, p, k] = x[0]
            if n > 1:
                out[1, p, k] = x[1]
            if k == N - 1:
                break
            c = idx[k]
            v = u[p, k]
            for j in range(n):
                acc = Bd[p, c, j, 0] * v
                for m in range(n):
                    acc += A[p, c, j, m] * x[m]
                xn[j] = acc
            for j in range(n):
                x[j] = xn[j]
    return out


def _linear2_regular_kernel(A, Bd, u, x0):
    """Fast path for the two-state plant on a regular grid (the GA's case); (2, P, N)."""
    P, N = u.shape
    out = np.empty((2, P, N))
    for p in range(P):
        a00 = A[p, 0, 0, 0]
        a01 = A[p, 0, 0, 1]
        a10 = A[p, 0, 1, 0]
        a11 = A[p, 0, 1, 1]
        b0 = Bd[p, 0, 0, 0]
        b1 = Bd[p, 0, 1, 0]
        w = x0[p, 0]
        i = x0[p, 1]
        for k in range(N):
            out[0, p, k] = w
            out[1, p, k] = i
            v = u[p, k]
            w, i = a00 * w + a01 * i + b0 * v, a10 * w + a11 * i + b1 * v
    return out


def _linear2_kernel(A, Bd, idx, u, x0):
    """Fast path for the two-state plant on an irregular grid (a jittered log): each
    interval's matrices by its index ``idx``; (2, P, N)."""
    P, N = u.shape
    out = np.empty((2, P, N))
    for p in range(P):
        w = x0[p, 0]
        i = x0[p, 1]
        for k in range(N):
            out[0, p, k] = w
            out[1, p, k] = i
            if k == N - 1:
                break
            c = idx[k]
            v = u[p, k]
            w, i = (A[p, c, 0, 0] * w + A[p, c, 0, 1] * i + Bd[p, c, 0, 0] * v,
                    A[p, c, 1, 0] * w + A[p, c, 1, 1] * i + Bd[p, c, 1, 0] * v)
    return out


KERNELS = (_kernel, _linear_kernel, _linear2_regular_kernel, _linear2_kernel)
"""The loops numba compiles (plain Python here; see :func:`motor_id.simulate.warm_up`)."""

_COMPILED: dict[str, Callable[..., Any]] = {}
_COMPILE_LOCK = threading.Lock()


def _prime_allocator() -> None:
    """Allocate and free one large block once, so that malloc keeps big arrays around.

    glibc serves blocks above its mmap threshold (128 KiB at start) with fresh pages and
    trims its heap when more than twice that is free. A GA generation on 4,000 samples
    allocates and frees a few MiB, so until the threshold has risen every generation
    page-faults its arrays in again: 97,000 minor faults and +0.17 s of CPU (doubling
    the GA's time) in the first fit of a process. Freeing one mmap()ed block raises the
    threshold to its size (mallopt(3), "dynamic mmap threshold"); on other allocators
    this is an allocation of untouched memory and does nothing.
    """
    np.empty(_HEAP_PRIME_BYTES // 8)


def compiled(func: Callable[..., Any]) -> Any:
    """The numba-compiled form of a kernel in :data:`KERNELS`, created on first use.

    numba is imported here, not with this module: it costs 0.2-0.4 s, and only a
    simulation needs it. The machine code comes from numba's on-disk cache when one
    matches (see :func:`motor_id.simulate.warm_up`).
    """
    jitted = _COMPILED.get(func.__name__)
    if jitted is None:
        with _COMPILE_LOCK:
            jitted = _COMPILED.get(func.__name__)
            if jitted is None:
                import numba

                _prime_allocator()
                jitted = numba.njit(cache=True, nogil=True)(func)
                _COMPILED[func.__name__] = jitted
    return jitted


def loaded(func: Callable[..., Any]) -> Any | None:
    """The compiled form of a kernel in :data:`KERNELS` if this process has created it."""
    return _COMPILED.get(func.__name__)
