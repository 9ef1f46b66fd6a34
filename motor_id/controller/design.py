"""Controller design: feedforward constants and cascaded PI gains with error bars.

From identified motor parameters (and their covariance) to the WPILib SysId feedforward
``V = kS sgn(w) + kV w + kA dw/dt``, the electrical and mechanical time constants and PI
gains for a current and a speed loop; each loop is then checked on the full model
(:mod:`motor_id.controller.loops`).
"""

from collections.abc import Mapping
import math
from typing import Any

import numpy as np

from motor_id.contracts import INPUT_KINDS, linear_unit, units_of
from motor_id.controller.loops import (
    DELAY_SAMPLES,
    loop_transfer_functions,
    LoopCheck,
    margins,
)
from motor_id.controller.result import (
    ControllerDesign,
    Feedforward,
    format_number,
    LoopDesign,
    PiLoops,
    Quantity,
    TimeConstants,
)
from motor_id.effects import role_params
from motor_id.errors import ConfigError
from motor_id.identify.result import ParameterCovariance
from motor_id.model import MECHANICAL_PARAMS, PARAM_NAMES

VOLTAGE_NAMES = PARAM_NAMES
TORQUE_NAMES = MECHANICAL_PARAMS
"""The parameters a design reads, for a voltage and a torque plant (the model's names)."""
CONVENTION = 'WPILib SysId: V = kS sgn(w) + kV w + kA dw/dt'
KS_EFFECTS = tuple(spec.name for spec, _ in role_params('kS'))
"""Effects whose parameter gives kS (static friction, a brush drop)."""
KS_SOURCES = (*KS_EFFECTS, '+'.join(KS_EFFECTS), 'measured', 'user')

# Default bandwidth rule: a loop's crossover a decade above the open-loop pole it speeds
# up (1/tau_e for the current loop, 1/tau_m for a torque plant's speed loop), and a
# decade between the current and the speed loop of a cascade.
BANDWIDTH_RATIO = 10.0

# With DELAY_SAMPLES of delay a default crossover at most f_s / 20 costs 27 deg at
# crossover.
SAMPLE_FRACTION = 1.0 / 20.0

# Speed PI zero a factor below crossover when no inner loop sets the symmetric-optimum
# ratio (torque plants): a = 4 makes the loop on an integrating plant critically damped.
TORQUE_ZERO_RATIO = 4.0

FD_RELATIVE_STEP = 1e-5

_OUTPUTS = ('kV', 'kA', 'tau_e', 'tau_m', 'current_kp', 'current_ki', 'speed_kp', 'speed_ki')


def _entry(value: float | None, std: float | None = None) -> Quantity:
    """A :class:`Quantity` with NaN (unknown) mapped to None and numpy scalars to float."""
    if value is None or not np.isfinite(value):
        return Quantity(None, None)
    if std is not None and not np.isfinite(std):
        std = None
    return Quantity(float(value), None if std is None else float(std))


def check_input_kind(input_kind: str) -> tuple[str, ...]:
    """The parameter names of an ``input_kind`` plant; ConfigError for an unknown kind."""
    if input_kind not in INPUT_KINDS:
        raise ConfigError(f'input_kind must be one of {INPUT_KINDS}, got {input_kind!r}')
    return VOLTAGE_NAMES if input_kind == 'voltage' else TORQUE_NAMES


