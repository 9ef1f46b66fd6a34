"""The simulation-error problem of one recording: blocks, residuals, Jacobian, fit.

A model family (the plant and its effects, some parameters free) is simulated on
contiguous blocks of a record from the input alone, each from a state set by its first
samples (or from its first sample when it opens a run at rest), and scored at the
samples each channel reports fresh. :mod:`.simulation_fit` fits and selects families on
it; :mod:`.simulation_uncertainty` puts error bars on the chosen one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import itertools
import math
from typing import Any, TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares

from motor_id.analysis.friction import folded_load
from motor_id.effects import EFFECTS, role_keys
from motor_id.identify.space import VOLTAGE_FREE
from motor_id.identify.validation import initial_state_at, run_init_samples, SavedModel
from motor_id.metrics import noise_floor, normalised_fit
from motor_id.model import MECHANICAL_PARAMS
from motor_id.simulate import apply_input_maps, discretise_batch, split_input_maps

if TYPE_CHECKING:
    from motor_id.recording import Recording

MIN_BLOCK = 50
"""Fewest samples of a block after its initial ones."""
MAX_NFEV = 60
"""Residual evaluations of one candidate's least-squares fit (each one Jacobian is one
batched simulation of all the perturbed parameter sets)."""
LOG_REACH = math.log(1e6)
"""A physical parameter is simulated within this (log) distance of its start: a fit that
drifts towards L_m = 0 meets a flat cost instead of a singular model."""


def sim_channels(rec: Recording) -> tuple[str, ...]:
    """The channels the stage scores: the measured ones, position first; a speed that
    the importer derived from the position (``meta['speed_estimate']``) is left out."""
    if rec.has_position and 'speed_estimate' in rec.meta:
        return ('position',) + rec.channels()[1:]
    return (('position',) if rec.has_position else ()) + rec.channels()


REST_SIGMAS = 3.0
"""A reading within this many of its noise levels of zero reads "at rest"."""


def _at_rest(rec: Recording, k: int, noise: Mapping[str, float] | None = None) -> bool:
    """The axis is at rest at sample ``k``: no input from ``k`` or over the interval
    before it, a speed reading of zero and, where measured, no current. The state at
    ``k`` is what the inputs before ``k`` left: a run that opens with a step from rest
    (a SysId test, the dynamic steps of ``motor-id experiment``) opens at rest. Zero is
    to a millionth of the channel's spread, or within :data:`REST_SIGMAS` of its noise
    level ``noise[channel]`` where given (a tachometer or an estimated speed is noisy at
    rest; an encoder at rest reads exactly zero).

    With a measured position and its noise level, the positions of the last
    :data:`REST_WINDOW` samples must not move either (their least-squares slope within
    :data:`REST_SIGMAS` of its noise): an arm that creeps down under its gravity at
    0.03 rad/s, three speed-noise levels, is not at rest. Set to zero there, its state
    biased the arm's kA (with the truth's effects held, J came out +6 % on both seeds
    tried, +2 to +3 % with this test).
    """
    def still(x: np.ndarray, ch: str) -> bool:
        tol = max(1e-6 * (float(np.std(x)) or 1.0), REST_SIGMAS * (noise or {}).get(ch, 0.0))
        return bool(abs(x[k]) <= tol)

    idle = rec.input[k] == 0 or (k > 0 and rec.input[k - 1] == 0)
    return bool(idle) and still(rec.speed, 'speed') and \
        (rec.current is None or still(rec.current, 'current')) and \
        _position_still(rec, k, noise or {})


REST_WINDOW = 5
"""Samples up to the one tested whose positions show whether the axis still moves."""


def _position_still(rec: Recording, k: int, noise: Mapping[str, float]) -> bool:
    """The positions of samples ``k - REST_WINDOW + 1 .. k`` have a slope within
    :data:`REST_SIGMAS` of what the position noise gives it. True without a position,
    its noise level or enough samples before ``k``, and where those samples are not one
    motion with ``k`` (:func:`_joined`: a SysId log's previous test ends moving, then
    the next opens at rest)."""
    if rec.position is None or 'position' not in noise or k < REST_WINDOW - 1:
        return True
    lo = k - REST_WINDOW + 1
    if not _joined(rec, lo, k, noise):
        return True
    t = rec.time[lo:k + 1]
    x = rec.position[lo:k + 1]
    tc = t - t.mean()
    ss = float(np.dot(tc, tc))
    if ss <= 0.0:
        return True
    slope = float(np.dot(tc, x - x.mean())) / ss
    return abs(slope) <= REST_SIGMAS * noise['position'] / math.sqrt(ss)


def _joined(rec: Recording, lo: int, k: int, noise: Mapping[str, float]) -> bool:
    """Samples ``lo .. k`` are one motion: every position step agrees with the speed
    readings either side of it (their mean times the interval) within
    :data:`REST_SIGMAS` of the two readings' noise."""
    if rec.position is None:
        return False
    dt = np.diff(rec.time[lo:k + 1])
    dx = np.diff(rec.position[lo:k + 1])
    w = rec.speed[lo:k + 1]
    moved = 0.5 * (w[1:] + w[:-1]) * dt
    tol = REST_SIGMAS * (math.sqrt(2.0) * noise['position'] + dt * noise.get('speed', 0.0))
    return bool(np.all(np.abs(dx - moved) <= tol))


