"""The physics of the independent simulator: a DC motor on a serial card, from the equations.

It shares no code with ``motor_id`` (numpy and numba only), so the project's effect
detectors can be checked on data they were not tuned on; the seeded cases drawn on it
are :mod:`motor_id.testing.independent_sim`. SI units throughout: speed w [rad/s],
current i [A], shaft angle theta [rad], winding temperature rise dT [K], voltage [V],
torque [N m], time [s].

Continuous model (one mass, or two masses with ``resonance``)::

    J dw/dt     = K i - B w - T_f - T_L - k_q w |w|
    L di/dt     = V_motor - R(dT) i - K w - V_b sgn(i)
    dtheta/dt   = w
    C_th ddT/dt = i^2 R(dT) - dT / R_th,      R(dT) = R0 (1 + alpha dT)
    tau_s dy/dt = w - y                       (speed sensor lag)

Friction is stick-slip: at w = 0 the shaft stays stuck while the drive torque
``|K i - T_L - spring|`` is at most the break-away torque T_s; moving, T_f = T_c sgn(w)
with T_c <= T_s. The brush drop is treated the same way: at i = 0 no current flows while
``|V - K w| <= V_b``. The events (w or i crossing zero, the stuck shaft breaking away,
the blocked brushes starting to conduct) are located inside each RK4 sub-step by regula
falsi with re-integration from the sub-step's start; the modes are then decided anew, so
nothing chatters and the integrator keeps its fourth order through the events. The
amplifier holds each sample's command (zero-order hold), delays it by ``d`` whole samples,
clips it at +-V_max and only then applies its dead zone V_dz. With ``resonance`` the
motor (J_m = J / (1 + r), with B and friction) drives the load (J_l = J r / (1 + r), with
the load torques) through a spring k_s = J_l (2 pi f_r)^2 and damper
c_s = 2 zeta sqrt(k_s J_l); the motor-side speed is measured. Samples are the states at
the sample instants, before that sample's command acts. The encoder speed is the count
difference over the past period, i.e. the mean speed of that period on a grid of
q = 2 pi / (cpr T).
"""

from collections.abc import Mapping
from dataclasses import asdict, dataclass
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

try:  # numba is a dependency of the project; the plain-Python path is only a fallback
    import numba
    _jit = numba.njit(cache=False, nogil=True)
except ImportError:  # pragma: no cover
    def _jit(f: Any) -> Any:
        return f

ALPHA_COPPER = 0.0039
"""Temperature coefficient of copper resistance [1/K]."""

EFFECTS = ('coulomb_friction', 'load_torque', 'quadratic_load', 'brush_drop', 'dead_zone',
           'voltage_saturation', 'input_delay', 'sensor_lag', 'speed_quantization',
           'current_quantization', 'resistance_drift', 'resonance')
"""Effect names this simulator can hide (the analysis' names where it has them)."""

# indices of the state vector and of the parameter vector of the integrator kernel
_W, _I, _TH, _DT, _WL, _PHI, _Y = range(7)
_NX = 7
(_P_JM, _P_JL, _P_KS, _P_CS, _P_RES, _P_B, _P_K, _P_R0, _P_L, _P_ALPHA, _P_CTH, _P_RTH,
 _P_TS, _P_TC, _P_TL, _P_KQ, _P_VB, _P_TAUS) = range(18)
_NP = 18
_MAX_EVENTS = 8


