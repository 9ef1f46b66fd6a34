"""A dead zone of the driver: nothing passes below V_dz."""

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, ElectricalTerm, InputMap, Values


def _apply(u: np.ndarray, v: Values) -> np.ndarray:
    return np.sign(u) * np.maximum(np.abs(u) - v['V_dz'][:, None], 0.0)


def _columns(t: np.ndarray, u: np.ndarray, i: np.ndarray) -> list:
    u_max = float(np.max(np.abs(u))) or 1.0
    return [(f * u_max, np.sign(u) * np.minimum(np.abs(u), f * u_max))
            for f in (0.02, 0.05, 0.1, 0.2, 0.3, 0.45)]


def _start(value: float | None, coef: float) -> dict[str, float]:
    return {} if value is None else {'V_dz': value}


SPEC = EffectSpec(
    'dead_zone', 'V_eff = 0 if |V| <= V_dz else V - V_dz sgn(V)',
    (EffectParam('V_dz', 'V (input unit)', 0.8, 0.0, 1e3, 'input', (5e-3, 0.6, 14),
                 (0.0, 1.0), role='dead_band'),),
    description='the driver passes nothing below V_dz',
    input_map=InputMap(2, _apply),
    electrical_term=ElectricalTerm(_columns, _start),
    shows_offset=True, named_on_offset=True)
