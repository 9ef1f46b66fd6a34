"""An independent second simulator of a DC motor on a serial card: seeded hidden-effect cases.

The motor, amplifier, integrator and sensors are :mod:`motor_id.testing.independent_physics`,
written from the equations with no motor_id code (only :func:`to_recording` imports
``motor_id.recording.Recording``, inside the function), so the project's effect detectors
can be checked on data they were not tuned on. This module draws the cases: a motor of a
class, an effect with a magnitude in its detectable range, an excitation that reveals it,
the sample period, the record length and the noise.

Detectable ranges drawn by :func:`make_case`, relative to the case's motor and excitation
(A: excitation amplitude, stall = K A / R0, w_nl = K A / (R0 B + K^2),
tau_m = J R0 / (R0 B + K^2), T: sample period):

=====================  ===============================================================
coulomb_friction       T_c in [0.01, 0.05] x stall, break-away T_s = T_c x [1.1, 1.6]
load_torque            |T_L| in [0.01, 0.05] x stall, either sign
quadratic_load         k_q w_nl^2 in [0.03, 0.15] x stall
brush_drop             V_b in [0.02, 0.08] x A
dead_zone              V_dz in [0.05, 0.2] x A
voltage_saturation     V_max in [0.5, 0.85] x max |command|
input_delay            d = round([0.05, 0.3] x tau_m / T), 2 .. 40 samples
sensor_lag             tau_s in [0.1, 0.4] x tau_m, at least 1.5 T
speed_quantization     q = 2 pi / (cpr T) in about [0.02, 0.06] x w_nl (cpr an integer)
current_quantization   q_i in [0.1, 0.4] x std of the true current
resistance_drift       R rises by [0.10, 0.40] x R0 over the record; thermal time
                       constant R_th C_th in [0.2, 0.6] x record length, alpha 0.0039 /K
resonance              r in [0.3, 3], zeta in [0.02, 0.1], f_r log-uniform in
                       [f_hi / 4, f_hi], f_hi = min(0.1 / T, 3 / (2 pi tau_m))
=====================  ===============================================================

Excitations that cannot reveal an effect are not drawn with it: the binary PRBS makes a
static input map (dead zone, saturation) a pure gain, and the unipolar staircase never
reverses the voltage (the current only briefly, when braking), so a brush drop and a dead
zone look alike on it.
"""


from dataclasses import asdict, dataclass, field
import math
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.testing.independent_physics import (
    ALPHA_COPPER,
    amplifier,
    default_n_sub,
    EFFECTS,
    encoder_speed,
    integrate,
    measure,
    Motor,
    simulate,
)

if TYPE_CHECKING:  # the one motor_id import, inside to_recording
    from motor_id.recording import Recording

__all__ = ['ALPHA_COPPER', 'amplifier', 'CaseTruth', 'default_n_sub', 'draw_motor', 'EFFECTS',
           'encoder_speed', 'EXCITATIONS', 'integrate', 'make_case', 'make_excitation',
           'measure', 'Motor', 'MOTOR_CLASSES', 'NOT_REVEALED_BY', 'simulate', 'to_recording']

EXCITATIONS = ('steps', 'prbs', 'multisine', 'staircase')
"""Excitation profiles; 'staircase' is unipolar, the others are bipolar."""

MOTOR_CLASSES = ('industrial', 'servo', 'hobby')

NOT_REVEALED_BY = {
    'dead_zone': ('prbs', 'staircase'),
    'voltage_saturation': ('prbs',),
    'brush_drop': ('staircase', 'prbs'),
}
"""Excitations under which an effect is indistinguishable from a plain gain or offset."""

_CLASS_RANGES = {
    # K [V s/rad], R [Ohm], J [kg m^2], L/R [s], B R / K^2 [-], supply [V], tau_m [s]
    'industrial': {'K': (0.3, 1.2), 'R': (0.1, 1.0), 'J': (1e-2, 1e-1), 'tau_e': (2e-3, 8e-3),
                   'beta': (0.005, 0.05), 'V': (100.0, 300.0), 'tau_m': (0.01, 1.0)},
    'servo': {'K': (0.03, 0.15), 'R': (0.5, 5.0), 'J': (1e-5, 1e-4), 'tau_e': (0.5e-3, 2e-3),
              'beta': (0.005, 0.05), 'V': (24.0, 48.0), 'tau_m': (3e-3, 0.2)},
    'hobby': {'K': (0.005, 0.02), 'R': (2.0, 10.0), 'J': (1e-7, 1e-6), 'tau_e': (0.2e-3, 1e-3),
              'beta': (0.01, 0.1), 'V': (3.0, 12.0), 'tau_m': (3e-3, 0.2)},
}

