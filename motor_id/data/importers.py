"""Importers of measured data sets (EMPS, Dunker GR 42x25, CSV, rosbag2, SysId) as Recordings."""

import math
import os

import numpy as np
from numpy.typing import NDArray

from motor_id.contracts import channel_units
from motor_id.data.csv_io import read_csv
from motor_id.data.sysid import load_sysid
from motor_id.errors import ConfigError, DataError
from motor_id.recording import Recording

EMPS_CITATION = ('A. Janot, M. Gautier, M. Brunot, "Data Set and Reference Models of EMPS", '
                 'Workshop on Nonlinear System Identification Benchmarks, Eindhoven, 2019')
EMPS_REFERENCE = {
    'model': 'M qdd + Fv qd + Fc sign(qd) + OF = gtau * vir',
    'M': 95.1089, 'Fv': 203.5034, 'Fc': 20.3935, 'OF': -3.1648,
    'units': {'M': 'kg', 'Fv': 'N s/m', 'Fc': 'N', 'OF': 'N'},
    'relative_force_error': 0.0408,
    'asymmetric': {'M': 95.154, 'Fv+': 166.71, 'Fc+': 20.144, 'Fv-': 240.42, 'Fc-': 20.628},
}
"""Published inverse-dynamics least-squares estimates of the EMPS benchmark."""
EMPS_TS = 1e-3
EMPS_VARIABLES = ('t', 'qm', 'qg', 'vir', 'gtau', 'kp', 'kv')

DUNKER_K_T = 0.0514
"""Torque constant of the Dunkermotoren GR 42x25 [N m/A] (datasheet; k_t = k_e)."""
DUNKER_DATASHEET = {'R': 5.95, 'L': 8.9e-3, 'k_t': DUNKER_K_T, 'k_e': DUNKER_K_T,
                    'J_rotor': 7.1e-6, 'V_nominal': 24.0, 'I_nominal': 0.86,
                    'speed_nominal_rpm': 3600, 'gear': 16,
                    'units': {'R': 'Ohm', 'L': 'H', 'k_t': 'N m/A', 'k_e': 'V s/rad',
                              'J_rotor': 'kg m^2', 'V_nominal': 'V', 'I_nominal': 'A'}}
DUNKER_AUTHORS_FIT = {'J_eff': 1.14e-6, 'b': [2.0e-5, 2.4e-5], 'T0': [0.0070, 0.0081],
                      'delay_s': 0.15, 'fixed': ['R', 'L', 'k'],
                      'units': {'J_eff': 'kg m^2', 'b': 'N m s/rad', 'T0': 'N m'}}
DUNKER_SIGN_RULE = ('torque = k_t * |i| * s with s = sign(m{n}vel) where the measured '
                    'speed is non-zero; else sign(m{n}setvel) where the set-point is non-zero '
                    '(start-up); else the sign of the last non-zero measured speed (the '
                    'current trailing a stop), 0 before any motion. The logged current has '
                    'no sign and follows the speed, also during the ~0.12 s after a '
                    'set-point step to 0 while the motor still runs')
SOURCES = ('emps', 'dunker', 'csv', 'bag', 'sysid')


