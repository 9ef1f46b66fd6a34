"""The ``controller`` block of an analysis: feedforward constants of the simulation-error
model, each with its error bar and unit, or why the record does not determine it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from motor_id.contracts import units_of
from motor_id.effects import role_params
from motor_id.records import optional, Record

if TYPE_CHECKING:
    from motor_id.analysis.simulation_result import SimulationStage


@dataclass(frozen=True, kw_only=True)
class FeedforwardConstant(Record):
    """One constant (kS, kV, kA, kG, ...): ``value`` and ``std``, both null when the
    record does not determine it; then its ``particular_value``, the ``interval`` the
    data allow and a ``note`` why."""

    value: float | None
    std: float | None
    particular_value: float | None = optional()
    interval: tuple[float, float] | None = optional()
    note: str | None = optional()
    unit: str | None = optional()


@dataclass(frozen=True, kw_only=True)
class ControllerBlock(Record):
    """Feedforward constants by name, the model they come from (its name), the
    mechanism and how they follow from the model's parameters (``source``)."""

    feedforward: dict[str, FeedforwardConstant]
    model: str | None
    mechanism: str | None = optional()
    source: str


def controller_block(sim: SimulationStage | None, input_kind: str, linear: bool,
                     mechanism: str) -> ControllerBlock | None:
    """The feedforward constants of the simulation-error model: a voltage plant's
    (:func:`voltage_controller`) or a torque plant's (:func:`torque_controller`); None
    without that model."""
    if input_kind == 'torque':
        return torque_controller(sim, linear, mechanism)
    return voltage_controller(sim, input_kind, linear, mechanism)


def _units(input_kind: str, linear: bool) -> dict[str, str]:
    u = units_of(input_kind, linear)
    return {'kS': u['kS'], 'kV': u['kV'], 'kA': u['kA'], 'kS-': u['kS'], 'kV-': u['kV'],
            'kG': u['kS'], **{p.role: p.unit for _, p in role_params('offset')}}


def voltage_controller(sim: SimulationStage | None, input_kind: str, linear: bool,
                       mechanism: str) -> ControllerBlock | None:
    """WPILib SysId's feedforward constants of the simulation-error model of a voltage
    plant with their error bars, as the fit's block has them; None without that
    model."""
    combos = sim.estimates.combinations if sim and sim.estimates else None
    if not sim or not combos:
        return None
    units = _units(input_kind, linear)
    ff: dict[str, FeedforwardConstant] = {}
    for c in combos:
        ff[c.name] = (FeedforwardConstant(value=c.value, std=c.std, unit=units.get(c.name))
                      if c.determined else
                      FeedforwardConstant(value=None, std=None, particular_value=c.value,
                                          interval=c.interval, note=c.note or None,
                                          unit=units.get(c.name)))
    source = ('the simulation-error model (simulation.model): kS = V_b + T_c R_m / K_T, '
              'kV = (R_m B + K_T K_b) / K_T, kA = (R_m J + B L_m) / K_T')
    if 'kG' in ff:
        source += (', kG = T_g R_m / K_T: V = kS sgn(w) + kG cos(theta + offset) + kV w '
                   '+ kA dw/dt' if 'offset' in ff else
                   ', kG = T_g R_m / K_T: V = kS sgn(w) + kG + kV w + kA dw/dt')
    return ControllerBlock(feedforward=ff, model=sim.chosen, mechanism=mechanism,
                           source=source)


TORQUE_FEEDFORWARD = {'kS': ('coulomb_friction.T_c',), 'kV': ('B',), 'kA': ('J',),
                      'kG': ('elevator_gravity.T_g', 'arm_gravity.T_g'),
                      'offset': ('arm_gravity.offset',)}
"""For a torque plant the feedforward constants are parameters: u = T_c sgn(w) + T_g
[cos(theta + offset)] + B w + J dw/dt."""


def torque_controller(sim: SimulationStage | None, linear: bool,
                      mechanism: str) -> ControllerBlock | None:
    """The feedforward constants of a torque plant: its simulation-error model's
    parameters (:data:`TORQUE_FEEDFORWARD`; kS 0 for a model without Coulomb
    friction); None without that model."""
    params = (sim.estimates.parameters if sim and sim.estimates else None) or {}
    if not sim or not params:
        return None
    units = _units('torque', linear)
    ff: dict[str, FeedforwardConstant] = {}
    for name, keys in TORQUE_FEEDFORWARD.items():
        key = next((k for k in keys if k in params), None)
        if key is None:
            if name == 'kS':
                ff[name] = FeedforwardConstant(
                    value=0.0, std=None, note='the chosen model has no Coulomb friction',
                    unit=units[name])
            continue
        p = params[key]
        ff[name] = (FeedforwardConstant(value=p.value, std=p.std, unit=units[name])
                    if p.determined else
                    FeedforwardConstant(value=None, std=None, particular_value=p.value,
                                        note=p.note or None, unit=units[name]))
    return ControllerBlock(feedforward=ff, model=sim.chosen, mechanism=mechanism,
                           source='the simulation-error model of a torque plant: kS = T_c, '
                                  'kV = B, kA = J (kG = T_g)')
