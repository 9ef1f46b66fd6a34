"""The delay of a model family fitted by simulation error: a profile over whole samples,
then refined between them (:mod:`.simulation_fit` calls it for each family with a delay)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from motor_id.analysis.simulation_problem import fraction_keys, SimulationProblem
from motor_id.effects import EFFECTS

if TYPE_CHECKING:
    from motor_id.recording import Recording

PROFILE_POINTS = 10
"""Delays of the coarse profile (:func:`profile_delay`)."""
PROFILE_NFEV = 15
"""Residual evaluations of each brief refit of the delay profile."""
MAX_DELAY_S = 0.3
"""Longest input delay the stage tries [s] (and at most a fifth of the shortest block)."""


def delay_grid(rec: Recording, blocks: Sequence[tuple[int, int]]) -> np.ndarray:
    """Whole-sample delays the stage tries: every one up to 12, then about 8 % apart, to
    :data:`MAX_DELAY_S` or a fifth of the shortest block."""
    dt = float(np.median(np.diff(rec.time)))
    shortest = min(b - a for a, b in blocks)
    top = int(max(1, min(MAX_DELAY_S / dt, shortest / 5)))
    grid = np.unique(np.concatenate([np.arange(0, min(top, 12) + 1),
                                     np.rint(np.geomspace(12, max(top, 12), 30))]))
    return grid[grid <= top]


PROFILED = tuple(e for e, spec in EFFECTS.items()
                 if spec.params and all(p.spacing == 'integer' for p in spec.params))
"""Effects of a whole number of samples, found by :func:`profile_delay`."""


def samples_param(effect: str) -> str:
    """The parameter of a :data:`PROFILED` effect: its number of samples."""
    return str(EFFECTS[effect].params[0].name)


def profile_key(effect: str) -> str:
    """``'effect.param'`` of a :data:`PROFILED` effect's number of samples."""
    return f'{effect}.{samples_param(effect)}'


def profiled(family: Sequence[str]) -> str:
    """The effect of ``family`` that :func:`profile_delay` finds ('' for none; a family
    holds at most one, see :func:`.simulation_fit.pairs`)."""
    return next((e for e in family if e in PROFILED), '')


def with_delay(prob: SimulationProblem, d: float, effect: str) -> SimulationProblem:
    """``prob`` with its delay ``effect`` set to ``d`` samples."""
    return prob.variant(effects={**prob.model.effects,
                                 effect: {samples_param(effect): float(d)}})


def profiled_problem(prob: SimulationProblem, d: float, effect: str) -> SimulationProblem:
    """``prob`` at the delay ``d`` the profile chose, the delay free where it is refined
    between samples."""
    p = with_delay(prob, d, effect)
    keys = [k for k in fraction_keys({effect: None}) if k not in p.free]
    return p.variant(free=p.free + keys) if keys else p


def profile_delay(prob: SimulationProblem, blocks: Sequence[tuple[int, int]],
                   z0: np.ndarray | None, effect: str,
                   around: float | None = None) -> tuple[SimulationProblem, np.ndarray, int]:
    """The delay (of ``effect``: an input delay, a start latency) by profile: the model
    refitted (briefly) at each delay of a coarse grid, then at the neighbours of the
    best, then fully at the best. ``around``: the delay a smaller family found, whose
    neighbours replace the coarse grid.

    A delay cannot be found at the other parameters' start: a slow pole (a large L_m)
    that mimicked the delay in the equation-error fit makes every delay look worse there.
    Returns the problem at the chosen delay, its fit and the evaluations used.
    """
    grid = delay_grid(prob.rec, blocks)
    coarse = grid[:: max(1, grid.size // PROFILE_POINTS)]
    nfev = 0
    tried: dict[float, tuple[float, np.ndarray]] = {}

    def at(d: float) -> None:
        nonlocal nfev
        if d in tried:
            return
        p = with_delay(prob, d, effect)
        z, n = p.fit(blocks, z0, max_nfev=PROFILE_NFEV)
        nfev += n
        tried[d] = (p.cost(z, blocks), z)

    for d in (coarse if around is None else [around]):
        at(float(d))
    best = min(tried, key=lambda k: tried[k][0])
    i = int(np.searchsorted(grid, best))
    for j in range(max(0, i - 3), min(grid.size, i + 4)):
        at(float(grid[j]))
    best = min(tried, key=lambda k: tried[k][0])
    p = profiled_problem(prob, best, effect)   # and refined between samples
    z0 = np.concatenate([tried[best][1], [best]])[:len(p.free)]
    z, n = p.fit(blocks, z0)
    return p, z, nfev + n
