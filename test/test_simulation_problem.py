"""The simulation-error problem's blocks: where each block's simulation starts from."""

import numpy as np
import pytest

from motor_id.analysis.simulation_problem import SimulationProblem
from motor_id.identify.validation import SavedModel
from motor_id.recording import Recording
from motor_id.simulate import simulate_batch

P = {'J': 0.1, 'K_T': 1.0, 'K_b': 1.0, 'B': 0.05, 'L_m': 1e-3, 'R_m': 1.0}
FRICTION = {'coulomb_friction': {'T_c': 1.0}}
T = 0.01
N_INIT = 20


def _two_runs(held: float) -> Recording:
    """A motor held by its friction (1 N m) at ``held`` volts, then a run opening with a
    6 V step from its first sample for 0.15 s (shorter than the initial samples),
    noise-free, with its position."""
    n = 120
    t = np.arange(2 * n) * T
    u = np.full(2 * n, held)
    u[n:n + 15] = 6.0
    u[n + 15:] = 0.0
    out = simulate_batch(P, t, u, 'voltage', 'zoh', FRICTION, position=True)
    return Recording(t, u, out['speed'][0], segments=[(0, n), (n, 2 * n)],
                     position=out['position'][0])


def _problem(rec: Recording) -> SimulationProblem:
    return SimulationProblem(rec, SavedModel('voltage', dict(P), FRICTION), N_INIT, [])


def test_a_run_that_opens_with_a_step_from_rest_is_simulated_from_its_first_sample():
    # the step of a SysId test or of `motor-id experiment` starts at the run's first
    # sample: the state there is what the rest before left (speed and current zero).
    # Before, it was taken from a quadratic over the first 20 samples, across the step's
    # end: the true model missed this noise-free record by 0.42 rad/s (11 % of the speed's
    # spread) and 0.15 rad
    rec = _two_runs(held=0.0)
    prob = _problem(rec)
    assert prob.first(120) == 120
    err = prob.rmse(prob.start(), [(120, 240)])
    assert err['speed'] == pytest.approx(0.0, abs=1e-9 * np.ptp(rec.speed))
    assert err['position'] == pytest.approx(0.0, abs=1e-9)


def test_a_run_that_opens_after_a_holding_input_sets_its_state_from_its_first_samples():
    # 0.5 V held the axis on its friction: the speed reads zero, but the current does
    # not: not at rest, the run's first samples set the state (as `motor-id validate`
    # scores the run: 2 without a measured current); a block inside a run from its own
    rec = _two_runs(held=0.5)
    assert rec.speed[120] == 0.0
    prob = _problem(rec)
    assert prob.n_open == 2
    assert prob.first(120) == 120 + prob.n_open - 1
    assert prob.first(150) == 150 + N_INIT - 1
