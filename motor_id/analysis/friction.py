"""Friction by direction, as axis makers state it, from a model's effects."""

from __future__ import annotations

from collections.abc import Mapping

from motor_id.effects import EFFECTS


def friction_summary(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
                     input_kind: str) -> dict[str, float] | None:
    """Friction by direction, as axis makers state it: Fc+/Fc- (dry, with a constant
    load or force offset folded in) and Fv+/Fv- (viscous); None without dry friction."""
    if 'coulomb_friction' not in effects:
        return None
    tc = effects['coulomb_friction']['T_c']
    tl = effects.get('load_torque', {}).get('T_L', 0.0)
    asym = effects.get('asymmetric_friction', {})
    b = params['B']
    out = {'Fc+': tc + tl, 'Fc-': tc + asym.get('dT_c', 0.0) - tl,
           'Fv+': b, 'Fv-': b + asym.get('dB', 0.0)}
    for e in ('stiction', 'stribeck_friction'):
        if e in effects:
            out['F_static'] = effects[e]['T_s']
    if 'stribeck_friction' in effects:
        out['v_stribeck'] = effects['stribeck_friction']['v_s']
    return out


def folded_load(effects: Mapping[str, Mapping[str, float]]) -> bool:
    """A constant load is not separable from asymmetric Coulomb levels.

    Moving, the axis feels ``T_c + T_L`` forward and ``T_c + dT_c - T_L`` backward; at
    rest it breaks away at the same two levels. Only ``Fc+`` and ``Fc-`` are determined,
    and ``(T_c, dT_c, T_L)`` can slide along a line that changes nothing simulated,
    unless a static level (stiction, Stribeck friction: break-away at ``T_s +- T_L``)
    tells the load apart.
    """
    static = any(e in EFFECTS and 'T_s' in {q.name for q in EFFECTS[e].params}
                 for e in effects)
    return {'coulomb_friction', 'asymmetric_friction', 'load_torque'} <= set(effects) \
        and not static
