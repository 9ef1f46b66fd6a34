"""A constant load torque (or force offset)."""

import numpy as np

from motor_id.effects.spec import (
    Confusion,
    EffectParam,
    EffectSpec,
    KernelArg,
    MechanicalTerm,
)

SPEC = EffectSpec(
    'load_torque', 'tau -= T_L',
    (EffectParam('T_L', 'N m', 0.05, -1e3, 1e3, 'torque', (1e-4, 0.5, 12), (-2.0, 2.0),
                 'signed', role='load'),),
    description='constant load torque (or force offset)',
    kernel_args=(KernelArg('T_L', 'T_L'),),
    mechanical_term=MechanicalTerm('T_L', ' + T_L', np.ones_like),
    confused_with=(
        Confusion('brush_drop', 'reverse the motor: a brush drop changes sign with the '
                  'current, a load torque keeps its sign'),
        Confusion('dead_zone', 'reverse the input: a dead zone is symmetric, a constant '
                  'load is not')))
