"""A fan or pump load that grows with the square of the speed."""

import numpy as np

from motor_id.effects.spec import (
    Confusion,
    EffectParam,
    EffectSpec,
    KernelArg,
    MechanicalTerm,
)


def _column(w: np.ndarray) -> np.ndarray:
    return w * np.abs(w)


SPEC = EffectSpec(
    'quadratic_load', 'tau -= k_q w |w|',
    (EffectParam('k_q', 'N m s^2/rad^2', 2e-4, 0.0, 1e3, 'torque/speed^2', (1e-4, 1.0, 16),
                 (0.0, 2.0)),),
    description='fan or pump load growing with the square of speed',
    kernel_args=(KernelArg('k_q', 'k_q'),),
    mechanical_term=MechanicalTerm('k_q', ' + k_q w|w|', _column),
    confused_with=(
        Confusion('voltage_saturation',
                  'a staircase of input levels below and above the suspected limit: a '
                  'quadratic load bends the steady-state map smoothly, saturation cuts it '
                  'flat'),
        Confusion('coulomb_friction',
                  'a staircase of several steady speeds: friction offsets the speed-input '
                  'map by a constant, a quadratic load bends it')))