@dataclass
class CaseTruth:
    """The truth of one generated case (never part of the data)."""

    seed: int
    effect: str
    effect_params: dict
    sim_effects: dict
    motor: dict
    motor_class: str
    excitation: str
    amplitude: float
    sample_period: float
    n_samples: int
    n_sub: int
    noise: dict
    known: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True)
class CaseData:
    """What the user of a generated motor has: the record and the told resistance.

    Attributes
    ----------
    time, input, speed, current : ndarray
        [s], [V], [rad/s], [A].
    known : dict
        ``{'R_m': R0 (1 + r_m_error)}`` [ohm].
    input_kind : str
        ``'voltage'``.
    """

    time: np.ndarray
    input: np.ndarray
    speed: np.ndarray
    current: np.ndarray
    known: dict[str, float]
    input_kind: str = 'voltage'


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_motor(rng: np.random.Generator, motor_class: str) -> Motor:
    """Draw a datasheet-like motor of ``motor_class`` with a seeded random spread.

    Parameters
    ----------
    rng : numpy.random.Generator
    motor_class : {'industrial', 'servo', 'hobby'}

    Returns
    -------
    Motor
        K, R, J, L/R and the supply are log-uniform in the class ranges; draws are
        repeated until tau_m lies in the class range and tau_m >= 4 L/R.
    """
    if motor_class not in _CLASS_RANGES:
        raise ValueError(f'unknown motor class {motor_class!r}; choose from {MOTOR_CLASSES}')
    c = _CLASS_RANGES[motor_class]
    for _ in range(1000):
        K, R, J = (_loguniform(rng, *c[k]) for k in ('K', 'R', 'J'))
        tau_e = _loguniform(rng, *c['tau_e'])
        B = _loguniform(rng, *c['beta']) * K ** 2 / R
        m = Motor(J=J, K=K, R=R, L=tau_e * R, B=B, V_supply=_loguniform(rng, *c['V']),
                  motor_class=motor_class)
        if c['tau_m'][0] <= m.tau_m <= c['tau_m'][1] and m.tau_m >= 4 * tau_e:
            return m
    raise RuntimeError(f'could not draw a {motor_class} motor')  # pragma: no cover


# ---------------------------------------------------------------------------- excitations

def _prbs_bits(n_bits: int, rng: np.random.Generator) -> np.ndarray:
    """Maximal-length 9-bit LFSR sequence (x^9 + x^5 + 1) from a random non-zero state."""
    reg = int(rng.integers(1, 512))
    bits = np.empty(n_bits)
    for k in range(n_bits):
        b = ((reg >> 8) ^ (reg >> 4)) & 1
        bits[k] = reg & 1
        reg = ((reg << 1) | b) & 0x1FF
    return bits