@dataclass
class Motor:
    """Nameplate of one DC motor (K_T = K_b = K in SI units).

    Attributes: J [kg m^2], K [N m/A = V s/rad], R [Ohm] (cold), L [H], B [N m s/rad],
    V_supply [V], motor_class.
    """

    J: float
    K: float
    R: float
    L: float
    B: float
    V_supply: float
    motor_class: str = 'custom'

    @property
    def tau_e(self) -> float:
        """Electrical time constant L / R [s]."""
        return self.L / self.R

    @property
    def tau_m(self) -> float:
        """Mechanical time constant J R / (R B + K^2) [s]."""
        return self.J * self.R / (self.R * self.B + self.K ** 2)

    def no_load_speed(self, voltage: float) -> float:
        """Steady no-load speed V K / (R B + K^2) [rad/s] at ``voltage``."""
        return voltage * self.K / (self.R * self.B + self.K ** 2)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the analysis' symbols (J, K_T, K_b, B, L_m, R_m) too."""
        d = asdict(self)
        d.update(K_T=self.K, K_b=self.K, L_m=self.L, R_m=self.R)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> 'Motor':
        """Inverse of :meth:`to_dict` (the analysis' duplicate symbols are ignored)."""
        return cls(**{k: d[k] for k in ('J', 'K', 'R', 'L', 'B', 'V_supply', 'motor_class')})


# ----------------------------------------------------------------------------- amplifier

def amplifier(command: ArrayLike, effects: Mapping[str, Any] | None = None) -> np.ndarray:
    """Terminal voltage from the command: delay d samples, clip at +-V_max, then dead zone.

    Parameters
    ----------
    command : array_like
        Commanded voltage per sample [V] (held over each sample period).
    effects : dict, optional
        ``{'input_delay': {'d': int}, 'voltage_saturation': {'V_max': V},
        'dead_zone': {'V_dz': V}}``, any subset.

    Returns
    -------
    ndarray
        The voltage applied to the motor per sample [V].
    """
    effects = effects or {}
    v = np.asarray(command, dtype=float).copy()
    d = int(effects.get('input_delay', {}).get('d', 0))
    if d > 0:
        v = np.concatenate([np.zeros(min(d, v.size)), v[:max(v.size - d, 0)]])
    if 'voltage_saturation' in effects:
        vmax = float(effects['voltage_saturation']['V_max'])
        v = np.clip(v, -vmax, vmax)
    if 'dead_zone' in effects:
        vdz = float(effects['dead_zone']['V_dz'])
        v = np.where(np.abs(v) <= vdz, 0.0, v - vdz * np.sign(v))
    return v


# ---------------------------------------------------------------------------- integrator

@_jit
def _deriv(x: np.ndarray, v: float, w_stuck: bool, sw: float, i_stuck: bool, si: float,
           p: np.ndarray, dx: np.ndarray) -> None:
    w = x[_W]
    i = x[_I]
    R = p[_P_R0] * (1.0 + p[_P_ALPHA] * x[_DT])
    if i_stuck:
        dx[_I] = 0.0
    else:
        dx[_I] = (v - R * i - p[_P_K] * w - p[_P_VB] * si) / p[_P_L]
    if p[_P_RES] > 0.0:
        wl = x[_WL]
        shaft = p[_P_KS] * x[_PHI] + p[_P_CS] * (w - wl)
        dx[_WL] = (shaft - p[_P_TL] - p[_P_KQ] * wl * abs(wl)) / p[_P_JL]
        dx[_PHI] = w - wl
        load = shaft
    else:
        dx[_WL] = 0.0
        dx[_PHI] = 0.0
        load = p[_P_TL] + p[_P_KQ] * w * abs(w)
    if w_stuck:
        dx[_W] = 0.0
    else:
        dx[_W] = (p[_P_K] * i - p[_P_B] * w - p[_P_TC] * sw - load) / p[_P_JM]
    dx[_TH] = w
    if p[_P_CTH] > 0.0:
        dx[_DT] = (i * i * R - x[_DT] / p[_P_RTH]) / p[_P_CTH]
    else:
        dx[_DT] = 0.0
    if p[_P_TAUS] > 0.0:
        dx[_Y] = (w - x[_Y]) / p[_P_TAUS]
    else:
        dx[_Y] = 0.0


