"""Controller results out: a design from the fit JSON, and as ROS parameters."""

from collections.abc import Mapping
import math
from typing import Any

import numpy as np

from motor_id.controller.design import check_input_kind, ControllerDesign, design_controller
from motor_id.effects import role_params
from motor_id.errors import ConfigError


def _kS_from_effects(  # noqa: N802 - kS: WPILib's symbol
        effects: Mapping[str, Any], vals: Mapping[str, float],
        input_kind: str) -> dict[str, Any] | None:
    """Return kS from the fitted effect parameters whose role is ``'kS'`` (a dry friction
    torque through R_m / K_T, a voltage drop as it is; None if none).

    The std comes from the effect parameters' stds only: R_m / K_T is taken as exact.
    """
    def val_std(entry: Any) -> tuple[Any, float]:
        if isinstance(entry, dict):
            return entry.get('value'), entry.get('std') or 0.0
        return entry, 0.0

    value, var, sources = 0.0, 0.0, []
    for spec, p in role_params('kS'):
        entry = (effects.get(spec.name) or {}).get(p.name)
        if entry is None or input_kind not in spec.kinds:
            continue
        t, ts = val_std(entry)
        if t is None:
            return None
        if p.scale != 'torque':   # a voltage drop
            value, var = value + abs(t), var + ts ** 2
        else:
            scale = 1.0 if input_kind == 'torque' else vals['R_m'] / vals['K_T']
            if not np.isfinite(scale):
                return None
            value, var = value + abs(t) * scale, var + (ts * scale) ** 2
        sources.append(spec.name)
    if not sources:
        return None
    return {'value': value, 'std': math.sqrt(var), 'source': '+'.join(sources)}


def _gravity_from_effects(effects: Mapping[str, Any], vals: Mapping[str, float],
                          input_kind: str) -> dict[str, dict[str, Any]]:
    """``kG`` (a gravity torque through R_m / K_T, or as it is on a torque plant) and an
    arm's ``offset`` [rad] from the fitted effect parameters with those roles, each
    ``{value, std, unit}`` (the std from the parameter's alone: R_m / K_T taken as exact)."""
    out: dict[str, dict[str, Any]] = {}
    for role, convert in (('kG', True), ('offset', False)):
        for spec, p in role_params(role):
            entry = (effects.get(spec.name) or {}).get(p.name)
            if entry is None:
                continue
            v, s = (entry.get('value'), entry.get('std')) if isinstance(entry, dict) \
                else (entry, None)
            scale = vals['R_m'] / vals['K_T'] if convert and input_kind == 'voltage' else 1.0
            if v is None or not np.isfinite(scale):
                out[role] = {'value': None, 'std': None}
                continue
            if not convert:
                v = math.remainder(v, 2.0 * math.pi)
            out[role] = {'value': v * scale, 'std': None if s is None else s * scale}
            if not convert:
                out[role]['unit'] = p.unit
    return out


def _covariance_from_fit(result_dict: Mapping[str, Any], params: Mapping[str, Any],
                         values: Mapping[str, float | None],
                         notes: list[str]) -> dict[str, Any] | None:
    """The fit's parameter_covariance over the known parameters, else a diagonal one."""
    covariance = result_dict.get('parameter_covariance')
    if covariance is not None:
        if not isinstance(covariance, dict) or set(covariance) != {'names', 'matrix'}:
            raise ConfigError("parameter_covariance must be {'names': [...], "
                              "'matrix': [[...]]}")
        cov_names = list(covariance['names'])
        keep = [j for j, n in enumerate(cov_names) if values.get(n) is not None]
        try:
            m = np.asarray(covariance['matrix'], dtype=float)[np.ix_(keep, keep)]
        except (TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f'parameter_covariance matrix is unusable: {exc}') from exc
        return {'names': [cov_names[j] for j in keep], 'matrix': m.tolist()}
    with_std = [n for n, v in values.items() if v is not None
                and params[n].get('std') is not None]
    if not with_std:
        return None
    notes.append('the fit JSON has no parameter_covariance: stds are combined as '
                 'independent (correlations ignored), so error bars of ratios such '
                 'as kA = R_m J / K_T can be far too large or too small')
    return {'names': with_std,
            'matrix': np.diag([params[n]['std'] ** 2 for n in with_std]).tolist()}


