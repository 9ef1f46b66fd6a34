"""Excitation profiles as the card plays them: one sample value per sample period."""

import math

import numpy as np
from numpy.typing import NDArray

from motor_id.errors import ConfigError
from motor_id.excitation import make_excitation, PROFILES

MAX_PROFILE_SAMPLES = 10_000_000
"""Longest profile a card (or the host, streaming it) plays, in samples."""


def profile_length(duration: float, period: float) -> int:
    """Samples of a profile lasting ``duration`` seconds at ``period`` seconds per sample.

    Returns 0 for a non-finite or non-positive duration.
    """
    if not (math.isfinite(duration) and duration > 0):
        return 0
    return math.ceil(duration / period - 1e-9)


def profile_samples(name: str, amplitude: float, seed: int, duration: float,
                    period: float) -> NDArray[np.float64]:
    """The voltages of profile ``name``, one per sample, as float32 values.

    The one definition of what a profile sends: the simulated card plays it when it
    gets a ``StartProfile`` frame, and the driver streams it as ``SetVoltage`` commands
    to a card that answers ``unsupported`` to profiles.

    Parameters
    ----------
    name : str
        One of :data:`motor_id.excitation.PROFILES`.
    amplitude : float
        Amplitude [V].
    seed : int
        Seed of random profiles (prbs, multisine).
    duration : float
        Length [s]; the profile has ``ceil(duration / period)`` samples.
    period : float
        Sample period [s]; sample ``k`` is the profile at ``k * period``.

    Returns
    -------
    ndarray of float
        Values rounded to float32 (what the wire carries), as float64.

    Raises
    ------
    ConfigError
        Unknown profile, or a length outside 1 .. :data:`MAX_PROFILE_SAMPLES` samples.
    """
    if name not in PROFILES:
        raise ConfigError(f'unknown profile {name!r}; choose one of {", ".join(PROFILES)}')
    n = profile_length(duration, period)
    if not 0 < n <= MAX_PROFILE_SAMPLES:
        raise ConfigError(f'a profile of {duration} s at {period} s per sample has {n} '
                          f'samples; allowed: 1 .. {MAX_PROFILE_SAMPLES}')
    values = make_excitation(name, np.arange(n) * period, amplitude, seed)
    return np.asarray(values, dtype=np.float32).astype(float)
