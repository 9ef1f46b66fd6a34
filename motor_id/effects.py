"""The catalogue of named effects: each physical term beyond the linear DC-motor model.

An effect (:class:`EffectSpec`) is an equation with named parameters (:class:`EffectParam`:
unit, default, allowed range, and the analysis' start grid and search range in units of
a data scale of :data:`SCALES`). The simulator, the fitter and the discrepancy analysis
all read this one catalogue, :data:`EFFECTS`; :mod:`motor_id.model` holds the linear
plant they extend.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
import math

import numpy as np

from motor_id.contracts import INPUT_KINDS
from motor_id.errors import ConfigError

__all__ = ['EFFECTS', 'EffectParam', 'EffectSpec', 'parse_effect_args', 'SCALES',
           'validate_effects']


SCALES = ('one', 'torque', 'input', 'speed', 'torque/speed', 'torque/speed^2', 'record',
          'sample',
          'per_record', 'per_sample', 'heating', 'max_delay', 'current', 'lag_floor')
"""Data scales an effect parameter's start grid and search range are stated in.

The analysis measures them on each recording: ``torque`` the stall torque K_T A / R_m
(the input amplitude A for a torque plant), ``input`` A, ``speed`` the top speed,
``torque/speed`` and ``torque/speed^2`` their ratios, ``record`` the record length and
``sample`` the sample period [s], ``per_record`` / ``per_sample`` their inverses [Hz], ``heating``
R_m / (i_rms^2 record) [Ohm/(A^2 s)], ``max_delay`` the longest delay tried [samples],
``current`` the current's spread [A], ``lag_floor`` the shortest sensor lag that is more
than the sampling itself (half a sample period; a whole one when the speed is counted
by an encoder, whose count difference averages over the period); ``one`` is 1.
"""


def _at_scale(end: float | tuple[float, str], scale: str, scales: Mapping[str, float]
              ) -> float:
    """An end point ``m`` (in units of ``scale``) or ``(m, other_scale)`` as a number."""
    if isinstance(end, tuple):
        return float(end[0]) * scales[end[1]]
    return float(end) * scales[scale]


@dataclass(frozen=True)
class EffectParam:
    """One parameter of an effect: name, unit, default, allowed range, analysis grid.

    ``low`` / ``high`` are the allowed range (any motor). ``scale`` names the data scale
    of :data:`SCALES` that ``start`` (``(first, last, n)``: the analysis' start grid)
    and ``search`` (``(low, high)``: its search range) are multiples of; an end point
    may also be ``(multiple, other_scale)``. ``spacing`` is ``'log'``, ``'linear'``,
    ``'signed'`` (a log grid of both signs) or ``'integer'`` (every whole number from
    ``first`` to ``last``; the parameter is then found by the grid, never refined).
    """

    name: str
    unit: str
    default: float
    low: float
    high: float
    scale: str = 'one'
    start: tuple = ()
    search: tuple = ()
    spacing: str = 'log'

    def start_values(self, scales: Mapping[str, float]) -> np.ndarray:
        """The start grid on one recording's scales (``{scale: value}``), an array."""
        first, last, n = self.start
        a, b = _at_scale(first, self.scale, scales), _at_scale(last, self.scale, scales)
        if self.spacing == 'integer':
            return np.arange(max(1, int(round(a))), max(2, int(round(b))) + 1, dtype=float)
        if self.spacing == 'linear':
            return np.linspace(a, b, n)
        a = max(a, 1e-300)
        v = np.geomspace(a, max(b, a), n)
        return np.concatenate([v, -v]) if self.spacing == 'signed' else v

    def search_range(self, scales: Mapping[str, float]) -> tuple[float, float]:
        """``(low, high)`` search range on one recording's scales, inside the allowed one."""
        if not self.search:
            return (self.low, self.high)
        lo = _at_scale(self.search[0], self.scale, scales)
        hi = _at_scale(self.search[1], self.scale, scales)
        lo, hi = max(lo, self.low), min(hi, self.high)
        return (lo, hi) if hi > lo else (self.low, self.high)


@dataclass(frozen=True)
class EffectSpec:
    """A named physical term that extends the linear model.

    ``category`` is ``'dynamic'`` (the term changes the motion and is found by fitting)
    or ``'measurement'`` (it changes only what a sensor reports on ``channel`` and is
    found from the measured values themselves). ``min_fraction`` maps a parameter name
    to ``(multiple, scale)``: below that the fitted term is not plausible as the named
    effect (a resistance that settles within a few samples is a wrong R_m, not heating).
    ``extends`` names the effect this one refines (asymmetric or Stribeck friction refine
    Coulomb friction): it is tried only once that effect is in the model, by the
    simulation-error stage of the analysis, never as a first explanation.
    ``simulation_only`` effects, too, only that stage tries.
    """

    name: str
    equation: str
    params: tuple
    kinds: tuple = INPUT_KINDS
    description: str = ''
    category: str = 'dynamic'
    channel: str = ''
    min_fraction: tuple = ()
    extends: str = ''
    simulation_only: bool = False
    """Tried only by the simulation-error stage: what shows it is a whole run's response
    from its start, which one-step errors never see (a drive's enable latency)."""

    def defaults(self) -> dict[str, float]:
        """Return ``{param: default}``."""
        return {p.name: p.default for p in self.params}

    def start_grid(self, scales: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Start points ``{param: array}`` (the Cartesian product of the param grids)."""
        axes = [p.start_values(scales) for p in self.params]
        mesh = np.meshgrid(*axes, indexing='ij')
        return {p.name: m.ravel() for p, m in zip(self.params, mesh, strict=True)}

    def implausible(self, values: Mapping[str, float], scales: Mapping[str, float]) -> str:
        """A one-line reason when fitted ``values`` are not plausible, else ``''``."""
        for name, (multiple, scale) in self.min_fraction:
            limit = multiple * scales[scale]
            if name in values and values[name] < limit:
                return (f'{self.name}.{name} = {values[name]:.4g} is below '
                        f'{multiple:g} x {scale} ({limit:.4g})')
        return ''


EFFECTS = {e.name: e for e in (
    EffectSpec('coulomb_friction', 'tau -= T_c sgn(w); stuck (w = 0) while |drive| <= T_c',
               (EffectParam('T_c', 'N m', 0.05, 0.0, 1e3, 'torque', (1e-4, 0.5, 16),
                            (0.0, 2.0)),),
               description='dry friction with stiction at zero speed'),
    EffectSpec('asymmetric_friction', 'Coulomb level T_c + dT_c and viscous B + dB when '
               'the motion is negative (w < 0); T_c and B when positive',
               (EffectParam('dT_c', 'N m', 0.0, -1e3, 1e3, 'torque', (1e-3, 0.2, 4),
                            (-2.0, 2.0), 'signed'),
                EffectParam('dB', 'N m s/rad', 0.0, -1e5, 1e5, 'torque/speed', (1e-3, 0.3, 4),
                            (-2.0, 2.0), 'signed')),
               description='direction-dependent dry and viscous friction (Fc+/Fc-, Fv+/Fv-)',
               extends='coulomb_friction'),
    EffectSpec('stribeck_friction', 'dry friction T_c + (T_s - T_c) exp(-(w / v_s)^2); '
               'break-away at T_s',
               (EffectParam('T_s', 'N m', 0.08, 0.0, 1e3, 'torque', (0.01, 0.6, 6), (0.0, 2.0)),
                EffectParam('v_s', 'rad/s', 0.05, 0.0, 1e4, 'speed', (0.003, 0.3, 6),
                            (0.0, 1.0))),
               description='friction falling from a static level to the Coulomb level as '
               'the speed rises (Stribeck curve)', extends='coulomb_friction'),
    EffectSpec('stiction', 'stuck (w = 0) while |drive| <= T_s; moving: Coulomb T_c',
               (EffectParam('T_s', 'N m', 0.08, 0.0, 1e3, 'torque', (0.01, 0.6, 8),
                            (0.0, 2.0)),),
               description='break-away torque above the Coulomb level at zero speed',
               extends='coulomb_friction'),
    EffectSpec('load_torque', 'tau -= T_L',
               (EffectParam('T_L', 'N m', 0.05, -1e3, 1e3, 'torque', (1e-4, 0.5, 12),
                            (-2.0, 2.0), 'signed'),),
               description='constant load torque (or force offset)'),
    EffectSpec('quadratic_load', 'tau -= k_q w |w|',
               (EffectParam('k_q', 'N m s^2/rad^2', 2e-4, 0.0, 1e3, 'torque/speed^2',
                            (1e-4, 1.0, 16), (0.0, 2.0)),),
               description='fan or pump load growing with the square of speed'),
    EffectSpec('brush_drop', 'V -= V_b sgn(i)',
               (EffectParam('V_b', 'V', 0.6, 0.0, 100.0, 'input', (1e-3, 0.3, 14),
                            (0.0, 1.0)),), kinds=('voltage',),
               description='constant voltage drop across the brushes'),
    EffectSpec('dead_zone', 'V_eff = 0 if |V| <= V_dz else V - V_dz sgn(V)',
               (EffectParam('V_dz', 'V (input unit)', 0.8, 0.0, 1e3, 'input',
                            (5e-3, 0.6, 14), (0.0, 1.0)),),
               description='the driver passes nothing below V_dz'),
    EffectSpec('input_delay', 'V_eff(k) = V(k - d)',
               (EffectParam('d', 'samples', 3, 0, 500, 'one', (1, (1.0, 'max_delay'), 0),
                            (), 'integer'),),
               description='transport delay of whole samples'),
    EffectSpec('voltage_saturation', 'V_eff = clip(V, -V_max, V_max)',
               (EffectParam('V_max', 'V (input unit)', 6.0, 0.0, 1e4, 'input',
                            (0.15, 0.98, 16), (0.01, 2.0), 'linear'),),
               description='the amplifier clips the input'),
    EffectSpec('sensor_lag', 'tau_s dy/dt = w - y (speed sensor first-order filter)',
               (EffectParam('tau_s', 's', 0.05, 0.0, 10.0, 'sample', (0.5, (0.1, 'record'), 16),
                            (0.0, (0.2, 'record'))),),
               description='first-order lag of the speed measurement',
               min_fraction=(('tau_s', (1.0, 'lag_floor')),)),
    EffectSpec('speed_quantization', 'y = q round(w_m / q); w_m = the mean of w over '
               '(t[k-1], t[k]] if counted else w(t[k])',
               (EffectParam('q', 'rad/s per count', 0.3, 0.0, 1e3, 'speed'),
                EffectParam('counted', '-', 1.0, 0.0, 1.0, 'one')),
               description='encoder counts per sample period: the speed sits on a grid; '
               'a count difference is the mean speed over the sample period (counted = 1), '
               'a quantised speed sensor reads it at the sample (counted = 0)',
               category='measurement', channel='speed'),
    EffectSpec('current_quantization', 'y_i = q_i round(i / q_i)',
               (EffectParam('q_i', 'A per count', 0.01, 0.0, 1e3, 'current'),),
               kinds=('voltage',),
               description='current ADC resolution: the current sits on a grid',
               category='measurement', channel='current'),
    EffectSpec('resistance_drift', 'R = R_m + dR, d(dR)/dt = k_h i^2 (1 + dR / R_m) - '
               'dR / tau_th (copper loss i^2 R, averaged over each interval)',
               (EffectParam('k_h', 'Ohm/(A^2 s)', 0.02, 0.0, 1e3, 'heating', (0.03, 10.0, 5),
                            (0.0, 1000.0)),
                EffectParam('tau_th', 's', 20.0, 0.1, 1e5, 'record', (0.05, 0.8, 3),
                            ((1.0, 'sample'), 10.0))), kinds=('voltage',),
               description='armature heating raises the resistance',
               min_fraction=(('tau_th', (0.03, 'record')),)),
    EffectSpec('resonance', 'two-mass shaft: J_m = J/(1+r), J_l = J r/(1+r), '
               'k_s = J_l (2 pi f_r)^2, c_s = 2 zeta sqrt(k_s J_l)',
               (EffectParam('r', '-', 1.0, 0.01, 100.0, 'one', (0.25, 4.0, 3)),
                EffectParam('f_r', 'Hz', 4.0, 0.01, 1e3, 'per_sample',
                            ((3.0, 'per_record'), 0.2, 10), ((3.0, 'per_record'), 0.5)),
                EffectParam('zeta', '-', 0.05, 0.0, 5.0, 'one', (0.03, 0.15, 2))),
               description='a compliant shaft between motor and load'),
    EffectSpec('start_latency', 'V_eff = 0 for d samples after the input leaves zero; '
               'V_eff = V otherwise',
               (EffectParam('d', 'samples', 10, 0, 500, 'one', (1, (1.0, 'max_delay'), 0),
                            (), 'integer'),),
               description="the drive's enable latency: it applies nothing for a while "
               'after the command leaves zero (a motor controller arming on its first '
               'non-zero frame), and follows at once afterwards', simulation_only=True),
)}
"""The catalogue of named effects; parameter ranges are the allowed ranges."""


def validate_effects(effects: Mapping[str, Mapping[str, float] | None] | None,
                     input_kind: str = 'voltage') -> dict[str, dict[str, float]]:
    """Check an ``{effect: {param: value}}`` mapping against :data:`EFFECTS`.

    Missing parameters take their defaults. Returns a new, complete dict.
    """
    out: dict[str, dict[str, float]] = {}
    for name, values in (effects or {}).items():
        if name not in EFFECTS:
            raise ConfigError(f'unknown effect {name!r}; known effects: {sorted(EFFECTS)}')
        spec = EFFECTS[name]
        if input_kind not in spec.kinds:
            raise ConfigError(f'effect {name!r} does not apply to a {input_kind}-input plant')
        values = dict(values or {})
        unknown = set(values) - {p.name for p in spec.params}
        if unknown:
            raise ConfigError(f'effect {name!r} has no parameter(s) {sorted(unknown)}; '
                              f'it takes {[p.name for p in spec.params]}')
        full: dict[str, float] = {}
        for p in spec.params:
            v = float(values.get(p.name, p.default))
            if not (math.isfinite(v) and p.low <= v <= p.high):
                raise ConfigError(f'effect {name}.{p.name} = {v} is outside '
                                  f'[{p.low}, {p.high}] {p.unit}')
            full[p.name] = v
        out[name] = full
    return out


def parse_effect_args(items: Iterable[str] | None) -> dict[str, dict[str, float]]:
    """Parse CLI items ``NAME`` or ``NAME=VALUE`` or ``NAME.PARAM=VALUE`` into effects.

    ``NAME=VALUE`` sets the effect's first parameter.
    """
    effects: dict[str, dict[str, float]] = {}
    for item in items or ():
        key, _, value = item.partition('=')
        name, _, pname = key.partition('.')
        if name not in EFFECTS:
            raise ConfigError(f'unknown effect {name!r}; known effects: {sorted(EFFECTS)}')
        entry = effects.setdefault(name, {})
        if value:
            pname = pname or EFFECTS[name].params[0].name
            try:
                entry[pname] = float(value)
            except ValueError:
                raise ConfigError(f'effect value {item!r} is not a number') from None
    return effects
