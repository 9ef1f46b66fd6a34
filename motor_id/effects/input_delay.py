"""A transport delay between the logged and the applied input, in samples (a fraction of
one included)."""

import numpy as np

from motor_id.effects.spec import Confusion, EffectParam, EffectSpec, InputMap, Values


def _apply(u: np.ndarray, v: Values) -> np.ndarray:
    """``u`` delayed by ``d = n + f`` samples (``n`` whole, ``0 <= f < 1``) under a
    zero-order hold: over each sample interval the plant sees ``V(k - n - 1)`` for the
    first fraction ``f`` of it and ``V(k - n)`` for the rest, applied as their interval
    mean ``(1 - f) V(k - n) + f V(k - n - 1)``; before the run's first sample its first
    input. A whole ``d`` is the input shifted, bit for bit."""
    d = np.maximum(np.asarray(v['d'], dtype=float), 0.0)
    n = np.floor(d + 1e-9).astype(int)
    f = np.where(d - n > 1e-9, d - n, 0.0)
    N = u.shape[1]
    for p in range(u.shape[0]):
        if n[p] == 0 and f[p] == 0.0:
            continue
        row = u[p].copy()
        shifted = np.concatenate([np.full(min(n[p], N), row[0]), row[:max(N - n[p], 0)]])
        if f[p] > 0.0:
            before = np.concatenate([[row[0]], shifted[:-1]])
            shifted = (1.0 - f[p]) * shifted + f[p] * before
        u[p] = shifted
    return u


SPEC = EffectSpec(
    'input_delay', 'V_eff(t) = V(t - d T) under a zero-order hold: V_eff(k) = '
    '(1 - f) V(k - n) + f V(k - n - 1), d = n + f',
    (EffectParam('d', 'samples', 3, 0, 500, 'one', (1, (1.0, 'max_delay'), 0), (),
                 'integer', role='delay', refined=False, fraction=True),),
    description='transport delay of the input: whole samples on the grid, then a fraction '
    'of one where the simulation-error stage refines it',
    input_map=InputMap(0, _apply),
    confused_with=(
        Confusion('resonance', 'a multisine through the suspected resonance: a delay only '
                  'shifts the phase, a compliant shaft rings'),),
    stage_rule='always')