@_jit
def _rk4(x: np.ndarray, v: float, h: float, w_stuck: bool, sw: float, i_stuck: bool,
         si: float, p: np.ndarray, out: np.ndarray, k1: np.ndarray, k2: np.ndarray,
         k3: np.ndarray, k4: np.ndarray, xt: np.ndarray) -> None:
    _deriv(x, v, w_stuck, sw, i_stuck, si, p, k1)
    for j in range(_NX):
        xt[j] = x[j] + 0.5 * h * k1[j]
    _deriv(xt, v, w_stuck, sw, i_stuck, si, p, k2)
    for j in range(_NX):
        xt[j] = x[j] + 0.5 * h * k2[j]
    _deriv(xt, v, w_stuck, sw, i_stuck, si, p, k3)
    for j in range(_NX):
        xt[j] = x[j] + h * k3[j]
    _deriv(xt, v, w_stuck, sw, i_stuck, si, p, k4)
    for j in range(_NX):
        out[j] = x[j] + h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    if p[_P_TAUS] <= 0.0:
        out[_Y] = out[_W]


@_jit
def _sign(a: float) -> float:
    return 1.0 if a > 0.0 else (-1.0 if a < 0.0 else 0.0)


@_jit
def _shaft_drive(x: np.ndarray, p: np.ndarray) -> float:
    """Torque that would accelerate the motor at w = 0, friction excluded [N m]."""
    if p[_P_RES] > 0.0:
        load = p[_P_KS] * x[_PHI] - p[_P_CS] * x[_WL]
    else:
        load = p[_P_TL]
    return p[_P_K] * x[_I] - load


@_jit
def _event_value(kind: int, x: np.ndarray, v: float, sw: float, si: float,
                 p: np.ndarray) -> float:
    """Positive before the event, negative after: 0 w crosses zero, 1 i crosses zero,
    2 the stuck shaft breaks away, 3 the blocked brushes start to conduct."""
    if kind == 0:
        return x[_W] * sw
    if kind == 1:
        return x[_I] * si
    if kind == 2:
        return p[_P_TS] - abs(_shaft_drive(x, p))
    return p[_P_VB] - abs(v - p[_P_K] * x[_W])


@_jit
def _modes(x: np.ndarray, v: float, p: np.ndarray, force_w: float,
           force_i: float) -> tuple[bool, float, bool, float]:
    """Modes of the next piece: (w stuck, sign of w's motion, i stuck, sign of i)."""
    w_stuck = False
    sw = _sign(x[_W])
    if (p[_P_TS] > 0.0 or p[_P_TC] > 0.0) and x[_W] == 0.0:
        drive = _shaft_drive(x, p)
        if force_w != 0.0:
            sw = force_w
        elif abs(drive) <= p[_P_TS]:
            w_stuck = True
            sw = 0.0
        else:
            sw = _sign(drive)
    i_stuck = False
    si = _sign(x[_I])
    if p[_P_VB] > 0.0 and x[_I] == 0.0:
        drive_v = v - p[_P_K] * x[_W]
        if force_i != 0.0:
            si = force_i
        elif abs(drive_v) <= p[_P_VB]:
            i_stuck = True
            si = 0.0
        else:
            si = _sign(drive_v)
    return w_stuck, sw, i_stuck, si


@_jit
def _first_event(x: np.ndarray, xn: np.ndarray, v: float, w_stuck: bool, sw: float,
                 i_stuck: bool, si: float, p: np.ndarray) -> tuple[float, int]:
    """The earliest event between x and xn: (linear estimate of its fraction, kind or -1)."""
    armed = ((p[_P_TS] > 0.0 or p[_P_TC] > 0.0) and not w_stuck,
             p[_P_VB] > 0.0 and not i_stuck, w_stuck, i_stuck)
    frac = 2.0
    kind = -1
    for kk in range(4):
        if not armed[kk]:
            continue
        g1 = _event_value(kk, xn, v, sw, si, p)
        if g1 < 0.0:
            g0 = _event_value(kk, x, v, sw, si, p)
            f = g0 / (g0 - g1) if g0 > 0.0 else 0.0
            if f < frac:
                frac = f
                kind = kk
    return frac, kind