def make_excitation(kind: str, n_samples: int, sample_period: float, amplitude: float,
                    tau_m: float, rng: np.random.Generator) -> np.ndarray:
    """A command profile of this simulator's own.

    Parameters
    ----------
    kind : {'steps', 'prbs', 'multisine', 'staircase'}
        'steps': steps of random height in [0.3, 1] A alternating +, rest, -, rest, each
        held 3 to 10 tau_m; 'prbs': +-A, one bit per ~tau_m / 2; 'multisine': 12
        log-spaced sines with random phases between ~1 / record and ~1 / tau_m, peak A;
        'staircase': unipolar 0 -> A in 5 levels and back down, each held 5 to 15 tau_m,
        repeated.
    n_samples : int
    sample_period : float
        [s]
    amplitude : float
        A [V].
    tau_m : float
        Mechanical time constant [s] (sets the time scales).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray
        Command per sample [V].
    """
    n, T, A = int(n_samples), float(sample_period), float(amplitude)
    tau_n = max(tau_m / T, 1.0)  # tau_m in samples
    if kind == 'steps':
        u = np.empty(n)
        k, phase = 0, 0
        while k < n:
            hold = int(np.clip(rng.uniform(3, 10) * tau_n, 5, max(n // 8, 5)))
            level = (1.0, 0.0, -1.0, 0.0)[phase % 4] * A * rng.uniform(0.3, 1.0)
            u[k:k + hold] = level
            k += hold
            phase += 1
        return u
    if kind == 'prbs':
        bit = int(np.clip(round(0.5 * tau_n), 1, max(n // 64, 1)))
        bits = _prbs_bits(n // bit + 1, rng)
        return A * (2.0 * np.repeat(bits, bit)[:n] - 1.0)
    if kind == 'multisine':
        t = np.arange(n) * T
        f_lo = 2.0 / (n * T)
        f_hi = min(0.2 / T, 2.0 / (2.0 * math.pi * tau_m))
        f_hi = max(f_hi, 4 * f_lo)
        cycles = np.unique(np.round(np.geomspace(f_lo, f_hi, 12) * n * T))
        phases = rng.uniform(0.0, 2.0 * math.pi, cycles.size)
        u = np.sin(2.0 * math.pi * np.outer(t, cycles / (n * T)) + phases).sum(axis=1)
        return A * u / np.max(np.abs(u))
    if kind == 'staircase':
        levels = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25]) * A
        hold = int(np.clip(rng.uniform(5, 15) * tau_n, 10, max(n // 16, 10)))
        return levels[(np.arange(n) // hold) % levels.size]
    raise ValueError(f'unknown excitation {kind!r}; choose from {EXCITATIONS}')


# --------------------------------------------------------------------------- case drawing

def _draw_effect(name: str, rng: np.random.Generator, motor: Motor, amplitude: float,
                 command: np.ndarray, T: float,
                 n_sub: int) -> tuple[dict[str, float], dict[str, float]]:
    """Return (simulator parameters, analysis parameters) of effect ``name``."""
    stall = motor.K * amplitude / motor.R
    w_nl = motor.no_load_speed(amplitude)
    tau_m = motor.tau_m
    if name == 'coulomb_friction':
        T_c = _loguniform(rng, 0.01, 0.05) * stall
        T_s = T_c * float(rng.uniform(1.1, 1.6))
        return {'T_c': T_c, 'T_s': T_s}, {'T_c': T_c, 'T_s': T_s}
    if name == 'load_torque':
        T_L = float(rng.choice([-1.0, 1.0])) * _loguniform(rng, 0.01, 0.05) * stall
        return {'T_L': T_L}, {'T_L': T_L}
    if name == 'quadratic_load':
        k_q = _loguniform(rng, 0.03, 0.15) * stall / w_nl ** 2
        return {'k_q': k_q}, {'k_q': k_q}
    if name == 'brush_drop':
        V_b = _loguniform(rng, 0.02, 0.08) * amplitude
        return {'V_b': V_b}, {'V_b': V_b}
    if name == 'dead_zone':
        V_dz = _loguniform(rng, 0.05, 0.2) * amplitude
        return {'V_dz': V_dz}, {'V_dz': V_dz}
    if name == 'voltage_saturation':
        V_max = float(rng.uniform(0.5, 0.85)) * float(np.max(np.abs(command)))
        return {'V_max': V_max}, {'V_max': V_max}
    if name == 'input_delay':
        d = int(np.clip(round(_loguniform(rng, 0.05, 0.3) * tau_m / T), 2, 40))
        return {'d': d}, {'d': float(d)}
    if name == 'sensor_lag':
        tau_s = max(_loguniform(rng, 0.1, 0.4) * tau_m, 1.5 * T)
        return {'tau_s': tau_s}, {'tau_s': tau_s}
    if name == 'speed_quantization':
        q_target = _loguniform(rng, 0.02, 0.06) * w_nl
        cpr = max(1, int(round(2.0 * math.pi / (q_target * T))))
        q = 2.0 * math.pi / (cpr * T)
        return {'cpr': cpr}, {'q': q, 'cpr': cpr}
    if name == 'current_quantization':
        clean = integrate(motor, command, T, {}, n_sub)
        q_i = _loguniform(rng, 0.1, 0.4) * float(np.std(clean['current']))
        return {'q_i': q_i}, {'q_i': q_i}
    if name == 'resistance_drift':
        return _draw_heating(rng, motor, command, T, n_sub)
    if name == 'resonance':
        f_hi = min(0.1 / T, 3.0 / (2.0 * math.pi * tau_m))
        f_r = _loguniform(rng, f_hi / 4.0, f_hi)
        r = _loguniform(rng, 0.3, 3.0)
        zeta = _loguniform(rng, 0.02, 0.1)
        return {'r': r, 'f_r': f_r, 'zeta': zeta}, {'r': r, 'f_r': f_r, 'zeta': zeta}
    raise ValueError(f'unknown effect {name!r}; choose from {EFFECTS}')


def _draw_heating(rng: np.random.Generator, motor: Motor, command: np.ndarray, T: float,
                  n_sub: int) -> tuple[dict[str, float], dict[str, float]]:
    """Thermal R_th, C_th giving a drawn resistance rise over the record (two passes)."""
    rise = float(rng.uniform(0.10, 0.40))
    n_sub = default_n_sub(motor, T, {'resistance_drift': {}})  # the final run's sub-steps
    length = command.size * T
    tau_th = float(rng.uniform(0.2, 0.6)) * length
    clean = integrate(motor, command, T, {}, n_sub)
    power = max(float(np.mean(clean['current'] ** 2)) * motor.R, 1e-300)
    R_th = rise / (ALPHA_COPPER * power * (1.0 - math.exp(-length / tau_th)))
    sim = {'alpha': ALPHA_COPPER, 'R_th': R_th, 'C_th': tau_th / R_th}
    for attempt in range(4):  # correct for the feedback of R on the power
        got = float(integrate(motor, command, T, {'resistance_drift': sim},
                              n_sub)['resistance'][-1]) / motor.R - 1.0
        if abs(got - rise) <= 0.005 * rise or attempt == 3:
            break
        sim['R_th'] *= rise / max(got, 1e-12)
        sim['C_th'] = tau_th / sim['R_th']
    analysis = {'k_h': ALPHA_COPPER * motor.R ** 2 / sim['C_th'], 'tau_th': tau_th,
                'rise_target': rise, 'rise': got,
                'T_rise_K': got / ALPHA_COPPER}
    return sim, analysis


def make_case(seed: int, effect: str | None = None, motor_class: str | None = None,
              sample_period: float | None = None, n_samples: int | None = None,
              noise: float | tuple[float, float] = 0.005, r_m_error: float = 0.0,
              excitation: str | None = None) -> tuple[CaseData, CaseTruth]:
    """Generate one seeded case: motor, excitation, at most one effect, noise.

    Parameters
    ----------
    seed : int
        Everything random follows from ``np.random.default_rng(seed)``.
    effect : str, optional
        One of :data:`EFFECTS`, ``'none'`` for a clean case, or None to draw one.
    motor_class : {'industrial', 'servo', 'hobby'}, optional
        Drawn when omitted.
    sample_period : float, optional
        [s]; drawn log-uniform in [1 ms, min(20 ms, max(1 ms, tau_m / 2))] when omitted.
    n_samples : int, optional
        Drawn log-uniform in [2000, 25000] when omitted.
    noise : float or (float, float)
        Speed and current white-noise std as fractions of each channel's std.
    r_m_error : float
        Relative error of the resistance the user is told (an ohmmeter's error).
    excitation : str, optional
        One of :data:`EXCITATIONS`; drawn among those that reveal the effect.

    Returns
    -------
    data : CaseData
        What a user of the motor would have (``known``: ``R_m`` = R0 (1 + r_m_error)).
    truth : CaseTruth
    """
    if sample_period is not None and not 0.0 < sample_period <= 1.0:
        raise ValueError(f'sample_period must be in (0, 1] s, got {sample_period}')
    if n_samples is not None and int(n_samples) < 2:
        raise ValueError(f'n_samples must be >= 2, got {n_samples}')
    if np.any(np.asarray(noise) < 0):
        raise ValueError(f'noise fractions must be >= 0, got {noise}')
    if motor_class is not None and motor_class not in MOTOR_CLASSES:
        raise ValueError(f'unknown motor class {motor_class!r}; choose from {MOTOR_CLASSES}')
    rng = np.random.default_rng(seed)
    if effect is None:
        effect = str(rng.choice(EFFECTS))
    if effect != 'none' and effect not in EFFECTS:
        raise ValueError(f'unknown effect {effect!r}; choose from {EFFECTS} or none')
    if motor_class is None:
        motor_class = str(rng.choice(MOTOR_CLASSES))
    motor = draw_motor(rng, motor_class)
    if sample_period is None:
        hi = min(0.02, max(1e-3, motor.tau_m / 2.0))
        sample_period = _loguniform(rng, 1e-3, hi) if hi > 1e-3 else 1e-3
    if n_samples is None:
        n_samples = int(round(_loguniform(rng, 2000, 25000)))
    allowed = [e for e in EXCITATIONS if e not in NOT_REVEALED_BY.get(effect, ())]
    if excitation is None:
        excitation = str(rng.choice(allowed))
    if excitation not in allowed:
        raise ValueError(f'excitation {excitation!r} cannot reveal {effect!r}; use {allowed}')
    amplitude = float(rng.uniform(0.3, 0.8)) * motor.V_supply
    command = make_excitation(excitation, n_samples, sample_period, amplitude, motor.tau_m,
                              rng)
    n_sub = default_n_sub(motor, sample_period)
    sim_effects: dict[str, dict[str, float]] = {}
    effect_params: dict[str, float] = {}
    if effect != 'none':
        sim_params, effect_params = _draw_effect(effect, rng, motor, amplitude, command,
                                                 sample_period, n_sub)
        sim_effects = {effect: sim_params}
        n_sub = default_n_sub(motor, sample_period, sim_effects)
    levels = _noise_levels(noise)
    speed, current, _ = simulate(motor, command, sample_period, sim_effects, levels, rng, n_sub)
    t = np.arange(n_samples) * sample_period
    known = {'R_m': motor.R * (1.0 + r_m_error)}
    data = CaseData(t, command, speed, current, dict(known))
    truth = CaseTruth(seed=int(seed), effect=effect, effect_params=effect_params,
                      sim_effects=sim_effects, motor=motor.to_dict(), motor_class=motor_class,
                      excitation=excitation, amplitude=amplitude,
                      sample_period=float(sample_period), n_samples=int(n_samples),
                      n_sub=int(n_sub), noise={'speed': levels[0], 'current': levels[1]},
                      known=known)
    return data, truth


def _noise_levels(noise: float | tuple[float, float]) -> tuple[float, float]:
    """``(speed, current)`` noise fractions from one value or a pair."""
    if isinstance(noise, (int, float, np.integer, np.floating)):
        return float(noise), float(noise)
    speed, current = noise
    return float(speed), float(current)


def to_recording(data: CaseData) -> 'Recording':
    """Build a ``motor_id.recording.Recording`` from the data of :func:`make_case`."""
    from motor_id.recording import Recording
    meta = {'source': 'motor_id.testing.independent_sim', 'known': dict(data.known)}
    return Recording(data.time, data.input, data.speed, data.current, data.input_kind, meta)


def main() -> None:
    """Print a timing table: one 25,000-sample simulation per class and sample period."""
    import time
    make_case(0, effect='none', n_samples=2000)  # compile the kernel first
    print(f'{"class":<11}{"T [ms]":>7}{"n_sub":>7}{"simulate [s]":>14}')
    for motor_class in MOTOR_CLASSES:
        for T in (1e-3, 5e-3, 20e-3):
            data, truth = make_case(0, effect='coulomb_friction', motor_class=motor_class,
                                    sample_period=T, n_samples=25000)
            motor = Motor.from_dict(truth.motor)
            t0 = time.perf_counter()
            simulate(motor, data.input, T, truth.sim_effects, rng=0, n_sub=truth.n_sub)
            elapsed = time.perf_counter() - t0
            print(f'{motor_class:<11}{T * 1e3:>7.0f}{truth.n_sub:>7d}{elapsed:>14.3f}')


if __name__ == '__main__':
    main()
