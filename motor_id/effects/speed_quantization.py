"""An encoder's speed: a count difference (the mean over the period) on a grid."""

import numpy as np

from motor_id.effects.signals import interval_mean, on_grid
from motor_id.effects.spec import EffectParam, EffectSpec, OutputMap, Values


def _apply(y: np.ndarray, v: Values) -> np.ndarray:
    y = np.where(v['counted'][:, None] > 0.5, interval_mean(y), y)
    return on_grid(y, v['q'][:, None])


SPEC = EffectSpec(
    'speed_quantization', 'y = q round(w_m / q); w_m = the mean of w over (t[k-1], t[k]] '
    'if counted else w(t[k])',
    (EffectParam('q', 'rad/s per count', 0.3, 0.0, 1e3, 'speed', role='grid',
                 refined=False),
     EffectParam('counted', '-', 1.0, 0.0, 1.0, 'one', role='counted')),
    description='encoder counts per sample period: the speed sits on a grid; a count '
    'difference is the mean speed over the sample period (counted = 1), a quantised speed '
    'sensor reads it at the sample (counted = 0)',
    category='measurement', channel='speed',
    output_map=OutputMap(_apply))