def load_emps(path: str | os.PathLike[str]) -> Recording:
    """Load the EMPS benchmark (``DATA_EMPS.mat``) as a force-input recording.

    Parameters
    ----------
    path : str or Path
        The benchmark's MATLAB v5 file.

    Returns
    -------
    Recording
        ``input_kind='torque'``: ``voltage`` holds the motor force at the load
        ``gtau * vir`` [N], ``speed`` the load speed [m/s] from the measured position
        ``qm`` by a second-order central difference (one-sided at the two ends), no
        current. Time is the exact 1 ms grid (the file's ``t`` agrees to < 1e-7 s).

    Notes
    -----
    The axis runs in closed loop (cascaded P/PD position control), so the input is
    correlated with the output noise; the published reference model and values are in
    ``meta['reference']``. The speed has a resolution of one position step (5e-8 m) over
    2 ms, 2.5e-5 m/s.
    """
    from scipy.io import loadmat
    path = str(path)
    try:
        mat = loadmat(path)
    except FileNotFoundError as exc:
        raise DataError(f'{path}: no such file') from exc
    except (ValueError, TypeError, OSError, NotImplementedError) as exc:
        raise DataError(f'{path}: not a MATLAB .mat file readable by scipy ({exc})') from exc
    missing = [v for v in EMPS_VARIABLES if v not in mat]
    if missing:
        present = sorted(k for k in mat if not k.startswith('__'))
        raise DataError(f'{path}: not the EMPS data set: variable(s) {", ".join(missing)} '
                        f'missing (found {", ".join(present) or "none"})')
    col = {k: np.asarray(mat[k], dtype=float).ravel() for k in EMPS_VARIABLES}
    n = col['t'].size
    for k in ('qm', 'qg', 'vir'):
        if col[k].size != n:
            raise DataError(f'{path}: {k} has {col[k].size} samples but t has {n}')
    for k in ('gtau', 'kp', 'kv'):
        if col[k].size != 1:
            raise DataError(f'{path}: {k} should be a scalar, has {col[k].size} values')
    if n < 3:
        raise DataError(f'{path}: only {n} samples')
    time = np.arange(n) * EMPS_TS
    jitter = float(np.max(np.abs(col['t'] - time)))
    if jitter > 1e-6:
        raise DataError(f'{path}: t is not the 1 ms grid of the benchmark '
                        f'(deviates by up to {jitter:g} s)')
    bad = [k for k in ('qm', 'vir') if not np.all(np.isfinite(col[k]))]
    if bad:
        raise DataError(f'{path}: NaN/inf in {", ".join(bad)}')
    gtau = float(col['gtau'][0])
    force = gtau * col['vir']
    speed = np.gradient(col['qm'], EMPS_TS)
    steps = np.abs(np.diff(col['qm']))
    quantum = float(np.min(steps[steps > 0])) if np.any(steps > 0) else 0.0
    meta = {
        'dataset': 'EMPS',
        'provenance': ('EMPS benchmark (Electro-Mechanical Positioning System), file '
                       'DATA_EMPS.mat as redistributed under Apache-2.0'),
        'source': os.path.basename(path),
        'citation': EMPS_CITATION,
        'license': 'Apache-2.0 (host repository of the benchmark file)',
        'plant': ('Maxon DC motor driving a ball-screw prismatic axis; current-controlled '
                  'drive seen from the load: force input [N], load speed [m/s]'),
        'closed_loop': True,
        'loop_note': ('position control in closed loop (vir = kp*kv*(qg - q) - kv*dq_f); '
                      'the input depends on the measured output: identification in '
                      'closed loop'),
        'input': 'force at the load = gtau * vir [N]',
        'speed_estimate': ('second-order central difference of qm, (qm[k+1]-qm[k-1])/2Ts '
                           '(one-sided at the ends)'),
        'position_quantum_m': quantum,
        'time_note': f'exact 1 ms grid; the file t deviates by <= {jitter:.2g} s',
        'gtau': gtau, 'kp': float(col['kp'][0]), 'kv': float(col['kv'][0]),
        'reference': EMPS_REFERENCE,
        'units': channel_units('torque', linear=True, position=True),
        'parameter_meaning': {'J': 'moving mass M [kg]', 'B': 'viscous friction Fv [N s/m]'},
    }
    return Recording(time, force, speed, input_kind='torque', meta=meta,
                     position=col['qm'].copy())


