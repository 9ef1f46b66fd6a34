"""An arm's gravity: T_g cos(theta + offset) from the joint's measured position."""

import math

import numpy as np

from motor_id.effects.spec import EffectParam, EffectSpec, KernelArg, PositionTerm


def _columns(position: np.ndarray) -> list[np.ndarray]:
    # T_g cos(theta + offset) = T_g cos(offset) cos(theta) - T_g sin(offset) sin(theta)
    return [np.cos(position), -np.sin(position)]


def _params(coef: np.ndarray, torque_per_input: float) -> dict[str, float]:
    a, b = float(coef[0]), float(coef[1])
    return {'T_g': math.hypot(a, b) * torque_per_input, 'offset': math.atan2(b, a)}


SPEC = EffectSpec(
    'arm_gravity', 'tau -= T_g cos(theta + offset), theta the measured joint position',
    (EffectParam('T_g', 'N m', 0.5, 0.0, 1e4, 'torque', (1e-3, 1.0, 12), (0.0, 2.0),
                 role='kG'),
     EffectParam('offset', 'rad', 0.0, -2.0 * math.pi, 2.0 * math.pi, 'one',
                 (-math.pi, math.pi, 12), (-2.0 * math.pi, 2.0 * math.pi), 'linear',
                 role='offset')),
    description="an arm's gravity: horizontal where theta + offset = 0, hanging at rest "
    'where theta + offset = -pi/2 (offset: from the encoder zero to horizontal)',
    kernel_args=(KernelArg('G_cos', 'T_g'), KernelArg('G_off', 'offset')),
    mechanism='arm', position=True,
    position_term=PositionTerm(_columns, _params))
