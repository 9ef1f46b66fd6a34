"""The virtual card's behaviour without I/O: commands in, samples out, in card time.

* :class:`VirtualCard` is the card's behaviour without any I/O: it answers commands and
  produces :class:`~motor_id.card.protocol.Sample` objects in card time. The plant is
  advanced with :func:`motor_id.simulate.simulate_batch`, the same code the fitter
  uses, so every named effect of :data:`motor_id.effects.EFFECTS` behaves identically.
* :class:`motor_id.card.simulator.CardSimulator` serves it on a pseudo-terminal and
  :mod:`motor_id.card.faults` corrupts its frames.

How the plant is advanced exactly
---------------------------------
The input of the card is known ahead of time: a held voltage stays until the next
command and a profile is evaluated in full when it starts. The card therefore keeps a
*plan* of the next ``horizon`` samples. Whenever a command changes the input, or the
plan runs out, it re-simulates the whole input history since start plus the new plan
in one ``simulate_batch`` call. Effects with memory (input delay, sensor lag,
resistance drift, the resonant shaft) are thus continued exactly, not restarted per
chunk, and the stream equals ``simulate_batch(t, voltage)`` of the received samples
(up to the float32 wire format). Commands are rare, so the cost is one simulation of
the history per command and per ``horizon`` samples. After ``max_history`` samples the
history is cut: the simulation restarts from the exact state vector at that point, but
the internal states of input delay, sensor lag and resistance drift (and the resonant
load speed) restart there too (documented approximation; 200000 samples by default).

The command watchdog
--------------------
With ``watchdog`` > 0 the card stops the motor when the host goes silent, as the
firmware does (``firmware/motor_card.h``): while it holds a commanded voltage or plays a
profile, a sample taken ``watchdog`` card seconds or more after the last command of any
kind (a ``Ping`` will do) is at 0 V, the profile is abandoned and the card is idle until
the next command. The plan is made without the watchdog; when it fires the card
re-plans from that sample on, exactly as after a ``Stop``, so a host that pings costs
nothing.
"""

from collections.abc import Callable
from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np

from motor_id.card.profile import MAX_PROFILE_SAMPLES, profile_length, profile_samples
from motor_id.card.protocol import (
    Command,
    Ping,
    Reply,
    Sample,
    SetPeriod,
    SetVoltage,
    StartProfile,
    Stop,
)
from motor_id.contracts import FLAG_PROFILE, FLAG_PROFILE_END, FLAG_STARTUP
from motor_id.errors import ConfigError
from motor_id.excitation import PROFILES
from motor_id.model import DISCRETISATIONS, Plant
from motor_id.records import Record
from motor_id.simulate import simulate_batch

MIN_PERIOD = 1e-4
MAX_PERIOD = 10.0

_IDLE, _EXTERNAL, _PROFILE = 'idle', 'external', 'profile'
"""What drives the card's output: nothing (0 V), a held command, a profile."""


@dataclass(frozen=True)
class WatchdogTrip:
    """The watchdog stopped the motor: from sample ``seq`` at card time ``t_us`` [us] on,
    0 V; the last command had come at card time ``last_command_us`` [us]."""

    seq: int
    t_us: int
    last_command_us: int

    @property
    def silence(self) -> float:
        """Card seconds without a command before the stop."""
        return (self.t_us - self.last_command_us) / 1e6


def _check_period(period: float) -> int:
    if not (isinstance(period, (int, float)) and MIN_PERIOD <= period <= MAX_PERIOD):
        raise ConfigError(f'sample period must be in [{MIN_PERIOD}, {MAX_PERIOD}] s, '
                          f'got {period!r}')
    return round(period * 1e6)


_CARD_UNITS = {'speed_noise': 'rad/s', 'current_noise': 'A', 'period': 's', 'watchdog': 's'}


