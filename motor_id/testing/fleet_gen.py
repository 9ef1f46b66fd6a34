"""A robot fleet's daily rosbag2 recordings, simulated from the DC-motor physics alone.

Written from the equations, with no code in common with :mod:`motor_id.model` or
:mod:`motor_id.simulate` (numpy, scipy and rosbags' writer only), so that the fleet
pipeline is tested on data its own model did not make. Per motor, x = [w, i]:

    J dw/dt = K_T i - B w - T_c sgn(w)          L di/dt = V - R i - K_b w,  K_b = K_T

The voltage is held between controller ticks; without Coulomb friction each tick is
integrated exactly (matrix exponential of the augmented system); with it, in sub-steps
of the same exact solution with the friction torque held per sub-step and the shaft
stuck at zero speed while the drive torque is below T_c.

A robot records one bag a day (``robot_NN/robot_NN_YYYY-MM-DD/``, a rosbag2 folder with
``metadata.yaml`` and one MCAP file, as ``ros2 bag record -s mcap -o NAME`` writes it):
``/joint_states`` (sensor_msgs/JointState, header-stamped; velocity = speed, effort =
measured current, position = the integrated speed) and one ``/<motor>_cmd``
(std_msgs/Float64, the voltage, logged at the instant it is applied).

Day-to-day variation that is normal comes from the ambient temperature (uniform within
+-``temp_span_k`` kelvin): copper R = R0 (1 + 0.00393 dT) (+-2 % at +-5 K), magnets
K_T = K_T0 (1 - 0.0012 dT), grease B = B0 (1 - 0.01 dT), plus an independent day jitter
per parameter. Drifts (:class:`Drift`) are steps or ramps of a relative size on one
parameter of one motor from a given day.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
import datetime as dt
import json
import os
from pathlib import Path
import shutil
from typing import Any, TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm

if TYPE_CHECKING:
    from motor_id.fleet.history import DriftRow

ALPHA_CU = 0.00393
"""Temperature coefficient of copper resistance [1/K]."""
ALPHA_MAGNET = -0.0012
"""Temperature coefficient of an NdFeB magnet's flux, hence of K_T = K_b [1/K]."""
ALPHA_GREASE = -0.01
"""Relative change of a bearing's viscous friction per kelvin (thinner grease when warm)."""
DRIFTABLE = ('K_T', 'R_m', 'B', 'T_c', 'J', 'L_m')


@dataclass(frozen=True)
class MotorTruth:
    """A motor's true parameters (SI): J [kg m^2], K_T [N m/A] (= K_b), B [N m s/rad],
    L_m [H], R_m [Ohm], T_c [N m]."""

    J: float = 0.01
    K_T: float = 0.3
    B: float = 0.003
    L_m: float = 0.012
    R_m: float = 1.2
    T_c: float = 0.0

    def scaled(self, **factors: float) -> MotorTruth:
        """A copy with each named parameter multiplied by its factor."""
        d = asdict(self)
        for k, f in factors.items():
            d[k] = d[k] * f
        return MotorTruth(**d)


@dataclass(frozen=True)
class Drift:
    """An ageing effect: ``parameter`` of ``robot``/``motor`` changes by ``size`` (relative,
    -0.1 = 10 % lower) from day ``onset`` (0-based), at once (``step``) or linearly over
    ``ramp_days`` days (``ramp``)."""

    robot: str
    motor: str
    parameter: str
    size: float
    onset: int
    kind: str = 'step'
    ramp_days: int = 5

    def factor(self, day: int) -> float:
        """Multiplier of the parameter on ``day``."""
        if day < self.onset:
            return 1.0
        if self.kind == 'step':
            return 1.0 + self.size
        frac = min(1.0, (day - self.onset + 1) / self.ramp_days)
        return 1.0 + self.size * frac

    def full_day(self) -> int:
        """First day on which the drift has its whole size."""
        return self.onset if self.kind == 'step' else self.onset + self.ramp_days - 1