def _check_values(values: Mapping[str, float | None], input_kind: str) -> dict[str, float]:
    """Return ``{name: float}`` with NaN for an unknown (None) parameter."""
    names = check_input_kind(input_kind)
    if not isinstance(values, dict):
        raise ConfigError(f'values must be a dict {{name: float}} with {", ".join(names)}')
    missing = [n for n in names if n not in values]
    if missing:
        raise ConfigError(f'values lacks {", ".join(missing)}: a {input_kind} plant needs '
                          f'{", ".join(names)} (None marks an unknown one)')
    extra = [n for n in values if n not in VOLTAGE_NAMES]
    if extra:
        raise ConfigError(f'unknown parameter(s) {", ".join(map(str, extra))}: use the '
                          f'model symbols {", ".join(VOLTAGE_NAMES)}')
    out = {}
    for n in names:
        v = values[n]
        if v is None:
            out[n] = math.nan
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                or not math.isfinite(v):
            raise ConfigError(f'parameter {n} must be a finite number or None, got {v!r}')
        if v < 0 or (v == 0 and n != 'B'):
            raise ConfigError(f'parameter {n} must be > 0{" (B >= 0)" if n == "B" else ""}, '
                              f'got {v}')
        out[n] = float(v)
    return out


def _check_covariance(covariance: ParameterCovariance | Mapping[str, Any] | None,
                      values: Mapping[str, float]) -> tuple[list[str], np.ndarray | None]:
    """Return ``(names, matrix)`` or ``([], None)``; only known parameters may appear."""
    if covariance is None:
        return [], None
    if isinstance(covariance, ParameterCovariance):
        covariance = covariance.to_dict()
    if not isinstance(covariance, dict) or set(covariance) != {'names', 'matrix'}:
        raise ConfigError("covariance must be {'names': [...], 'matrix': [[...]]}")
    names = list(covariance['names'])
    if len(set(names)) != len(names):
        raise ConfigError(f'covariance names repeat: {names}')
    for n in names:
        if n not in values:
            raise ConfigError(f'covariance names {n!r}, which is not a parameter of this '
                              f'plant ({", ".join(values)})')
        if math.isnan(values[n]):
            raise ConfigError(f'covariance names {n!r}, whose value is unknown (None): drop '
                              'its row and column')
    try:
        m = np.array(covariance['matrix'], dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f'covariance matrix is not numeric: {exc}') from exc
    k = len(names)
    if m.shape != (k, k):
        raise ConfigError(f'covariance matrix must be {k}x{k} for names {names}, got shape '
                          f'{m.shape}')
    if not np.all(np.isfinite(m)):
        raise ConfigError('covariance matrix has NaN or inf entries')
    if not np.allclose(m, m.T, rtol=1e-8, atol=1e-14 * max(np.abs(m).max(), 1e-300)):
        raise ConfigError('covariance matrix must be symmetric')
    if k and np.linalg.eigvalsh(m).min() < -1e-9 * max(np.abs(m).max(), 1e-300):
        raise ConfigError('covariance matrix must be positive semi-definite')
    return names, m


def _check_kS(  # noqa: N802 - kS is the symbol of the WPILib feedforward
        kS: Mapping[str, Any] | None) -> tuple[float, float | None, str | None]:
    """Return ``(value, std, source)``; the default is 0 V with no error bar."""
    if kS is None:
        return 0.0, None, None
    if not isinstance(kS, dict) or 'value' not in kS or set(kS) - {'value', 'std', 'source'}:
        raise ConfigError("kS must be {'value': float, 'std': float|None, 'source': str}")
    v, s = kS['value'], kS.get('std')
    for name, x in (('value', v), ('std', s)):
        if name == 'std' and x is None:
            continue
        if isinstance(x, bool) or not isinstance(x, (int, float, np.floating)) \
                or not math.isfinite(x) or x < 0:
            raise ConfigError(f'kS {name} must be a finite number >= 0, got {x!r}')
    source = kS.get('source', 'user')
    if source not in KS_SOURCES:
        raise ConfigError(f'kS source must be one of {KS_SOURCES}, got {source!r}')
    return float(v), None if s is None else float(s), source


def _positive_or_none(x: Any, name: str) -> float | None:
    return None if x is None else _positive(x, name)


def _positive(x: Any, name: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.floating)) \
            or not math.isfinite(x) or x <= 0:
        raise ConfigError(f'{name} must be a finite number > 0, got {x!r}')
    return float(x)