@dataclass(frozen=True)
class CardTruth(Record):
    """What a :class:`VirtualCard` simulates: its true plant, noise and settings.

    Attributes
    ----------
    params : dict of str to float
    input_kind : str
    effects : dict of str to dict
        The true plant (:class:`~motor_id.model.Plant`), its keys in its JSON's order.
    method : str
        Discretisation of the plant.
    period, watchdog : float
        Sample period and watchdog time [s] (watchdog 0: off).
    with_current, profiles : bool
    speed_noise, current_noise : float
        Standard deviations [rad/s], [A].
    units : dict of str to str
    """

    params: dict[str, float]
    input_kind: str
    effects: dict[str, dict[str, float]]
    method: str
    period: float
    with_current: bool
    profiles: bool
    watchdog: float
    speed_noise: float
    current_noise: float
    units: dict[str, str] = field(default_factory=lambda: dict(_CARD_UNITS))


class VirtualCard:
    """The card's logic in card time: commands in, samples out, no I/O.

    Parameters
    ----------
    plant : motor_id.model.Plant, optional
        The true motor and its effects (default: the paper's motor, no effects).
    period : float
        Initial sample period [s] (whole microseconds).
    with_current : bool
        Send the current (ignored for torque plants, which have none).
    speed_noise, current_noise : float
        Standard deviation of white measurement noise [rad/s] and [A] (absolute: a
        streaming card does not know the signals' spread in advance).
    method : {'zoh', 'euler'}
        Discretisation of the true plant.
    max_input : float
        Largest |voltage| or profile amplitude the card accepts [V].
    horizon : int
        Samples planned ahead per simulation.
    max_history : int
        Samples of input history kept for exact continuation (see the module notes).
    profiles : bool
        False: a card without built-in profiles, answering ``unsupported`` to every
        ``StartProfile`` (the host then streams the profile as ``SetVoltage`` commands).
    watchdog : float
        Card seconds without a command after which a held voltage or a running profile
        drops to 0 V (see the module notes); 0: no watchdog.
    random_state : int, Generator or None
        Seeds the measurement noise.

    Notes
    -----
    Sample ``k`` carries the speed and current measured at ``t_card[k]`` and the
    voltage applied from ``t_card[k]`` to ``t_card[k+1]``, the convention of
    :func:`motor_id.simulate.simulate_batch` and :class:`motor_id.recording.Recording`.
    The applied voltage is rounded to float32 first, so the reported value is the
    applied one exactly. Commands act from the next sample; a reply's ``value`` is that
    sample's sequence number. The card starts at rest holding 0 V.

    Attributes
    ----------
    watchdog_trips : int
        Times the watchdog stopped the motor.
    last_trip : WatchdogTrip or None
        When it last did.
    """

    def __init__(self, plant: Plant | None = None, period: float = 0.01,
                 with_current: bool = True, speed_noise: float = 0.0,
                 current_noise: float = 0.0, method: str = 'zoh', max_input: float = 100.0,
                 horizon: int = 1024, max_history: int = 200_000, profiles: bool = True,
                 watchdog: float = 0.0,
                 random_state: int | np.random.Generator | None = None) -> None:
        self.plant = Plant() if plant is None else plant
        if not isinstance(self.plant, Plant):
            raise ConfigError(f'plant must be a motor_id.model.Plant, got {plant!r}')
        if method not in DISCRETISATIONS:
            raise ConfigError(f'method must be one of {DISCRETISATIONS}, got {method!r}')
        for name, value in (('speed_noise', speed_noise), ('current_noise', current_noise)):
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f'{name} must be a finite std >= 0, got {value}')
        if not (math.isfinite(max_input) and max_input > 0):
            raise ConfigError(f'max_input must be > 0, got {max_input}')
        if int(horizon) < 2 or int(max_history) < int(horizon):
            raise ConfigError('horizon must be >= 2 and max_history >= horizon')
        if not (math.isfinite(watchdog) and watchdog >= 0):
            raise ConfigError(f'watchdog must be a finite time >= 0 s (0: off), got '
                              f'{watchdog}')
        self.watchdog_us = round(watchdog * 1e6)
        self.watchdog_trips = 0
        self.last_trip: WatchdogTrip | None = None
        self._mode = _IDLE
        self._last_command_us = 0
        self.period_us = _check_period(period)
        self.with_current = bool(with_current) and self.plant.input_kind == 'voltage'
        self.speed_noise = float(speed_noise)
        self.current_noise = float(current_noise)
        self.method = method
        self.max_input = float(max_input)
        self.horizon = int(horizon)
        self.max_history = int(max_history)
        self.profiles = bool(profiles)
        self._rng = np.random.default_rng(random_state)
        self._theta = self.plant.params.to_dict()
        self.seq = 0
        """Sequence number of the next sample (not wrapped)."""
        self.t_us = 0
        """Card time of the next sample [us]."""
        self._hold = 0.0
        self._profile: tuple[np.ndarray, int] | None = None
        self._startup = True
        self._x0: np.ndarray | None = None
        self._hist_t = np.zeros(0, dtype=np.int64)
        self._hist_u = np.zeros(0)
        self._plan_t = np.zeros(0, dtype=np.int64)
        self._plan_u = np.zeros(0)
        self._pos = 0
        self._plan_flags = np.zeros(0, dtype=np.int64)
        self._plan_speed = np.zeros(0)
        self._plan_current: np.ndarray | None = None
        self._plan_x = np.zeros((0, 2))
        self._replan()

    @property
    def period(self) -> float:
        """Current sample period [s]."""
        return self.period_us / 1e6

    @property
    def profile_running(self) -> bool:
        """True while the next sample belongs to an excitation profile."""
        return self._profile is not None and self.seq < self._profile[1] + self._profile[0].size

    def truth(self) -> CardTruth:
        """The simulated card's true plant, noise and settings (``to_dict()``: JSON)."""
        plant = self.plant
        return CardTruth(plant.params.to_dict(), plant.input_kind, plant.effects, self.method,
                         self.period, self.with_current, self.profiles,
                         self.watchdog_us / 1e6, self.speed_noise, self.current_noise)

    # -- planning -----------------------------------------------------------------------

    def _inputs(self, seqs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.full(seqs.size, self._hold)
        flags = np.zeros(seqs.size, dtype=np.int64)
        if self._profile is not None:
            values, start = self._profile
            idx = seqs - start
            on = (idx >= 0) & (idx < values.size)
            u[on] = values[idx[on]]
            flags[on] = FLAG_PROFILE
            flags[idx == values.size - 1] |= FLAG_PROFILE_END
        return u, flags

    def _replan(self, extend: bool = False) -> None:
        done = self._pos
        hist_t = np.concatenate([self._hist_t, self._plan_t[:done]])
        hist_u = np.concatenate([self._hist_u, self._plan_u[:done]]) if done else self._hist_u
        if extend and hist_t.size > self.max_history:
            # cut the history: continue from the exact state at the next sample
            self._x0 = self._plan_x[done]
            hist_t = hist_t[:0]
            hist_u = hist_u[:0]
        seqs = self.seq + np.arange(self.horizon)
        t_us = self.t_us + np.arange(self.horizon, dtype=np.int64) * self.period_us
        u, flags = self._inputs(seqs)
        out = simulate_batch(self._theta, np.concatenate([hist_t, t_us]) / 1e6,
                             np.concatenate([hist_u, u]), self.plant.input_kind,
                             self.method, self.plant.effects, self._x0)
        m = hist_t.size
        self._hist_t, self._hist_u = hist_t, hist_u
        self._plan_t, self._plan_u, self._plan_flags = t_us, u, flags
        self._plan_speed = out['speed'][0, m:]
        self._plan_current = out['current'][0, m:] if 'current' in out else None
        self._plan_x = out['states'][0, m:]
        self._pos = 0

    # -- stream ---------------------------------------------------------------------------

    def step(self) -> Sample:
        """Produce the next sample and advance the card by one period.

        Returns
        -------
        motor_id.card.protocol.Sample
        """
        if self._watchdog_due():
            self._stop_motor()
            self.watchdog_trips += 1
            self.last_trip = WatchdogTrip(self.seq, self.t_us, self._last_command_us)
        if self._pos >= self._plan_t.size - 1:
            self._replan(extend=True)
        k = self._pos
        speed = float(self._plan_speed[k])
        if self.speed_noise:
            speed += self.speed_noise * self._rng.standard_normal()
        current = float('nan')
        if self.with_current and self._plan_current is not None:
            current = float(self._plan_current[k])
            if self.current_noise:
                current += self.current_noise * self._rng.standard_normal()
        flags = int(self._plan_flags[k]) | (FLAG_STARTUP if self._startup else 0)
        sample = Sample(self.seq % 2 ** 32, int(self._plan_t[k]) / 1e6,
                        float(self._plan_u[k]), speed, current, flags)
        self._startup = False
        self._pos += 1
        self.seq += 1
        self.t_us = int(self._plan_t[k]) + self.period_us
        return sample

    def samples(self, n: int) -> list[Sample]:
        """The next ``n`` samples as a list."""
        return [self.step() for _ in range(int(n))]

    def _watchdog_due(self) -> bool:
        """Has the host been silent for the watchdog time while the card drives?"""
        if not self.watchdog_us or self._mode == _IDLE:
            return False
        if self._mode == _PROFILE and not self.profile_running:
            return False
        silent = self.t_us - self._last_command_us
        return silent >= self.watchdog_us

    def _stop_motor(self) -> None:
        """0 V from the next sample on; nothing drives the card."""
        self._profile = None
        self._hold = 0.0
        self._mode = _IDLE
        self._replan()

    def handle(self, command: Command, t_us: int | None = None) -> Reply:
        """Execute one command from the next sample on.

        Parameters
        ----------
        command : SetVoltage, StartProfile, Stop, SetPeriod or Ping
        t_us : int, optional
            Card time the command arrived [us] (the watchdog counts from it); default:
            the time of the next sample.

        Returns
        -------
        motor_id.card.protocol.Reply
        """
        handler = self._HANDLERS.get(type(command))
        if handler is None:
            raise ConfigError(f'the card has no command {type(command).__name__}')
        self._last_command_us = self.t_us if t_us is None else int(t_us)
        name, method = handler
        status, value = method(self, command)
        return Reply(name, status, value % 2 ** 32)

    def _input_ok(self, value: float) -> bool:
        return math.isfinite(value) and abs(value) <= self.max_input

    def _set_voltage(self, cmd: SetVoltage) -> tuple[str, int]:
        if not self._input_ok(cmd.voltage):
            return 'bad_value', self.seq
        self._hold = float(np.float32(cmd.voltage))
        self._profile = None
        self._mode = _EXTERNAL
        self._replan()
        return 'ok', self.seq

    def _start_profile(self, cmd: StartProfile) -> tuple[str, int]:
        if not self.profiles:
            return 'unsupported', self.seq
        if cmd.name not in PROFILES:
            return 'unknown_profile', self.seq
        n = profile_length(cmd.duration, self.period)
        if not (self._input_ok(cmd.amplitude) and 0 < n <= MAX_PROFILE_SAMPLES):
            return 'bad_value', self.seq
        values = profile_samples(cmd.name, cmd.amplitude, cmd.seed, cmd.duration, self.period)
        self._profile = (values, self.seq)
        self._hold = 0.0
        self._mode = _PROFILE
        self._replan()
        return 'ok', self.seq

    def _stop(self, cmd: Stop) -> tuple[str, int]:
        self._stop_motor()
        return 'ok', self.seq

    def _set_period(self, cmd: SetPeriod) -> tuple[str, int]:
        if self.profile_running:
            return 'busy', self.seq
        if not (math.isfinite(cmd.period) and MIN_PERIOD <= cmd.period <= MAX_PERIOD):
            return 'bad_value', self.seq
        period_us = round(cmd.period * 1e6)
        if self._pos:
            self.t_us = int(self._plan_t[self._pos - 1]) + period_us
        elif self._hist_t.size:
            self.t_us = int(self._hist_t[-1]) + period_us
        self.period_us = period_us
        self._replan()
        return 'ok', self.seq

    def _ping(self, cmd: Ping) -> tuple[str, int]:
        return 'ok', cmd.token

    _HANDLERS: dict[type, tuple[str, Callable[[Any, Any], tuple[str, int]]]] = {
        SetVoltage: ('set_voltage', _set_voltage),
        StartProfile: ('start_profile', _start_profile),
        Stop: ('stop', _stop), SetPeriod: ('set_period', _set_period),
        Ping: ('ping', _ping)}
