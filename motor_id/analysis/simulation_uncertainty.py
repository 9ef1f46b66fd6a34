"""Error bars and determinacy of a model fitted on simulation error.

A simulation error is not white: a force the model misses for a moment shifts the whole
rest of the block, so the residuals of one block move together, and the Gauss-Newton
covariance (which counts every sample as an independent observation) is far too small.
The error bars here are the largest of three estimates, each in the search coordinates
(logs of the physical parameters, effect parameters as they are):

1. Gauss-Newton, ``(J^T W J)^-1`` with each channel's noise level from its residuals;
2. the block sandwich (:func:`motor_id.identify.uncertainty.robust_covariance`): the
   spread of the score ``J^T r`` between blocks, each block simulated from its own
   start, so blocks are nearly independent however correlated the samples within one;
3. halves: the model refitted on the first and on the second half of the blocks
   (:func:`halves_split`: of each run, so each half is like a repeat recording), each
   from the stage's own start. For two independent halves the difference of their
   estimates has about twice the variance of each half's, four times the whole
   record's, so ``|a - b| / 2`` estimates one standard deviation of the estimate from
   the whole record. It is what a repeat recording would show, and the error bar is
   never smaller. Starting both from the stage's start (not from the whole-record
   estimate) also puts the optimiser's own spread into it: simulation errors with dry
   friction are piecewise smooth, and along a shallow valley (a load torque against
   asymmetric Coulomb levels: only Fc+ and Fc- are sharp) the fit stops at a point that
   depends on its path.

To that, in quadrature, a model error none of the three can see: a delay of a whole
number of samples (a start latency, an input delay held at a given value; the stage
refines its input delay between samples, where its covariance holds its part) stands
for a real one that lies anywhere between its neighbours on the grid (a robot's latency
is a few milliseconds that jitter, a fraction of a sample). The model is refitted at the
neighbouring delays (:func:`_delay_neighbours`); a value that moves by ``D`` per sample
of delay gets ``D / sqrt(3)`` (:data:`DELAY_SPREAD`), the root mean square of a delay
uniform over a sample each side, as ``std_delay``. Below a sample a delay and kA act
alike at low frequencies (``V(t - tau) ~ V - kV tau dw/dt``) and the data hardly tell
them apart: a continuous delay freed in the Gauss-Newton step moved kA by a third of its
real error at most. On the simulated arm (100 Hz, 3 ms latency) a one-sample input delay
took kA from 0.083 to 0.070 V s^2/rad (truth 0.080), and its error bar of 0.0017 put the
truth 4 to 8 of them away in each of 5 live runs that chose the delay.

A model without a delay refined between samples is refitted with one added and free
(:func:`_fraction_refit`), and each value's whole move goes into ``std_delay``: a
latency under a sample, which the held-out cost hardly sees, biases kA by about kV times
it (a SysId log of 5 ms samples with 2 ms: kA 3.5 % high, 98 of its Gauss-Newton error
bars); on a record without a latency the freed delay stays near 0 and so does the move
(where a delay uniform over [0, 1] sample had widened kA 75-fold).

A parameter is determined when the data see it: its column of the weighted Jacobian is
not (numerically) a combination of the others. A voltage plant measured by speed (and
position) alone never determines J, K_T, K_b, B and L_m one by one: the stage holds K_T
at the equation-error value, and reports the combinations the data do
determine, WPILib SysId's ``kS`` (per direction), ``kV`` and ``kA``, with error bars.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
import math

import numpy as np

from motor_id.analysis.friction import folded_load, friction_summary
from motor_id.analysis.simulation_problem import fraction_keys, SimulationProblem
from motor_id.analysis.simulation_result import (
    DerivedEstimate,
    ESTIMATES_METHOD,
    ParameterEstimate,
    StageEstimates,
)
from motor_id.effects import EFFECTS, role_keys, role_value
from motor_id.identify.determinacy import MAX_RELATIVE_STD
from motor_id.identify.uncertainty import (
    combine,
    delta_method,
    feedforward_of,
    robust_covariance,
)

RANK_TOL = 1e-7
"""Singular-value ratio of the column-scaled weighted Jacobian below which a direction
is not seen."""
ANGLES = {'offset': 'kG'}
"""Combinations that are angles, each with the amplitude it is the phase of: determined by
their error bar alone (an offset near 0 is no less known than one near 1 rad), and only
where the amplitude is (the angle of a gravity the data cannot tell from none is not
known, however alike the halves' values)."""
MAX_ANGLE_STD = 0.35
"""Largest error bar of a determined angle [rad] (20 deg)."""
HALF_NFEV = 40
"""Residual evaluations of each half's refit (it starts at the whole-record estimate)."""
DELAY_SPREAD = 1.0 / math.sqrt(3.0)
"""Standard deviation [samples] of a real delay uniform within one sample each side of
the whole number the stage found."""


def _noise_weights(r: np.ndarray, chan: np.ndarray, n_params: int) -> np.ndarray:
    """1 / (each channel's residual std) per row."""
    w = np.empty_like(r)
    for c in np.unique(chan):
        m = chan == c
        dof = max(m.sum() - n_params * m.mean(), 1.0)
        s = math.sqrt(float(np.sum(r[m] ** 2)) / dof) or 1.0
        w[m] = 1.0 / s
    return w


def _seen(Jw: np.ndarray) -> np.ndarray:
    """Per column: not in the numerical null space of the column-scaled Jacobian."""
    norm = np.linalg.norm(Jw, axis=0)
    if not Jw.size or not np.any(norm > 0):
        return np.zeros(Jw.shape[1], dtype=bool)
    Js = Jw / np.where(norm > 0, norm, 1.0)
    _, s, Vt = np.linalg.svd(Js, full_matrices=False)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    Vn = Vt[rank:].T
    proj = np.linalg.norm(Vn, axis=1) if Vn.size else np.zeros(Jw.shape[1])
    return (norm > 0) & (proj < 1e-3)


def _torque_scaled(name: str) -> bool:
    """``effect.param`` of an effect with a torque in it (catalogue scale ``torque...``):
    its SI values follow K_T's, which speed alone does not fix."""
    e, _, p = name.partition('.')
    return bool(p) and any(q.scale.startswith('torque') for q in EFFECTS[e].params)


def halves_split(blocks: Sequence[tuple[int, int]],
                 runs: Sequence[tuple[int, int]] | None = None
                 ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Two halves of the blocks, each like a repeat recording of the whole.

    Within each run the blocks in time order are cut into an earlier and a later half,
    so a record of one run splits into its earlier and its later half (a drift between
    them shows). Of the runs of several blocks, the first gives its earlier half to the
    first half, the next to the second, and so on in turn: the earlier and the later part
    of a run differ by more than noise (the low and the high speeds of a SysId ramp, where
    only the low ones tell kS from kV), so each half gets the one of a run and the other
    of the next, where giving the first half every earlier part left the second with
    high speeds only (on a real drivetrain's ramps kS 0 against 0.19 V). A run's middle
    block (an odd count, a run of one block) goes to the two sides in turn: a WPILib SysId
    log of two ramps and two step tests gives each half a ramp each way and one step test,
    where cutting the record at its middle left one half with ramps only, and so without
    the acceleration (kA) that only steps show.
    """
    runs = list(runs) if runs else [(min(a for a, _ in blocks), max(b for _, b in blocks))] \
        if blocks else []
    first: list[tuple[int, int]] = []
    second: list[tuple[int, int]] = []
    turn = flip = 0
    for lo, hi in runs:
        own = sorted(b for b in blocks if lo <= b[0] < hi)
        k = len(own) // 2
        early, late = (first, second) if flip % 2 == 0 else (second, first)
        early += own[:k]
        late += own[len(own) - k:]
        flip += k > 0
        if len(own) % 2:
            (first if turn % 2 == 0 else second).append(own[k])
            turn += 1
    return sorted(first), sorted(second)


def _halves(prob: SimulationProblem, z: np.ndarray, blocks: Sequence[tuple[int, int]],
            say: Callable[[str], object]) -> tuple[np.ndarray, np.ndarray] | None:
    first, second = halves_split(blocks, prob.rec.segment_ranges)
    if not first or not second:
        return None
    say(f'simulation error: refitting on each half ({len(first)} and {len(second)} '
        'blocks) for the error bars')
    return _half_fit(prob, z, first), _half_fit(prob, z, second)


def _half_fit(prob: SimulationProblem, z: np.ndarray, half: Sequence[tuple[int, int]]
              ) -> np.ndarray:
    """``prob`` fitted on the blocks of ``half``: from the stage's own start and from the
    whole record's estimate ``z``, the one that fits the half better.

    From the stage's start, not only from ``z``: where the cost has a long shallow
    valley (a load torque against asymmetric Coulomb levels) the optimiser stops at a
    point that depends on its path, and that spread belongs in the error bar too. From
    ``z`` as well: where the cost has two basins (a speed sensor's lag against the
    inertia: a fast wheel read through a slow filter, or a slow wheel read as it is),
    the start can lie in the other one, and a half stopped there differs from the whole
    record by the distance between the basins, not by what the half's data allow; the
    half's own best fit is the one a repeat recording would give.
    """
    fits = [prob.fit(half, max_nfev=HALF_NFEV)[0], prob.fit(half, z, max_nfev=HALF_NFEV)[0]]
    costs = [prob.cost(zz, half) for zz in fits]
    return fits[int(np.argmin(costs))]


def whole_sample_effects(effects: Mapping[str, object]) -> list[str]:
    """The effects of ``effects`` that are a whole number of samples (a delay)."""
    return [e for e in effects if e in EFFECTS and EFFECTS[e].params
            and all(p.spacing == 'integer' for p in EFFECTS[e].params)]


Neighbour = tuple[SimulationProblem, np.ndarray, float]
"""A refit of the model at another delay, and the share of its values' move that goes
into the error bars (:data:`DELAY_SPREAD` for a whole sample, 1 for the fraction)."""


def _delay_neighbours(prob: SimulationProblem, z: np.ndarray,
                      blocks: Sequence[tuple[int, int]], say: Callable[[str], object]
                      ) -> list[Neighbour]:
    """The model refitted (from ``z``, :data:`HALF_NFEV` evaluations) with each of its
    whole-sample delays one sample shorter (where it is not 0) and one longer (a delay
    refined between samples is free in the fit: its covariance holds its part), and,
    where it has no delay that is refined between samples, with one freed
    (:func:`_fraction_refit`)."""
    out: list[Neighbour] = []
    for e in whole_sample_effects(prob.model.effects):
        p = EFFECTS[e].params[0].name
        if f'{e}.{p}' in prob.free:
            continue
        d = float(prob.model.effects[e][p])
        for step in (-1.0, 1.0):
            if d + step < 0:
                continue
            q = prob.variant(effects={**prob.model.effects,
                                      e: {**prob.model.effects[e], p: d + step}})
            say(f'simulation error: refitting with {e} {d + step:g} samples for the error '
                'bars')
            zq, _ = q.fit(blocks, z, max_nfev=HALF_NFEV)
            out.append((q, zq, DELAY_SPREAD))
    if not fraction_keys(prob.model.effects):
        out += _fraction_refit(prob, z, blocks, say)
    return out + _lag_refit(prob, z, blocks, say) + _delay_as_lag_refit(prob, z, blocks, say)


FRACTION_START = 0.5
"""The delay [samples] the refit of :func:`_fraction_refit` starts from."""


def _fraction_delays(kind: str) -> list[tuple[str, list[str]]]:
    """The catalogue's delays refined between samples for a ``kind`` plant: each
    effect with its :func:`fraction_keys`, in catalogue order."""
    return [(e, fraction_keys({e: None})) for e, spec in EFFECTS.items()
            if fraction_keys({e: None}) and kind in spec.kinds]


def _fraction_refit(prob: SimulationProblem, z: np.ndarray,
                    blocks: Sequence[tuple[int, int]], say: Callable[[str], object]
                    ) -> list[Neighbour]:
    """The model of no delay refitted (from ``z``, :data:`HALF_NFEV` evaluations) with a
    delay that is refined between samples added and free: a latency under a sample, which
    the stage's held-out cost need not see (kA takes ``kV`` times it, and the two act
    alike at low frequencies), moves the values by what the model without it is off.
    That whole move goes into the error bars; on a record without a latency the delay
    comes out near 0 and so does the move."""
    out: list[Neighbour] = []
    for e, keys in _fraction_delays(prob.kind):
        effects = {**prob.model.effects, e: {**EFFECTS[e].defaults(),
                                             keys[0].partition('.')[2]: FRACTION_START}}
        q = prob.variant(effects=effects, free=prob.free + keys)
        say(f'simulation error: refitting with {e} free between samples for the error bars')
        zq, _ = q.fit(blocks, np.concatenate([z, [FRACTION_START]]), max_nfev=HALF_NFEV)
        out.append((q, zq, 1.0))
    return out


LAG_SHORT = 0.05
"""The winding's time constant [sample periods] that :func:`_lag_refit` leaves it."""
REJECTED = 2.0
"""A lag given to a delay, or a delay to a lag, whose refit has over this many times the
model's simulation error is an explanation the data reject: its move stays out of the
error bars. The refits that the error bars need came out at 0.93 to 1.56 times (the
simulated robot's wheel, arm and elevator, SysId JSON and .wpilog routines, 4 seeds
each); the 33-sample lag of a drivetrain whose wheels slip (the 2023 Miami log) given
to a delay, at 3.3 times, had made its kA not determined."""


def _lag_refit(prob: SimulationProblem, z: np.ndarray,
               blocks: Sequence[tuple[int, int]], say: Callable[[str], object]
               ) -> list[Neighbour]:
    """A speed-only voltage plant whose winding's time constant ``L_m / R_m`` came out
    over :data:`LAG_SHORT` of a sample, refitted (:data:`HALF_NFEV` evaluations) with
    that lag given to an input delay refined between samples instead, and ``L_m`` held
    short. Speed alone hardly tells a lag under a sample from a delay: on the simulated
    robot's wheel (100 Hz, a command acting 2.5 to 12.5 ms after the sample it answers)
    the fit put a 9.5 ms electrical time constant (truth 1 ms) in place of the latency,
    and kA came out +6 % high against error bars of 0.8 %; given to a delay, kA was
    +2.8 %. The whole move goes into ``std_delay``."""
    if prob.kind != 'voltage' or prob.rec.has_current or 'L_m' not in prob.free:
        return []
    params, effects = prob.to_model(z)
    T = prob.rec.sample_period
    lag = params['L_m'] / params['R_m'] / T - LAG_SHORT
    if not lag > 0.0:
        return []
    keys = fraction_keys(prob.model.effects)
    if keys:
        e, _, p = keys[0].partition('.')
        effects = {**effects, e: {**effects[e], p: effects[e][p] + lag}}
    else:
        delays = _fraction_delays(prob.kind)
        if not delays:
            return []
        e, keys = delays[0]
        effects = {**effects, e: {**EFFECTS[e].defaults(), keys[0].partition('.')[2]: lag}}
    held = {**params, 'L_m': LAG_SHORT * T * params['R_m']}
    free = [n for n in prob.free if n != 'L_m'] + [k for k in keys if k not in prob.free]
    q = prob.variant(held, effects, free)
    say('simulation error: refitting with the lag of the winding given to a delay for the '
        'error bars')
    zq, _ = q.fit(blocks, q.start(), max_nfev=HALF_NFEV)
    return [(q, zq, 1.0)] if _plausible(prob, z, q, zq, blocks, say) else []


def _plausible(prob: SimulationProblem, z: np.ndarray, q: SimulationProblem, zq: np.ndarray,
               blocks: Sequence[tuple[int, int]], say: Callable[[str], object]) -> bool:
    """The refit ``q`` at ``zq`` explains the blocks within :data:`REJECTED` times the
    simulation error of ``prob`` at ``z`` (else it says so)."""
    ratio = q.cost(zq, blocks) / prob.cost(z, blocks)
    if ratio <= REJECTED:
        return True
    say(f'simulation error: that refit has {ratio:.1f} times the error: the data reject it')
    return False


def _delay_as_lag_refit(prob: SimulationProblem, z: np.ndarray,
                        blocks: Sequence[tuple[int, int]], say: Callable[[str], object]
                        ) -> list[Neighbour]:
    """:func:`_lag_refit` the other way: a speed-only voltage plant whose input delay
    (refined between samples) has a fraction of a sample over :data:`LAG_SHORT`, refitted
    (:data:`HALF_NFEV` evaluations) with that fraction given to the winding's lag
    (``L_m / R_m`` longer by it, ``L_m`` free) and the delay held at its whole samples.
    A robot's commands act after a delay that jitters within a sample (they leave and
    arrive at any time between samples), behind an electrical lag of its own; speed
    alone tells neither from the other, and the fitted delay takes both: on the simulated
    robot's arm (100 Hz, commands acting 1 to 8 ms late, a 1 ms winding) 0.68 samples and
    kA 4.5 % low against error bars of 1.2 %. The real split lies anywhere between the two
    fits: the move's root mean square over that, ``move / sqrt(3)``
    (:data:`DELAY_SPREAD`), goes into ``std_delay`` (kA +- 6 % there)."""
    if prob.kind != 'voltage' or prob.rec.has_current or 'L_m' not in prob.free:
        return []
    params, effects = prob.to_model(z)
    T = prob.rec.sample_period
    out: list[Neighbour] = []
    for key in fraction_keys(prob.model.effects):
        if key not in prob.free:
            continue
        e, _, p = key.partition('.')
        d = float(effects[e][p])
        whole = math.floor(d + 1e-9)
        if not d - whole > LAG_SHORT:
            continue
        held = {**params, 'L_m': params['L_m'] + (d - whole) * T * params['R_m']}
        effs = {**effects, e: {**effects[e], p: float(whole)}}
        free = [n for n in prob.free if n != key]
        say(f'simulation error: refitting with the fraction of {e} given to the lag of the '
            'winding for the error bars')
        # the plant first, the effects held: with a break-away level free too, the fit
        # from the delay's values moved that level instead of J and stopped at 2.5 times
        # the cost
        plant = prob.variant(held, effs, [n for n in free if '.' not in n])
        zp, _ = plant.fit(blocks, plant.start(), max_nfev=HALF_NFEV)
        q = prob.variant(plant.to_model(zp)[0], effs, free)
        zq, _ = q.fit(blocks, q.start(), max_nfev=HALF_NFEV)
        if _plausible(prob, z, q, zq, blocks, say):
            out.append((q, zq, DELAY_SPREAD))
    return out


def _coords(q: SimulationProblem, zq: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """The search coordinates of ``names`` in the refit ``q`` at ``zq``: its free ones,
    or the values it holds (logs of physical parameters)."""
    out = []
    for name in names:
        if name in q.free:
            out.append(zq[q.free.index(name)])
            continue
        e, _, p = name.partition('.')
        out.append(q.model.effects[e][p] if p else math.log(q.model.parameters[name]))
    return np.array(out, dtype=float)


def _si(prob: SimulationProblem, z: np.ndarray) -> dict[str, float]:
    """The free parameters of ``z`` in SI units, by name."""
    params, effects = prob.to_model(z)
    out: dict[str, float] = {}
    for name in prob.free:
        e, _, p = name.partition('.')
        out[name] = effects[e][p] if p else params[name]
    return out


def _derived(prob: SimulationProblem, z: np.ndarray, cov: np.ndarray,
             halves: tuple[np.ndarray, np.ndarray] | None,
             fn: Callable[[dict[str, float], dict[str, dict[str, float]]],
                          Mapping[str, float] | None],
             neighbours: Sequence[Neighbour] = ()
             ) -> list[DerivedEstimate]:
    """Quantities ``fn(params, effects)`` of the model with delta-method error bars,
    floored by the halves' spread as the parameters are, and the delay's part from the
    ``neighbours`` (:func:`_delay_neighbours`) in quadrature; one whose error bar is over
    :data:`~motor_id.identify.determinacy.MAX_RELATIVE_STD` of its value is not
    determined (the fit's rule), with the interval of two error bars."""

    def values(zz: np.ndarray, of: SimulationProblem = prob) -> dict[str, float]:
        params, effects = of.to_model(zz)
        return dict(fn(params, effects) or {})

    base, std_model = delta_method(values, z, cov)
    ha = hb = None
    if halves is not None:
        ha, hb = values(halves[0]), values(halves[1])
    moved = [(values(zq, q), share) for q, zq, share in neighbours]
    out: list[DerivedEstimate] = []
    for key, val in base.items():
        std = std_model[key]
        pair = None
        if ha is not None and hb is not None:
            pair = (ha[key], hb[key])
            std = max(std, abs(ha[key] - hb[key]) / 2, abs(val - (ha[key] + hb[key]) / 2))
        std_delay = None
        if moved:
            std_delay = max(share * _angle_diff(key, m.get(key, val), val)
                            for m, share in moved)
            std = math.hypot(std, std_delay)
        entry = DerivedEstimate(name=key, value=float(val), std_model=std_model[key],
                                determined=True, halves=pair, std=std, std_delay=std_delay)
        amplitude = next((e for e in out if e.name == ANGLES.get(key)), None)
        if amplitude is not None and not amplitude.determined:
            entry = replace(entry, determined=False, note=(
                f'not determined by this record: {amplitude.name}, whose angle it is, is '
                'not determined'))
        elif key in ANGLES and std <= MAX_ANGLE_STD:
            pass   # an angle: its error bar, not its value, says what the data determine
        elif not std <= MAX_RELATIVE_STD * abs(val):
            lo, hi = float(val - 2 * std), float(val + 2 * std)
            entry = replace(entry, determined=False, interval=(lo, hi), note=(
                f'not determined by this record: its error bar is '
                f'{"over 1000" if not std <= 10 * abs(val) else f"{100 * std / abs(val):.0f}"} '
                f'% of the value (data allow about {lo:.3g} .. {hi:.3g})'))
        out.append(entry)
    return out


def _angle_diff(key: str, a: float, b: float) -> float:
    """``|a - b|``, for an angle the shortest way round."""
    return abs(math.remainder(a - b, 2.0 * math.pi)) if key in ANGLES else abs(a - b)


def stage_estimates(prob: SimulationProblem, z: np.ndarray,
                    blocks: Sequence[tuple[int, int]], halves: bool = True,
                    say: Callable[[str], object] | None = None) -> StageEstimates:
    """Values, error bars and determinacy of the free parameters at ``z`` (see the
    module notes); for a speed-only voltage plant also kS, kV, kA.

    Returns
    -------
    StageEstimates
        ``parameters`` by name (SI; effect parameters as ``effect.param``),
        ``combinations`` (a voltage plant's SysId constants), ``friction``.
    """
    say = say or (lambda _msg: None)
    r = prob.residuals(z[None, :], blocks)[0]
    J = prob.jacobian(z, blocks)
    blk, chan, _ = prob.layout(blocks)
    w = _noise_weights(r, chan, z.size)
    Jw, rw = J * w[:, None], r * w
    d = z.size
    eye = np.eye(d)
    H = Jw.T @ Jw
    cov_gn = np.linalg.pinv(H, rcond=1e-15)
    n_blocks = int(blk.max()) + 1 if blk.size else 1
    cov_rob = robust_covariance(Jw, rw, eye, blk, n_blocks) if n_blocks > 1 else cov_gn
    cov = combine(cov_gn, cov_rob)
    seen = _seen(Jw)
    half = _halves(prob, z, blocks, say) if halves else None
    nbrs = _delay_neighbours(prob, z, blocks, say) if halves else []
    std_z = np.sqrt(np.maximum(np.diag(cov), 0.0))
    floor = np.zeros(d) if half is None else \
        np.maximum(np.abs(half[0] - half[1]) / 2, np.abs(z - (half[0] + half[1]) / 2))
    std_final = np.maximum(std_z, floor)
    if nbrs:
        std_final = np.hypot(std_final, np.max(
            [share * np.abs(_coords(q, zq, prob.free) - z) for q, zq, share in nbrs],
            axis=0))
    values = _si(prob, z)
    ha = _si(prob, half[0]) if half is not None else None
    hb = _si(prob, half[1]) if half is not None else None
    speed_only = prob.kind == 'voltage' and not prob.rec.has_current
    physical = set(prob.physical_indices())
    params: dict[str, ParameterEstimate] = {}
    for j, name in enumerate(prob.free):
        v = values[name]
        log = j in physical
        std_m = abs(v) * std_z[j] if log else std_z[j]
        std = abs(v) * std_final[j] if log else std_final[j]
        determined, note = bool(seen[j]), ''
        if speed_only and (log or _torque_scaled(name)):
            determined = False
            note = ('speed alone determines kS, kV and kA, not this (K_T is held at the '
                    'equation-error value)')
        elif not seen[j]:
            note = 'the simulation error does not see it apart from the others'
        params[name] = ParameterEstimate(
            value=v, std=float(std) if determined else None, std_model=float(std_m),
            determined=determined, note=note,
            halves=(ha[name], hb[name]) if ha is not None and hb is not None else None)
    if folded_load(prob.model.effects):
        for name in (role_keys(prob.model.effects, 'kS', 'torque')
                     + role_keys(prob.model.effects, 'kS_extra_negative')):
            if name in params and params[name].determined:
                params[name] = replace(params[name], determined=False, std=None, note=(
                    'only as Fc+ and Fc- (see friction): a constant load folds into them'))
        params[role_keys(prob.model.effects, 'load')[0]] = ParameterEstimate(
            value=role_value(prob.model.effects, 'load'), std=None, std_model=None,
            determined=False,
            note='held at the equation-error value: a constant load and asymmetric '
            'Coulomb levels act alike (only Fc+ = T_c + T_L and Fc- = T_c + dT_c - T_L '
            'are determined)')
    for name in ('K_T',) if speed_only else ():
        params[name] = ParameterEstimate(
            value=prob.model.parameters[name], std=None, std_model=None, determined=False,
            note='held at the equation-error value (speed alone cannot tell it)')
    combinations = (tuple(_derived(prob, z, cov, half, feedforward_of, nbrs))
                    if prob.kind == 'voltage' else None)
    friction = _derived(prob, z, cov, half, lambda p, e: friction_summary(
        p, e, prob.kind), nbrs)
    return StageEstimates(method=ESTIMATES_METHOD, parameters=params,
                          combinations=combinations,
                          friction=tuple(friction) if friction and not speed_only else ())
