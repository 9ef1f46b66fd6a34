"""Seeded hidden-effect cases: a perturbed paper motor, one named effect, an excitation, noise.

Each case draws, from its own seed: an effect of :data:`motor_id.effects.EFFECTS` (or none),
a magnitude inside that effect's *detectable range*, a motor (the paper's motor with every
parameter perturbed, K_T = K_b as SI units demand), an excitation profile and its
amplitude. It simulates the voltage-driven motor with speed and current measured and adds
white noise. The truth comes back separately in a :class:`HiddenCase` and is never
written into the data: the recording's metadata name only the generator and the seed.

Detectable ranges are stated relative to the case's own motor and excitation, so that
every drawn effect changes the outputs by clearly more than the noise:

=====================  ===============================================================
coulomb_friction       T_c in [0.005, 0.05] x stall torque K_T A / R_m
load_torque            |T_L| in [0.005, 0.05] x stall torque, either sign
quadratic_load         k_q w_nl^2 in [0.02, 0.15] x stall torque (w_nl: no-load speed)
brush_drop             V_b in [0.01, 0.08] x amplitude A
dead_zone              V_dz in [0.03, 0.2] x A
input_delay            d in 2 .. 8 samples
voltage_saturation     V_max in [0.5, 0.85] x A
sensor_lag             tau_s in [0.05, 0.3] x mechanical time constant J R_m / K_T^2
speed_quantization     q in [0.02, 0.06] x w_nl
current_quantization   q_i in [0.1, 0.4] x std of the true current
resistance_drift       tau_th in [0.2, 0.6] x record length, steady rise dR in
                       [0.2, 1.0] x R_m at the record's RMS current
resonance              r in [0.3, 3], f_r in [0.5, 5] Hz, zeta in [0.02, 0.1]
=====================  ===============================================================

Measurement effects (quantisation) act after the noise, as a sensor's counter or ADC
does: the reported values sit exactly on the grid.

The resistance a user knows comes from an ohmmeter: ``case.known['R_m']`` is the true
R_m off by a seeded 2 to 5 %, either sign (``r_m_error=None``; pass a number to fix
the relative error, 0 for the true value).

Some excitations cannot reveal an effect at all, and cases with it draw from the other
profiles: a binary input (PRBS) only ever takes two values, so a static input map (dead
zone, saturation) acts on it as a plain gain; the paper's steps only ever go up, so the
current never reverses and a brush drop (``V_b sgn(i)``) and a dead zone
(``V_dz sgn(V)``) are the same term; under a binary input the current's sign follows the
input's except for short reversal transients, so a brush drop is a plain input gain
there, too.
"""

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from motor_id.effects import EFFECTS, on_grid
from motor_id.errors import ConfigError
from motor_id.excitation import make_excitation, PROFILES
from motor_id.model import MotorParams, PAPER_MOTOR, Plant
from motor_id.recording import Recording
from motor_id.simulate import simulate_batch

VOLTAGE_EFFECTS = tuple(n for n, e in EFFECTS.items() if 'voltage' in e.kinds and not e.mechanism
                        and not e.extends and not e.simulation_only)
"""Effects the generator hides: every voltage-plant effect except the refinements of
another (asymmetric, Stribeck, static friction) and the drive's start latency, which
only the simulation-error stage of a record with a position tries
(:mod:`motor_id.analysis.simulation_fit`)."""
"""Effects the generator can hide (all apply to the voltage-driven motor)."""

NOT_REVEALED_BY = {
    'dead_zone': ('prbs', 'paper_steps'),
    'voltage_saturation': ('prbs',),
    'brush_drop': ('paper_steps', 'prbs'),
}
"""Excitations under which an effect is identical to another one (see the module notes)."""


@dataclass
class HiddenCase:
    """The truth of one generated case (kept apart from the data)."""

    seed: int
    effect: str
    effect_params: dict
    motor: dict
    excitation: str
    amplitude: float
    sample_period: float
    n_samples: int
    noise: dict
    known: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def perturbed_motor(rng: np.random.Generator, spread: float = 0.25) -> MotorParams:
    """The paper's motor with each parameter scaled by ``exp(U(-spread, spread))``.

    K_T and K_b are equal (one constant in SI units); B spreads twice as wide.
    """
    p = PAPER_MOTOR

    def f(s: float = spread) -> float:
        return float(np.exp(rng.uniform(-s, s)))

    k = 0.65 * f(0.8 * spread)
    return MotorParams(J=p.J * f(), K_T=k, K_b=k, B=p.B * f(2 * spread), L_m=p.L_m * f(),
                       R_m=p.R_m * f(0.8 * spread))


