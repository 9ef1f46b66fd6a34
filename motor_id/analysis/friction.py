"""Friction by direction, as axis makers state it, from a model's effects."""

from __future__ import annotations

from collections.abc import Mapping


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
