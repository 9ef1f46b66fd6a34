"""The paper's real-coded genetic algorithm, in ask / tell / stop form.

Genes live in the unit cube; :class:`Bounds` maps them to parameter values on a linear
or a log scale (log where a parameter spans decades). One generation is

1. elitism: the best ``elite`` individuals survive unchanged;
2. selection: linear-ranking roulette wheel (or binary tournament);
3. crossover: with probability ``crossover`` a pair is recombined by blend crossover
   (BLX-alpha), otherwise copied;
4. mutation: each gene with probability ``mutation`` gets a Gaussian step of
   ``mutation_scale`` (unit-cube units), clipped to the bounds.

Defaults are the paper's: population 20, crossover 0.75, mutation 0.04, 160 generations.
"""

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from motor_id.errors import ConfigError
from motor_id.records import Record

SELECTIONS = ('ranking', 'tournament')


@dataclass(frozen=True)
class Bounds:
    """Box bounds with a per-parameter scale.

    Parameters
    ----------
    names : tuple of str
    low, high : tuple of float
    log : tuple of bool
        True where the gene maps to ``exp`` of a linear range (requires low > 0).
    """

    names: tuple
    low: tuple
    high: tuple
    log: tuple

    def __post_init__(self) -> None:
        n = len(self.names)
        if not (len(self.low) == len(self.high) == len(self.log) == n):
            raise ConfigError('bounds: names, low, high and log must have the same length')
        for name, lo, hi, lg in zip(self.names, self.low, self.high, self.log, strict=True):
            if not (np.isfinite(lo) and np.isfinite(hi)) or not lo < hi:
                raise ConfigError(f'bounds for {name}: need finite low < high, '
                                  f'got [{lo}, {hi}]')
            if lg and lo <= 0:
                raise ConfigError(f'bounds for {name}: a log-scale range needs low > 0, '
                                  f'got {lo}')

    @property
    def dim(self) -> int:
        """Number of parameters."""
        return len(self.names)

    def _edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lo = np.array(self.low, dtype=float)
        hi = np.array(self.high, dtype=float)
        lg = np.array(self.log, dtype=bool)
        lo = np.where(lg, np.log(np.where(lg, lo, 1.0)), lo)
        hi = np.where(lg, np.log(np.where(lg, hi, 1.0)), hi)
        return lo, hi, lg

    def decode(self, genes: ArrayLike) -> NDArray[np.float64]:
        """Unit-cube genes (..., d) -> parameter values (..., d)."""
        lo, hi, lg = self._edges()
        z = lo + np.asarray(genes, dtype=float) * (hi - lo)
        return np.where(lg, np.exp(np.where(lg, z, 0.0)), z)   # exp of the log genes only

    def encode(self, values: ArrayLike) -> NDArray[np.float64]:
        """Parameter values (..., d) -> unit-cube genes (..., d), clipped to [0, 1]."""
        lo, hi, lg = self._edges()
        v = np.asarray(values, dtype=float)
        z = np.where(lg, np.log(np.where(lg, np.maximum(v, 1e-300), 1.0)), v)
        return np.clip((z - lo) / (hi - lo), 0.0, 1.0)


@dataclass(frozen=True)
class GenerationRecord(Record):
    """What one generation looked like (``to_dict()``: these keys in this order)."""

    generation: int
    best_cost: float
    mean_cost: float
    best: dict[str, float] = field(default_factory=dict)