def time_constants(values: Mapping[str, Any],
                   input_kind: str = 'voltage') -> tuple[Any, Any]:
    """Electrical and mechanical time constants [s] (works element-wise on arrays).

    Parameters
    ----------
    values : dict
        ``J, K_T, K_b, B, L_m, R_m`` (voltage plant) or ``J, B`` (torque plant), SI units.
    input_kind : {'voltage', 'torque'}
        The plant kind (see :func:`design_controller`).

    Returns
    -------
    tau_e, tau_m : float or ndarray
        ``tau_e = L_m / R_m`` (NaN for a torque plant) and
        ``tau_m = J R_m / (K_T K_b + R_m B)`` (voltage plant: the speed time constant with
        the back-EMF damping, L_m neglected) or ``J / B`` (torque plant).
    """
    v = values
    if input_kind == 'torque':
        with np.errstate(divide='ignore'):
            return math.nan, np.divide(v['J'], v['B'])
    return (np.divide(v['L_m'], v['R_m']),
            np.divide(v['J'] * v['R_m'], v['K_T'] * v['K_b'] + v['R_m'] * v['B']))


def controller_constants(values: Mapping[str, Any], input_kind: str,
                         current_bandwidth_hz: float | None,
                         speed_bandwidth_hz: float) -> dict[str, float | np.ndarray]:
    """Feedforward constants, time constants and PI gains (element-wise on arrays).

    Parameters
    ----------
    values : dict
        Plant parameters in SI units (floats or equally shaped arrays).
    input_kind : {'voltage', 'torque'}
        The plant kind (see :func:`design_controller`).
    current_bandwidth_hz, speed_bandwidth_hz : float
        Designed loop crossover frequencies [Hz] (the current one is ignored for torque
        plants).

    Returns
    -------
    dict
        ``kV, kA, tau_e, tau_m, current_kp, current_ki, speed_kp, speed_ki`` (NaN where
        not applicable). Units: see :func:`design_controller`.

    Notes
    -----
    Current loop (voltage plant), pole-zero cancellation on ``1 / (L_m s + R_m)``:
    ``kp = L_m w_ci``, ``ki = R_m w_ci`` so the loop is ``w_ci / s``.

    Speed loop, symmetric-optimum style on ``K / (J s + B)`` times the closed current loop
    ``1 / (1 + s / w_ci)``: the PI zero sits at ``w_cs / a`` with ``a = w_ci / w_cs``
    (voltage plant; the zero and the inner-loop pole lie symmetric about the crossover,
    which puts the phase maximum at crossover) or ``a = 4`` (torque plant, no inner loop),
    and ``kp`` makes ``|C P| = 1`` at ``w_cs`` on that design plant exactly.
    """
    v = values
    tau_e, tau_m = time_constants(v, input_kind)
    ws = 2 * np.pi * speed_bandwidth_hz
    if input_kind == 'voltage':
        if current_bandwidth_hz is None:
            raise ConfigError('a voltage plant needs current_bandwidth_hz')
        wi = 2 * np.pi * current_bandwidth_hz
        kV = v['K_b'] + v['R_m'] * v['B'] / v['K_T']
        kA = v['R_m'] * v['J'] / v['K_T']
        current_kp, current_ki = v['L_m'] * wi, v['R_m'] * wi
        gain, a, lag = v['K_T'], wi / ws, np.hypot(1.0, ws / wi)
    else:
        kV, kA = v['B'], v['J']
        current_kp = current_ki = math.nan
        gain, a, lag = 1.0, TORQUE_ZERO_RATIO, 1.0
    zero = ws / a
    speed_kp = ws * np.hypot(v['J'] * ws, v['B']) * lag / (gain * np.hypot(ws, zero))
    return {'kV': kV, 'kA': kA, 'tau_e': tau_e, 'tau_m': tau_m,
            'current_kp': current_kp, 'current_ki': current_ki,
            'speed_kp': speed_kp, 'speed_ki': speed_kp * zero}


