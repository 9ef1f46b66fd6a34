"""Input signals: the paper's Eq. 14 steps, bipolar steps, PRBS and multisine."""

import numpy as np
from numpy.typing import ArrayLike, NDArray

from motor_id.errors import ConfigError

PAPER_STEPS = ((0.0, 0.0), (3.0, 3.8), (16.0, 7.0), (28.0, 9.0))
"""The paper's Eq. 14 input: (start time [s], voltage [V])."""

PROFILES = ('paper_steps', 'bipolar_steps', 'prbs', 'multisine')


def paper_steps(t: ArrayLike, amplitude: float = 9.0) -> NDArray[np.float64]:
    """The paper's input: 0, 3.8, 7, 9 V from 0, 3, 16, 28 s (scaled to ``amplitude``)."""
    t = np.asarray(t, dtype=float)
    u = np.zeros_like(t)
    for start, level in PAPER_STEPS:
        u[t >= start] = level * amplitude / 9.0
    return u


def bipolar_steps(t: ArrayLike, amplitude: float = 9.0,
                  period: float = 4.0) -> NDArray[np.float64]:
    """Steps through +-amplitude levels so the motor reverses and stops."""
    t = np.asarray(t, dtype=float)
    levels = np.array([0.0, 0.5, 1.0, 0.0, -0.5, -1.0, 0.25, -0.25]) * amplitude
    k = np.floor(t / (period / 2)).astype(int) % levels.size
    return levels[k]


def prbs(t: ArrayLike, amplitude: float = 9.0, dwell: float = 0.3,
         random_state: int | np.random.Generator | None = 0,
         offset: float = 0.0) -> NDArray[np.float64]:
    """Pseudo-random binary sequence between ``offset +- amplitude`` with a minimum dwell."""
    t = np.asarray(t, dtype=float)
    rng = np.random.default_rng(random_state)
    n = int(np.ceil((t[-1] - t[0]) / dwell)) + 2 if t.size else 1
    bits = rng.integers(0, 2, n) * 2 - 1
    k = np.floor((t - (t[0] if t.size else 0.0)) / dwell).astype(int)
    return offset + amplitude * bits[k]


def multisine(t: ArrayLike, amplitude: float = 9.0, f_min: float = 0.05, f_max: float = 5.0,
              n_tones: int = 12,
              random_state: int | np.random.Generator | None = 0) -> NDArray[np.float64]:
    """Sum of log-spaced sines with Schroeder-like random phases, peak-scaled."""
    t = np.asarray(t, dtype=float)
    rng = np.random.default_rng(random_state)
    freqs = np.geomspace(f_min, f_max, n_tones)
    phases = rng.uniform(0, 2 * np.pi, n_tones)
    u = np.sin(2 * np.pi * freqs[None, :] * t[:, None] + phases[None, :]).sum(axis=1)
    peak = np.max(np.abs(u)) if u.size else 1.0
    return amplitude * u / (peak if peak > 0 else 1.0)


def make_excitation(name: str, t: ArrayLike, amplitude: float = 9.0,
                    random_state: int | np.random.Generator | None = 0) -> NDArray[np.float64]:
    """Evaluate a named profile at times ``t``."""
    if name == 'paper_steps':
        return paper_steps(t, amplitude)
    if name == 'bipolar_steps':
        return bipolar_steps(t, amplitude)
    if name == 'prbs':
        return prbs(t, amplitude, random_state=random_state)
    if name == 'multisine':
        return multisine(t, amplitude, random_state=random_state)
    raise ConfigError(f'unknown excitation {name!r}; choose one of {", ".join(PROFILES)}')
