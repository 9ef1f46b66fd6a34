"""Armature heating: the resistance rises with the copper loss and cools back."""

import numpy as np

from motor_id.effects.spec import (
    Confusion,
    EffectParam,
    EffectSpec,
    ElectricalTerm,
    KernelArg,
)


def heating_regressor(t: np.ndarray, i: np.ndarray, tau: float) -> np.ndarray:
    """First-order lag of i^2 from zero (a winding that starts cold) times i."""
    from scipy.signal import lfilter
    dt = float(np.mean(np.diff(t)))
    a = np.exp(-dt / tau)
    h = lfilter([1.0 - a], [1.0, -a], i * i)
    return h * i


def _columns(t: np.ndarray, u: np.ndarray, i: np.ndarray) -> list:
    T = float(t[-1] - t[0])
    return [(f * T, heating_regressor(t, i, f * T)) for f in (0.05, 0.1, 0.2, 0.4, 0.8, 1.6)]


def _start(value: float | None, coef: float) -> dict[str, float]:
    # the heating regressor has unit DC gain: dR = k_h tau_th h, so coef = k_h tau_th
    return {} if value is None else {'k_h': coef / value, 'tau_th': value}


SPEC = EffectSpec(
    'resistance_drift', 'R = R_m + dR, d(dR)/dt = k_h i^2 (1 + dR / R_m) - dR / tau_th '
    '(copper loss i^2 R, averaged over each interval)',
    (EffectParam('k_h', 'Ohm/(A^2 s)', 0.02, 0.0, 1e3, 'heating', (0.03, 10.0, 5),
                 (0.0, 1000.0)),
     EffectParam('tau_th', 's', 20.0, 0.1, 1e5, 'record', (0.05, 0.8, 3),
                 ((1.0, 'sample'), 10.0))), kinds=('voltage',),
    description='armature heating raises the resistance',
    min_fraction=(('tau_th', (0.03, 'record')),),
    kernel_args=(KernelArg('k_h', 'k_h'), KernelArg('tau_th', 'tau_th', 1.0)),
    heating=True,
    electrical_term=ElectricalTerm(_columns, _start),
    confused_with=(
        Confusion('brush_drop', 'measure the current over a long run at a constant load: '
                  'heating makes the voltage error grow with the integral of i^2, a brush '
                  'drop is there at once'),
        Confusion('dead_zone', 'measure the current and repeat the same steps cold and '
                  'warm: heating changes the response over time, a dead zone does not')))
