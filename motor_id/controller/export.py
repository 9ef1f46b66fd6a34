"""Controller results out: a design from a fit (or its JSON), and as ROS parameters."""

from collections.abc import Mapping, Sequence
from dataclasses import replace
import math
from typing import Any, cast

import numpy as np

from motor_id.controller.design import check_input_kind, design_controller
from motor_id.controller.result import ControllerDesign, Quantity
from motor_id.effects import role_params
from motor_id.errors import ConfigError
from motor_id.identify.result import (
    Combination,
    EffectEstimate,
    Estimate,
    IdentificationResult,
    ParameterCovariance,
)
from motor_id.output import to_jsonable


def _kS_from_effects(  # noqa: N802 - kS: WPILib's symbol
        effects: Mapping[str, Any], vals: Mapping[str, float],
        input_kind: str) -> dict[str, float | str] | None:
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
                          input_kind: str) -> dict[str, Quantity]:
    """``kG`` (a gravity torque through R_m / K_T, or as it is on a torque plant) and an
    arm's ``offset`` [rad] from the fitted effect parameters with those roles, each with
    its std (the parameter's alone: R_m / K_T taken as exact) and the offset's unit."""
    out: dict[str, Quantity] = {}
    for role, convert in (('kG', True), ('offset', False)):
        for spec, p in role_params(role):
            entry = (effects.get(spec.name) or {}).get(p.name)
            if entry is None:
                continue
            v, s = (entry.get('value'), entry.get('std')) if isinstance(entry, dict) \
                else (entry, None)
            scale = vals['R_m'] / vals['K_T'] if convert and input_kind == 'voltage' else 1.0
            if v is None or not np.isfinite(scale):
                out[role] = Quantity(None, None)
                continue
            if not convert:
                v = math.remainder(v, 2.0 * math.pi)
            out[role] = Quantity(v * scale, None if s is None else s * scale,
                                 None if convert else p.unit)
    return out


def _covariance_from_fit(covariance: ParameterCovariance | None,
                         params: Mapping[str, Estimate], values: Mapping[str, float | None],
                         notes: list[str]) -> ParameterCovariance | None:
    """The fit's parameter_covariance over the known parameters, else a diagonal one."""
    if covariance is not None:
        keep = [j for j, n in enumerate(covariance.names) if values.get(n) is not None]
        try:
            m = np.asarray(covariance.matrix, dtype=float)[np.ix_(keep, keep)]
        except (TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f'parameter_covariance matrix is unusable: {exc}') from exc
        return ParameterCovariance(names=[covariance.names[j] for j in keep],
                                   matrix=m.tolist())
    with_std = [n for n, v in values.items() if v is not None and params[n].std is not None]
    if not with_std:
        return None
    notes.append('the fit JSON has no parameter_covariance: stds are combined as '
                 'independent (correlations ignored), so error bars of ratios such '
                 'as kA = R_m J / K_T can be far too large or too small')
    return ParameterCovariance(
        names=with_std, matrix=np.diag([cast(float, params[n].std) ** 2
                                        for n in with_std]).tolist())


def from_fit(result: IdentificationResult, *, linear: bool = False,
             **kw: Any) -> ControllerDesign:
    """Design a controller from a fit's result.

    Parameters
    ----------
    result : IdentificationResult
        Its parameters (values, stds, particular values), ``parameter_covariance``
        (else the stds form a diagonal one, correlations ignored, said in the notes),
        ``input_kind``, fitted ``effects`` (for kS, kG) and determined combinations
        (kV, kA, kS, kG of a speed-only fit).
    linear : bool
        A linear axis: units per metre.
    **kw
        Passed to :func:`design_controller` (``input_kind`` and ``kS`` override what the
        result says).

    Returns
    -------
    ControllerDesign
        Entries that need an undetermined parameter are null, with a note naming the
        assumption that would determine it.
    """
    params = {n: replace(e, value=_known(e.value), std=_known(e.std),
                         particular_value=_known(e.particular_value))
              for n, e in result.parameters.items()}
    kw.setdefault('linear', linear)
    effects = {e: {p: v.to_dict() if isinstance(v, EffectEstimate) else v
                   for p, v in vals.items()} for e, vals in result.effects.items()}
    return _design(params, result.parameter_covariance, to_jsonable(effects),
                   result.identifiable_combinations,
                   kw.pop('input_kind', result.input_kind), **kw)


