"""A current ADC's resolution: the current on a grid."""

import numpy as np

from motor_id.effects.signals import on_grid
from motor_id.effects.spec import EffectParam, EffectSpec, OutputMap, Values


def _apply(y: np.ndarray, v: Values) -> np.ndarray:
    return on_grid(y, v['q_i'][:, None])


SPEC = EffectSpec(
    'current_quantization', 'y_i = q_i round(i / q_i)',
    (EffectParam('q_i', 'A per count', 0.01, 0.0, 1e3, 'current', role='grid'),),
    kinds=('voltage',),
    description='current ADC resolution: the current sits on a grid',
    category='measurement', channel='current',
    output_map=OutputMap(_apply))