@_jit
def _substep(x: np.ndarray, v: float, h: float, p: np.ndarray, xn: np.ndarray,
             k1: np.ndarray, k2: np.ndarray, k3: np.ndarray, k4: np.ndarray,
             xt: np.ndarray) -> None:
    """Advance x by h in place, locating the events of friction and brushes inside it.

    Each piece runs with fixed modes up to the earliest event (regula falsi on the event
    function, re-integrating from the piece's start), then the modes are decided anew.
    """
    remaining = h
    force_w = 0.0   # direction of a break-away located at the end of the previous piece
    force_i = 0.0
    for event in range(_MAX_EVENTS + 1):
        w_stuck, sw, i_stuck, si = _modes(x, v, p, force_w, force_i)
        force_w = 0.0
        force_i = 0.0
        _rk4(x, v, remaining, w_stuck, sw, i_stuck, si, p, xn, k1, k2, k3, k4, xt)
        frac, kind = _first_event(x, xn, v, w_stuck, sw, i_stuck, si, p)
        if kind < 0 or event == _MAX_EVENTS:
            for j in range(_NX):
                x[j] = xn[j]
            if kind == 0 or kind == 1:
                x[kind] = 0.0
            return
        f_lo, g_lo = 0.0, _event_value(kind, x, v, sw, si, p)
        f_hi, g_hi = 1.0, _event_value(kind, xn, v, sw, si, p)
        f = frac
        for _ in range(3):
            _rk4(x, v, f * remaining, w_stuck, sw, i_stuck, si, p, xn, k1, k2, k3, k4, xt)
            g = _event_value(kind, xn, v, sw, si, p)
            if g > 0.0:
                f_lo, g_lo = f, g
            else:
                f_hi, g_hi = f, g
            if g_lo - g_hi <= 0.0:
                break
            f = f_lo + (f_hi - f_lo) * g_lo / (g_lo - g_hi)
        _rk4(x, v, f * remaining, w_stuck, sw, i_stuck, si, p, xn, k1, k2, k3, k4, xt)
        for j in range(_NX):
            x[j] = xn[j]
        if kind == 0 or kind == 1:
            x[kind] = 0.0
            if kind == 0 and p[_P_TAUS] <= 0.0:
                x[_Y] = 0.0
        elif kind == 2:
            force_w = _sign(_shaft_drive(x, p))
        else:
            force_i = _sign(v - p[_P_K] * x[_W])
        remaining -= f * remaining
        if remaining <= 0.0:
            return


@_jit
def _integrate(v: np.ndarray, dt: float, n_sub: int, p: np.ndarray,
               x0: np.ndarray) -> np.ndarray:
    n = v.shape[0]
    out = np.empty((n, _NX))
    x = x0.copy()
    xn = np.empty(_NX)
    k1 = np.empty(_NX)
    k2 = np.empty(_NX)
    k3 = np.empty(_NX)
    k4 = np.empty(_NX)
    xt = np.empty(_NX)
    h = dt / n_sub
    for k in range(n):
        for j in range(_NX):
            out[k, j] = x[j]
        for _ in range(n_sub):
            _substep(x, v[k], h, p, xn, k1, k2, k3, k4, xt)
    return out


def _resonance_masses(J: float, r: float, f_r: float,
                      zeta: float) -> tuple[float, float, float, float]:
    """Motor and load inertia, shaft stiffness and damping of the two-mass shaft."""
    J_m = J / (1.0 + r)
    J_l = J * r / (1.0 + r)
    k_s = J_l * (2.0 * math.pi * f_r) ** 2
    c_s = 2.0 * zeta * math.sqrt(k_s * J_l)
    return J_m, J_l, k_s, c_s


