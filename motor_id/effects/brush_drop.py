"""A constant voltage drop across the brushes, with the sign of the current."""

import numpy as np

from motor_id.effects.spec import (
    Confusion,
    EffectParam,
    EffectSpec,
    ElectricalTerm,
    KernelArg,
)


def _columns(t: np.ndarray, u: np.ndarray, i: np.ndarray) -> list:
    return [(None, np.sign(i))]


def _start(value: float | None, coef: float) -> dict[str, float]:
    return {'V_b': coef} if coef > 0 else {}


SPEC = EffectSpec(
    'brush_drop', 'V -= V_b sgn(i)',
    (EffectParam('V_b', 'V', 0.6, 0.0, 100.0, 'input', (1e-3, 0.3, 14), (0.0, 1.0),
                 role='kS'),), kinds=('voltage',),
    description='constant voltage drop across the brushes',
    kernel_args=(KernelArg('V_b', 'V_b'),),
    electrical_term=ElectricalTerm(_columns, _start),
    confused_with=(
        Confusion('dead_zone', 'braking steps in which the current reverses while the input '
                  'keeps its sign: a brush drop follows the current sign, a dead zone the '
                  'input sign'),),
    shows_offset=True)