@dataclass
class FleetSpec:
    """What to generate.

    Attributes
    ----------
    robots : int
    motors : tuple of str
        Joint names; each has a command topic ``/<name>_cmd``.
    days : int
        Recordings per robot, one a day from ``start``.
    start : str
        ISO date of day 0.
    nominal : MotorTruth
    unit_spread : float
        Relative std of each parameter from motor to motor (manufacturing spread).
    temp_span_k : float
        Ambient temperature varies uniformly within +-this [K] from day to day.
    day_jitter : dict
        Independent relative std per parameter and day (beyond temperature).
    drifts : tuple of Drift
    duration_s, period_s : float
        Length of a recording and the controller / sensor period [s].
    max_voltage : float
        Largest voltage command [V].
    speed_noise, current_noise : float
        Sensor noise, a fraction of each channel's std.
    broken : tuple
        ``(robot, day, kind)`` recordings to damage: ``truncated`` (the MCAP file cut
        in half) or ``no_command`` (the first motor's command topic missing).
    storage : {'mcap', 'sqlite3'}
    layout : {'folder', 'file'}
        A rosbag2 folder per recording, or a bare ``.mcap`` file (``mcap`` only).
    seed : int
    motor_type : str or None
        Written as every motor's ``type:`` in the profile (all motors siblings).
    """

    robots: int = 3
    motors: tuple[str, ...] = ('wheel_left', 'wheel_right')
    days: int = 12
    start: str = '2026-01-05'
    nominal: MotorTruth = field(default_factory=MotorTruth)
    unit_spread: float = 0.05
    temp_span_k: float = 5.0
    day_jitter: dict[str, float] = field(default_factory=lambda: {
        'K_T': 0.001, 'R_m': 0.002, 'B': 0.01, 'J': 0.002, 'L_m': 0.005, 'T_c': 0.02})
    drifts: tuple[Drift, ...] = ()
    duration_s: float = 20.0
    period_s: float = 0.01
    max_voltage: float = 12.0
    speed_noise: float = 0.005
    current_noise: float = 0.01
    broken: tuple[tuple[str, int, str], ...] = ()
    storage: str = 'mcap'
    layout: str = 'folder'
    seed: int = 0
    motor_type: str | None = None

    def robot_names(self) -> list[str]:
        """``robot_00``, ``robot_01``, ..."""
        return [f'robot_{k:02d}' for k in range(self.robots)]


@dataclass(frozen=True)
class FleetRecording:
    """One generated recording: whose, which day, where, and how it is damaged.

    Attributes
    ----------
    robot : str
    day : int
        Days from the fleet's start.
    date : str
        ISO date.
    path : str
        The bag folder (or file).
    start_ns : int
        Wall-clock time of its first tick [ns since the epoch].
    broken : str or None
        ``'truncated'``, ``'no_command'`` or None.
    """

    robot: str
    day: int
    date: str
    path: str
    start_ns: int
    broken: str | None


@dataclass(frozen=True)
class DetectionScore:
    """How the fleet's drift rows match one generated drift (see :func:`score_detection`)."""

    motor: str
    drift: str
    onset: str
    flagged: bool
    change: float | None
    since: str | None
    dated: int | None
    detect: int | None
    delay: int | None
    other_flags: str


@dataclass
class FleetTruth:
    """What was generated: the recordings and every motor's true parameters per day.

    ``truth``: ``{(robot, motor): [MotorTruth per day]}``; ``profile``: the fleet profile
    (the YAML document of ``motor-id fleet --profile``, ``motors:`` keys).
    """

    spec: FleetSpec
    recordings: list[FleetRecording]
    truth: dict[tuple[str, str], list[MotorTruth]]
    profile: dict[str, Any]


# --------------------------------------------------------------------------- physics
def _system(p: MotorTruth) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Continuous state matrix and input matrix (columns: voltage, friction torque)."""
    a = np.array([[-p.B / p.J, p.K_T / p.J],
                  [-p.K_T / p.L_m, -p.R_m / p.L_m]])
    b = np.array([[0.0, -1.0 / p.J],
                  [1.0 / p.L_m, 0.0]])
    return a, b


def _discrete(a: NDArray[np.float64], b: NDArray[np.float64], h: float
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact hold-equivalent (A_d, B_d) over ``h`` seconds (matrix exponential)."""
    n, m = a.shape[0], b.shape[1]
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a
    big[:n, n:] = b
    e = expm(big * h)
    return e[:n, :n], e[:n, n:]


