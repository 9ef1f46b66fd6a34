"""Batch simulation of many parameter sets at once (the GA's and the fitter's hot loop).

One compiled kernel steps every member of a batch through the same input record. The
linear part is exact (per-interval discretisation from :mod:`motor_id.model`); the
named effects enter as inputs held over each interval: extra voltage (brush drop,
resistance drift), extra torque (Coulomb friction with stiction, constant and quadratic
load), static input maps (delay, dead zone, saturation) and output maps (sensor lag,
quantisation).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import functools
import inspect
import time
from typing import Any, cast, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.effects import as_batch, EFFECTS, FRICTION_COLUMNS, validate_effects
from motor_id.errors import ConfigError
from motor_id.model import continuous_matrices, discretize, interval_integrals, Plant
from motor_id.records import Record
from motor_id.simulate_kernels import (
    _kernel,
    _linear2_kernel,
    _linear2_regular_kernel,
    _linear_kernel,
    compiled,
    KERNELS,
    loaded,
)

if TYPE_CHECKING:
    from motor_id.recording import Recording

REGULAR_RTOL = 1e-6


@dataclass(frozen=True)
class WarmUp(Record):
    """What :func:`warm_up` did."""

    seconds: float
    compiled: int
    kernels: int
    cache_dir: str


def warm_up() -> WarmUp:
    """Load (the first time ever: compile) every simulation kernel, before a fit needs it.

    Without it the first simulation of a process pays for numba's import and type-system
    set-up (~0.3 s of CPU with the kernels in numba's cache; several seconds to compile
    them without). Call it where a first fit must not stall, e.g. when a node starts.
    It is thread-safe, and cheap once done.

    Returns
    -------
    WarmUp
        ``seconds``: wall time of this call [s]; ``'compiled'``: kernels that had to
        be compiled now (0 when numba's cache served them all); ``kernels``: compiled
        kernel signatures now ready in this process; ``cache_dir``: numba's cache
        directory for the kernels' module.

    Notes
    -----
    The kernels (:mod:`motor_id.simulate_kernels`) are cached by numba (``cache=True``)
    in ``__pycache__`` next to their module or, where that is not writable (a read-only
    install), in numba's user-wide cache directory; the environment variable
    ``NUMBA_CACHE_DIR`` overrides both. Any edit of that module makes numba compile once
    more. Every simulation reaches the kernels with C-contiguous arrays of fixed dtypes,
    so each kernel has one signature and the four small simulations below cover all
    of them.
    """
    t0 = time.perf_counter()
    ready: list[Any] = [loaded(f) for f in KERNELS]
    if all(d is not None and d.signatures for d in ready):  # done before: nothing to load
        return WarmUp(seconds=time.perf_counter() - t0, compiled=0,
                      kernels=sum(len(d.signatures) for d in ready),
                      cache_dir=str(ready[0].stats.cache_path))
    from numba.core import event

    p = {'J': 0.05, 'K_T': 0.5, 'K_b': 0.5, 'B': 1e-3, 'L_m': 0.01, 'R_m': 2.0}
    t = np.array([0.0, 0.01, 0.02, 0.035])
    u = np.ones(t.size)
    with event.install_recorder('numba:compile') as recorder:
        simulate_batch(p, t[:3], u[:3])  # regular grid, no effects
        simulate_batch(p, t, u)  # irregular grid
        simulate_batch(p, t, u, 'torque')  # a one-state plant
        simulate_batch(p, t, u, effects={FRICTION_EFFECTS[0]: {}})
    ours = {id(compiled(f)) for f in KERNELS}
    fresh = sum(1 for _, ev in recorder.buffer  # (time, event) pairs
                if ev.is_start and id(ev.data['dispatcher']) in ours)
    return WarmUp(seconds=time.perf_counter() - t0, compiled=fresh,
                  kernels=sum(len(compiled(f).signatures) for f in KERNELS),
                  cache_dir=str(compiled(_kernel).stats.cache_path))


def interval_table(t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Split time stamps into unique interval lengths and an index per interval.

    Returns
    -------
    dts : ndarray, shape (K,)
    idx : ndarray of int, shape (N-1,)
    """
    t = np.ascontiguousarray(t, dtype=float)
    return _interval_table(t.tobytes())


@functools.lru_cache(maxsize=16)
def _interval_table(stamps: bytes) -> tuple[np.ndarray, np.ndarray]:
    """:func:`interval_table` of the time stamps held in ``stamps`` (cached: a fit
    simulates the same record, or the same runs of it, thousands of times)."""
    dt = np.diff(np.frombuffer(stamps))
    if dt.size == 0:
        return np.array([1.0]), np.zeros(0, dtype=np.int64)
    if np.ptp(dt) <= REGULAR_RTOL * np.mean(dt):
        return np.array([float(np.mean(dt))]), np.zeros(dt.size, dtype=np.int64)
    # round to 1 ns so that logged millisecond stamps collapse to a few lengths
    dtr = np.round(dt, 9)
    dts, idx = np.unique(dtr, return_inverse=True)
    return dts, idx.astype(np.int64)


def batch_size(theta: Mapping[str, ArrayLike]) -> int:
    """Number of members in a batch of parameters ``{name: (P,) array or scalar}``."""
    sizes = {np.asarray(v).size for v in theta.values() if np.asarray(v).ndim > 0}
    if len(sizes) > 1:
        raise ConfigError(f'batch parameters have different lengths {sorted(sizes)}')
    return sizes.pop() if sizes else 1


INPUT_MAPS = tuple(spec.name for spec in sorted(
    (s for s in EFFECTS.values() if s.input_map), key=lambda s: s.input_map.rank))
"""Effects that act on the input before the dynamics (:func:`apply_input_maps`), in the
order they apply; a delay reaches back in time, so a window of a record takes them from
the whole record."""


def split_input_maps(effects: Mapping[str, Mapping[str, ArrayLike]]
                     ) -> tuple[dict[str, Mapping[str, ArrayLike]],
                                dict[str, Mapping[str, ArrayLike]]]:
    """``effects`` as ``(input maps, the rest)``."""
    maps = {e: v for e, v in effects.items() if e in INPUT_MAPS}
    return maps, {e: v for e, v in effects.items() if e not in INPUT_MAPS}


def apply_input_maps(u: ArrayLike, effects: Mapping[str, Mapping[str, ArrayLike]], P: int,
                     segments: Sequence[tuple[int, int]] | None = None) -> np.ndarray:
    """Static input maps and delay, per member: returns ``u_eff`` of shape (P, N).

    ``segments``: the ranges ``[start, stop)`` of separate input streams
    (:attr:`Recording.input_streams`: a SysId log's tests), each mapped on its own: a
    delay at a stream's start reaches back to the stream's first input, not to the
    previous one's last (a test that starts from the idle drive). Tests recorded back to
    back are one stream: there a delayed step starts from the rest before it."""
    u = np.broadcast_to(np.asarray(u, dtype=float), (P, np.shape(u)[-1])).copy()
    for a, b in segments or [(0, u.shape[1])]:
        for name in INPUT_MAPS:
            if name in effects:
                spec = EFFECTS[name]
                u[:, a:b] = spec.input_map.apply(u[:, a:b], spec.batch(effects[name], P))
    return u


def _initial_batch(x0: ArrayLike | None, P: int, n: int, resonance_states: int,
                   position: bool = False) -> np.ndarray:
    """``x0`` as (P, n): missing states 0; with a two-mass shaft (``resonance_states`` =
    the dynamic states) the load starts at the motor's speed; with ``position`` too, the
    last entry of an ``x0`` that stops short of the load's states is the position, as the
    last state is (before, it fell on the load's speed and the simulated position started
    from 0)."""
    x0b = np.zeros((P, n))
    if x0 is None:
        return x0b
    x0 = np.asarray(x0, dtype=float)
    x0 = np.broadcast_to(x0, (P, x0.size)) if x0.ndim == 1 else x0
    m = min(x0.shape[1], n)
    if resonance_states and position and 1 < m <= resonance_states - 1:
        x0b[:, :m - 1] = x0[:, :m - 1]
        x0b[:, n - 1] = x0[:, m - 1]
    else:
        x0b[:, :m] = x0[:, :m]
    if resonance_states:   # load starts at the motor's speed, shaft untwisted
        x0b[:, resonance_states - 2] = x0b[:, 0]
    return x0b


def simulate_batch(theta: Mapping[str, ArrayLike], t: ArrayLike, u: ArrayLike,
                   input_kind: str = 'voltage', method: str = 'zoh',
                   effects: Mapping[str, Mapping[str, ArrayLike]] | None = None,
                   x0: ArrayLike | None = None, position: bool = False,
                   measured_position: ArrayLike | None = None) -> dict[str, np.ndarray]:
    """Simulate P parameter sets on one input record.

    Parameters
    ----------
    theta : dict
        Physical parameters, each a scalar or an array of shape (P,).
    t : array_like, shape (N,)
        Sample times [s], strictly increasing, possibly irregular.
    u : array_like, shape (N,) or (P, N)
        Input (voltage [V] or torque [N m]) held from ``t[k]`` to ``t[k+1]``.
    input_kind : {'voltage', 'torque'}
    method : {'zoh', 'euler'}
    effects : dict, optional
        ``{effect: {param: scalar or (P,) array}}`` from :data:`motor_id.effects.EFFECTS`.
    x0 : array_like, shape (n,) or (P, n), optional
        Initial state; zeros when omitted. With ``position`` the position is the last
        state.
    position : bool
        Also integrate the motor's position (exactly, with the held inputs: an extra
        state ``d(theta)/dt = w``); on by itself with an effect that reads the position
        (an arm's gravity) and no ``measured_position``.
    measured_position : array_like, shape (N,), optional
        The record's measured position [rad or m]: an effect that reads the position
        takes it from here, exogenous like the input (else from the integrated one).

    Returns
    -------
    dict
        ``'speed'`` (P, N) as the sensor reports it, ``'current'`` (P, N) for a voltage
        plant, ``'position'`` (P, N) with ``position``, ``'states'`` (P, N, n).
    """
    position = position or (measured_position is None and reads_position(effects))
    return discretise_batch(theta, t, input_kind, method, effects, position).run(
        u, x0, measured_position=measured_position)


def reads_position(effects: Mapping[str, Any] | None) -> bool:
    """An effect of ``effects`` reads the joint's position (an arm's gravity)."""
    return any(EFFECTS[e].position for e in (effects or {}) if e in EFFECTS)


FRICTION_EFFECTS = tuple(n for n, spec in EFFECTS.items() if spec.friction_term)
"""Effects that fill the kernel's dry-friction table (:func:`friction_table`), in order."""
KERNEL_ARGS = {a.arg: (n, a) for n, spec in EFFECTS.items() for a in spec.kernel_args}
"""The kernel's arguments that effects declare: ``{argument: (effect, KernelArg)}``."""
_EFFECT_ARGS = tuple(a for a in inspect.signature(_kernel).parameters if a in KERNEL_ARGS)
"""Those arguments in the order of the kernel's signature."""
if len(_EFFECT_ARGS) != len(KERNEL_ARGS):   # a declared argument the kernel lacks
    raise ConfigError(f'the simulation kernel has no argument(s) '
                      f'{sorted(set(KERNEL_ARGS) - set(_EFFECT_ARGS))}')
KERNEL_EFFECTS = frozenset(FRICTION_EFFECTS) | {n for n, _ in KERNEL_ARGS.values()}
"""Effects the general kernel steps (the others are input or output maps)."""


@dataclass
class DiscretisedBatch:
    """A batch of plants discretised on the intervals of one record: what every run of
    the record (:func:`simulate_runs`) and every block of it shares (made by
    :func:`discretise_batch`)."""

    effects: dict[str, Mapping[str, ArrayLike]]
    full: dict[str, np.ndarray]
    input_kind: str
    position: bool
    dts: np.ndarray
    idx: np.ndarray
    A: np.ndarray
    Bd: np.ndarray
    Hm: np.ndarray
    Hq: np.ndarray
    n_dyn: int
    resonance: bool

    def run(self, u: ArrayLike, x0: ArrayLike | None, rows: tuple[int, int] | None = None,
            members: np.ndarray | None = None, measured_position: ArrayLike | None = None
            ) -> dict[str, np.ndarray]:
        """Simulate samples ``rows`` (``[a, b)``; all when None) of the record with the
        input ``u`` of those samples, for the batch members ``members`` (all when None);
        ``measured_position`` is the whole record's (sliced here like the intervals)."""
        effects, full, A, Bd, Hm, Hq = (self.effects, self.full, self.A, self.Bd, self.Hm,
                                        self.Hq)
        if members is not None:
            effects = {e: _take(v, members) for e, v in effects.items()}
            full = {k: v[members] for k, v in full.items()}
            A, Bd = A[members], Bd[members]
            if Hm.shape[0] > 1:
                Hm, Hq = Hm[members], Hq[members]
        P = A.shape[0]
        idx = self.idx if rows is None else self.idx[rows[0]:max(rows[1] - 1, rows[0])]
        theta_m = np.zeros(0)
        if measured_position is not None:
            mp = np.asarray(measured_position, dtype=float)
            theta_m = np.ascontiguousarray(mp if rows is None else mp[rows[0]:rows[1]])
        n = A.shape[3]
        x0b = _initial_batch(x0, P, n, self.n_dyn if self.resonance else 0, self.position)
        ueff = apply_input_maps(u, effects, P)
        # one array layout per argument, so that each kernel has one compiled signature
        A = np.ascontiguousarray(A)
        Bd = np.ascontiguousarray(Bd)
        if not KERNEL_EFFECTS & set(effects) and not self.position:
            if n == 2 and self.dts.size == 1:
                X = compiled(_linear2_regular_kernel)(A, Bd, ueff, x0b)
            elif n == 2:
                X = compiled(_linear2_kernel)(A, Bd, idx, ueff, x0b)
            else:
                X = compiled(_linear_kernel)(A, Bd, idx, ueff, x0b)
            # state-major from the kernel: each channel is one contiguous (P, N) block
            out = {'speed': output_maps(X[0], 'speed', effects, P),
                   'states': X.transpose(1, 2, 0)}
            if self.input_kind == 'voltage':
                out['current'] = output_maps(X[1], 'current', effects, P)
            return out

        X, Y = compiled(_kernel)(A, Bd, idx, self.dts, ueff, x0b,
                                 self.input_kind == 'voltage', friction_table(effects, P),
                                 *kernel_args(effects, P), full.get('R_m', np.ones(P)), Hm,
                                 Hq, n - 1 if self.position else -1, theta_m)
        out = {'speed': output_maps(Y, 'speed', effects, P), 'states': X}
        if self.position:
            out['position'] = np.ascontiguousarray(X[:, :, n - 1])
        if self.input_kind == 'voltage':
            out['current'] = output_maps(X[:, :, 1], 'current', effects, P)
        return out


def kernel_args(effects: Mapping[str, Mapping[str, ArrayLike]], P: int) -> list[np.ndarray]:
    """The kernel's effect arguments in its signature's order, each (P,): the effect's
    parameter where it is in ``effects``, else the argument's value for its absence."""
    out = []
    for arg in _EFFECT_ARGS:
        name, karg = KERNEL_ARGS[arg]
        out.append(as_batch(effects[name][karg.param], P) if name in effects
                   else np.full(P, karg.absent))
    return out


def discretise_batch(theta: Mapping[str, ArrayLike], t: ArrayLike, input_kind: str,
                     method: str, effects: Mapping[str, Mapping[str, ArrayLike]] | None,
                     position: bool) -> DiscretisedBatch:
    """The batch's plants discretised on every interval of ``t`` (effects completed
    with their defaults), ready to :meth:`DiscretisedBatch.run` on any stretch of the
    record: :func:`simulate_batch` on several stretches with one discretisation."""
    effects = dict(effects or {})
    for name, vals in effects.items():
        if name not in EFFECTS:
            validate_effects({name: {}}, input_kind)  # raises with the list of names
        missing = {p.name for p in EFFECTS[name].params} - set(vals)
        if missing:
            effects[name] = {**EFFECTS[name].defaults(), **vals}
    P = batch_size({**theta, **{f'{e}.{k}': v for e, d in effects.items()
                                for k, v in d.items()}})
    dts, idx = interval_table(np.asarray(t, dtype=float))
    full = {k: as_batch(v, P) for k, v in theta.items()}
    res = next((v for e, v in effects.items() if EFFECTS[e].plant_term), None)
    res_b = {k: as_batch(v, P) for k, v in res.items()} if res else None
    F, G = continuous_matrices(full, input_kind, res_b)
    n_dyn = F.shape[1]
    if position:
        F, G = with_position(F, G)
    A, Bd = discretize(F, G, dts, method)
    nz = F.shape[1] + G.shape[2]
    if input_kind == 'voltage' and any(EFFECTS[e].heating for e in effects):
        Hm, Hq = interval_integrals(F, G, dts, row=1)
    else:
        Hm, Hq = np.zeros((1, 1, nz)), np.zeros((1, 1, nz, nz))
    return DiscretisedBatch(effects, full, input_kind, position, dts, idx, A, Bd, Hm, Hq, n_dyn,
                        res_b is not None)


def with_position(F: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``F, G`` with one more state, the motor's position: ``d(theta)/dt = w``."""
    P, n, _ = F.shape
    Fp = np.zeros((P, n + 1, n + 1))
    Fp[:, :n, :n] = F
    Fp[:, n, 0] = 1.0
    Gp = np.zeros((P, n + 1, G.shape[2]))
    Gp[:, :n] = G
    return Fp, Gp


def friction_table(effects: Mapping[str, Mapping[str, ArrayLike]], P: int) -> np.ndarray:
    """The kernel's dry-friction parameters, shape (P, 5): each effect of
    :data:`FRICTION_EFFECTS` in ``effects`` fills its columns, in catalogue order.

    Columns (:data:`motor_id.effects.FRICTION_COLUMNS`): Coulomb level for positive and
    for negative motion, the extra viscous friction of negative motion, the static
    (break-away) level, the Stribeck speed.
    """
    fr = np.zeros((P, FRICTION_COLUMNS))
    for name in FRICTION_EFFECTS:
        if name in effects:
            spec = EFFECTS[name]
            spec.friction_term(fr, spec.batch(effects[name], P))
    return fr


def simulate_runs(theta: Mapping[str, ArrayLike], t: np.ndarray, u: np.ndarray,
                  input_kind: str = 'voltage', method: str = 'zoh',
                  effects: Mapping[str, Mapping[str, ArrayLike]] | None = None,
                  x0: ArrayLike | None = None,
                  segments: Sequence[tuple[int, int]] | None = None,
                  measured_position: ArrayLike | None = None) -> dict[str, np.ndarray]:
    """:func:`simulate_batch` over separate runs joined in one record.

    Each run ``[a, b)`` of ``segments`` is simulated on its own, from its own initial
    state: ``x0`` holds one block of ``n0`` values per run side by side (shape
    ``(n_runs * n0,)`` or ``(P, n_runs * n0)``). Members that differ only in the
    initial states of other runs (a Jacobian's initial-state columns) are simulated
    once on this one. Without ``segments`` this is :func:`simulate_batch`.

    Returns
    -------
    dict
        ``'speed'`` and, for a voltage plant, ``'current'``, each (P, N).
    """
    if not segments or len(segments) == 1:
        return simulate_batch(theta, t, u, input_kind, method, effects, x0,
                              measured_position=measured_position)
    effects = effects or {}
    # the plants are discretised once on every interval of the record, not once a run
    disc = discretise_batch(theta, t, input_kind, method, effects,
                            measured_position is None and reads_position(effects))
    x0 = None if x0 is None else np.asarray(x0, dtype=float)
    n0 = None if x0 is None else x0.shape[-1] // len(segments)
    members = _member_table(theta, effects) \
        if x0 is not None and x0.ndim == 2 and np.ndim(u) == 1 else None
    parts = []
    for k, (a, b) in enumerate(segments):
        xk = None if x0 is None else np.ascontiguousarray(
            x0[..., k * cast(int, n0):(k + 1) * cast(int, n0)])
        if members is not None and xk is not None and xk.shape[0] == members.shape[0]:
            _, first, inverse = np.unique(np.concatenate([members, xk], axis=1), axis=0,
                                          return_index=True, return_inverse=True)
            if first.size < xk.shape[0]:
                part = disc.run(u[a:b], xk[first], (a, b), first, measured_position)
                parts.append({c: v[inverse.ravel()] for c, v in part.items()
                              if c in ('speed', 'current')})
                continue
        parts.append(disc.run(u[..., a:b], xk, (a, b), None, measured_position))
    return {c: np.concatenate([p[c] for p in parts], axis=1)
            for c in ('speed', 'current') if c in parts[0]}


def _member_table(theta: Mapping[str, ArrayLike],
                  effects: Mapping[str, Mapping[str, ArrayLike]]) -> np.ndarray | None:
    """Every batch parameter as a column, one row per member (None for one member)."""
    values = list(theta.values()) + [v for d in effects.values() for v in d.values()]
    P = batch_size({str(k): v for k, v in enumerate(values)})
    return np.column_stack([as_batch(v, P) for v in values]) if P > 1 else None


def _take(values: Mapping[str, ArrayLike], rows: np.ndarray) -> dict[str, ArrayLike]:
    """The batch parameters of the members ``rows`` (scalars as they are)."""
    return {k: (np.asarray(v)[rows] if np.ndim(v) else v) for k, v in values.items()}


def output_maps(Y: np.ndarray, channel: str,
                effects: Mapping[str, Mapping[str, ArrayLike]], P: int) -> np.ndarray:
    """The simulated ``channel`` (P, N) as its sensor reports it: the output maps of the
    effects on that channel (an encoder's count difference and grid, an ADC's grid)."""
    for name, vals in effects.items():
        spec = EFFECTS[name]
        if spec.output_map and spec.channel == channel:
            Y = spec.output_map.apply(Y, spec.batch(vals, P))
    return Y


def simulate_recording(plant: Plant, t: ArrayLike, u: ArrayLike, speed_noise: float = 0.0,
                       current_noise: float = 0.0, with_current: bool = True,
                       method: str = 'zoh',
                       random_state: int | np.random.Generator | None = None,
                       meta: Mapping[str, Any] | None = None) -> Recording:
    """Simulate one plant and return a :class:`motor_id.recording.Recording`.

    Parameters
    ----------
    plant : motor_id.model.Plant
    t, u : array_like
        Times [s] and input.
    speed_noise, current_noise : float
        Standard deviation of additive white Gaussian noise as a fraction of the
        channel's own standard deviation (0.005 = 0.5 %).
    with_current : bool
        Include the current channel (voltage plants only).
    method : {'zoh', 'euler'}
    random_state : int, Generator or None
    meta : dict, optional

    Returns
    -------
    Recording
    """
    from motor_id.recording import Recording

    rng = np.random.default_rng(random_state)   # a Generator comes back as is
    out = simulate_batch(plant.params.to_dict(), t, u, plant.input_kind, method,
                         plant.effects)
    speed = out['speed'][0]
    speed = speed + speed_noise * np.std(speed) * rng.standard_normal(speed.size)
    current = None
    if with_current and plant.input_kind == 'voltage':
        current = out['current'][0]
        current = current + current_noise * np.std(current) * rng.standard_normal(current.size)
    info = {'simulated': True, 'truth': plant.to_dict(), 'speed_noise': speed_noise,
            'current_noise': current_noise}
    info.update(meta or {})
    return Recording(np.asarray(t, dtype=float), np.asarray(u, dtype=float), speed,
                     current, plant.input_kind, info)