class GeneticAlgorithm:
    """Real-coded bounded GA with an ask / tell / stop loop (as in pycma).

    Parameters
    ----------
    bounds : Bounds
    population : int
    generations : int
    crossover : float
        Probability that a selected pair is recombined.
    mutation : float
        Per-gene mutation probability.
    mutation_scale : float
        Standard deviation of a mutation step, in unit-cube units.
    blend_alpha : float
        BLX-alpha extension of the crossover interval.
    elite : int
        Individuals copied unchanged into the next generation.
    selection : {'ranking', 'tournament'}
    x0 : array_like, optional
        A parameter vector to seed one member of the first population.
    random_state : int, numpy.random.Generator or None
        Seed; the same seed reproduces the same run bit for bit.

    Notes
    -----
    Use ``while not ga.stop(): X = ga.ask(); ga.tell(cost(X))``. ``ask`` returns decoded
    parameter values; costs that are NaN or inf count as worst.
    """

    def __init__(self, bounds: Bounds, population: int = 20, generations: int = 160,
                 crossover: float = 0.75, mutation: float = 0.04, mutation_scale: float = 0.1,
                 blend_alpha: float = 0.3, elite: int = 1, selection: str = 'ranking',
                 x0: ArrayLike | None = None,
                 random_state: int | np.random.Generator | None = None) -> None:
        if population < 2:
            raise ConfigError(f'population must be >= 2, got {population}')
        if generations < 1:
            raise ConfigError(f'generations must be >= 1, got {generations}')
        if not 0.0 <= crossover <= 1.0:
            raise ConfigError(f'crossover probability must be in [0, 1], got {crossover}')
        if not 0.0 <= mutation <= 1.0:
            raise ConfigError(f'mutation probability must be in [0, 1], got {mutation}')
        if not 0 <= elite < population:
            raise ConfigError(f'elite must be in [0, population), got {elite}')
        if selection not in SELECTIONS:
            raise ConfigError(f'selection must be one of {SELECTIONS}, got {selection!r}')
        self.bounds = bounds
        self.population = int(population)
        self.generations = int(generations)
        self.crossover = float(crossover)
        self.mutation = float(mutation)
        self.mutation_scale = float(mutation_scale)
        self.blend_alpha = float(blend_alpha)
        self.elite = int(elite)
        self.selection = selection
        self.x0 = x0
        self.random_state = random_state
        self.rng_ = np.random.default_rng(random_state)   # a Generator comes back as is
        d = bounds.dim
        self.genes_ = self.rng_.random((self.population, d))
        if x0 is not None:
            self.genes_[0] = bounds.encode(np.asarray(x0, dtype=float))
        self.generation_ = 0
        self.evaluations_ = 0
        self.costs_: NDArray[np.float64] | None = None
        self.best_genes_: NDArray[np.float64] | None = None
        self.best_cost_ = np.inf
        self.history_: list[GenerationRecord] = []
        self._cancelled = False
        self._asked = False

    @property
    def best_(self) -> NDArray[np.float64] | None:
        """Best parameter vector found so far (decoded)."""
        return None if self.best_genes_ is None else self.bounds.decode(self.best_genes_)

    def ask(self) -> NDArray[np.float64]:
        """Return the current population as parameter values, shape (population, d)."""
        self._asked = True
        return self.bounds.decode(self.genes_)

    def tell(self, costs: ArrayLike) -> None:
        """Take the costs of the population from :meth:`ask` and breed the next one."""
        if not self._asked:
            raise ConfigError('tell() called without a preceding ask()')
        self._asked = False
        costs = np.asarray(costs, dtype=float).reshape(-1)
        if costs.size != self.population:
            raise ConfigError(f'tell() needs {self.population} costs, got {costs.size}')
        costs = np.where(np.isfinite(costs), costs, np.inf)
        self.evaluations_ += costs.size
        order = np.argsort(costs, kind='stable')
        if costs[order[0]] < self.best_cost_:
            self.best_cost_ = float(costs[order[0]])
            self.best_genes_ = self.genes_[order[0]].copy()
        finite = costs[np.isfinite(costs)]
        best = self.bounds.decode(self.genes_[order[0]])
        self.history_.append(GenerationRecord(
            self.generation_, float(costs[order[0]]),
            float(finite.mean()) if finite.size else float('inf'),
            {n: float(v) for n, v in zip(self.bounds.names, best, strict=True)}))
        self.costs_ = costs
        self.generation_ += 1
        self.genes_ = self._breed(self.genes_[order])

    def _select(self, k: int) -> np.ndarray:
        """Indices (into the rank-sorted population) of k parents."""
        P = self.population
        if self.selection == 'tournament':
            a = self.rng_.integers(0, P, k)
            b = self.rng_.integers(0, P, k)
            return np.minimum(a, b)
        # linear ranking, selection pressure 2: best gets weight 2/P, worst 0
        w = 2.0 * (P - np.arange(P)) / (P * (P + 1))
        return self.rng_.choice(P, size=k, p=w / w.sum())

    def _breed(self, ranked: np.ndarray) -> np.ndarray:
        P, d = ranked.shape
        children = np.empty_like(ranked)
        children[:self.elite] = ranked[:self.elite]
        n_new = P - self.elite
        n_pairs = (n_new + 1) // 2
        parents = ranked[self._select(2 * n_pairs)].reshape(n_pairs, 2, d)
        p1, p2 = parents[:, 0], parents[:, 1]
        do_cross = self.rng_.random(n_pairs) < self.crossover
        a = self.blend_alpha
        u = self.rng_.uniform(-a, 1 + a, (n_pairs, d))
        c1 = np.where(do_cross[:, None], p1 + u * (p2 - p1), p1)
        c2 = np.where(do_cross[:, None], p2 + u * (p1 - p2), p2)
        offspring = np.concatenate([c1, c2])[:n_new]
        mutate = self.rng_.random(offspring.shape) < self.mutation
        step = self.rng_.normal(0.0, self.mutation_scale, offspring.shape)
        offspring = np.where(mutate, offspring + step, offspring)
        children[self.elite:] = np.clip(offspring, 0.0, 1.0)
        return children

    def cancel(self) -> None:
        """Ask the loop to stop after the current generation."""
        self._cancelled = True

    def stop(self) -> dict[str, int]:
        """Return a dict of stop reasons (empty while the run should go on): the number of
        ``generations`` reached, ``cancelled`` (True)."""
        reasons: dict[str, int] = {}
        if self.generation_ >= self.generations:
            reasons['generations'] = self.generations
        if self._cancelled:
            reasons['cancelled'] = True
        return reasons

    def run(self, cost: Callable[[NDArray[np.float64]], ArrayLike],
            callback: Callable[['GeneticAlgorithm'], object] | None = None) -> 'GeneticAlgorithm':
        """Run to the end: ``cost(X) -> (population,)``; ``callback(ga)`` True cancels."""
        while not self.stop():
            self.tell(cost(self.ask()))
            if callback is not None and callback(self):
                self.cancel()
        return self
