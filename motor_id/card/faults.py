"""Faults a simulated card injects: torn, lost, repeated, reordered frames; spikes.

:class:`FaultConfig` says what and how often, :class:`FaultInjector` applies it to a
stream of samples and encoded frames (no I/O: :class:`motor_id.card.simulator.CardSimulator`
calls it).
"""

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, replace
import math

import numpy as np

from motor_id.card.protocol import HEADER, Sample
from motor_id.errors import ConfigError


@dataclass(frozen=True)
class FaultConfig:
    """Transport faults the simulated card injects into its sample frames.

    Attributes
    ----------
    garbage : float
        Probability per frame of a burst of 1..``garbage_max`` random bytes before it.
        The bytes never contain 0xA5 (the first sync byte), so each one is counted
        exactly once as garbage by :class:`~motor_id.card.stream.FrameParser`.
    garbage_max : int
    drop : float
        Probability that a frame is not sent (a sequence gap).
    bad_crc : float
        Probability that one payload bit of a frame is flipped (a CRC error).
    duplicate : float
        Probability that a frame is sent twice.
    reorder : float
        Probability that a frame is held back and sent after the next one.
    disconnect_every : float
        Wall-clock seconds between disconnects (0: never). The pty is closed, the
        ``link`` removed, and after ``disconnect_for`` seconds a new pty appears
        behind the same link.
    disconnect_for : float
        Wall-clock seconds the device is away.
    spike_every : float
        Card seconds between current spikes (0: never): one sample's current reads
        ``spike_current`` instead of the measured value (a sensor glitch or a stalled
        rotor seen by an over-current limit).
    spike_current : float
        The spike's current [A].

    Notes
    -----
    At most one of drop / bad_crc / duplicate / reorder hits a frame, tried in that
    order. Replies to commands are never corrupted.
    """

    garbage: float = 0.0
    garbage_max: int = 16
    drop: float = 0.0
    bad_crc: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    disconnect_every: float = 0.0
    disconnect_for: float = 1.0
    spike_every: float = 0.0
    spike_current: float = 50.0

    def __post_init__(self) -> None:
        for name in ('garbage', 'drop', 'bad_crc', 'duplicate', 'reorder'):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ConfigError(f'fault {name} is a probability in [0, 1], got {p}')
        if not 1 <= self.garbage_max <= 4096:
            raise ConfigError(f'garbage_max must be in [1, 4096], got {self.garbage_max}')
        if not (self.disconnect_every >= 0 and self.disconnect_for > 0):
            raise ConfigError('disconnect needs EVERY >= 0 and DOWN > 0 seconds')
        if not (self.spike_every >= 0 and math.isfinite(self.spike_current)):
            raise ConfigError('current_spike needs EVERY >= 0 seconds and a finite current')

    @property
    def any(self) -> bool:
        """True when some fault is switched on."""
        return any((self.garbage, self.drop, self.bad_crc, self.duplicate, self.reorder,
                    self.disconnect_every, self.spike_every))

    @classmethod
    def parse(cls, items: Iterable[str]) -> 'FaultConfig':
        """Build from CLI items.

        ``garbage=P[:MAX]``, ``drop=P``, ``bad_crc=P``, ``duplicate=P``, ``reorder=P``
        (probabilities per frame), ``disconnect=EVERY[:DOWN]`` (wall-clock seconds) and
        ``current_spike=EVERY[:AMPS]`` (card seconds, amperes).
        """
        values: dict[str, float] = {}
        garbage_max = FaultConfig.garbage_max
        for item in items or ():
            name, _, value = item.partition('=')
            first, _, second = value.partition(':')
            two = ('garbage', 'disconnect', 'current_spike')
            if name not in ('drop', 'bad_crc', 'duplicate', 'reorder') + two or \
                    (second and name not in two):
                raise ConfigError(
                    f'unknown fault {item!r}; use garbage=P[:MAX], drop=P, bad_crc=P, '
                    'duplicate=P, reorder=P, disconnect=EVERY[:DOWN] or '
                    'current_spike=EVERY[:AMPS]')
            try:
                if name == 'disconnect':
                    values['disconnect_every'] = float(first)
                    if second:
                        values['disconnect_for'] = float(second)
                elif name == 'current_spike':
                    values['spike_every'] = float(first)
                    if second:
                        values['spike_current'] = float(second)
                elif name == 'garbage':
                    values['garbage'] = float(first)
                    if second:
                        garbage_max = int(second)
                else:
                    values[name] = float(first)
            except ValueError:
                raise ConfigError(f'fault {item!r} needs a number, e.g. {name}=0.01') from None
        return cls(garbage_max=garbage_max, **values)


class FaultInjector:
    """Apply a :class:`FaultConfig` to a stream of encoded sample frames.

    Parameters
    ----------
    config : FaultConfig
    random_state : int, Generator or None

    Attributes
    ----------
    stats : collections.Counter
        ``frames`` (offered), ``dropped``, ``bad_crc``, ``duplicated``, ``reordered``,
        ``garbage_bytes``, ``garbage_bursts``, ``spikes``.
    """

    def __init__(self, config: FaultConfig | None = None,
                 random_state: int | np.random.Generator | None = None) -> None:
        self.config = config or FaultConfig()
        self._rng = np.random.default_rng(random_state)
        self._held: bytes | None = None
        self._next_spike = self.config.spike_every
        self.stats: Counter[str] = Counter()

    def sample(self, sample: Sample) -> Sample:
        """Apply the measurement faults (current spikes) to one sample; return it."""
        every = self.config.spike_every
        if not every or not sample.has_current or sample.t_card < self._next_spike:
            return sample
        self._next_spike = (math.floor(sample.t_card / every) + 1) * every
        self.stats['spikes'] += 1
        return replace(sample, current=float(np.float32(self.config.spike_current)))

    def reset(self) -> None:
        """Forget a held-back frame (the link went down)."""
        self._held = None

    def apply(self, frame: bytes) -> bytes:
        """Return the bytes to send for one encoded frame (may be empty or hold two)."""
        c, r = self.config, self._rng
        self.stats['frames'] += 1
        out = bytearray()
        if c.garbage and r.random() < c.garbage:
            junk = r.integers(0, 255, int(r.integers(1, c.garbage_max + 1)))
            junk[junk >= 0xA5] += 1
            out += junk.astype(np.uint8).tobytes()
            self.stats['garbage_bytes'] += junk.size
            self.stats['garbage_bursts'] += 1
        if c.drop and r.random() < c.drop:
            self.stats['dropped'] += 1
            frame = b''
        elif c.bad_crc and r.random() < c.bad_crc:
            bad = bytearray(frame)
            payload = len(frame) - HEADER.size - 4
            bit = int(r.integers(0, 8 * payload))
            bad[HEADER.size + bit // 8] ^= 1 << (bit % 8)
            frame = bytes(bad)
            self.stats['bad_crc'] += 1
        elif c.duplicate and r.random() < c.duplicate:
            frame = frame + frame
            self.stats['duplicated'] += 1
        elif c.reorder and self._held is None and r.random() < c.reorder:
            self._held = frame
            self.stats['reordered'] += 1
            return bytes(out)
        out += frame
        if frame and self._held is not None:
            out += self._held
            self._held = None
        return bytes(out)