def reading_noise(rec: Recording, fresh: Mapping[str, np.ndarray]) -> dict[str, float]:
    """White-noise level of the position, speed and current readings (their fresh
    samples), of those measured."""
    out = {}
    for ch in ('position', 'speed', 'current'):
        x = getattr(rec, ch)
        if x is not None:
            keep = fresh.get(ch)
            out[ch] = noise_floor(x if keep is None else x[keep])
    return out


def open_samples(rec: Recording, model: SavedModel, init_samples: int) -> int:
    """Initial samples of a block that opens a run not at rest.

    ``init_samples`` where they span less than the plant's mechanical time constant (a
    quadratic through their positions then stands for the state at their end: 20 samples
    of 1 ms on the EMPS axis, whose time constant is 0.47 s); else the scored run's own
    (:func:`~motor_id.identify.validation.run_init_samples`, as ``motor-id validate`` and
    the fit % per run take them): a SysId step test that a vendor logger (REV's URCL,
    CTRE's SignalLogger) logs from its first status frame opens moving, and 20 samples
    of a 20-40 ms loop (0.4-0.8 s against the drive's 0.05-0.2 s) left out the step's
    transient, all that shows kA.
    """
    p = model.parameters
    if model.input_kind == 'voltage':
        tau = p['J'] * p['R_m'] / (p['K_T'] * p['K_b'] + p['R_m'] * p['B'])
    else:
        tau = p['J'] / p['B'] if p['B'] > 0 else math.inf
    if (init_samples - 1) * rec.sample_period < tau:
        return init_samples
    return min(init_samples, run_init_samples(model.input_kind, rec.has_current))