def _known(x: float | None) -> float | None:
    """None for an unknown or non-finite number (as the fit's JSON writes it)."""
    return None if x is None or not math.isfinite(x) else float(x)


def _or_nan(x: float | None) -> float:
    return math.nan if x is None else x


def _quantity(c: Combination, absolute: bool = False) -> Quantity:
    """A determined combination as a design entry (its magnitude: ``absolute``)."""
    value = _known(c.value)
    return Quantity(None if value is None else abs(value) if absolute else value,
                    _known(c.std))


def from_identification(result_dict: Mapping[str, Any], **kw: Any) -> ControllerDesign:
    """Design a controller from the fit JSON of ``motor-id fit --json`` (read back here,
    then as :func:`from_fit`).

    Parameters
    ----------
    result_dict : dict
        ``{'parameters': {name: {'value', 'std', 'determined'}}, ...}``; an optional
        top-level ``'parameter_covariance': {'names', 'matrix'}`` (linear units) is used
        as the covariance, else the stds form a diagonal one (correlations ignored, said
        in the notes). ``'input_kind'``, fitted ``'effects'`` (coulomb_friction T_c,
        brush_drop V_b, for kS), ``'identifiable_combinations'`` and ``data.linear`` (a
        linear axis: units per metre) are used when present.
    **kw
        Passed to :func:`design_controller` (``covariance`` and ``values`` are taken from
        the dict; ``input_kind`` and ``kS`` override what the dict says).

    Returns
    -------
    ControllerDesign
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
    _check_present(names, params, input_kind)
    if not all(isinstance(params[n], dict) for n in names):
        raise ConfigError("each fit parameter must be {'value', 'std', 'determined'}")
    covariance = result_dict.get('parameter_covariance')
    if covariance is not None:
        if not isinstance(covariance, dict) or set(covariance) != {'names', 'matrix'}:
            raise ConfigError("parameter_covariance must be {'names': [...], "
                              "'matrix': [[...]]}")
        covariance = ParameterCovariance(names=list(covariance['names']),
                                         matrix=covariance['matrix'])
    combos = [Combination(name=str(c.get('name')), value=cast(float, c.get('value')),
                          std=c.get('std'), determined=c.get('determined', True))
              for c in result_dict.get('identifiable_combinations') or []
              if isinstance(c, dict)]
    effects = result_dict.get('effects')
    if 'linear' not in kw:
        kw['linear'] = bool((result_dict.get('data') or {}).get('linear', False))
    return _design({n: Estimate.from_dict(p) for n, p in params.items() if n in names},
                   covariance, effects if isinstance(effects, dict) else None, combos,
                   input_kind, **kw)


def _check_present(names: Sequence[str], params: Mapping[str, object], input_kind: str
                   ) -> None:
    missing = [n for n in names if n not in params]
    if missing:
        raise ConfigError(f'the fit JSON lacks parameters {", ".join(missing)} for a '
                          f'{input_kind} plant')


def _design(params: Mapping[str, Estimate], covariance: ParameterCovariance | None,
            effects: Mapping[str, Any] | None, combos: Sequence[Combination],
            input_kind: str, **kw: Any) -> ControllerDesign:
    """The design from a fit's typed pieces (``kw``: :func:`design_controller`'s)."""
    names = check_input_kind(input_kind)
    _check_present(names, params, input_kind)
    values = {n: params[n].value for n in names}
    undetermined = [n for n in names if values[n] is None]
    notes: list[str] = []
    cov = _covariance_from_fit(covariance, params, values, notes)
    if 'kS' not in kw and effects is not None:
        kw['kS'] = _kS_from_effects(effects, {n: _or_nan(values[n]) for n in names},
                                    input_kind)
    design = design_controller(values, covariance=cov, input_kind=input_kind, **kw)
    _feedforward_from_combinations(design, combos, notes)
    if effects is not None:
        # T_g R_m / K_T is determined where K_T alone is not (speed only): the fit's
        # particular K_T then carries the ratio
        vals = {n: _or_nan(values[n] if values[n] is not None else
                           params[n].particular_value) for n in names}
        g = _gravity_from_effects(effects, vals, input_kind)
        ff = design.feedforward
        design.feedforward = replace(ff, kG=g.get('kG', ff.kG), offset=g.get('offset',
                                                                             ff.offset))
        combo = next((c for c in combos if c.name == 'kG'), None)
        if combo is not None:   # speed only: the delta method on the determined T_g / K_T
            design.feedforward = replace(design.feedforward, kG=_quantity(combo))
    if undetermined:
        how = ('state one with --fix NAME=VALUE (e.g. --fix J=...)' if input_kind == 'torque'
               else 'record the current channel (with the K_T = K_b tie, on by default) or '
                    'state one with --fix NAME=VALUE (e.g. --fix J=...)')
        notes.append(f'{", ".join(undetermined)} not determined by the data, so the entries '
                     f'that need them are null: {how} to determine them')
    design.notes.extend(notes)
    return design


def _feedforward_from_combinations(design: ControllerDesign, combinations: Sequence[Combination],
                                   notes: list[str]) -> None:
    """kV and kA from the determined combinations of a speed-only fit, where the
    physical parameters they are usually computed from are not determined."""
    combos = {c.name: c for c in combinations if c.determined}
    filled = []
    ff = design.feedforward
    if 'kV' in combos and ff.kV.value is None:
        ff = replace(ff, kV=_quantity(combos['kV']))
        filled.append('kV')
    if 'kA' in combos and ff.kA.value is None:
        ff = replace(ff, kA=_quantity(combos['kA']))
        filled.append('kA')
    if 'kS' in combos and (not ff.kS.value or ff.kS.std is None):
        # T_c R_m / K_T: determined on speed alone though K_T is not
        ff = replace(ff, kS=_quantity(combos['kS'], absolute=True))
        design.notes[:] = [n for n in design.notes if not n.startswith('kS = 0')]
        notes.append('kS from the fitted static friction through R_m / K_T, a combination '
                     'the speed determines (delta-method error bar)')
    design.feedforward = ff
    if filled:
        notes.append(f'{" and ".join(filled)} from the speed transfer function the data '
                     'determine (kV = a0/b0; kA = a1/b0 = R_m J/K_T + B L_m/K_T, the second '
                     'term negligible for a short electrical time constant)')


def to_ros_parameters(design: ControllerDesign | Mapping[str, Any],
                      node_name: str = '/**') -> dict[str, dict[str, dict[str, float]]]:
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
    d = design if isinstance(design, ControllerDesign) else ControllerDesign.from_dict(design)
    ff, tc = d.feedforward, d.time_constants
    flat: dict[str, float | None] = {'controller.kS': ff.kS.value, 'controller.kV': ff.kV.value,
                                     'controller.kA': ff.kA.value,
                                     'controller.tau_e': tc.electrical.value,
                                     'controller.tau_m': tc.mechanical.value}
    for loop, entry in (('current', d.pi.current), ('speed', d.pi.speed)):
        flat[f'controller.{loop}.kp'] = None if entry is None else entry.kp.value
        flat[f'controller.{loop}.ki'] = None if entry is None else entry.ki.value
        flat[f'controller.{loop}.bandwidth_hz'] = None if entry is None else entry.bandwidth_hz
    params = {k: float(v) for k, v in flat.items() if v is not None}
    return {node_name: {'ros__parameters': params}}