def simulate_motor(p: MotorTruth, u: NDArray[np.float64], period: float, substeps: int = 8
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Speed and current at the ticks for a voltage held over each tick.

    Parameters
    ----------
    p : MotorTruth
    u : ndarray, shape (n,)
        Voltage applied from tick k to tick k + 1 [V].
    period : float
        Tick period [s].
    substeps : int
        Sub-steps per tick when ``p.T_c > 0``.

    Returns
    -------
    w, i : ndarray, shape (n,)
        State at each tick, before ``u[k]`` acts (starting at rest).
    """
    a, b = _system(p)
    n = len(u)
    w = np.zeros(n)
    cur = np.zeros(n)
    x = np.zeros(2)
    if p.T_c <= 0:
        ad, bd = _discrete(a, b, period)
        for k in range(n):
            w[k], cur[k] = x
            x = ad @ x + bd[:, 0] * u[k]
        return w, cur
    h = period / substeps
    ad, bd = _discrete(a, b, h)
    for k in range(n):
        w[k], cur[k] = x
        for _ in range(substeps):
            drive = p.K_T * x[1]
            if x[0] == 0.0 and abs(drive) <= p.T_c:
                fr = drive     # stuck: friction balances the drive
            else:
                fr = p.T_c * np.sign(x[0] if x[0] != 0.0 else drive)
            new = ad @ x + bd[:, 0] * u[k] + bd[:, 1] * fr
            if x[0] != 0.0 and np.sign(new[0]) != np.sign(x[0]) and \
                    abs(p.K_T * new[1]) <= p.T_c:
                new[0] = 0.0   # stopped within the sub-step and held by stiction
            x = new
    return w, cur


def driving_commands(n: int, period: float, max_voltage: float, rng: np.random.Generator
                     ) -> NDArray[np.float64]:
    """A day of ordinary driving: held voltage levels of random length, with stops."""
    u = np.zeros(n)
    k = 0
    while k < n:
        hold = int(rng.uniform(0.25, 1.5) / period)
        level = 0.0 if rng.random() < 0.15 else rng.uniform(-1.0, 1.0) * max_voltage
        u[k:k + hold] = level
        k += hold
    return u


# --------------------------------------------------------------------------- fleet
def motor_truths(spec: FleetSpec, rng: np.random.Generator
                 ) -> dict[tuple[str, str], list[MotorTruth]]:
    """``{(robot, motor): [MotorTruth per day]}`` with unit spread, temperature, drifts."""
    out: dict[tuple[str, str], list[MotorTruth]] = {}
    names = ('J', 'K_T', 'B', 'L_m', 'R_m', 'T_c')
    temps = {r: rng.uniform(-spec.temp_span_k, spec.temp_span_k, spec.days)
             for r in spec.robot_names()}
    for robot in spec.robot_names():
        for motor in spec.motors:
            unit = spec.nominal.scaled(**{k: float(np.exp(rng.normal(0, spec.unit_spread)))
                                          for k in names})
            days = []
            for day in range(spec.days):
                d_t = temps[robot][day]
                f = {'R_m': 1 + ALPHA_CU * d_t, 'K_T': 1 + ALPHA_MAGNET * d_t,
                     'B': 1 + ALPHA_GREASE * d_t}
                for k, s in spec.day_jitter.items():
                    f[k] = f.get(k, 1.0) * float(np.exp(rng.normal(0, s)))
                for d in spec.drifts:
                    if d.robot == robot and d.motor == motor:
                        f[d.parameter] = f.get(d.parameter, 1.0) * d.factor(day)
                days.append(unit.scaled(**f))
            out[(robot, motor)] = days
    return out


def fleet_profile(spec: FleetSpec) -> dict[str, Any]:
    """The ``motor-id fleet --profile`` mapping for the generated bags."""
    motors = {}
    for m in spec.motors:
        motors[m] = {'input': f'/{m}_cmd', 'speed': '/joint_states:velocity',
                     'current': '/joint_states:effort', 'joint': m, 'effort_is': 'current',
                     'resistance': round(spec.nominal.R_m, 6)}
        if spec.motor_type:
            motors[m]['type'] = spec.motor_type
    return {'motors': motors}


def generate_fleet(spec: FleetSpec, out_dir: str | os.PathLike[str]) -> FleetTruth:
    """Write the fleet's recordings under ``out_dir`` and its profile as ``fleet.yaml``.

    Parameters
    ----------
    spec : FleetSpec
    out_dir : str or Path
        Created; ``<robot>/<robot>_<date>/`` per recording (or ``<robot>_<date>.mcap``
        with ``layout='file'``), ``fleet.yaml`` and ``truth.json``.

    Returns
    -------
    FleetTruth
    """
    import yaml
    if spec.layout == 'file' and spec.storage != 'mcap':
        raise ValueError('layout file needs storage mcap')
    for d in spec.drifts:
        if d.parameter not in DRIFTABLE or d.motor not in spec.motors:
            raise ValueError(f'bad drift {d}')
    rng = np.random.default_rng(spec.seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    truths = motor_truths(spec, rng)
    start = dt.date.fromisoformat(spec.start)
    n = int(round(spec.duration_s / spec.period_s))
    broken = {(r, d): kind for r, d, kind in spec.broken}
    recs: list[FleetRecording] = []
    for robot in spec.robot_names():
        for day in range(spec.days):
            date = start + dt.timedelta(days=day)
            clock = dt.datetime(date.year, date.month, date.day, 9, 0,
                                tzinfo=dt.timezone.utc)
            clock += dt.timedelta(seconds=float(rng.uniform(0, 8 * 3600)))
            start_ns = int(clock.timestamp()) * 10 ** 9
            channels: dict[str, tuple[NDArray[np.float64], ...]] = {}
            for motor in spec.motors:
                p = truths[(robot, motor)][day]
                u = driving_commands(n, spec.period_s, spec.max_voltage, rng)
                w, cur = simulate_motor(p, u, spec.period_s)
                w = w + rng.normal(0, spec.speed_noise * max(float(np.std(w)), 1e-9), n)
                cur = cur + rng.normal(0, spec.current_noise * max(float(np.std(cur)), 1e-9), n)
                channels[motor] = (u, w, cur)
            kind = broken.get((robot, day))
            name = f'{robot}_{date.isoformat()}'
            path = out / robot / name
            path.parent.mkdir(parents=True, exist_ok=True)
            drop = {spec.motors[0]} if kind == 'no_command' else set()
            written = write_robot_bag(path, start_ns, spec.period_s, channels, spec.storage,
                                      drop_commands=drop)
            if spec.layout == 'file':
                target = path.parent / (name + '.mcap')
                shutil.move(str(written), target)
                shutil.rmtree(path)
                path = target
            if kind == 'truncated':
                _truncate(path)
            recs.append(FleetRecording(robot, day, date.isoformat(), str(path), start_ns,
                                       kind))
    profile = fleet_profile(spec)
    with open(out / 'fleet.yaml', 'w', encoding='utf-8') as fh:
        yaml.safe_dump(profile, fh, sort_keys=False)
    truth = FleetTruth(spec, recs, truths, profile)
    with open(out / 'truth.json', 'w', encoding='utf-8') as fh:
        json.dump(truth_json(truth), fh, indent=1)
    return truth


def truth_json(truth: FleetTruth) -> dict[str, Any]:
    """The generated truth as JSON-ready data (drifts, recordings, per-day parameters)."""
    return {'drifts': [asdict(d) for d in truth.spec.drifts],
            'recordings': [asdict(r) for r in truth.recordings],
            'parameters': {f'{r}/{m}': [asdict(p) for p in days]
                           for (r, m), days in truth.truth.items()}}


def _truncate(path: str | os.PathLike[str]) -> None:
    p = Path(path)
    files = [p] if p.is_file() else sorted(p.glob('*.mcap')) + sorted(p.glob('*.db3'))
    for f in files:
        size = f.stat().st_size
        with open(f, 'r+b') as fh:
            fh.truncate(size // 2)


# --------------------------------------------------------------------------- bags
def write_robot_bag(path: str | os.PathLike[str], start_ns: int, period: float,
                    channels: Mapping[str, Sequence[NDArray[np.float64]]], storage: str = 'mcap',
                    drop_commands: Collection[str] = ()) -> Path:
    """Write one robot's recording as a rosbag2 folder the way a robot's recorder does.

    Parameters
    ----------
    path : Path
        The bag folder to create (must not exist).
    start_ns : int
        Wall-clock time of the first tick [ns since the epoch].
    period : float
        Tick period [s].
    channels : dict
        ``{joint: (voltage, speed, current)}``, arrays of one length.
    storage : {'mcap', 'sqlite3'}
    drop_commands : set of str
        Joints whose command topic is left out (a damaged recording).

    Returns
    -------
    Path
        The storage file written inside the folder.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    joint_state = store.types['sensor_msgs/msg/JointState']
    header_t = store.types['std_msgs/msg/Header']
    time_t = store.types['builtin_interfaces/msg/Time']
    float64 = store.types['std_msgs/msg/Float64']
    names = list(channels)
    n = len(next(iter(channels.values()))[0])
    volts = np.array([channels[m][0] for m in names])
    speed = np.array([channels[m][1] for m in names])
    current = np.array([channels[m][2] for m in names])
    position = np.cumsum(speed, axis=1) * period
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(Path(path), version=9, storage_plugin=plugin) as writer:
        js = writer.add_connection('/joint_states', joint_state.__msgtype__, typestore=store)
        cmds = {m: writer.add_connection(f'/{m}_cmd', float64.__msgtype__, typestore=store)
                for m in names if m not in drop_commands}
        last: dict[str, float] = {}
        for k in range(n):
            t_ns = start_ns + int(round(k * period * 1e9))
            for j, m in enumerate(names):
                # a controller publishes a command when it changes, and at 10 Hz
                if m in cmds and (k % 10 == 0 or volts[j, k] != last.get(m)):
                    last[m] = volts[j, k]
                    writer.write(cmds[m], t_ns, store.serialize_cdr(
                        float64(data=float(volts[j, k])), float64.__msgtype__))
            msg = joint_state(
                header=header_t(stamp=time_t(sec=t_ns // 10 ** 9, nanosec=t_ns % 10 ** 9),
                                frame_id=''),
                name=names, position=position[:, k].copy(), velocity=speed[:, k].copy(),
                effort=current[:, k].copy())
            # the recorder receives the state a little after its stamp
            writer.write(js, t_ns + 300_000, store.serialize_cdr(msg, joint_state.__msgtype__))
    files = sorted(Path(path).glob('*.mcap')) + sorted(Path(path).glob('*.db3'))
    return files[0]



# --------------------------------------------------------------------------- scoring
def drift_benchmark_spec(seed: int = 17, robots: int = 4) -> FleetSpec:
    """A held-out fleet as the drift targets state them: ``robots`` x 2 wheels x 10-12
    daily recordings (R_m +-2 % from day to day), with K_T -8 % (step), B +60 % (5-day
    ramp) and R_m +12 % (step) on three distinct wheels from days drawn in 2..7 (days
    counted from 0, as :class:`Drift` counts them: the 3rd to the 8th recording); the
    other wheels clean. The seed draws the days, the wheels and the fleet."""
    rng = np.random.default_rng(seed)
    days = int(rng.integers(10, 13))
    kinds = (('K_T', -0.08, 'step'), ('B', 0.60, 'ramp'), ('R_m', 0.12, 'step'))
    wheels = [(f'robot_{r:02d}', m) for r in range(robots)
              for m in ('wheel_left', 'wheel_right')]
    picked = rng.choice(len(wheels), size=len(kinds), replace=False)
    drifts = tuple(Drift(wheels[j][0], wheels[j][1], param, size, int(rng.integers(2, 8)),
                         kind, ramp_days=5)
                   for j, (param, size, kind) in zip(picked, kinds, strict=True))
    return FleetSpec(robots=robots, days=days, drifts=drifts, seed=seed + 6)


def random_drifts(spec: FleetSpec, rng: np.random.Generator, count: int,
                  parameters: Sequence[tuple[str, float]] = (('K_T', -0.08), ('R_m', 0.12),
                                                             ('B', 0.6)),
                  first: int = 1, last: int | None = None, ramp_share: float = 0.5
                  ) -> tuple[Drift, ...]:
    """``count`` drifts on distinct motors, each on a parameter and size drawn from
    ``parameters`` (the sign kept, the size scaled by 0.8-1.2), a step or a 5-day ramp,
    from a day drawn uniformly in ``first..last`` (default: the days leaving 3 after)."""
    last = spec.days - 3 if last is None else last
    motors = [(r, m) for r in spec.robot_names() for m in spec.motors]
    picked = rng.choice(len(motors), size=count, replace=False)
    out = []
    for j in picked:
        param, size = parameters[int(rng.integers(len(parameters)))]
        kind = 'ramp' if rng.random() < ramp_share else 'step'
        out.append(Drift(motors[j][0], motors[j][1], param,
                         float(size * rng.uniform(0.8, 1.2)),
                         int(rng.integers(first, last + 1)), kind, ramp_days=5))
    return tuple(out)


def score_detection(spec: FleetSpec, drift_rows: Iterable[DriftRow]
                    ) -> tuple[list[DetectionScore], list[str], int]:
    """How the drift rows (:class:`motor_id.fleet.history.DriftRow`) match the drifts.

    Returns
    -------
    rows : list of DetectionScore
        Per drift: ``motor``, ``drift``, ``onset``, ``flagged``, ``change``, ``since``,
        ``dated`` (recordings from the onset to ``since``: 0 is right), ``detect``
        (recordings from the onset to the first flag, the onset recording counting 1),
        ``delay`` (the same from the day the drift reached full size), ``other_flags``
        (other parameters of that motor flagged; K_b is K_T's twin in SI units and not
        counted).
    false : list of str
        Parameters flagged on motors without a drift.
    clean_series : int
        Histories of motors without a drift.
    """
    by: dict[tuple[str, str], dict[str, DriftRow]] = {}
    for d in drift_rows:
        by.setdefault((d.robot, d.motor), {})[d.parameter] = d
    start = dt.date.fromisoformat(spec.start)

    def day(iso: str | None) -> int:
        return (dt.date.fromisoformat((iso or spec.start)[:10]) - start).days
    rows: list[DetectionScore] = []
    for dr in spec.drifts:
        per = by.get((dr.robot, dr.motor), {})
        found = per.get(dr.parameter)
        cp = None
        if found is not None and found.detected:     # the change nearest the onset
            cp = min(found.finding.change_points, key=lambda c: abs(day(c.since) - dr.onset))
        others = sorted(p for p, x in per.items() if x.detected and p != dr.parameter
                        and not (dr.parameter == 'K_T' and p == 'K_b'))
        flagged = None if cp is None else day(cp.flagged_at)
        rows.append(DetectionScore(
            motor=f'{dr.robot}/{dr.motor}',
            drift=f'{dr.parameter} {dr.size * 100:+.0f} % {dr.kind}',
            onset=(start + dt.timedelta(days=dr.onset)).isoformat(),
            flagged=cp is not None, change=None if cp is None else cp.change,
            since=None if cp is None else (cp.since or '')[:10],
            dated=None if cp is None else day(cp.since) - dr.onset,
            detect=None if flagged is None else flagged - dr.onset + 1,
            delay=None if flagged is None else flagged - dr.full_day() + 1,
            other_flags=', '.join(others) or '-'))
    drifting = {(dr.robot, dr.motor) for dr in spec.drifts}
    false = sorted(f'{k[0]}/{k[1]} {p}' for k, per in by.items() if k not in drifting
                   for p, x in per.items() if x.detected)
    clean_series = sum(len(per) for k, per in by.items() if k not in drifting)
    return rows, false, clean_series
