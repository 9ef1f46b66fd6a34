"""An elevator's gravity: a constant load T_g against upward motion (its mechanism)."""

import numpy as np

from motor_id.effects.spec import (
    Confusion,
    EffectParam,
    EffectSpec,
    KernelArg,
    MechanicalTerm,
    PositionTerm,
)


def _columns(position: np.ndarray) -> list[np.ndarray]:
    return [np.ones_like(position)]


def _params(coef: np.ndarray, torque_per_input: float) -> dict[str, float]:
    return {'T_g': float(coef[0]) * torque_per_input}


SPEC = EffectSpec(
    'elevator_gravity', 'tau -= T_g (J dw/dt = K_T i - B w - ... - T_g)',
    (EffectParam('T_g', 'N m', 0.5, -1e4, 1e4, 'torque', (1e-3, 1.0, 12), (-2.0, 2.0),
                 'signed', role='kG'),),
    description="an elevator's gravity: a constant load against upward (positive) motion; "
    'a force [N] on a linear axis',
    kernel_args=(KernelArg('T_G', 'T_g'),),
    mechanical_term=MechanicalTerm('T_g', ' + T_g', np.ones_like),
    excludes=('load_torque', 'asymmetric_friction'),
    confused_with=(
        Confusion('load_torque', 'none needed: an elevator carries its gravity as a constant '
                  'load, so a further constant load is the same term'),
        Confusion('asymmetric_friction', 'a known payload or a load cell: the dry levels up '
                  '(T_c + T_g) and down (T_c + dT_c - T_g) are two numbers for three '
                  'parameters, so the two are never fitted together')),
    mechanism='elevator',
    position_term=PositionTerm(_columns, _params))
