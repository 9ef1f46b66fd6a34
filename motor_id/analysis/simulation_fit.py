"""Fit and select the extended model by simulation error, the way benchmarks score it.

The equation-error stages of the analysis (one-step predictions, the inverse dynamics of a
closed-loop record) find which named effects a record needs. A user who simulates the
model from the input alone (the EMPS benchmark, a feedforward design, a SysId log's step
tests) judges it by its simulation error, where small force errors add up over seconds.
This stage starts from the analysis' chosen model and

1. splits each run into contiguous blocks; every block is simulated from the input alone,
   from a state set by its first ``init_samples`` samples (the benchmark protocol);
2. refits the model by least squares on the blocks' simulation error of the channels the
   benchmark scores (position where it is measured; else speed and current);
3. tries the refinements of its effects (:attr:`motor_id.model.EffectSpec.extends`:
   asymmetric, Stribeck and static friction refine Coulomb friction), each fitted on the
   training blocks and judged on the held-out blocks (every third), and keeps one only
   when it cuts the held-out simulation error by ``min_gain``;
4. refits the chosen model on every block.

Both models are reported: the equation-error one (for a closed-loop record, the inverse
dynamics estimate) and this one; ``motor-id validate`` simulates with this one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
import itertools
import math
from typing import Any, TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares

from motor_id.identify.validation import initial_state_at, SavedModel
from motor_id.model import EFFECTS, MECHANICAL_PARAMS
from motor_id.simulate import apply_input_maps, simulate_batch, split_input_maps

if TYPE_CHECKING:
    from motor_id.recording import Recording

MIN_BLOCK = 50
"""Fewest samples of a block after its initial ones."""
MAX_NFEV = 60
"""Residual evaluations of one candidate's least-squares fit (each one Jacobian is one
batched simulation of all the perturbed parameter sets)."""
VOLTAGE_FIT = ('J', 'K_T', 'K_b', 'B', 'L_m')


@dataclass
class SimCandidate:
    """One model fitted on simulation error."""

    name: str
    parameters: dict[str, float]
    effects: dict[str, dict[str, float]]
    train_rmse: dict[str, float] = field(default_factory=dict)
    heldout_rmse: dict[str, float] = field(default_factory=dict)
    heldout_cost: float = math.inf
    nfev: int = 0
    failed: str = ''

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {'name': self.name, 'parameters': self.parameters, 'effects': self.effects,
                'train_rmse': self.train_rmse, 'heldout_rmse': self.heldout_rmse,
                'heldout_cost': _finite(self.heldout_cost), 'nfev': self.nfev,
                **({'failed': self.failed} if self.failed else {})}


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def sim_channels(rec: Recording) -> tuple[str, ...]:
    """The channels the stage scores: the measured ones, position first; a speed that
    the importer derived from the position (``meta['speed_estimate']``) is left out."""
    if rec.has_position and 'speed_estimate' in rec.meta:
        return ('position',) + rec.channels()[1:]
    return (('position',) if rec.has_position else ()) + rec.channels()


def make_blocks(rec: Recording, n_blocks: int, init_samples: int) -> list[tuple[int, int]]:
    """Contiguous ``[start, stop)`` blocks inside each run, about ``n_blocks`` in all.

    A run too short for a block of :data:`MIN_BLOCK` scored samples is one block.
    """
    runs = rec.segment_ranges
    total = sum(b - a for a, b in runs)
    out: list[tuple[int, int]] = []
    for a, b in runs:
        k = max(1, round(n_blocks * (b - a) / total))
        k = max(1, min(k, (b - a) // (MIN_BLOCK + init_samples)))
        edges = np.linspace(a, b, k + 1).round().astype(int)
        out += [(int(x), int(y)) for x, y in itertools.pairwise(edges)
                if y - x > init_samples + 1]
    return out


class SimulationProblem:
    """Simulation error of a model family on the blocks of one recording."""

    def __init__(self, rec: Recording, model: SavedModel, init_samples: int,
                 free: Sequence[str]) -> None:
        self.rec = rec
        self.model = model
        self.n_init = init_samples
        self.free = list(free)
        self.channels = sim_channels(rec)
        self.scale = {ch: float(np.std(getattr(rec, ch))) or 1.0 for ch in self.channels}
        self.kind = model.input_kind
        self.n_states = 1 + (model.input_kind == 'voltage') + rec.has_position

    # parameter vector <-> model
    def unpack(self, z: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """``z`` of shape (P, n) -> batch parameters and effects."""
        theta: dict[str, Any] = dict(self.model.parameters)
        effects: dict[str, dict[str, Any]] = {e: dict(v) for e, v in self.model.effects.items()}
        for j, name in enumerate(self.free):
            e, _, p = name.partition('.')
            if p:
                effects[e][p] = z[:, j]
            else:
                theta[name] = np.exp(z[:, j])   # physical parameters: log scale
        return theta, effects

    def start(self) -> np.ndarray:
        """The model's own values as a parameter vector."""
        out = []
        for name in self.free:
            e, _, p = name.partition('.')
            out.append(self.model.effects[e][p] if p else math.log(self.model.parameters[name]))
        return np.array(out, dtype=float)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Allowed ranges (the catalogue's for effect parameters)."""
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

    def simulate(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]
                 ) -> list[dict[str, np.ndarray]]:
        """Per block: ``{channel: (P, n_scored)}`` simulated from the block's own start."""
        z = np.atleast_2d(z)
        P = z.shape[0]
        theta, effects = self.unpack(z)
        maps, rest = split_input_maps(effects)
        ueff = apply_input_maps(self.rec.input, maps, P)
        out = []
        pos = self.rec.has_position
        for a, b in blocks:
            k0 = a + self.n_init - 1
            x0 = np.broadcast_to(initial_state_at(self.rec, k0, self.n_init, self.kind,
                                                  theta, pos), (P, self.n_states))
            sim = simulate_batch(theta, self.rec.time[k0:b], np.ascontiguousarray(
                ueff[:, k0:b]), self.kind, 'zoh', rest, x0, position=pos)
            out.append({ch: sim[ch][:, 1:] for ch in self.channels})
        return out

    def residuals(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]) -> np.ndarray:
        """Scaled simulation errors, shape (P, M); a diverging member gets large ones."""
        sims = self.simulate(z, blocks)
        parts = []
        for (a, b), sim in zip(blocks, sims, strict=True):
            k0 = a + self.n_init - 1
            for ch in self.channels:
                y = getattr(self.rec, ch)[k0 + 1:b]
                parts.append((sim[ch] - y[None, :]) / self.scale[ch])
        r = np.concatenate(parts, axis=1)
        return np.where(np.isfinite(r), r, 1e3)

    def rmse(self, z: np.ndarray, blocks: Sequence[tuple[int, int]]) -> dict[str, float]:
        """Per channel RMSE [SI] over the scored samples of ``blocks``."""
        sims = self.simulate(z, blocks)
        out = {}
        for ch in self.channels:
            err = np.concatenate([sim[ch][0] - getattr(self.rec, ch)[a + self.n_init:b]
                                  for (a, b), sim in zip(blocks, sims, strict=True)])
            out[ch] = float(np.sqrt(np.mean(err ** 2)))
        return out

    def fit(self, blocks: Sequence[tuple[int, int]], z0: np.ndarray | None = None,
            max_nfev: int = MAX_NFEV) -> tuple[np.ndarray, int]:
        """Least squares on the simulation error of ``blocks``; ``(z, nfev)``."""
        z0 = self.start() if z0 is None else z0
        lo, hi = self.bounds()
        z0 = np.clip(z0, lo, hi)
        steps = 1e-4 * np.maximum(np.abs(z0), 1e-3)
        steps = np.where(np.isin(np.arange(z0.size), self._physical()), 1e-4, steps)

        def fun(z: np.ndarray) -> np.ndarray:
            return self.residuals(z[None, :], blocks)[0]

        def jac(z: np.ndarray) -> np.ndarray:
            zz = np.repeat(z[None, :], z.size + 1, axis=0)
            h = np.where(z + steps <= hi, steps, -steps)
            zz[1:] += np.diag(h)
            r = self.residuals(zz, blocks)
            return ((r[1:] - r[0]) / h[:, None]).T

        if not self.free:
            return z0, 0
        sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), x_scale='jac',
                            max_nfev=max_nfev, method='trf')
        return sol.x, int(sol.nfev)

    def _physical(self) -> list[int]:
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
    parameter of the dynamic effects."""
    names = list(MECHANICAL_PARAMS) if model.input_kind == 'torque' else list(VOLTAGE_FIT)
    if model.input_kind == 'voltage' and not rec.has_current:
        names = ['J', 'B']    # speed alone sees J/K and B/K: K_T, K_b, L_m stay as found
    for e, vals in model.effects.items():
        spec = EFFECTS[e]
        if spec.category != 'dynamic':
            continue
        for p in spec.params:
            if p.spacing != 'integer' and p.name in vals:
                names.append(f'{e}.{p.name}')
    return names


def refinements(model: SavedModel) -> list[str]:
    """Effects to try on ``model``, each alone first: the refinements of its effects, and
    an effect that refinements extend when the model lacks it (an equation-error stage
    that took asymmetric friction for a load torque never named Coulomb friction)."""
    out = [e for e, spec in EFFECTS.items()
           if spec.extends and spec.extends in model.effects and e not in model.effects
           and model.input_kind in spec.kinds]
    bases = {spec.extends for spec in EFFECTS.values() if spec.extends}
    return out + sorted(b for b in bases if b not in model.effects)


def pairs(helpful: Sequence[str]) -> list[tuple[str, ...]]:
    """Pairs of effects that each helped alone and can coexist (stiction and Stribeck
    friction both set the static level); an added base effect (Coulomb friction) that
    helped is also paired with each of its refinements."""
    out: list[tuple[str, ...]] = [(a, b) for a, b in itertools.combinations(helpful, 2)
           if {a, b} != {'stiction', 'stribeck_friction'}
           and not (EFFECTS[a].extends == b or EFFECTS[b].extends == a)]
    for base in helpful:
        out += [(base, e) for e, spec in EFFECTS.items() if spec.extends == base]
    return out


def _start_values(effect: str, effects: Mapping[str, Mapping[str, float]],
                  drive_scale: float) -> dict[str, float]:
    """A refinement's start: no change from the model it refines (static friction at the
    Coulomb level plus a little); an added Coulomb friction at 2 % of the largest drive
    torque ``drive_scale``."""
    vals = EFFECTS[effect].defaults()
    tc = effects.get('coulomb_friction', {}).get('T_c', 0.0)
    if effect == 'coulomb_friction':
        vals['T_c'] = 0.02 * drive_scale
    elif effect == 'asymmetric_friction':
        vals = {'dT_c': 0.0, 'dB': 0.0}
    elif effect in ('stiction', 'stribeck_friction'):
        vals['T_s'] = 1.2 * tc
    return vals


def simulation_stage(rec: Recording, model: SavedModel, init_samples: int = 20,
                     n_blocks: int = 6, min_gain: float = 0.05,
                     progress: Callable[[str], object] | None = None) -> dict[str, Any]:
    """Fit ``model`` and its refinements by simulation error; the JSON block.

    Parameters
    ----------
    rec : Recording
    model : SavedModel
        The analysis' chosen model (start values and effects).
    init_samples : int
        Samples at the start of each block that set its initial state.
    n_blocks : int
        About how many blocks the record is cut into; every third is held out.
    min_gain : float
        Fraction of the held-out simulation error a refinement must remove.
    progress : callable, optional

    Returns
    -------
    dict
        ``channels``, ``init_samples``, ``blocks``, ``heldout_blocks``, ``candidates``
        (each fitted on the training blocks, scored on the held-out ones), ``chosen``,
        ``model`` (the chosen model refitted on every block: ``input_kind``,
        ``parameters``, ``effects``) and ``rmse`` (its RMSE on every block).
    """
    say = progress or (lambda _msg: None)
    blocks = make_blocks(rec, n_blocks, init_samples)
    held = blocks[2::3] if len(blocks) >= 3 else []
    train = [b for b in blocks if b not in held] if held else blocks
    cands: list[SimCandidate] = []
    best: tuple[SimCandidate, np.ndarray, SimulationProblem] | None = None
    gain_needed = (1.0 - min_gain) ** 2    # on the squared error
    base_cost = math.inf
    helpful: list[str] = []
    singles: list[tuple[str, ...]] = [(e,) for e in refinements(model)]
    for stage in ('base', 'singles', 'pairs'):
        families: list[tuple[str, ...]] = ([()] if stage == 'base' else
                                           singles if stage == 'singles' else pairs(helpful))
        for extra in families:
            cand, z, prob = _fit_family(rec, model, extra, train, held, init_samples, say)
            cands.append(cand)
            if cand.failed or not math.isfinite(cand.heldout_cost):
                continue
            if stage == 'base':
                base_cost = cand.heldout_cost
            elif stage == 'singles' and cand.heldout_cost < gain_needed * base_cost:
                helpful.append(extra[0])
            if best is None or cand.heldout_cost < gain_needed * best[0].heldout_cost:
                best = (cand, z, prob)
    if best is None:
        return {'channels': list(sim_channels(rec)), 'init_samples': init_samples,
                'blocks': blocks, 'candidates': [c.to_dict() for c in cands],
                'chosen': None, 'model': None,
                'failed': 'no model could be fitted by simulation error'}
    chosen, best_z, best_prob = best
    say(f'simulation error: refitting {chosen.name} on all {len(blocks)} blocks')
    with np.errstate(all='ignore'):
        z, _ = best_prob.fit(blocks, best_z)
        params, effects = best_prob.to_model(z)
        rmse = best_prob.rmse(z, blocks)
    return {'method': 'least squares on the simulation error of each block, simulated from '
            'the input alone from a state set by its first samples',
            'channels': list(best_prob.channels), 'init_samples': init_samples,
            'blocks': [list(b) for b in blocks], 'heldout_blocks': [list(b) for b in held],
            'min_gain': min_gain, 'candidates': [c.to_dict() for c in cands],
            'chosen': chosen.name,
            'model': {'input_kind': model.input_kind, 'parameters': params,
                      'effects': effects},
            'friction': friction_summary(params, effects, model.input_kind),
            'rmse': rmse}


def _fit_family(rec: Recording, model: SavedModel, extra: tuple[str, ...],
                train: list[tuple[int, int]],
                held: list[tuple[int, int]], init_samples: int,
                say: Callable[[str], object]
                ) -> tuple[SimCandidate, np.ndarray, SimulationProblem]:
    """``model`` plus the refinements ``extra`` fitted on ``train``, scored on ``held``."""
    u_max = float(np.max(np.abs(rec.input)))
    scale = u_max if model.input_kind == 'torque' else \
        model.parameters['K_T'] * u_max / model.parameters['R_m']
    effects = dict(model.effects)
    for e in extra:   # in order: an added Coulomb friction before its refinements
        effects[e] = _start_values(e, effects, scale)
    m = SavedModel(model.input_kind, dict(model.parameters), effects, model.source)
    name = '+'.join(e for e in effects if EFFECTS[e].category == 'dynamic') or 'linear'
    prob = SimulationProblem(rec, m, init_samples, free_names(m, rec))
    say(f'simulation error: fitting {name} on {len(train)} blocks')
    cand = SimCandidate(name, {}, {})
    z = prob.start()
    try:
        with np.errstate(all='ignore'):
            z, cand.nfev = prob.fit(train)
            cand.parameters, cand.effects = prob.to_model(z)
            cand.train_rmse = prob.rmse(z, train)
            score_on = held or train
            if held:
                cand.heldout_rmse = prob.rmse(z, held)
            cand.heldout_cost = float(np.mean(prob.residuals(z[None, :], score_on) ** 2))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        cand.failed = f'{type(exc).__name__}: {exc}'
    return cand, z, prob


def friction_summary(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]],
                     input_kind: str) -> dict[str, float] | None:
    """Friction by direction, as axis makers state it: Fc+/Fc- (dry, with a constant
    load or force offset folded in) and Fv+/Fv- (viscous); None without dry friction."""
    if 'coulomb_friction' not in effects:
        return None
    tc = effects['coulomb_friction']['T_c']
    tl = effects.get('load_torque', {}).get('T_L', 0.0)
    asym = effects.get('asymmetric_friction', {})
    b = params['B']
    out = {'Fc+': tc + tl, 'Fc-': tc + asym.get('dT_c', 0.0) - tl,
           'Fv+': b, 'Fv-': b + asym.get('dB', 0.0)}
    for e in ('stiction', 'stribeck_friction'):
        if e in effects:
            out['F_static'] = effects[e]['T_s']
    if 'stribeck_friction' in effects:
        out['v_stribeck'] = effects['stribeck_friction']['v_s']
    return out
