"""An independent second simulator of a DC motor on a serial card, written from the physics.

It shares no code with ``motor_id`` (only :func:`to_recording` imports
``motor_id.recording.Recording``, inside the function), so the project's effect detectors
can be checked on data they were not tuned on. SI units throughout: speed w [rad/s],
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

import numpy as np

try:  # numba is a dependency of the project; the plain-Python path is only a fallback
    import numba
    _jit = numba.njit(cache=False, nogil=True)
except ImportError:  # pragma: no cover
    def _jit(f):
        return f

ALPHA_COPPER = 0.0039
"""Temperature coefficient of copper resistance [1/K]."""

EFFECTS = ('coulomb_friction', 'load_torque', 'quadratic_load', 'brush_drop', 'dead_zone',
           'voltage_saturation', 'input_delay', 'sensor_lag', 'speed_quantization',
           'current_quantization', 'resistance_drift', 'resonance')
"""Effect names this simulator can hide (the analysis' names where it has them)."""

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
    def tau_e(self):
        """Electrical time constant L / R [s]."""
        return self.L / self.R

    @property
    def tau_m(self):
        """Mechanical time constant J R / (R B + K^2) [s]."""
        return self.J * self.R / (self.R * self.B + self.K ** 2)

    def no_load_speed(self, voltage):
        """Steady no-load speed V K / (R B + K^2) [rad/s] at ``voltage``."""
        return voltage * self.K / (self.R * self.B + self.K ** 2)

    def to_dict(self):
        """JSON-ready dict with the analysis' symbols (J, K_T, K_b, B, L_m, R_m) too."""
        d = asdict(self)
        d.update(K_T=self.K, K_b=self.K, L_m=self.L, R_m=self.R)
        return d

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`to_dict` (the analysis' duplicate symbols are ignored)."""
        return cls(**{k: d[k] for k in ('J', 'K', 'R', 'L', 'B', 'V_supply', 'motor_class')})


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

    def to_dict(self):
        """JSON-ready dict."""
        return asdict(self)


def _loguniform(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_motor(rng, motor_class):
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


# ----------------------------------------------------------------------------- amplifier

def amplifier(command, effects=None):
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
def _deriv(x, v, w_stuck, sw, i_stuck, si, p, dx):
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
def _rk4(x, v, h, w_stuck, sw, i_stuck, si, p, out, k1, k2, k3, k4, xt):
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
def _sign(a):
    return 1.0 if a > 0.0 else (-1.0 if a < 0.0 else 0.0)


@_jit
def _shaft_drive(x, p):
    """Torque that would accelerate the motor at w = 0, friction excluded [N m]."""
    if p[_P_RES] > 0.0:
        load = p[_P_KS] * x[_PHI] - p[_P_CS] * x[_WL]
    else:
        load = p[_P_TL]
    return p[_P_K] * x[_I] - load


@_jit
def _event_value(kind, x, v, sw, si, p):
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
def _modes(x, v, p, force_w, force_i):
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
def _first_event(x, xn, v, w_stuck, sw, i_stuck, si, p):
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
def _substep(x, v, h, p, xn, k1, k2, k3, k4, xt):
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
def _integrate(v, dt, n_sub, p, x0):
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


def _resonance_masses(J, r, f_r, zeta):
    """Motor and load inertia, shaft stiffness and damping of the two-mass shaft."""
    J_m = J / (1.0 + r)
    J_l = J * r / (1.0 + r)
    k_s = J_l * (2.0 * math.pi * f_r) ** 2
    c_s = 2.0 * zeta * math.sqrt(k_s * J_l)
    return J_m, J_l, k_s, c_s


def _param_vector(motor, effects):
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


def default_n_sub(motor, sample_period, effects=None):
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


def _check_effects(effects):
    unknown = set(effects) - set(EFFECTS)
    if unknown:
        raise ValueError(f'unknown effect(s) {sorted(unknown)}; choose from {EFFECTS}')


def integrate(motor, voltage, sample_period, effects=None, n_sub=None):
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

def encoder_speed(angle, cpr, sample_period, jitter, rng):
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


def measure(states, sample_period, effects=None, noise=(0.005, 0.005), rng=None):
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


def simulate(motor, command, sample_period, effects=None, noise=(0.005, 0.005), rng=None,
             n_sub=None):
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


# ---------------------------------------------------------------------------- excitations

def _prbs_bits(n_bits, rng):
    """Maximal-length 9-bit LFSR sequence (x^9 + x^5 + 1) from a random non-zero state."""
    reg = int(rng.integers(1, 512))
    bits = np.empty(n_bits)
    for k in range(n_bits):
        b = ((reg >> 8) ^ (reg >> 4)) & 1
        bits[k] = reg & 1
        reg = ((reg << 1) | b) & 0x1FF
    return bits


def make_excitation(kind, n_samples, sample_period, amplitude, tau_m, rng):
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

def _draw_effect(name, rng, motor, amplitude, command, T, n_sub):
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


def _draw_heating(rng, motor, command, T, n_sub):
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


def make_case(seed, effect=None, motor_class=None, sample_period=None, n_samples=None,
              noise=0.005, r_m_error=0.0, excitation=None):
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
    data : dict
        ``{'time', 'input', 'speed', 'current'}`` (ndarrays, [s], [V], [rad/s], [A]),
        ``'input_kind': 'voltage'`` and ``'known': {'R_m': R0 (1 + r_m_error)}``.
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
    sim_effects, effect_params = {}, {}
    if effect != 'none':
        sim_params, effect_params = _draw_effect(effect, rng, motor, amplitude, command,
                                                 sample_period, n_sub)
        sim_effects = {effect: sim_params}
        n_sub = default_n_sub(motor, sample_period, sim_effects)
    noise = (float(noise), float(noise)) if np.ndim(noise) == 0 else tuple(map(float, noise))
    speed, current, _ = simulate(motor, command, sample_period, sim_effects, noise, rng, n_sub)
    t = np.arange(n_samples) * sample_period
    known = {'R_m': motor.R * (1.0 + r_m_error)}
    data = {'time': t, 'input': command, 'speed': speed, 'current': current,
            'input_kind': 'voltage', 'known': dict(known)}
    truth = CaseTruth(seed=int(seed), effect=effect, effect_params=effect_params,
                      sim_effects=sim_effects, motor=motor.to_dict(), motor_class=motor_class,
                      excitation=excitation, amplitude=amplitude,
                      sample_period=float(sample_period), n_samples=int(n_samples),
                      n_sub=int(n_sub), noise={'speed': noise[0], 'current': noise[1]},
                      known=known)
    return data, truth


def to_recording(data):
    """Build a ``motor_id.recording.Recording`` from the data of :func:`make_case`."""
    from motor_id.recording import Recording
    meta = {'source': 'motor_id.testing.independent_sim', 'known': dict(data['known'])}
    return Recording(data['time'], data['input'], data['speed'], data['current'],
                     data['input_kind'], meta)


def main():
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
            simulate(motor, data['input'], T, truth.sim_effects, rng=0, n_sub=truth.n_sub)
            elapsed = time.perf_counter() - t0
            print(f'{motor_class:<11}{T * 1e3:>7.0f}{truth.n_sub:>7d}{elapsed:>14.3f}')


if __name__ == '__main__':
    main()
