"""Friction by direction, as axis makers state it, from a model's effects."""

from __future__ import annotations

from collections.abc import Mapping

from motor_id.effects import role_keys, role_value


def friction_summary(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
                     input_kind: str) -> dict[str, float] | None:
    """Friction by direction, as axis makers state it: Fc+/Fc- (dry, with a constant
    load or force offset folded in) and Fv+/Fv- (viscous); None without dry friction.

    The effects' parameters are read by their roles (:data:`motor_id.effects.ROLES`):
    the dry friction torque (``kS`` in torque units), a constant ``load``, the extras of
    negative motion, the ``static`` level (the largest where two effects set one, as
    the simulator takes it) and the ``stribeck_speed``.
    """
    if not role_keys(effects, 'kS', 'torque'):
        return None
    tc = role_value(effects, 'kS', scale='torque')
    tl = role_value(effects, 'load')
    b = params['B']
    out = {'Fc+': tc + tl, 'Fc-': tc + role_value(effects, 'kS_extra_negative') - tl,
           'Fv+': b, 'Fv-': b + role_value(effects, 'kV_extra_negative')}
    static = [effects[k.partition('.')[0]][k.partition('.')[2]]
              for k in role_keys(effects, 'static')]
    if static:
        out['F_static'] = max(static)
    if role_keys(effects, 'stribeck_speed'):
        out['v_stribeck'] = role_value(effects, 'stribeck_speed')
    return out


def folded_load(effects: Mapping[str, Mapping[str, float]]) -> bool:
    """A constant load is not separable from asymmetric Coulomb levels.

    Moving, the axis feels ``T_c + T_L`` forward and ``T_c + dT_c - T_L`` backward; at
    rest it breaks away at the same two levels. Only ``Fc+`` and ``Fc-`` are determined,
    and ``(T_c, dT_c, T_L)`` can slide along a line that changes nothing simulated,
    unless a static level (stiction, Stribeck friction: break-away at ``T_s +- T_L``)
    tells the load apart.
    """
    return bool(role_keys(effects, 'kS', 'torque') and role_keys(effects, 'kS_extra_negative')
                and role_keys(effects, 'load') and not role_keys(effects, 'static'))
