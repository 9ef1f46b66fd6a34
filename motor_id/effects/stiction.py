"""Stiction: a break-away level above the Coulomb level at rest."""

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, Values


def _friction(fr: np.ndarray, v: Values) -> None:
    fr[:, 3] = np.maximum(fr[:, 3], v['T_s'])


SPEC = EffectSpec(
    'stiction', 'stuck (w = 0) while |drive| <= T_s; moving: Coulomb T_c',
    (EffectParam('T_s', 'N m', 0.08, 0.0, 1e3, 'torque', (0.01, 0.6, 8), (0.0, 2.0),
                 role='static'),),
    description='break-away torque above the Coulomb level at zero speed',
    extends='coulomb_friction',
    friction_term=_friction,
    excludes=('stribeck_friction',),
    stage_start=lambda drive, coulomb: {'T_s': 1.2 * coulomb})
