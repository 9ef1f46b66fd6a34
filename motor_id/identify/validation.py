"""Score a saved model on another recording: simulation from the input alone.

A model (the JSON of ``motor-id fit`` or ``motor-id analyze``: physical parameters, named
effects, the speed reading) is simulated on a recording it was not fitted to. Only what
the recording does not measure is estimated, and only from its first samples: the
measured channels start at their first measured values, an unmeasured current from a
least-squares match of the first ``init_samples`` samples. Each run of a joined recording
starts anew. The score is per channel, over the samples after the initial ones.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from motor_id.contracts import INPUT_KINDS
from motor_id.effects import count_reading, EFFECTS, role_keys
from motor_id.errors import ConfigError, DataError
from motor_id.identify.mechanism import check_mechanism
from motor_id.metrics import normalised_fit
from motor_id.model import MECHANICAL_PARAMS, PARAM_NAMES
from motor_id.recording import Recording
from motor_id.records import Record
from motor_id.simulate import apply_input_maps, simulate_batch, split_input_maps


@dataclass
class SavedModel:
    """A model as a report saved it: plant kind, physical parameters (SI), effects."""

    input_kind: str
    parameters: dict[str, float]
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    source: str = ''

    @classmethod
    def from_report(cls, report: dict[str, Any], source: str = '', use_simulation: bool = True
                    ) -> SavedModel:
        """Read the JSON of ``motor-id fit`` or ``motor-id analyze``.

        Undetermined parameters enter with their particular value: any point on an
        unseen direction gives the same input-output behaviour. An analyze report with a
        simulation-error model (``simulation.model``) gives that one unless
        ``use_simulation`` is False: then the equation-error model, the report's
        ``parameters`` with the effects of the search's chosen model (``chosen``, or
        ``chosen.equation_error`` where the stage chose the reported model).

        Raises
        ------
        ConfigError
            Not a report of either command, or a parameter without any value.
        """
        if not isinstance(report, dict) or 'parameters' not in report:
            raise ConfigError(f'{source or "the model"}: not a motor-id fit or analyze '
                              'report (no "parameters")')
        sim = (report.get('simulation') or {}).get('model') if use_simulation else None
        if sim:
            return cls(sim['input_kind'], {k: float(v) for k, v in sim['parameters'].items()},
                       {e: {p: float(v) for p, v in d.items()}
                        for e, d in sim['effects'].items()}, source)
        kind = report.get('input_kind') or report.get('data', {}).get('input_kind')
        if kind not in INPUT_KINDS:
            raise ConfigError(f'{source or "the model"}: the report names no plant kind '
                              '("input_kind": voltage or torque)')
        names = PARAM_NAMES if kind == 'voltage' else MECHANICAL_PARAMS
        params = {}
        for n in names:
            p = report['parameters'].get(n)
            v = None
            if isinstance(p, dict):
                v = p.get('value')
                if v is None:
                    v = p.get('particular_value')
            elif isinstance(p, (int, float)):
                v = p
            if v is None or not math.isfinite(float(v)):
                raise ConfigError(f'{source or "the model"}: parameter {n} has no value '
                                  'to simulate with')
            params[n] = float(v)
        effects = _effects(report)
        return cls(kind, params, effects, source)


def _effects(report: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Named effects of a fit report (``effects``) or of an analyze report (the chosen
    model's effects and the speed reading)."""
    out: dict[str, dict[str, float]] = {}
    if 'verdict' in report:      # analyze: the search's model (the stage's is read whole)
        chosen = report.get('chosen') or {}
        for e, vals in (chosen.get('equation_error') or chosen).get('effects', {}).items():
            out[e] = {p: float(v['value'] if isinstance(v, dict) else v)
                      for p, v in vals.items()}
        for key in role_keys(count_reading(), 'counted'):
            counted = report['parameters'].get(key)
            if isinstance(counted, dict) and counted.get('value'):
                out.update(count_reading())
        return out
    for e, vals in (report.get('effects') or {}).items():
        if e not in EFFECTS:
            raise ConfigError(f'unknown effect {e!r} in the model')
        out[e] = {p: float(v['value'] if isinstance(v, dict) else v) for p, v in vals.items()}
        grid = {k.partition('.')[2] for k in role_keys({e: None}, 'grid')}
        if grid:   # a sensor's grid is not simulated
            out[e] = {k: (0.0 if k in grid else v) for k, v in out[e].items()}
    return out


