"""Matrix exponential of a batch of small matrices (vectorised scaling and squaring).

Why not :func:`scipy.linalg.expm` directly: since SciPy 1.15 it takes a batch by
looping over its matrices in Python (about 75 us per 4x4 matrix), and a fit of a
jittered record discretises thousands of (plant, interval) pairs per evaluation. This
module is the same algorithm (Higham 2005, Pade 13 with scaling and squaring) written
over the whole batch in NumPy; the tests hold it to SciPy's result.
"""

from __future__ import annotations

import numpy as np

_B13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
        1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
        33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0)
_THETA13 = 5.371920351148152
"""Largest 1-norm for which Pade 13 is accurate to double precision (Higham 2005)."""
_MAX_SQUARINGS = 1100
SMALL_BATCH = 8
"""Below this many matrices SciPy's own expm is used (no batch overhead to save)."""


def expm(a: np.ndarray) -> np.ndarray:
    """``exp(a)`` for each matrix of a stack ``a`` (shape ``(..., n, n)``).

    Parameters
    ----------
    a : ndarray, shape (..., n, n)

    Returns
    -------
    ndarray, same shape
        Non-finite matrices give NaN results (never an exception).

    Notes
    -----
    Each matrix is scaled by ``2^-s`` so that its 1-norm is at most theta_13, its
    [13/13] Pade approximant is evaluated with six matrix products and one solve (all
    batched), and the result is squared ``s`` times (only the matrices that need it).
    """
    a = np.asarray(a, dtype=float)
    shape = a.shape
    n = shape[-1]
    flat = a.reshape(-1, n, n)
    if flat.shape[0] < SMALL_BATCH:
        from scipy.linalg import expm as scipy_expm
        finite = np.all(np.isfinite(flat), axis=(1, 2))
        out = np.full_like(flat, np.nan)
        if np.any(finite):
            out[finite] = scipy_expm(flat[finite])
        return out.reshape(shape)
    finite = np.all(np.isfinite(flat), axis=(1, 2))
    x = np.where(finite[:, None, None], flat, 0.0)
    norm = np.max(np.sum(np.abs(x), axis=1), axis=1)
    with np.errstate(divide='ignore'):
        s = np.ceil(np.log2(np.maximum(norm, 1e-300) / _THETA13))
    s = np.clip(np.nan_to_num(s, nan=0.0), 0, _MAX_SQUARINGS).astype(int)
    x = x * np.exp2(-s)[:, None, None]
    eye = np.eye(n)
    x2 = x @ x
    x4 = x2 @ x2
    x6 = x4 @ x2
    b = _B13
    u = x @ (x6 @ (b[13] * x6 + b[11] * x4 + b[9] * x2)
             + b[7] * x6 + b[5] * x4 + b[3] * x2 + b[1] * eye)
    v = (x6 @ (b[12] * x6 + b[10] * x4 + b[8] * x2)
         + b[6] * x6 + b[4] * x4 + b[2] * x2 + b[0] * eye)
    with np.errstate(all='ignore'):
        r = np.linalg.solve(v - u, v + u)
        for k in range(int(s.max(initial=0))):
            m = s > k
            r[m] = r[m] @ r[m]
    r[~finite] = np.nan
    return r.reshape(shape)