def _choose_bandwidths(vals: Mapping[str, float], input_kind: str, current_hz: float | None,
                       speed_hz: float | None, sample_period: float | None,
                       notes: list[str]) -> tuple[float | None, float]:
    """Default (or check) the loop bandwidths [Hz] from the nominal parameters."""
    cap = None if sample_period is None else SAMPLE_FRACTION / sample_period
    nyquist = None if sample_period is None else 0.5 / sample_period
    tau_e, tau_m = time_constants(vals, input_kind)
    if input_kind == 'voltage' and current_hz is None:
        current_hz = BANDWIDTH_RATIO / (2 * np.pi * tau_e)
        rule = f'{BANDWIDTH_RATIO:g} / (2 pi tau_e)'
        if cap is not None and current_hz > cap:
            current_hz, rule = cap, f'capped at f_s/{1 / SAMPLE_FRACTION:g}'
        notes.append(f'current bandwidth {format_number(current_hz)} Hz by default ({rule}); '
                     'pass current_bandwidth_hz to choose it')
    if speed_hz is None:
        if input_kind == 'voltage':
            assert current_hz is not None   # a voltage plant's is set above
            speed_hz = current_hz / BANDWIDTH_RATIO
            rule = 'a decade below the current loop'
        else:
            if vals['B'] == 0:
                raise ConfigError('tau_m = J/B is infinite (B = 0): pass speed_bandwidth_hz')
            speed_hz = BANDWIDTH_RATIO / (2 * np.pi * tau_m)
            rule = f'{BANDWIDTH_RATIO:g} / (2 pi tau_m)'
        if cap is not None and speed_hz > cap:
            speed_hz, rule = cap, f'capped at f_s/{1 / SAMPLE_FRACTION:g}'
        notes.append(f'speed bandwidth {format_number(speed_hz)} Hz by default ({rule}); '
                     'pass speed_bandwidth_hz to choose it')
    for name, f in (('current_bandwidth_hz', current_hz), ('speed_bandwidth_hz', speed_hz)):
        if nyquist is not None and f is not None and np.isfinite(f) and f >= nyquist:
            raise ConfigError(f'{name} {f:.4g} Hz is at or above the Nyquist frequency '
                              f'{nyquist:.4g} Hz of sample_period {sample_period:g} s: '
                              f'choose at most f_s/{1 / SAMPLE_FRACTION:g} = {cap:.4g} Hz')
    if input_kind == 'voltage' and current_hz is not None and speed_hz >= current_hz:
        raise ConfigError(f'speed bandwidth {speed_hz:.4g} Hz must be below the current '
                          f'bandwidth {current_hz:.4g} Hz (a cascade needs a faster inner '
                          'loop; a decade below is the default)')
    return current_hz, speed_hz


def _propagate(vals: Mapping[str, float], input_kind: str,
               bandwidths: tuple[float | None, float],
               names: list[str], cov: np.ndarray | None) -> dict[str, float | None]:
    """Delta-method std of every output: sqrt(g' C g), g by central differences."""
    if cov is None:
        return {k: None for k in _OUTPUTS}
    grads = np.zeros((len(_OUTPUTS), len(names)))
    for j, n in enumerate(names):
        h = FD_RELATIVE_STEP * (abs(vals[n]) or math.sqrt(cov[j, j]) or 1.0)
        up, down = dict(vals), dict(vals)
        up[n] += h
        down[n] -= h
        hi = controller_constants(up, input_kind, *bandwidths)
        lo = controller_constants(down, input_kind, *bandwidths)
        grads[:, j] = [(hi[k] - lo[k]) / (2 * h) for k in _OUTPUTS]
    grads = np.where(np.isfinite(grads), grads, 0.0)  # NaN outputs stay None below
    var = np.einsum('kj,jl,kl->k', grads, cov, grads)
    return {k: math.sqrt(max(var[i], 0.0)) for i, k in enumerate(_OUTPUTS)}