@dataclass(frozen=True)
class RunScore(Record):
    """The scores of one run (a SysId test, a joined file): its name and per channel
    ``{'fit_percent', 'rmse', 'samples'}``, as the whole recording's (``to_dict()``:
    ``{'name', 'channels'}``)."""

    name: str
    channels: dict[str, dict[str, float]]


@dataclass
class Validation:
    """What a model does on a recording: per-channel scores (of the whole recording and
    of each run) and the simulation."""

    channels: dict[str, dict[str, float]]
    init_samples: int
    initial_states: list[dict[str, float]]
    time: np.ndarray = field(repr=False)
    segment: np.ndarray = field(repr=False)
    measured: dict[str, np.ndarray] = field(repr=False)
    simulated: dict[str, np.ndarray] = field(repr=False)
    model: str = ''
    runs: tuple[RunScore, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (no sample arrays)."""
        return {'model': self.model, 'init_samples': self.init_samples,
                'channels': self.channels, 'initial_states': self.initial_states,
                'samples': int(self.time.size),
                'segments': int(self.segment.max()) + 1 if self.segment.size else 0,
                'runs': [r.to_dict() for r in self.runs]}

    def summary(self) -> str:
        """One line per channel for people, then one per run."""
        lines = [f'model {self.model or "(given)"} on {self.time.size} samples, '
                 f'{int(self.segment.max()) + 1} run(s); the first {self.init_samples} '
                 'sample(s) of each run set its initial state']
        for ch, m in self.channels.items():
            lines.append(f'  {ch:<8} fit {m["fit_percent"]:7.2f} %   RMSE {m["rmse"]:.4g}')
        return '\n'.join(lines + run_lines(self.runs))

    def rows(self) -> tuple[list[str], np.ndarray]:
        """CSV header and rows: ``time,segment,<ch>_measured,<ch>_simulated,...``."""
        header = ['time', 'segment']
        cols = [self.time, self.segment.astype(float)]
        for ch in self.channels:
            header += [f'{ch}_measured', f'{ch}_simulated']
            cols += [self.measured[ch], self.simulated[ch]]
        return header, np.column_stack(cols)


def run_lines(runs: tuple[RunScore, ...] | list[RunScore]) -> list[str]:
    """The fit % of each run by name (nothing for a single run)."""
    if len(runs) < 2:
        return []
    width = max(len(r.name) for r in runs)
    lines = ['fit % per run (simulated from its input alone):']
    for r in runs:
        lines.append(f'  {r.name:<{width}}  ' + '   '.join(
            f'{ch} {m["fit_percent"]:6.2f} %' for ch, m in r.channels.items()))
    return lines


def _scores(rec: Recording, sims: Mapping[str, np.ndarray], mask: np.ndarray,
            channels: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Fit % and RMSE per channel over the samples of ``mask``."""
    out = {}
    for ch in channels:
        y = getattr(rec, ch)[mask]
        yh = sims[ch][mask]
        out[ch] = {'fit_percent': normalised_fit(y, yh),
                   'rmse': float(np.sqrt(np.mean((y - yh) ** 2))), 'samples': int(y.size)}
    return out


def _run_scores(rec: Recording, sims: Mapping[str, np.ndarray], mask: np.ndarray,
                channels: tuple[str, ...]) -> tuple[RunScore, ...]:
    """The scores of each run, named by ``meta['segment_names']`` (or ``run N``)."""
    names = list(rec.meta.get('segment_names') or [])
    out = []
    for k, (a, b) in enumerate(rec.segment_ranges):
        inside = np.zeros(len(rec), dtype=bool)
        inside[a:b] = True
        name = names[k] if k < len(names) else f'run {k + 1}'
        out.append(RunScore(name=name, channels=_scores(rec, sims, mask & inside, channels)))
    return tuple(out)


def validate(model: SavedModel, rec: Recording, init_samples: int | None = None,
             mechanism: str | None = None) -> Validation:
    """Simulate ``model`` on ``rec`` from its input and score every measured channel.

    Parameters
    ----------
    model : SavedModel
    rec : Recording
        Possibly joined runs (:meth:`Recording.concatenate`); each starts anew.
    init_samples : int, optional
        Samples at the start of each run used to set its initial state (and left out of
        the score). Default: 1, or 2 when the current is not measured (the first speed
        change shows the initial current).
    mechanism : {'simple', 'elevator', 'arm'}, optional
        What the joint moves: the model must then carry that mechanism's gravity (a
        model fitted with the mechanism), which reads ``rec``'s measured position where
        it has one. None: whatever the model carries.

    Returns
    -------
    Validation
        With the scores of each run too (named as ``meta['segment_names']`` names them:
        a SysId log's tests).

    Raises
    ------
    DataError
        A plant kind other than the model's, or runs too short for the initial samples.

    Examples
    --------
    A model fitted on one record, simulated from the input of another:

    >>> from motor_id import fit_report, Identifier, SavedModel, validate
    >>> from motor_id.testing.recordings import paper_recording, SI_MOTOR
    >>> train = paper_recording(SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=1)
    >>> test = paper_recording(SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=2)
    >>> report = fit_report(train, Identifier(R_m=2.3, random_state=0)).to_dict()
    >>> val = validate(SavedModel.from_report(report), test)
    >>> sorted(val.channels), round(val.channels['speed']['fit_percent'])
    (['current', 'speed'], 99)
    """
    rec.validate()
    gravity = check_mechanism(rec, mechanism) if mechanism else ''
    if gravity and gravity not in model.effects:
        raise DataError(f'the model has no {gravity}: fit it with mechanism {mechanism!r}',
                        params=('mechanism',))
    if rec.input_kind != model.input_kind:
        raise DataError(f'the model is of a {model.input_kind} plant, the recording has '
                        f'{rec.input_kind} input')
    unmeasured = model.input_kind == 'voltage' and not rec.has_current
    n_init = init_samples if init_samples is not None else \
        run_init_samples(model.input_kind, rec.has_current)
    if n_init < 1:
        raise ConfigError(f'init_samples must be at least 1, got {n_init}',
                          params=('init_samples',))
    channels = (('position',) if rec.has_position else ()) + rec.channels()
    sims = {ch: np.empty(len(rec)) for ch in channels}
    states = []
    score_mask = np.ones(len(rec), dtype=bool)
    maps, rest = split_input_maps(model.effects)
    src = rec
    if maps:   # on each input stream: a delay at a run's start reaches back where it can
        src = replace(rec, input=apply_input_maps(rec.input, maps, 1, rec.input_streams)[0])
        model = SavedModel(model.input_kind, model.parameters,
                           {e: model.effects[e] for e in rest}, model.source)
    for a, b in rec.segment_ranges:
        if b - a <= n_init:
            raise DataError(f'a run of {b - a} samples leaves nothing to score after '
                            f'{n_init} initial sample(s)')
        seg = src.slice(a, b)
        if rec.has_position:
            out, x0 = _simulate_from(model, seg, n_init)
        else:
            x0 = _initial_state(model, seg, n_init, unmeasured)
            out = _simulate(model, seg, x0)
        for ch in channels:
            sims[ch][a:b] = out[ch]
        names = ('speed',) + (('current',) if model.input_kind == 'voltage' else ()) \
            + (('position',) if rec.has_position else ())
        states.append({n: float(v) for n, v in zip(names, x0, strict=False)})
        score_mask[a:a + n_init] = False
    return Validation(channels=_scores(rec, sims, score_mask, channels), init_samples=n_init,
                      initial_states=states, time=rec.time, segment=rec.segment_index(),
                      measured={ch: getattr(rec, ch) for ch in channels}, simulated=sims,
                      model=model.source,
                      runs=_run_scores(rec, sims, score_mask, channels))


def run_init_samples(input_kind: str, has_current: bool) -> int:
    """Samples at the start of a run that set its state when it is scored (the default
    of :func:`validate`): 1, or 2 for a voltage plant without a measured current (the
    first speed change shows the initial current)."""
    return 2 if input_kind == 'voltage' and not has_current else 1


def _simulate(model: SavedModel, rec: Recording, x0: np.ndarray) -> dict[str, np.ndarray]:
    with np.errstate(all='ignore'):
        out = simulate_batch(model.parameters, rec.time, rec.input, model.input_kind, 'zoh',
                             model.effects, x0, measured_position=rec.position)
    res = {'speed': out['speed'][0]}
    if 'current' in out:
        res['current'] = out['current'][0]
    if not all(np.all(np.isfinite(v)) for v in res.values()):
        raise DataError('the model diverges on this recording (non-finite simulation)')
    return res


def _simulate_from(model: SavedModel, rec: Recording, n_init: int
                   ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The benchmark protocol on one run with a measured position: the state at sample
    ``n_init - 1`` from the samples up to it (:func:`initial_state_at`), simulated from
    there on the input alone (a delayed input reaches back before it). The samples before
    carry the measured values (they are not scored)."""
    k0 = n_init - 1
    x0 = initial_state_at(rec, k0, n_init, model.input_kind, model.parameters, True)
    maps, rest = split_input_maps(model.effects)
    ueff = apply_input_maps(rec.input, maps, 1)[0]
    with np.errstate(all='ignore'):
        sim = simulate_batch(model.parameters, rec.time[k0:], np.ascontiguousarray(ueff[k0:]),
                             model.input_kind, 'zoh', rest, x0, position=True,
                             measured_position=rec.position[k0:]
                             if rec.position is not None else None)
    out = {}
    for ch in ('position',) + rec.channels():
        full = np.array(getattr(rec, ch), dtype=float)
        full[k0:] = sim[ch][0]
        if not np.all(np.isfinite(full)):
            raise DataError('the model diverges on this recording (non-finite simulation)')
        out[ch] = full
    return out, x0


def _initial_state(model: SavedModel, rec: Recording, n_init: int,
                   unmeasured: bool) -> np.ndarray:
    """Measured states from the first sample; an unmeasured current by least squares on
    the first ``n_init`` speed samples."""
    speed0 = float(rec.speed[0])
    if model.input_kind != 'voltage':
        return np.array([speed0])
    if not unmeasured and rec.current is not None:
        return np.array([speed0, float(rec.current[0])])
    # the current that drives the first samples: quasi-static guess, then least squares
    p = model.parameters
    guess = (rec.input[0] - p['K_b'] * speed0) / p['R_m']
    if n_init < 2:
        return np.array([speed0, guess])
    head = rec.slice(0, n_init)
    scale = max(abs(guess), float(np.max(np.abs(rec.input))) / p['R_m'], 1e-12)
    grid = guess + scale * np.linspace(-2.0, 2.0, 81)
    batch = {k: np.full(grid.size, float(v)) for k, v in p.items()}   # one per start
    with np.errstate(all='ignore'):
        out = simulate_batch(batch, head.time, head.input, 'voltage', 'zoh', model.effects,
                             np.column_stack([np.full(grid.size, speed0), grid]),
                             measured_position=head.position)
    cost = np.sum((out['speed'] - head.speed[None, :]) ** 2, axis=1)
    k = int(np.nanargmin(np.where(np.isfinite(cost), cost, np.inf)))
    from scipy.optimize import minimize_scalar  # lazy: only without a measured current

    step = grid[1] - grid[0]

    def err(i0: float) -> float:
        with np.errstate(all='ignore'):
            o = simulate_batch(p, head.time, head.input, 'voltage', 'zoh', model.effects,
                               np.array([speed0, i0]), measured_position=head.position)
        return float(np.sum((o['speed'][0] - head.speed) ** 2))

    sol = minimize_scalar(err, bounds=(grid[k] - step, grid[k] + step), method='bounded')
    return np.array([speed0, float(sol.x)])


def initial_state_at(rec: Recording, k: int, n_init: int, input_kind: str,
                     params: Mapping[str, ArrayLike], position: bool = False) -> np.ndarray:
    """The state at sample ``k`` from samples ``k - n_init + 1 .. k`` only (the benchmark
    protocol: the first samples of a run set its state, nothing after them).

    Speed: with a measured position and at least 3 samples, the slope at ``k`` of a
    quadratic fitted to the positions (a count difference would be one grid step
    noisy); else the measured speed at ``k``. Current (voltage plant): measured, or the
    one that gives the acceleration the samples show, ``(J dw/dt + B w) / K_T``.
    Position (with ``position``): as measured at ``k``. Parameters of shape (P,) give
    P states, shape (P, n); scalars one, shape (n,).
    """
    lo = max(0, k - n_init + 1)
    t = rec.time[lo:k + 1] - rec.time[k]
    if rec.position is not None and t.size >= 3:
        c = np.polyfit(t, rec.position[lo:k + 1], 2)
        w, acc = float(c[1]), float(2.0 * c[0])
    else:
        w = float(rec.speed[k])
        acc = float(np.polyfit(t, rec.speed[lo:k + 1], 1)[0]) if t.size >= 2 else 0.0
    x: list[ArrayLike] = [w]
    if input_kind == 'voltage':
        if rec.current is not None:
            x.append(float(rec.current[k]))
        else:
            J, B, K_T = (np.asarray(params[n], dtype=float) for n in ('J', 'B', 'K_T'))
            x.append((J * acc + B * w) / K_T)
    if position:
        x.append(float(rec.position[k]) if rec.position is not None else 0.0)
    return np.stack(np.broadcast_arrays(*(np.asarray(c, dtype=float) for c in x)), axis=-1)