def from_identification(result_dict: Mapping[str, Any], **kw: Any) -> ControllerDesign:
    """Design a controller from the fit JSON of ``motor-id fit --json``.

    Parameters
    ----------
    result_dict : dict
        ``{'parameters': {name: {'value', 'std', 'determined'}}, ...}``; an optional
        top-level ``'parameter_covariance': {'names', 'matrix'}`` (linear units) is used
        as the covariance, else the stds form a diagonal one (correlations ignored, said
        in the notes). ``'input_kind'``, fitted ``'effects'`` (coulomb_friction T_c,
        brush_drop V_b, for kS) and ``data.linear`` (a linear axis: units per metre) are
        used when present.
    **kw
        Passed to :func:`design_controller` (``covariance`` and ``values`` are taken from
        the dict; ``input_kind`` and ``kS`` override what the dict says).

    Returns
    -------
    ControllerDesign
        Entries that need an undetermined parameter are null, with a note naming the
        assumption that would determine it.
    """
    if not isinstance(result_dict, dict) or not isinstance(result_dict.get('parameters'),
                                                           dict):
        raise ConfigError("result_dict must be a fit report's dict (FitReport.to_dict(), "
                          "the JSON of motor-id fit) with a 'parameters' dict")
    for k in ('values', 'covariance'):
        if k in kw:
            raise ConfigError(f'{k} comes from result_dict; do not pass it')
    input_kind = kw.pop('input_kind', result_dict.get('input_kind', 'voltage'))
    names = check_input_kind(input_kind)
    params = result_dict['parameters']
    missing = [n for n in names if n not in params]
    if missing:
        raise ConfigError(f'the fit JSON lacks parameters {", ".join(missing)} for a '
                          f'{input_kind} plant')
    if not all(isinstance(params[n], dict) for n in names):
        raise ConfigError("each fit parameter must be {'value', 'std', 'determined'}")
    values = {n: params[n].get('value') for n in names}
    undetermined = [n for n in names if values[n] is None]
    notes: list[str] = []
    covariance = _covariance_from_fit(result_dict, params, values, notes)
    if 'kS' not in kw and isinstance(result_dict.get('effects'), dict):
        vals = {n: math.nan if values[n] is None else values[n] for n in names}
        kw['kS'] = _kS_from_effects(result_dict['effects'], vals, input_kind)
    if 'linear' not in kw:
        kw['linear'] = bool((result_dict.get('data') or {}).get('linear', False))
    design = design_controller(values, covariance=covariance, input_kind=input_kind, **kw)
    _feedforward_from_combinations(design, result_dict, notes)
    if isinstance(result_dict.get('effects'), dict):
        # T_g R_m / K_T is determined where K_T alone is not (speed only): the fit's
        # particular K_T then carries the ratio
        vals = {n: values[n] if values[n] is not None else
                params[n].get('particular_value', math.nan) for n in names}
        vals = {n: math.nan if v is None else v for n, v in vals.items()}
        design.feedforward.update(_gravity_from_effects(result_dict['effects'], vals,
                                                        input_kind))
        combo = next((c for c in result_dict.get('identifiable_combinations') or []
                      if isinstance(c, dict) and c.get('name') == 'kG'), None)
        if combo is not None:   # speed only: the delta method on the determined T_g / K_T
            design.feedforward['kG'] = {'value': combo['value'], 'std': combo.get('std')}
    if undetermined:
        how = ('state one with --fix NAME=VALUE (e.g. --fix J=...)' if input_kind == 'torque'
               else 'record the current channel (with the K_T = K_b tie, on by default) or '
                    'state one with --fix NAME=VALUE (e.g. --fix J=...)')
        notes.append(f'{", ".join(undetermined)} not determined by the data, so the entries '
                     f'that need them are null: {how} to determine them')
    design.notes.extend(notes)
    return design


def _feedforward_from_combinations(design: ControllerDesign, result_dict: Mapping[str, Any],
                                   notes: list[str]) -> None:
    """kV and kA from the determined combinations of a speed-only fit, where the
    physical parameters they are usually computed from are not determined."""
    combos = {c.get('name'): c for c in result_dict.get('identifiable_combinations') or []
              if isinstance(c, dict) and c.get('determined', True)}
    filled = []
    for k in ('kV', 'kA'):
        entry = design.feedforward.get(k) or {}
        if k in combos and entry.get('value') is None:
            design.feedforward[k] = {'value': combos[k]['value'], 'std': combos[k].get('std')}
            filled.append(k)
    entry = design.feedforward.get('kS') or {}
    if 'kS' in combos and (not entry.get('value') or entry.get('std') is None):
        # T_c R_m / K_T: determined on speed alone though K_T is not
        design.feedforward['kS'] = {'value': abs(combos['kS']['value']),
                                    'std': combos['kS'].get('std')}
        design.notes[:] = [n for n in design.notes if not n.startswith('kS = 0')]
        notes.append('kS from the fitted static friction through R_m / K_T, a combination '
                     'the speed determines (delta-method error bar)')
    if filled:
        notes.append(f'{" and ".join(filled)} from the speed transfer function the data '
                     'determine (kV = a0/b0; kA = a1/b0 = R_m J/K_T + B L_m/K_T, the second '
                     'term negligible for a short electrical time constant)')


def to_ros_parameters(design: ControllerDesign | Mapping[str, Any],
                      node_name: str = '/**') -> dict[str, Any]:
    """Return the design as a ``ros__parameters`` dict for ``yaml.safe_dump`` (params file).

    Parameters
    ----------
    design : ControllerDesign or dict
        A design or its ``to_dict()``.
    node_name : str
        The node the parameters are for; ``'/**'`` applies to every node.

    Returns
    -------
    dict
        ``{node_name: {'ros__parameters': {'controller.kS': float, ...}}}`` with plain
        floats; null (unknown) entries are left out, since ROS parameters have no null.
        Keys: ``controller.{kS,kV,kA,tau_e,tau_m}``,
        ``controller.{current,speed}.{kp,ki,bandwidth_hz}``.
    """
    if not isinstance(node_name, str) or not node_name:
        raise ConfigError(f'node_name must be a non-empty string, got {node_name!r}')
    d = design.to_dict() if isinstance(design, ControllerDesign) else design
    if not isinstance(d, dict) or set(d) != {'feedforward', 'time_constants', 'pi', 'notes'}:
        raise ConfigError('design must be a ControllerDesign or its to_dict()')
    flat = {}
    for k in ('kS', 'kV', 'kA'):
        flat[f'controller.{k}'] = d['feedforward'][k]['value']
    flat['controller.tau_e'] = d['time_constants']['electrical']['value']
    flat['controller.tau_m'] = d['time_constants']['mechanical']['value']
    for loop in ('current', 'speed'):
        entry = d['pi'][loop] or {}
        for k in ('kp', 'ki'):
            flat[f'controller.{loop}.{k}'] = (entry.get(k) or {}).get('value')
        flat[f'controller.{loop}.bandwidth_hz'] = entry.get('bandwidth_hz')
    params = {k: float(v) for k, v in flat.items() if v is not None}
    return {node_name: {'ros__parameters': params}}