def effect_magnitude(name: str, rng: np.random.Generator, motor: MotorParams,
                     amplitude: float, t: np.ndarray, u: np.ndarray) -> dict[str, float]:
    """Draw the parameters of effect ``name`` inside its detectable range.

    Parameters
    ----------
    name : str
        An effect of :data:`VOLTAGE_EFFECTS`.
    rng : numpy.random.Generator
    motor : MotorParams
    amplitude : float
        Input amplitude A [V].
    t, u : ndarray
        Times and input of the case (for the record length and RMS current).

    Returns
    -------
    dict
        ``{param: value}``.
    """
    K, R, B, J = motor.K_T, motor.R_m, motor.B, motor.J
    stall = K * amplitude / R
    w_nl = K * amplitude / (R * B + K * motor.K_b)
    if name == 'coulomb_friction':
        return {'T_c': _loguniform(rng, 0.005, 0.05) * stall}
    if name == 'load_torque':
        return {'T_L': float(rng.choice([-1.0, 1.0])) * _loguniform(rng, 0.005, 0.05) * stall}
    if name == 'quadratic_load':
        return {'k_q': _loguniform(rng, 0.02, 0.15) * stall / w_nl ** 2}
    if name == 'brush_drop':
        return {'V_b': _loguniform(rng, 0.01, 0.08) * amplitude}
    if name == 'dead_zone':
        return {'V_dz': _loguniform(rng, 0.03, 0.2) * amplitude}
    if name == 'input_delay':
        return {'d': float(rng.integers(2, 9))}
    if name == 'voltage_saturation':
        return {'V_max': float(rng.uniform(0.5, 0.85)) * amplitude}
    if name == 'sensor_lag':
        tau_m = J * R / (K * motor.K_b)
        dt = float(np.median(np.diff(t)))
        return {'tau_s': max(_loguniform(rng, 0.05, 0.3) * tau_m, 1.5 * dt)}
    if name == 'speed_quantization':
        return {'q': _loguniform(rng, 0.02, 0.06) * w_nl}
    if name == 'current_quantization':
        out = simulate_batch(motor.to_dict(), t, u, 'voltage')
        return {'q_i': _loguniform(rng, 0.1, 0.4) * float(np.std(out['current'][0]))}
    if name == 'resistance_drift':
        out = simulate_batch(motor.to_dict(), t, u, 'voltage')
        i_rms = float(np.sqrt(np.mean(out['current'][0] ** 2))) or 1.0
        tau_th = float(rng.uniform(0.2, 0.6)) * float(t[-1] - t[0])
        dR = _loguniform(rng, 0.2, 1.0) * R
        return {'k_h': dR / (i_rms ** 2 * tau_th), 'tau_th': tau_th}
    if name == 'resonance':
        return {'r': _loguniform(rng, 0.3, 3.0), 'f_r': _loguniform(rng, 0.5, 5.0),
                'zeta': _loguniform(rng, 0.02, 0.1)}
    raise ConfigError(f'the generator cannot hide {name!r}; choose from {VOLTAGE_EFFECTS}')


def make_case(seed: int, effect: str | None = None, excitation: str | None = None,
              n_samples: int = 4000, sample_period: float = 0.01,
              noise: tuple[float, float] = (0.005, 0.01),
              r_m_error: float | None = None) -> tuple[Recording, HiddenCase]:
    """Generate one case.

    Parameters
    ----------
    seed : int
        Everything random about the case follows from it.
    effect : str, optional
        An effect name to hide, ``'none'`` for a clean case, or None to draw one of
        :data:`VOLTAGE_EFFECTS` at random.
    excitation : str, optional
        A profile of :data:`motor_id.excitation.PROFILES`; drawn when omitted.
    n_samples : int
    sample_period : float
        [s]
    noise : (float, float)
        Speed and current noise standard deviations as fractions of each channel's
        standard deviation.
    r_m_error : float, optional
        Relative error of the known R_m; None draws 2 to 5 %, either sign, from the seed
        (after everything else, so the data do not depend on it).

    Returns
    -------
    rec : Recording
        Voltage, speed and current, without the truth.
    case : HiddenCase
        The truth; ``case.known`` holds what a user would know (R_m).
    """
    rng = np.random.default_rng(seed)
    if effect is None:
        effect = str(rng.choice(VOLTAGE_EFFECTS))
    if effect != 'none' and effect not in VOLTAGE_EFFECTS:
        raise ConfigError(f'unknown effect {effect!r}; choose from {VOLTAGE_EFFECTS} or none')
    motor = perturbed_motor(rng)
    if excitation is None:
        allowed = [p for p in PROFILES if p not in NOT_REVEALED_BY.get(effect, ())]
        excitation = str(rng.choice(allowed))
    if excitation not in PROFILES:
        raise ConfigError(f'unknown excitation {excitation!r}; choose from {PROFILES}')
    amplitude = float(rng.uniform(6.0, 12.0))
    t = np.arange(n_samples) * sample_period
    u = make_excitation(excitation, t, amplitude, int(rng.integers(1 << 30)))
    params = {} if effect == 'none' else effect_magnitude(effect, rng, motor, amplitude, t, u)
    effects = {} if effect == 'none' else {effect: params}
    plant = Plant(motor, 'voltage', effects)
    speed, current = _measure(plant, t, u, noise, rng)
    if r_m_error is None:
        r_m_error = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.02, 0.05))
    meta = {'source': 'motor_id.testing.hidden', 'seed': int(seed)}
    rec = (Recording(t, u, speed, input_kind='voltage', meta=meta) if current is None
           else Recording(t, u, speed, current, 'voltage', meta))
    case = HiddenCase(int(seed), effect, params, motor.to_dict(), excitation, amplitude,
                      sample_period, n_samples, {'speed': noise[0], 'current': noise[1]},
                      {'R_m': motor.R_m * (1.0 + r_m_error), 'R_m_error': r_m_error})
    return rec, case


def _measure(plant: Plant, t: np.ndarray, u: np.ndarray, noise: tuple[float, float],
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulated speed and current with white noise, then the sensors' grids."""
    dynamic = {e: v for e, v in plant.effects.items() if EFFECTS[e].category == 'dynamic'}
    out = simulate_batch(plant.params.to_dict(), t, u, 'voltage', 'zoh', dynamic)
    speed, current = out['speed'][0], out['current'][0]
    n = t.size
    speed = speed + noise[0] * np.std(speed) * rng.standard_normal(n)
    current = current + noise[1] * np.std(current) * rng.standard_normal(n)
    if 'speed_quantization' in plant.effects:
        speed = on_grid(speed, plant.effects['speed_quantization']['q'])
    if 'current_quantization' in plant.effects:
        current = on_grid(current, plant.effects['current_quantization']['q_i'])
    return speed, current