def load_dunker(path: str | os.PathLike[str], motor: int = 1) -> Recording:
    """Load one motor of the Dunker GR 42x25 robot logs as a torque-input recording.

    Parameters
    ----------
    path : str or Path
        ``;``-separated CSV with three header lines (long name; unit; short name).
    motor : {1, 2, 3}

    Returns
    -------
    Recording
        ``input_kind='torque'``: ``voltage`` holds the motor torque ``k_t * |i| * sign``
        [N m] with ``k_t`` = 0.0514 N m/A (datasheet) and the sign rule of
        :data:`DUNKER_SIGN_RULE`; ``speed`` the measured motor speed ``m{n}vel`` [rad/s];
        no current channel (the current is the input). Times are the logged ``t`` [ms]
        divided by 1000, irregular as logged (about 23 to 38 ms apart), never resampled.
    """
    path = str(path)
    if motor not in (1, 2, 3):
        raise ConfigError(f'motor must be 1, 2 or 3, got {motor!r}')
    try:
        with open(path, newline='') as fh:
            lines = fh.read().splitlines()
    except FileNotFoundError as exc:
        raise DataError(f'{path}: no such file') from exc
    except OSError as exc:
        raise DataError(f'{path}: cannot read ({exc.strerror})') from exc
    except UnicodeDecodeError as exc:
        raise DataError(f'{path}: not a text file (expected the ;-separated Dunker log)') \
            from exc
    if len(lines) < 4:
        raise DataError(f'{path}: {len(lines)} line(s); expected 3 header lines and data')
    names = [c.strip() for c in lines[2].split(';')]
    wanted = ('t', f'm{motor}setvel', f'm{motor}vel', f'm{motor}cur')
    missing = [w for w in wanted if w not in names]
    if missing:
        raise DataError(f'{path}: not a Dunker GR 42x25 log: line 3 should hold the short '
                        f'names t;m1setvel;...;m{motor}cur, missing {", ".join(missing)} in '
                        f'{lines[2][:80]!r}')
    units = [c.strip() for c in lines[1].split(';')]
    if len(units) > names.index('t') and units[names.index('t')] != 'ms':
        raise DataError(f'{path}: time unit is {units[names.index("t")]!r}, expected ms')
    idx = {w: names.index(w) for w in wanted}
    data: dict[str, list[float]] = {w: [] for w in wanted}
    for lineno, line in enumerate(lines[3:], 4):
        if not line.strip():
            continue
        cells = line.split(';')
        for w, j in idx.items():
            cell = cells[j].strip() if j < len(cells) else ''
            try:
                value = float(cell)
            except ValueError:
                raise DataError(f'{path}:{lineno}: column {w!r} has non-numeric value '
                                f'{cell!r}') from None
            if not math.isfinite(value):
                raise DataError(f'{path}:{lineno}: column {w!r} is {cell} (NaN/inf)')
            data[w].append(value)
    t_ms = np.asarray(data['t'])
    bad = np.flatnonzero(np.diff(t_ms) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataError(f'{path}: time does not increase at data row {k + 1} '
                        f'(t = {t_ms[k]:g} ms after {t_ms[k - 1]:g} ms)')
    setvel = np.asarray(data[f'm{motor}setvel'])
    vel = np.asarray(data[f'm{motor}vel'])
    cur = np.asarray(data[f'm{motor}cur'])
    if np.any(cur < 0):
        raise DataError(f'{path}: m{motor}cur has negative values; this importer expects '
                        'the unsigned current magnitude of the Dunker logs')
    sign = dunker_sign(vel, setvel)
    torque = DUNKER_K_T * cur * sign
    dt = np.diff(t_ms) * 1e-3
    meta = {
        'dataset': 'Dunker GR 42x25',
        'provenance': ('three-wheeled mobile robot with 3 Dunkermotoren GR 42x25 brushed DC '
                       "motors under the robot's own P speed controller; public research "
                       'repository on wheel slippage, Apache-2.0'),
        'source': os.path.basename(path),
        'license': 'Apache-2.0',
        'motor': motor,
        'plant': 'motor side (gear 16:1 not applied): torque input [N m], speed [rad/s]',
        'closed_loop': True,
        'input': f'torque = k_t * |m{motor}cur| * sign, k_t = {DUNKER_K_T} N m/A',
        'sign_rule': DUNKER_SIGN_RULE.replace('{n}', str(motor)),
        'k_t': DUNKER_K_T,
        'datasheet': DUNKER_DATASHEET,
        'authors_fit': DUNKER_AUTHORS_FIT,
        'sampling': {'irregular': True, 'dt_min_s': float(dt.min()),
                     'dt_max_s': float(dt.max()), 'dt_mean_s': float(dt.mean())},
        'current_quantum_A': 0.0256,
        'sign_from_setpoint': int(np.count_nonzero((vel == 0) & (setvel != 0) & (cur > 0))),
        'sign_held': int(np.count_nonzero((vel == 0) & (setvel == 0) & (cur > 0))),
        'units': channel_units('torque'),
    }
    return Recording(t_ms * 1e-3, torque, vel, input_kind='torque', meta=meta)


def dunker_sign(vel: NDArray[np.float64], setvel: NDArray[np.float64]) -> NDArray[np.float64]:
    """Direction of the unsigned Dunker current: the rule of :data:`DUNKER_SIGN_RULE`.

    Parameters
    ----------
    vel, setvel : ndarray
        Measured speed and speed set-point [rad/s].

    Returns
    -------
    ndarray
        -1, 0 or +1 per sample.
    """
    vel = np.asarray(vel, dtype=float)
    setvel = np.asarray(setvel, dtype=float)
    last = np.maximum.accumulate(np.where(vel != 0, np.arange(vel.size), 0))
    held = np.sign(vel[last])
    return np.where(vel != 0, np.sign(vel), np.where(setvel != 0, np.sign(setvel), held))


def load_csv(path: str | os.PathLike[str], columns: str | dict[str, str] | None = None,
             input_kind: str | None = None) -> Recording:
    """Load a CSV recording (input column voltage, torque or force); see :func:`read_csv`."""
    return read_csv(path, columns=columns, input_kind=input_kind)


def load(source: str, path: str | os.PathLike[str], motor: int = 1,
         joint: str | None = None) -> Recording:
    """Dispatch to the loader of ``source`` ('emps', 'dunker', 'csv', 'bag' or 'sysid').

    'bag' reads the ``/samples`` topic of any rosbag2 recording; a field mapping is
    :func:`motor_id.data.rosbag.read_bag`'s. 'sysid' reads a WPILib SysId log
    (:func:`motor_id.data.sysid.load_sysid`; ``joint`` the side of a Drivetrain log).
    """
    if source == 'emps':
        return load_emps(path)
    if source == 'dunker':
        return load_dunker(path, motor)
    if source == 'csv':
        return load_csv(path)
    if source == 'bag':
        from motor_id.data.rosbag import read_bag
        return read_bag(path)
    if source == 'sysid':
        return load_sysid(path, joint)
    raise ConfigError(f'unknown source {source!r}; choose one of {", ".join(SOURCES)}')