def make_blocks(rec: Recording, n_blocks: int, init_samples: int,
                open_samples: int | None = None) -> list[tuple[int, int]]:
    """Contiguous ``[start, stop)`` blocks inside each run, about ``n_blocks`` in all.

    A run too short for a block of :data:`MIN_BLOCK` scored samples is one block. A block
    needs samples to score after its initial ones: ``init_samples``, or for a block that
    opens a run ``open_samples`` (default ``init_samples``; :func:`open_samples`), so a
    short run (a step test stopped early) can be a block of its own.
    """
    n_open = init_samples if open_samples is None else open_samples
    runs = rec.segment_ranges
    total = sum(b - a for a, b in runs)
    out: list[tuple[int, int]] = []
    for a, b in runs:
        k = max(1, round(n_blocks * (b - a) / total))
        k = max(1, min(k, (b - a) // (MIN_BLOCK + init_samples)))
        edges = np.linspace(a, b, k + 1).round().astype(int)
        out += [(int(x), int(y)) for x, y in itertools.pairwise(edges)
                if y - x > (n_open if x == a else init_samples) + 1]
    return out


class SimulationProblem:
    """Simulation error of a model family on the blocks of one recording."""

    def __init__(self, rec: Recording, model: SavedModel, init_samples: int,
                 free: Sequence[str], fresh: Mapping[str, np.ndarray] | None = None
                 ) -> None:
        self.rec = rec
        self.model = model
        self.n_init = init_samples
        self.free = list(free)
        self.channels = sim_channels(rec)
        self.scale = {ch: float(np.std(getattr(rec, ch))) or 1.0 for ch in self.channels}
        self.kind = model.input_kind
        self.n_states = 1 + (model.input_kind == 'voltage') + rec.has_position
        self.fresh = {ch: np.ones(len(rec), dtype=bool) if fresh is None or ch not in fresh
                      else np.asarray(fresh[ch], dtype=bool) for ch in self.channels}
        """Per channel: the samples scored (held readings: the fresh ones)."""
        self._start = self._start_vector()
        self._opens = {a for a, _ in rec.segment_ranges}
        self.n_open = open_samples(rec, model, init_samples)
        """Initial samples of a block that opens a run not at rest (:func:`open_samples`)."""
        noise = reading_noise(rec, self.fresh)
        self._rest = {a for a in self._opens if _at_rest(rec, a, noise)}

    def variant(self, parameters: Mapping[str, float] | None = None,
                effects: Mapping[str, Mapping[str, float]] | None = None,
                free: Sequence[str] | None = None) -> SimulationProblem:
        """This problem with the model's parameters, its effects or the free names
        replaced (the record, the initial samples and the scored samples kept)."""
        m = self.model
        model = SavedModel(m.input_kind, dict(m.parameters if parameters is None
                                              else parameters),
                           {e: dict(v) for e, v in (m.effects if effects is None
                                                    else effects).items()}, m.source)
        return SimulationProblem(self.rec, model, self.n_init,
                                 self.free if free is None else free, self.fresh)

    def first(self, a: int) -> int:
        """The sample a block from ``a`` is simulated from: after its initial samples;
        for a block that opens a run, its first sample when the run opens at rest (the
        state is known from that one sample, speed and current zero, and what follows, a
        step's delay included, is the model's to predict), else after :attr:`n_open`
        samples (:func:`open_samples`: as ``motor-id validate`` scores the run where
        ``n_init`` samples span more than the plant's time constant, so a step test that
        opens moving is fitted on its transient)."""
        if a in self._rest:
            return a
        return a + (self.n_open if a in self._opens else self.n_init) - 1

    # parameter vector <-> model
    def unpack(self, z: np.ndarray) -> tuple[dict[str, np.ndarray | float],
                                             dict[str, dict[str, np.ndarray | float]]]:
        """``z`` of shape (P, n) -> batch parameters and effects (held ones as floats)."""
        theta: dict[str, np.ndarray | float] = dict(self.model.parameters)
        effects: dict[str, dict[str, np.ndarray | float]] = {
            e: dict(v) for e, v in self.model.effects.items()}
        for j, name in enumerate(self.free):
            e, _, p = name.partition('.')
            if p:
                effects[e][p] = z[:, j]
            else:   # physical parameters: log scale, within a factor 1e6 of the start
                theta[name] = np.exp(np.clip(z[:, j], self._start[j] - LOG_REACH,
                                             self._start[j] + LOG_REACH))
        return theta, effects

    def start(self) -> np.ndarray:
        """The model's own values as a parameter vector."""
        return self._start.copy()

    def _start_vector(self) -> np.ndarray:
        out = []
        for name in self.free:
            e, _, p = name.partition('.')
            out.append(self.model.effects[e][p] if p else math.log(self.model.parameters[name]))
        return np.array(out, dtype=float)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Allowed ranges: the catalogue's for effect parameters; the physical ones are
        free (their logs: positive values; a finite bound would change the
        trust-region scaling of every step, and cost the fit its best minimum)."""
        lo, hi = [], []
        for name in self.free:
            e, _, p = name.partition('.')
            if p:
                spec = {q.name: q for q in EFFECTS[e].params}[p]
                lo.append(spec.low)
                hi.append(spec.high)
            else:
                lo.append(-np.inf)
                hi.append(np.inf)
        return np.array(lo), np.array(hi)

    def simulate(self, z: np.ndarray, blocks: Sequence[tuple[int, int]],
                 extra: Mapping[str, Mapping[str, Any]] | None = None
                 ) -> list[dict[str, np.ndarray]]:
        """Per block: ``{channel: (P, n_scored)}`` simulated from the block's own start;
        ``extra`` overrides effect parameters (arrays of shape (P,) for a batch)."""
        z = np.atleast_2d(z)
        P = z.shape[0]
        theta, effects = self.unpack(z)
        for e, vals in (extra or {}).items():
            effects[e] = {**effects.get(e, {}), **vals}
        maps, rest = split_input_maps(effects)
        ueff = apply_input_maps(self.rec.input, maps, P, self.rec.input_streams)
        out = []
        pos = self.rec.has_position
        disc = discretise_batch(theta, self.rec.time, self.kind, 'zoh', rest, pos)
        for a, b in blocks:
            k0 = self.first(a)
            x0 = np.broadcast_to(initial_state_at(self.rec, k0, k0 - a + 1, self.kind,
                                                  theta, pos), (P, self.n_states))
            if a in self._rest:   # a noisy reading at rest is not the state
                x0 = x0.copy()
                x0[:, :self.n_states - pos] = 0.0
            sim = disc.run(np.ascontiguousarray(ueff[:, k0:b]), x0, (k0, b), None,
                           self.rec.position)
            out.append({ch: sim[ch][:, 1:] for ch in self.channels})
        return out

    def residuals(self, z: np.ndarray, blocks: Sequence[tuple[int, int]],
                  extra: Mapping[str, Mapping[str, Any]] | None = None) -> np.ndarray:
        """Scaled simulation errors at the scored samples, shape (P, M) (rows in the
        order of :meth:`layout`); a diverging member gets large ones."""
        sims = self.simulate(z, blocks, extra)
        parts = []
        for (a, b), sim in zip(blocks, sims, strict=True):
            k0 = self.first(a)
            for ch in self.channels:
                keep = self.fresh[ch][k0 + 1:b]
                y = getattr(self.rec, ch)[k0 + 1:b][keep]
                parts.append((sim[ch][:, keep] - y[None, :]) / self.scale[ch])
        r = np.concatenate(parts, axis=1)
        return np.where(np.isfinite(r), r, 1e3)

    def layout(self, blocks: Sequence[tuple[int, int]]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per residual row: its block, channel (index into ``channels``) and sample."""
        blk, chan, samp = [], [], []
        for i, (a, b) in enumerate(blocks):
            k0 = self.first(a)
            for c, ch in enumerate(self.channels):
                k = np.arange(k0 + 1, b)[self.fresh[ch][k0 + 1:b]]
                blk.append(np.full(k.size, i))
                chan.append(np.full(k.size, c))
                samp.append(k)
        return np.concatenate(blk), np.concatenate(chan), np.concatenate(samp)

    def cost(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]) -> float:
        """The mean squared scaled residual of ``z`` (one parameter vector) over
        ``blocks``: the cost the stage compares candidates by (held-out, on the halves)."""
        return float(np.mean(self.residuals(z[None, :], blocks) ** 2))

    def _compared(self, z: np.ndarray, blocks: Sequence[tuple[int, int]], fresh: bool
                  ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per channel: the recorded and the simulated values of ``z`` over ``blocks``
        (each block from its own start), every sample after the first or (``fresh``)
        the fresh readings only."""
        sims = self.simulate(z, blocks)
        out = {}
        for ch in self.channels:
            y, yh = [], []
            for (a, b), sim in zip(blocks, sims, strict=True):
                k0 = self.first(a)
                keep = self.fresh[ch][k0 + 1:b] if fresh else slice(None)
                y.append(getattr(self.rec, ch)[k0 + 1:b][keep])
                yh.append(sim[ch][0][keep])
            out[ch] = (np.concatenate(y), np.concatenate(yh))
        return out

    def rmse(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]) -> dict[str, float]:
        """Per channel RMSE [SI] over the samples of ``blocks`` after their first."""
        return {ch: float(np.sqrt(np.mean((yh - y) ** 2)))
                for ch, (y, yh) in self._compared(z, blocks, False).items()}

    def fit_percent(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]
                    ) -> dict[str, float]:
        """Per channel: the normalised fit % (:func:`motor_id.metrics.normalised_fit`) of
        ``z`` simulated on ``blocks`` from each block's own start, over the scored
        samples (the fresh readings) of them all."""
        return {ch: normalised_fit(y, yh)
                for ch, (y, yh) in self._compared(z, blocks, True).items()}

    def fit(self, blocks: Sequence[tuple[int, int]], z0: np.ndarray | None = None,
            max_nfev: int = MAX_NFEV) -> tuple[np.ndarray, int]:
        """Least squares on the simulation error of ``blocks``; ``(z, nfev)``."""
        z0 = self.start() if z0 is None else z0
        lo, hi = self.bounds()
        z0 = np.clip(z0, lo, hi)

        def fun(z: np.ndarray) -> np.ndarray:
            return self.residuals(z[None, :], blocks)[0]

        def jac(z: np.ndarray) -> np.ndarray:
            return self.jacobian(z, blocks)

        if not self.free:
            return z0, 0
        sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), x_scale='jac',
                            max_nfev=max_nfev, method='trf')
        return sol.x, int(sol.nfev)

    def jacobian(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]) -> np.ndarray:
        """Forward-difference Jacobian of :meth:`residuals` (one batched simulation)."""
        _, hi = self.bounds()
        steps = 1e-4 * np.maximum(np.abs(z), 1e-3)
        steps = np.where(np.isin(np.arange(z.size), self.physical_indices()), 1e-4, steps)
        zz = np.repeat(z[None, :], z.size + 1, axis=0)
        h = np.where(z + steps <= hi, steps, -steps)
        zz[1:] += np.diag(h)
        r = self.residuals(zz, blocks)
        return ((r[1:] - r[0]) / h[:, None]).T

    def physical_indices(self) -> list[int]:
        return [j for j, n in enumerate(self.free) if '.' not in n]

    def to_model(self, z: np.ndarray) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
        """SI parameters and effects of ``z``."""
        theta, effects = self.unpack(np.atleast_2d(z))
        params = {k: float(np.ravel(v)[0]) for k, v in theta.items()}
        effs = {e: {p: float(np.ravel(v)[0]) for p, v in vals.items()}
                for e, vals in effects.items()}
        return params, effs


def free_names(model: SavedModel, rec: Recording) -> list[str]:
    """Parameters the stage fits: the plant's (R_m stays as given) and every continuous
    parameter of the dynamic effects, but a constant load that asymmetric Coulomb levels
    fold in (:func:`.friction.folded_load`: held at its start, the friction levels
    carry it)."""
    names = list(MECHANICAL_PARAMS) if model.input_kind == 'torque' else list(VOLTAGE_FREE)
    if model.input_kind == 'voltage' and not rec.has_current:
        # speed alone sees the three coefficients of b0 / (s^2 + a1 s + a0); K_T held as
        # found sets the scale, and J, B, L_m, K_b reach every (b0, a1, a0) (K_b held
        # too would pin kV = K_b + R_m B / K_T above K_b: an equation-error K_b too
        # high would be out of reach)
        names = ['J', 'B', 'L_m', 'K_b']
    held = set(role_keys(model.effects, 'load')) if folded_load(model.effects) else set()
    for e, vals in model.effects.items():
        spec = EFFECTS[e]
        if spec.category != 'dynamic':
            continue
        for p in spec.params:
            if p.spacing != 'integer' and p.name in vals and f'{e}.{p.name}' not in held:
                names.append(f'{e}.{p.name}')
    return names


def fraction_keys(effects: Mapping[str, object]) -> list[str]:
    """``effect.param`` of each delay of ``effects`` that is refined between samples
    (:attr:`motor_id.effects.EffectParam.fraction`)."""
    return [f'{e}.{p.name}' for e in effects if e in EFFECTS
            for p in EFFECTS[e].params if p.fraction]
