"""The physics of the independent simulator: a DC motor on a serial card, from the equations.

It shares no code with ``motor_id`` (numpy and numba only), so the project's effect
detectors can be checked on data they were not tuned on; the seeded cases drawn on it
are :mod:`motor_id.testing.independent_sim`. SI units throughout: speed w [rad/s],
current i [A], shaft angle theta [rad], winding temperature rise dT [K], voltage [V],
torque [N m], time [s].

Continuous model (one mass, or two masses with ``resonance``)::

    J dw/dt     = K i - B w - T_f - T_L - k_q w |w| - T_grav(theta)
    L di/dt     = V_motor - R(dT) i - K w - V_b sgn(i)
    dtheta/dt   = w
    C_th ddT/dt = i^2 R(dT) - dT / R_th,      R(dT) = R0 (1 + alpha dT)
    tau_s dy/dt = w - y                       (speed sensor lag)

A joint (:data:`MECHANISM_EFFECTS`) adds gravity, T_grav = T_g (elevator; theta a
height [m], torques forces [N]) or T_g cos(theta + offset) (arm; horizontal at
theta + offset = 0, hanging at -pi/2), and hard stops at theta = low, high: reaching one,
the joint stops dead (w = 0) and stays while pushed into it.
Friction is stick-slip: at w = 0 the shaft stays stuck while the drive torque
``|K i - T_L - T_grav - spring|`` is at most the break-away torque T_s (at a stop: while
the drive away from it is at most T_s); moving, T_f = T_c sgn(w) with T_c <= T_s. The
brush drop is treated the same way: at i = 0 no current flows while ``|V - K w| <= V_b``.
The events (w or i crossing zero, the stuck shaft breaking away, the blocked brushes
starting to conduct, a stop reached) are located inside each RK4 sub-step by regula
falsi with re-integration from the sub-step's start; the modes are then decided anew, so
nothing chatters and the integrator keeps its fourth order through the events. The
amplifier holds each sample's command (zero-order hold), delays it by ``d`` whole samples,
clips it at +-V_max and only then applies its dead zone V_dz. With ``resonance`` the
motor (J_m = J / (1 + r), with B and friction) drives the load (J_l = J r / (1 + r), with
the load torques) through a spring k_s = J_l (2 pi f_r)^2 and damper
c_s = 2 zeta sqrt(k_s J_l); the motor-side speed is measured. Samples are the states at
the sample instants, before that sample's command acts. The encoder speed is the count
difference over the past period, i.e. the mean speed of that period on a grid of
q = 2 pi / (cpr T). A torque drive (``input_kind='torque'``) replaces the winding's
equation by a current loop, tau_i di/dt = u / K - i. The compiled kernel is
:mod:`motor_id.testing.independent_kernel`; :class:`Plant` steps it on demand (the
simulated robot), :func:`feedforward` gives the true feedforward constants.
"""

from collections.abc import Mapping
from dataclasses import asdict, dataclass
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from motor_id.testing import independent_kernel as kern

ALPHA_COPPER = 0.0039
"""Temperature coefficient of copper resistance [1/K]."""

EFFECTS = ('coulomb_friction', 'load_torque', 'quadratic_load', 'brush_drop', 'dead_zone',
           'voltage_saturation', 'input_delay', 'sensor_lag', 'speed_quantization',
           'current_quantization', 'resistance_drift', 'resonance')
"""Effect names this simulator can hide (the analysis' names where it has them)."""

MECHANISM_EFFECTS = ('elevator_gravity', 'arm_gravity', 'hard_stops')
"""Position-dependent loads of a joint (never drawn as a hidden effect):
``elevator_gravity`` ``{'T_g'}``, ``arm_gravity`` ``{'T_g', 'offset'}``, ``hard_stops``
``{'low', 'high'}`` (either may be left out)."""

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

