"""Stribeck friction: a static level falling to the Coulomb level as the speed rises."""

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, Values


def _friction(fr: np.ndarray, v: Values) -> None:
    fr[:, 3] = np.maximum(fr[:, 3], v['T_s'])
    fr[:, 4] = v['v_s']


SPEC = EffectSpec(
    'stribeck_friction', 'dry friction T_c + (T_s - T_c) exp(-(w / v_s)^2); break-away at T_s',
    (EffectParam('T_s', 'N m', 0.08, 0.0, 1e3, 'torque', (0.01, 0.6, 6), (0.0, 2.0),
                 role='static'),
     EffectParam('v_s', 'rad/s', 0.05, 0.0, 1e4, 'speed', (0.003, 0.3, 6), (0.0, 1.0),
                 role='stribeck_speed')),
    description='friction falling from a static level to the Coulomb level as the speed '
    'rises (Stribeck curve)', extends='coulomb_friction',
    friction_term=_friction,
    stage_start=lambda drive, coulomb: {'T_s': 1.2 * coulomb})
