"""A drive's enable latency: nothing applied for d samples after the input leaves zero."""

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, InputMap, Values


def _apply(u: np.ndarray, v: Values) -> np.ndarray:
    d = np.rint(v['d']).astype(int)
    for p in range(u.shape[0]):
        if d[p] > 0:   # the d samples from each sample where the input leaves zero
            row = u[p]
            for k in np.flatnonzero((row[1:] != 0.0) & (row[:-1] == 0.0)) + 1:
                row[k:k + d[p]] = 0.0
    return u


SPEC = EffectSpec(
    'start_latency', 'V_eff = 0 for d samples after the input leaves zero; V_eff = V '
    'otherwise',
    (EffectParam('d', 'samples', 10, 0, 500, 'one', (1, (1.0, 'max_delay'), 0), (),
                 'integer'),),
    description="the drive's enable latency: it applies nothing for a while after the "
    'command leaves zero (a motor controller arming on its first non-zero frame), and '
    'follows at once afterwards', simulation_only=True,
    input_map=InputMap(1, _apply),
    stage_rule='input_leaves_zero')