def _verify(vals: Mapping[str, float], input_kind: str, nominal: Mapping[str, Any],
            sample_period: float | None, pm_min: float,
            notes: list[str]) -> dict[str, LoopCheck]:
    """Margins of each loop on the full model; notes for low margins or instability."""
    known = all(np.isfinite(nominal[k]) for k in ('speed_kp', 'speed_ki')) and \
        all(np.isfinite(x) for x in vals.values())
    if input_kind == 'voltage':
        known = known and np.isfinite(nominal['current_kp'])
    if not known:
        notes.append('loops not verified: some parameters are unknown')
        return {}
    loops = loop_transfer_functions(vals, input_kind, nominal, sample_period)
    out = {}
    for name, (num, den) in loops.items():
        m = margins(num, den)
        out[name] = m
        pm = m.phase_margin_deg
        if not m.closed_loop_stable:
            notes.append(f'{name} loop: UNSTABLE on the identified model: lower its '
                         'bandwidth')
        elif pm is None or pm < pm_min:
            notes.append(f'{name} loop: phase margin {format_number(pm)} deg is below the '
                         f'required {pm_min:g} deg: lower its bandwidth')
    return out


def design_controller(values: Mapping[str, float | None],
                      covariance: ParameterCovariance | Mapping[str, Any] | None = None,
                      input_kind: str = 'voltage', kS: Mapping[str, Any] | None = None,
                      current_bandwidth_hz: float | None = None,
                      speed_bandwidth_hz: float | None = None,
                      phase_margin_min_deg: float = 45.0,
                      sample_period: float | None = None,
                      linear: bool = False) -> ControllerDesign:
    """Feedforward constants and cascaded PI gains from identified motor parameters.

    Parameters
    ----------
    values : dict
        Voltage plant: ``J`` [kg m^2], ``K_T`` [N m/A], ``K_b`` [V s/rad], ``B``
        [N m s/rad], ``L_m`` [H], ``R_m`` [Ohm]; torque plant: ``J``, ``B`` (a mass [kg] and
        N s/m for a linear axis). ``None`` marks an unknown parameter: every entry that
        needs it comes out null.
    covariance : ParameterCovariance or dict, optional
        ``{'names': [...], 'matrix': [[...]]}`` in linear units over any subset of the
        parameters; the others are taken as exact (for example an assumed R_m).
    input_kind : {'voltage', 'torque'}
        Armature-voltage plant ``J dw/dt = K_T i - B w``, ``L_m di/dt = V - R_m i - K_b w``,
        or current-controlled (torque) drive ``J dw/dt = u - B w``.
    kS : dict, optional
        ``{'value': float, 'std': float|None, 'source': str}``: the input needed to break
        static friction, in input units (voltage plant: volts, e.g. ``T_c R_m / K_T`` or a
        brush drop ``V_b``). Default 0 (stated in the notes).
    current_bandwidth_hz, speed_bandwidth_hz : float, optional
        Loop crossover frequencies [Hz]. A chosen bandwidth is exact (no error bar).
        Defaults: current ``10 / (2 pi tau_e)``; speed a decade below the current loop
        (voltage plant) or ``10 / (2 pi tau_m)`` (torque plant); both at most f_s / 20
        when ``sample_period`` is given. A torque plant takes no current bandwidth.
    phase_margin_min_deg : float
        Phase margin [deg] a loop must reach on the identified model; below it the notes
        say so.
    sample_period : float, optional
        Controller sample period [s]: caps the default bandwidths and adds 1.5 samples of
        delay to each loop's check.
    linear : bool
        A linear axis: the units say metres (kV in V s/m, kA in V s^2/m).

    Returns
    -------
    ControllerDesign

    Notes
    -----
    Feedforward (WPILib SysId convention ``V = kS sgn(w) + kV w + kA dw/dt``), voltage
    plant with L_m neglected (its time constant is much shorter than a speed
    trajectory's). At constant speed ``dw/dt = 0`` so ``i = B w / K_T`` and
    ``V = R_m i + K_b w = (K_b + R_m B / K_T) w``, hence ``kV = K_b + R_m B / K_T``
    [V s/rad]. To accelerate, the extra current ``J (dw/dt) / K_T`` costs the extra
    voltage ``R_m J / K_T dw/dt``, hence ``kA = R_m J / K_T`` [V s^2/rad]. A torque plant
    gives ``u = B w + J dw/dt``: ``kV = B``, ``kA = J`` in input units (N m or N) per
    rad/s (or m/s) and per rad/s^2.

    Current loop: PI ``V = kp e + ki int(e)`` designed on the electrical plant
    ``1 / (L_m s + R_m)`` with the back-EMF ``K_b w`` as a disturbance. The back-EMF
    couples only near the mechanical frequencies (``1 / tau_m``), far below the current
    crossover, where the integrator rejects it; designing on the full two-state
    ``i / V`` would tie the gains to J and B for no benefit. The PI zero cancels the
    electrical pole (``ki / kp = R_m / L_m``) so the loop is ``w_ci / s``: a first-order
    closed loop with exactly the designed bandwidth. kp [V/A], ki [V/(A s)].

    Speed loop: PI from the speed error to the current (torque) command, designed on
    ``K_T / (J s + B)`` with the closed current loop as ``1 / (1 + s / w_ci)``, in the
    symmetric-optimum style (the zero at ``w_cs / a``, ``a = w_ci / w_cs``), not by
    cancelling the mechanical pole ``B / J``: that pole is often very slow, and
    cancelling it would leave a load-torque error decaying with ``J / B``. kp [A s/rad],
    ki [A/rad] (torque plant: input units s/rad and /rad).

    Both loops are then checked on the full identified model (the speed loop with the
    closed current loop, PI on the two-state model, as its inner dynamics), as rational
    functions of s (:func:`loop_transfer_functions`): the achieved phase margin, crossover,
    gain margin and closed-loop -3 dB bandwidth are reported (the tests hold them to
    python-control's ``stability_margins``, ``feedback`` and ``bandwidth``). Error bars:
    the delta method (central-difference gradients) on ``covariance``, the bandwidths
    held at their chosen values.
    """
    vals = _check_values(values, input_kind)
    names, cov = _check_covariance(covariance, vals)
    kS_value, kS_std, kS_source = _check_kS(kS)
    current_hz = _positive_or_none(current_bandwidth_hz, 'current_bandwidth_hz')
    speed_hz = _positive_or_none(speed_bandwidth_hz, 'speed_bandwidth_hz')
    sample_period = _positive_or_none(sample_period, 'sample_period')
    pm_min = _positive(phase_margin_min_deg, 'phase_margin_min_deg')
    if pm_min >= 90:
        raise ConfigError(f'phase_margin_min_deg must be below 90 deg, got {pm_min}')
    if input_kind == 'torque' and current_hz is not None:
        raise ConfigError('a torque plant has no current loop: drop current_bandwidth_hz')
    notes: list[str] = []
    current_hz, speed_hz = _choose_bandwidths(vals, input_kind, current_hz, speed_hz,
                                              sample_period, notes)
    bandwidths = (current_hz, speed_hz)
    nominal = controller_constants(vals, input_kind, *bandwidths)
    std = _propagate(vals, input_kind, bandwidths, names, cov)
    unknown = [n for n, x in vals.items() if math.isnan(x)]
    if unknown:
        notes.append(f'{", ".join(unknown)} unknown: entries that need them are null')
    checks = _verify(vals, input_kind, nominal, sample_period, pm_min, notes)
    if checks and sample_period is not None:
        notes.append(f'loops checked with {DELAY_SAMPLES:g} samples of delay '
                     f'({DELAY_SAMPLES * sample_period:.3g} s, 3rd-order Pade)')
    return _assemble(input_kind, nominal, std, (kS_value, kS_std, kS_source), bandwidths,
                     checks, cov is not None, notes, linear)


