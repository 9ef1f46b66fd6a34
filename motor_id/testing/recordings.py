"""The paper's experiment, simulated: the recordings the tests fit."""

import numpy as np

from motor_id.excitation import paper_steps
from motor_id.model import MotorParams, PAPER_MOTOR, Plant
from motor_id.recording import Recording
from motor_id.simulate import simulate_recording

PAPER_T = np.arange(4000) * 0.01
"""The paper's time base: 4000 samples at 10 ms [s]."""
SI_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
"""The paper's motor with K_T = K_b, as SI units require."""


def paper_recording(params: MotorParams = PAPER_MOTOR, speed_noise: float = 0.0,
                    current_noise: float = 0.0, seed: int = 0, with_current: bool = True,
                    effects: dict | None = None, method: str = 'zoh') -> Recording:
    """The paper's Eq. 14 experiment: 4000 samples at 10 ms.

    Parameters
    ----------
    params : MotorParams
        The true motor.
    speed_noise, current_noise : float
        Standard deviation of white noise on each channel as a fraction of the channel's
        own standard deviation (0.005 = 0.5 %).
    seed : int
        Seed of the noise.
    with_current : bool
        Whether the recording has a current channel.
    effects : dict, optional
        Named effects ``{effect: {param: value}}`` of the true plant.
    method : {'zoh', 'euler'}
        Discretisation of the simulation.

    Returns
    -------
    Recording
    """
    return simulate_recording(Plant(params, 'voltage', effects or {}), PAPER_T,
                              paper_steps(PAPER_T), speed_noise, current_noise,
                              with_current, method, seed)
