"""Saturation: the amplifier clips the input at +-V_max."""

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, InputMap, Values


def _apply(u: np.ndarray, v: Values) -> np.ndarray:
    vmax = v['V_max'][:, None]
    return np.clip(u, -vmax, vmax)


SPEC = EffectSpec(
    'voltage_saturation', 'V_eff = clip(V, -V_max, V_max)',
    (EffectParam('V_max', 'V (input unit)', 6.0, 0.0, 1e4, 'input', (0.15, 0.98, 16),
                 (0.01, 2.0), 'linear'),),
    description='the amplifier clips the input',
    input_map=InputMap(3, _apply))
