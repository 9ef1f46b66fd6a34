"""Asymmetric friction: other dry and viscous levels when the motion is negative."""

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, Values


def _friction(fr: np.ndarray, v: Values) -> None:
    fr[:, 1] = np.maximum(fr[:, 0] + v['dT_c'], 0.0)
    fr[:, 2] = v['dB']


SPEC = EffectSpec(
    'asymmetric_friction', 'Coulomb level T_c + dT_c and viscous B + dB when the motion is '
    'negative (w < 0); T_c and B when positive',
    (EffectParam('dT_c', 'N m', 0.0, -1e3, 1e3, 'torque', (1e-3, 0.2, 4), (-2.0, 2.0),
                 'signed', role='kS_extra_negative'),
     EffectParam('dB', 'N m s/rad', 0.0, -1e5, 1e5, 'torque/speed', (1e-3, 0.3, 4),
                 (-2.0, 2.0), 'signed', role='kV_extra_negative')),
    description='direction-dependent dry and viscous friction (Fc+/Fc-, Fv+/Fv-)',
    extends='coulomb_friction',
    friction_term=_friction,
    stage_start=lambda drive, coulomb: {'dT_c': 0.0, 'dB': 0.0})