def _resonance_masses(J: float, r: float, f_r: float,
                      zeta: float) -> tuple[float, float, float, float]:
    """Motor and load inertia, shaft stiffness and damping of the two-mass shaft."""
    J_m = J / (1.0 + r)
    J_l = J * r / (1.0 + r)
    k_s = J_l * (2.0 * math.pi * f_r) ** 2
    c_s = 2.0 * zeta * math.sqrt(k_s * J_l)
    return J_m, J_l, k_s, c_s


def _param_vector(motor: Motor, effects: Mapping[str, Any], input_kind: str = 'voltage',
                  current_loop: float | None = None) -> np.ndarray:
    p = kern.parameters()
    p[kern.P_JM] = motor.J
    res = effects.get('resonance')
    if res is not None:
        p[kern.P_JM], p[kern.P_JL], p[kern.P_KS], p[kern.P_CS] = _resonance_masses(
            motor.J, float(res['r']), float(res['f_r']), float(res['zeta']))
        p[kern.P_RES] = 1.0
    p[kern.P_B], p[kern.P_K], p[kern.P_R0], p[kern.P_L] = motor.B, motor.K, motor.R, motor.L
    heat = effects.get('resistance_drift')
    if heat is not None:
        p[kern.P_ALPHA] = float(heat.get('alpha', ALPHA_COPPER))
        p[kern.P_CTH], p[kern.P_RTH] = float(heat['C_th']), float(heat['R_th'])
    fr = effects.get('coulomb_friction')
    if fr is not None:
        p[kern.P_TC] = float(fr['T_c'])
        p[kern.P_TS] = float(fr.get('T_s', fr['T_c']))
        if p[kern.P_TS] < p[kern.P_TC]:
            raise ValueError('coulomb_friction: break-away torque T_s must be >= T_c')
    p[kern.P_TL] = float(effects.get('load_torque', {}).get('T_L', 0.0))
    p[kern.P_KQ] = float(effects.get('quadratic_load', {}).get('k_q', 0.0))
    p[kern.P_VB] = float(effects.get('brush_drop', {}).get('V_b', 0.0))
    p[kern.P_TAUS] = float(effects.get('sensor_lag', {}).get('tau_s', 0.0))
    _mechanism_parameters(p, effects)
    if input_kind == 'torque':
        p[kern.P_TORQUE] = 1.0
        p[kern.P_TAUI] = motor.tau_e if current_loop is None else float(current_loop)
        p[kern.P_VB] = 0.0
        if p[kern.P_TAUI] <= 0.0:
            raise ValueError('current_loop must be > 0 s')
    elif input_kind != 'voltage':
        raise ValueError(f"input_kind must be 'voltage' or 'torque', not {input_kind!r}")
    return p


def _mechanism_parameters(p: np.ndarray, effects: Mapping[str, Any]) -> None:
    """Gravity and hard stops into the parameter vector (a rigid joint only)."""
    if 'elevator_gravity' in effects and 'arm_gravity' in effects:
        raise ValueError('choose one of elevator_gravity and arm_gravity')
    if 'resonance' in effects and any(e in effects for e in MECHANISM_EFFECTS):
        raise ValueError('gravity and hard stops act on a rigid joint: not with resonance')
    if 'elevator_gravity' in effects:
        p[kern.P_TG] = float(effects['elevator_gravity']['T_g'])
    if 'arm_gravity' in effects:
        p[kern.P_TG] = float(effects['arm_gravity']['T_g'])
        p[kern.P_GOFF] = float(effects['arm_gravity'].get('offset', 0.0))
        p[kern.P_GARM] = 1.0
    stops = effects.get('hard_stops', {})
    p[kern.P_LO] = float(stops.get('low', -math.inf))
    p[kern.P_HI] = float(stops.get('high', math.inf))
    if not p[kern.P_LO] < p[kern.P_HI]:
        raise ValueError('hard_stops: low must be below high')


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
    gravity = effects.get('arm_gravity')
    if gravity is not None and float(gravity['T_g']) > 0.0:  # the pendulum's 1 / omega
        scales.append(math.sqrt(motor.J / float(gravity['T_g'])))
    return max(2, int(math.ceil(sample_period / (0.7 * min(scales)))))