def _param_vector(motor: Motor, effects: Mapping[str, Any]) -> np.ndarray:
    p = np.zeros(_NP)
    p[_P_JM] = motor.J
    res = effects.get('resonance')
    if res is not None:
        p[_P_JM], p[_P_JL], p[_P_KS], p[_P_CS] = _resonance_masses(
            motor.J, float(res['r']), float(res['f_r']), float(res['zeta']))
        p[_P_RES] = 1.0
    p[_P_B], p[_P_K], p[_P_R0], p[_P_L] = motor.B, motor.K, motor.R, motor.L
    heat = effects.get('resistance_drift')
    if heat is not None:
        p[_P_ALPHA] = float(heat.get('alpha', ALPHA_COPPER))
        p[_P_CTH], p[_P_RTH] = float(heat['C_th']), float(heat['R_th'])
    fr = effects.get('coulomb_friction')
    if fr is not None:
        p[_P_TC] = float(fr['T_c'])
        p[_P_TS] = float(fr.get('T_s', fr['T_c']))
        if p[_P_TS] < p[_P_TC]:
            raise ValueError('coulomb_friction: break-away torque T_s must be >= T_c')
    p[_P_TL] = float(effects.get('load_torque', {}).get('T_L', 0.0))
    p[_P_KQ] = float(effects.get('quadratic_load', {}).get('k_q', 0.0))
    p[_P_VB] = float(effects.get('brush_drop', {}).get('V_b', 0.0))
    p[_P_TAUS] = float(effects.get('sensor_lag', {}).get('tau_s', 0.0))
    return p


def default_n_sub(motor: Motor, sample_period: float,
                  effects: Mapping[str, Any] | None = None) -> int:
    """Sub-steps per sample: each RK4 step at most 0.7 x the fastest time scale."""
    effects = effects or {}
    # heating may raise R by up to ~1.5 x, shortening L/R
    scales = [motor.tau_e / (1.5 if 'resistance_drift' in effects else 1.0), motor.tau_m]
    res = effects.get('resonance')
    if res is not None:
        J_m, _, k_s, c_s = _resonance_masses(motor.J, float(res['r']), float(res['f_r']),
                                             float(res['zeta']))
        J_l = motor.J - J_m
        scales.append(1.0 / math.sqrt(k_s * (1.0 / J_m + 1.0 / J_l)))
        scales.append(J_m / max(c_s, 1e-300))
        scales.append(motor.J / (1.0 + float(res['r'])) * motor.R / motor.K ** 2)
    if 'sensor_lag' in effects:
        scales.append(float(effects['sensor_lag']['tau_s']))
    return max(2, int(math.ceil(sample_period / (0.7 * min(scales)))))


def _check_effects(effects: Mapping[str, Any]) -> None:
    unknown = set(effects) - set(EFFECTS)
    if unknown:
        raise ValueError(f'unknown effect(s) {sorted(unknown)}; choose from {EFFECTS}')


def integrate(motor: Motor, voltage: ArrayLike, sample_period: float,
              effects: Mapping[str, Any] | None = None,
              n_sub: int | None = None) -> dict[str, np.ndarray]:
    """Integrate the motor over held (zero-order hold) terminal voltages with RK4 sub-steps.

    Parameters
    ----------
    motor : Motor
    voltage : array_like
        Terminal voltage per sample [V], held over each sample period (the amplifier's
        output, see :func:`amplifier`).
    sample_period : float
        [s]
    effects : dict, optional
        ``{name: {param: value}}`` with the simulator's parameters: coulomb_friction
        (T_c, T_s), load_torque (T_L), quadratic_load (k_q), brush_drop (V_b), sensor_lag
        (tau_s), resistance_drift (C_th [J/K], R_th [K/W], alpha [1/K]), resonance
        (r, f_r [Hz], zeta). Amplifier and measurement effects are ignored here.
    n_sub : int, optional
        RK4 sub-steps per sample; default :func:`default_n_sub`.

    Returns
    -------
    dict of ndarray
        States at the sample instants (before each sample's voltage is applied):
        'speed' [rad/s] (motor side), 'current' [A], 'angle' [rad], 'temperature_rise'
        [K], 'resistance' [Ohm], 'load_speed' [rad/s], 'twist' [rad], 'sensor' [rad/s]
        (speed through the sensor lag, or the speed itself).
    """
    effects = effects or {}
    _check_effects(effects)
    if sample_period <= 0:
        raise ValueError('sample_period must be > 0 s')
    v = np.ascontiguousarray(voltage, dtype=float)
    if n_sub is None:
        n_sub = default_n_sub(motor, sample_period, effects)
    if int(n_sub) < 1:
        raise ValueError('n_sub must be >= 1')
    p = _param_vector(motor, effects)
    out = _integrate(v, float(sample_period), int(n_sub), p, np.zeros(_NX))
    return {'speed': out[:, _W], 'current': out[:, _I], 'angle': out[:, _TH],
            'temperature_rise': out[:, _DT],
            'resistance': motor.R * (1.0 + p[_P_ALPHA] * out[:, _DT]),
            'load_speed': out[:, _WL], 'twist': out[:, _PHI], 'sensor': out[:, _Y]}