def _assemble(input_kind: str, nominal: Mapping[str, Any], std: Mapping[str, float | None],
              kS: tuple[float, float | None, str | None],
              bandwidths: tuple[float | None, float],
              checks: Mapping[str, LoopCheck], has_cov: bool,
              notes: list[str], linear: bool = False) -> ControllerDesign:
    """Build the ControllerDesign in the contract's shape."""
    e = {k: _entry(nominal[k], std[k]) for k in _OUTPUTS}
    kS_value, kS_std, kS_source = kS
    if kS_source is None:
        how = ('T_c R_m / K_T from a coulomb_friction fit, or a brush_drop V_b'
               if input_kind == 'voltage' else 'T_c from a coulomb_friction fit')
        notes.insert(0, f'kS = 0: no static friction given (pass kS = {how})')
    if not has_cov:
        notes.append('no covariance given: std is null')
    units = {k: units_of(input_kind, linear)[k] for k in ('kS', 'kV', 'kA')}
    if input_kind == 'voltage':
        speed_units = {'kp': 'A s/rad', 'ki': 'A/rad'}
        assert bandwidths[0] is not None   # a voltage plant has a current loop
        zero_ratio = bandwidths[0] / bandwidths[1]
    else:
        speed_units = {'kp': 'N m s/rad', 'ki': 'N m/rad'}
        zero_ratio = TORQUE_ZERO_RATIO
        notes.append('torque plant: kV = B and kA = J in input units per rad/s and per '
                     'rad/s^2 (N per m/s and per m/s^2 for a linear axis); no current loop '
                     'and no tau_e (the drive closes the current loop): both null')
    if linear:
        speed_units = {k: linear_unit(u) for k, u in speed_units.items()}
    current = None
    if input_kind == 'voltage':
        current = _loop_entry(e['current_kp'], e['current_ki'], bandwidths[0],
                              checks.get('current', LoopCheck()), {'kp': 'V/A', 'ki': 'V/(A s)'},
                              'pole-zero cancellation of R_m/L_m on 1/(L_m s + R_m)')
    speed = _loop_entry(e['speed_kp'], e['speed_ki'], bandwidths[1],
                        checks.get('speed', LoopCheck()), speed_units,
                        f'symmetric-optimum style: PI zero at crossover/{zero_ratio:.3g}')
    return ControllerDesign(
        input_kind=input_kind,
        feedforward=Feedforward(kS=Quantity(kS_value, kS_std), kV=e['kV'], kA=e['kA'],
                                units=units, convention=CONVENTION),
        time_constants=TimeConstants(electrical=e['tau_e'], mechanical=e['tau_m']),
        pi=PiLoops(current=current, speed=speed), notes=notes)


def _loop_entry(kp: Quantity, ki: Quantity, bandwidth_hz: float | None, check: LoopCheck,
                units: dict[str, str], design: str) -> LoopDesign:
    if kp.value is None or bandwidth_hz is None or not np.isfinite(bandwidth_hz):
        bandwidth_hz = None
    return LoopDesign(kp=kp, ki=ki,
                      bandwidth_hz=None if bandwidth_hz is None else float(bandwidth_hz),
                      phase_margin_deg=check.phase_margin_deg, crossover_hz=check.crossover_hz,
                      gain_margin_db=check.gain_margin_db,
                      closed_loop_bandwidth_hz=check.closed_loop_bandwidth_hz,
                      closed_loop_stable=check.closed_loop_stable, units=units, design=design)