def _check_effects(effects: Mapping[str, Any]) -> None:
    unknown = set(effects) - set(EFFECTS) - set(MECHANISM_EFFECTS)
    if unknown:
        raise ValueError(f'unknown effect(s) {sorted(unknown)}; choose from '
                         f'{EFFECTS + MECHANISM_EFFECTS}')


def _initial_state(p: np.ndarray, theta0: float) -> np.ndarray:
    """At rest at position theta0 (inside the hard stops), no current."""
    if not p[kern.P_LO] <= theta0 <= p[kern.P_HI]:
        raise ValueError(f'theta0 = {theta0} lies outside the hard stops '
                         f'[{p[kern.P_LO]}, {p[kern.P_HI]}]')
    x0 = np.zeros(kern.NX)
    x0[kern.TH] = theta0
    return x0


def integrate(motor: Motor, voltage: ArrayLike, sample_period: float,
              effects: Mapping[str, Any] | None = None, n_sub: int | None = None,
              theta0: float = 0.0, input_kind: str = 'voltage',
              current_loop: float | None = None) -> dict[str, np.ndarray]:
    """Integrate the motor over held (zero-order hold) terminal voltages with RK4 sub-steps.

    Parameters
    ----------
    motor : Motor
    voltage : array_like
        Terminal voltage per sample [V], held over each sample period (the amplifier's
        output, see :func:`amplifier`); the commanded torque [N m or N] for a torque drive.
    sample_period : float
        [s]
    effects : dict, optional
        ``{name: {param: value}}`` with the simulator's parameters: coulomb_friction
        (T_c, T_s), load_torque (T_L), quadratic_load (k_q), brush_drop (V_b), sensor_lag
        (tau_s), resistance_drift (C_th [J/K], R_th [K/W], alpha [1/K]), resonance
        (r, f_r [Hz], zeta), and the joint's :data:`MECHANISM_EFFECTS`: elevator_gravity
        (T_g), arm_gravity (T_g, offset [rad]), hard_stops (low, high). Amplifier and
        measurement effects are ignored here.
    n_sub : int, optional
        RK4 sub-steps per sample; default :func:`default_n_sub`.
    theta0 : float
        Position at the start [rad, or m for an elevator]; the joint starts at rest.
    input_kind : {'voltage', 'torque'}
        'torque': a current-controlled drive, the current follows ``u / K`` with the time
        constant ``current_loop`` (default L / R) and the brush drop plays no part.
    current_loop : float, optional
        [s]

    Returns
    -------
    dict of ndarray
        States at the sample instants (before each sample's voltage is applied):
        'speed' [rad/s] (motor side), 'current' [A], 'angle' [rad] (the joint's position),
        'temperature_rise' [K], 'resistance' [Ohm], 'load_speed' [rad/s], 'twist' [rad],
        'sensor' [rad/s] (speed through the sensor lag, or the speed itself).
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
    p = _param_vector(motor, effects, input_kind, current_loop)
    out = kern.integrate_held(v, float(sample_period), int(n_sub), p,
                              _initial_state(p, float(theta0)))
    return {'speed': out[:, kern.W], 'current': out[:, kern.I], 'angle': out[:, kern.TH],
            'temperature_rise': out[:, kern.DT],
            'resistance': motor.R * (1.0 + p[kern.P_ALPHA] * out[:, kern.DT]),
            'load_speed': out[:, kern.WL], 'twist': out[:, kern.PHI],
            'sensor': out[:, kern.Y]}


class Plant:
    """A motor and its joint stepped forward on demand, for a simulator running in real time.

    The state persists between calls to :meth:`advance`, each of which holds one input
    over any duration (sub-stepped so that no RK4 step exceeds :func:`default_n_sub`'s).

    Parameters
    ----------
    motor, effects, theta0, input_kind, current_loop
        As in :func:`integrate`.
    """

    def __init__(self, motor: Motor, effects: Mapping[str, Any] | None = None,
                 theta0: float = 0.0, input_kind: str = 'voltage',
                 current_loop: float | None = None) -> None:
        effects = dict(effects or {})
        _check_effects(effects)
        self._p = _param_vector(motor, effects, input_kind, current_loop)
        self._x = _initial_state(self._p, float(theta0))
        self._h_max = 1.0 / default_n_sub(motor, 1.0, effects)
        self.time = 0.0
        """Time simulated so far [s]."""

    def advance(self, u: float, duration: float) -> None:
        """Hold the input u (voltage [V] or torque) for ``duration`` [s] (>= 0)."""
        if duration < 0:
            raise ValueError('duration must be >= 0 s')
        if duration == 0:
            return
        n_sub = max(1, math.ceil(duration / self._h_max))
        kern.advance(self._x, float(u), float(duration), n_sub, self._p)
        self.time += duration

    @property
    def speed(self) -> float:
        """[rad/s] (m/s for an elevator)"""
        return float(self._x[kern.W])

    @property
    def current(self) -> float:
        """[A]"""
        return float(self._x[kern.I])

    @property
    def position(self) -> float:
        """[rad] (m for an elevator)"""
        return float(self._x[kern.TH])

    @property
    def torque(self) -> float:
        """The motor's torque K i [N m] (N for an elevator)."""
        return float(self._p[kern.P_K] * self._x[kern.I])


def feedforward(motor: Motor, effects: Mapping[str, Any] | None = None,
                input_kind: str = 'voltage') -> dict[str, float]:
    """The true feedforward constants of the motor and its joint.

    ``u = kS sgn(w) + kG [cos(theta + offset)] + kV w + kA dw/dt`` in the input's unit:
    for a voltage drive kS = R T_c / K, kV = K + R B / K, kA = R J / K, kG = R T_g / K;
    for a torque drive kS = T_c, kV = B, kA = J, kG = T_g. ``offset`` [rad] for an arm,
    else 0.

    Returns
    -------
    dict
        ``{'kS', 'kV', 'kA', 'kG', 'offset'}``.
    """
    effects = effects or {}
    T_c = float(effects.get('coulomb_friction', {}).get('T_c', 0.0))
    gravity = effects.get('arm_gravity') or effects.get('elevator_gravity') or {}
    T_g = float(gravity.get('T_g', 0.0))
    offset = float(effects.get('arm_gravity', {}).get('offset', 0.0))
    if input_kind == 'torque':
        return {'kS': T_c, 'kV': motor.B, 'kA': motor.J, 'kG': T_g, 'offset': offset}
    g = motor.R / motor.K
    return {'kS': g * T_c, 'kV': motor.K + g * motor.B, 'kA': g * motor.J, 'kG': g * T_g,
            'offset': offset}


# ---------------------------------------------------------------------------- measurement

def encoder_speed(angle: np.ndarray, cpr: int, sample_period: float, jitter: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Speed from an incremental encoder: count differences per sample period.

    Parameters
    ----------
    angle : ndarray
        True shaft angle at the samples [rad] (the shaft is at rest before the first).
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
        before the first sample is taken at the first sample's angle.
    """
    ang = np.asarray(angle, dtype=float)
    ang = np.concatenate([ang[:1], ang])
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
             n_sub: int | None = None, theta0: float = 0.0,
             ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Command -> amplifier -> motor -> sensors.

    ``effects`` and ``theta0`` are those of :func:`integrate` (a joint with gravity and
    hard stops is a position-dependent case; its true position is ``states['angle']``).

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
    states = integrate(motor, v, sample_period, effects, n_sub, theta0)
    states['voltage'] = v
    speed, current = measure(states, sample_period, effects, noise, rng)
    return speed, current, states
