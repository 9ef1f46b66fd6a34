"""A transport delay of whole samples between the logged and the applied input."""

import numpy as np

from motor_id.effects.spec import Confusion, EffectParam, EffectSpec, InputMap, Values


def _apply(u: np.ndarray, v: Values) -> np.ndarray:
    d = np.rint(v['d']).astype(int)
    for p in range(u.shape[0]):
        if d[p] > 0:
            u[p, d[p]:] = u[p, :-d[p]].copy()
            u[p, :d[p]] = u[p, 0]
    return u


SPEC = EffectSpec(
    'input_delay', 'V_eff(k) = V(k - d)',
    (EffectParam('d', 'samples', 3, 0, 500, 'one', (1, (1.0, 'max_delay'), 0), (),
                 'integer', role='delay', refined=False),),
    description='transport delay of whole samples',
    input_map=InputMap(0, _apply),
    confused_with=(
        Confusion('resonance', 'a multisine through the suspected resonance: a delay only '
                  'shifts the phase, a compliant shaft rings'),),
    stage_rule='always')
