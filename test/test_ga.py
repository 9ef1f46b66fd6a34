"""The genetic algorithm: bounds, reproducibility, progress, cancellation."""

import itertools

import numpy as np
import pytest

from motor_id.errors import ConfigError
from motor_id.ga import Bounds, GeneticAlgorithm

BOUNDS = Bounds(('a', 'b'), (1e-3, -5.0), (1e3, 5.0), (True, False))


def sphere(X):
    return (np.log10(X[:, 0]) - 1.0) ** 2 + (X[:, 1] - 2.0) ** 2


def test_bounds_round_trip_and_log_scale():
    v = np.array([[10.0, 2.0]])
    np.testing.assert_allclose(BOUNDS.decode(BOUNDS.encode(v)), v, rtol=1e-12)
    assert BOUNDS.decode(np.array([0.5, 0.5]))[0] == pytest.approx(1.0)


def test_bad_settings_are_rejected():
    with pytest.raises(ConfigError, match='low < high'):
        Bounds(('a',), (2.0,), (1.0,), (False,))
    with pytest.raises(ConfigError, match='low > 0'):
        Bounds(('a',), (0.0,), (1.0,), (True,))
    with pytest.raises(ConfigError, match='crossover'):
        GeneticAlgorithm(BOUNDS, crossover=1.5)


def test_same_seed_same_history_bit_for_bit():
    h1 = GeneticAlgorithm(BOUNDS, random_state=42).run(sphere).history_
    h2 = GeneticAlgorithm(BOUNDS, random_state=42).run(sphere).history_
    h3 = GeneticAlgorithm(BOUNDS, random_state=43).run(sphere).history_
    assert [h.to_dict() for h in h1] == [h.to_dict() for h in h2]
    assert [h.best_cost for h in h1] != [h.best_cost for h in h3]


def test_converges_and_keeps_the_best():
    ga = GeneticAlgorithm(BOUNDS, random_state=1).run(sphere)
    assert ga.evaluations_ == 20 * 160
    best = [h.best_cost for h in ga.history_]
    assert all(b2 <= b1 for b1, b2 in itertools.pairwise(best))  # elitism: monotone
    assert ga.best_cost_ < 1e-3
    np.testing.assert_allclose(ga.best_, [10.0, 2.0], rtol=0.05, atol=0.03)


def test_ask_tell_stop_and_cancel():
    ga = GeneticAlgorithm(BOUNDS, generations=50, random_state=0)
    n = 0
    while not ga.stop():
        ga.tell(sphere(ga.ask()))
        n += 1
        if n == 7:
            ga.cancel()
    assert n == 7 and ga.stop() == {'cancelled': True}
    with pytest.raises(ConfigError, match='without a preceding ask'):
        ga.tell(np.zeros(20))