# ---------------------------------------------------------------------------- measurement

def encoder_speed(angle: np.ndarray, cpr: int, sample_period: float, jitter: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Speed from an incremental encoder: count differences per sample period.

    Parameters
    ----------
    angle : ndarray
        True shaft angle at the samples [rad] (the shaft starts at rest at angle 0).
    cpr : int
        Counts per revolution.
    sample_period : float
        [s]
    jitter : float
        Standard deviation of the angle jitter added before counting [rad].
    rng : numpy.random.Generator

    Returns
    -------
    ndarray
        ``(counts[k] - counts[k-1]) * q`` with ``q = 2 pi / (cpr T)`` [rad/s]; the count
        before the first sample is taken at angle 0.
    """
    ang = np.concatenate([[0.0], np.asarray(angle, dtype=float)])
    ang = ang + jitter * rng.standard_normal(ang.size)
    counts = np.floor(ang * cpr / (2.0 * math.pi))
    return np.diff(counts) * (2.0 * math.pi / (cpr * sample_period))


def measure(states: Mapping[str, np.ndarray], sample_period: float,
            effects: Mapping[str, Any] | None = None,
            noise: tuple[float, float] = (0.005, 0.005),
            rng: int | np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Measured speed and current from the true states.

    Speed: the encoder (``speed_quantization``, ``{'cpr': int}``) with noise as angle
    jitter before counting, else the sensor output plus white noise. Current: white noise,
    then the ADC of step q_i (``current_quantization``, ``{'q_i': A}``). Noise levels are
    fractions of each channel's standard deviation.

    Returns
    -------
    speed, current : ndarray
    """
    effects = effects or {}
    rng = np.random.default_rng(rng)
    ns, ni = noise
    n = states['speed'].size
    if 'speed_quantization' in effects:
        jitter = ns * float(np.std(states['speed'])) * sample_period / math.sqrt(2.0)
        speed = encoder_speed(states['angle'], int(effects['speed_quantization']['cpr']),
                              sample_period, jitter, rng)
    else:
        y = states['sensor']
        speed = y + ns * float(np.std(y)) * rng.standard_normal(n)
    i = states['current']
    current = i + ni * float(np.std(i)) * rng.standard_normal(n)
    if 'current_quantization' in effects:
        q_i = float(effects['current_quantization']['q_i'])
        current = q_i * np.round(current / q_i)
    return speed, current


def simulate(motor: Motor, command: ArrayLike, sample_period: float,
             effects: Mapping[str, Any] | None = None,
             noise: tuple[float, float] = (0.005, 0.005),
             rng: int | np.random.Generator | None = None,
             n_sub: int | None = None) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Command -> amplifier -> motor -> sensors.

    Returns
    -------
    speed, current : ndarray
        Measured channels [rad/s], [A].
    states : dict
        The true states of :func:`integrate`, plus 'voltage' (the motor's terminal
        voltage per sample).
    """
    effects = effects or {}
    _check_effects(effects)
    v = amplifier(command, effects)
    states = integrate(motor, v, sample_period, effects, n_sub)
    states['voltage'] = v
    speed, current = measure(states, sample_period, effects, noise, rng)
    return speed, current, states
