"""Coulomb friction: a dry friction level T_c against the motion, stuck at rest."""

import numpy as np

from motor_id.effects.spec import (
    Confusion,
    EffectParam,
    EffectSpec,
    MechanicalTerm,
    Values,
)


def _friction(fr: np.ndarray, v: Values) -> None:
    fr[:, 0] = fr[:, 1] = v['T_c']


SPEC = EffectSpec(
    'coulomb_friction', 'tau -= T_c sgn(w); stuck (w = 0) while |drive| <= T_c',
    (EffectParam('T_c', 'N m', 0.05, 0.0, 1e3, 'torque', (1e-4, 0.5, 16), (0.0, 2.0),
                 role='kS'),),
    description='dry friction with stiction at zero speed',
    friction_term=_friction,
    mechanical_term=MechanicalTerm('T_c', ' + T_c sgn(w)', np.sign, away_from_rest=True),
    confused_with=(
        Confusion('load_torque',
                  'reverse the motor (bipolar_steps with rests): Coulomb friction changes '
                  'sign with the speed, a constant load torque does not',
                  'reverse the motion: friction changes sign with the speed, a constant '
                  'load or force offset does not', one_way=True),
        Confusion('brush_drop',
                  'measure the current and brake hard (steps down) so that the current '
                  'reverses while the speed keeps its sign: friction follows the speed, '
                  'the brush drop the current'),
        Confusion('dead_zone',
                  'measure the current and decelerate with the input still positive: '
                  'friction raises the current needed at a given speed, a dead zone '
                  'lowers the voltage that reaches the motor',
                  'log the current with its sign and brake with the torque reversed while '
                  'the shaft still turns: friction follows the speed sign, a dead zone the '
                  'torque sign (a torque whose sign is inferred from the speed makes both '
                  'act alike)')),
    shows_offset=True, named_on_offset=True,
    stage_start=lambda drive, coulomb: {'T_c': 0.02 * drive})
