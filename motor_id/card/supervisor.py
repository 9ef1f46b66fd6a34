"""Safety limits of a motor run from the host: voltage, speed, current, the watchdog.

Nothing here touches a device or ROS: :class:`Supervisor` looks at each sample and
decides, and sends its commands through the ``send`` callable it was given (the
driver passes :meth:`motor_id.card.link.CardLink.send`).

* :class:`Limits`: the largest input [V] any output may carry (commands are clamped to
  it, profiles beyond it refused), and the speed [rad/s] and current [A] beyond which
  the excitation stops.
* :class:`Supervisor`: trips on a sample beyond a limit (the card is sent ``Stop``, so
  it holds 0 V, and the trip is latched until :meth:`Supervisor.reset`), holds 0 V when
  external commands stop arriving (the watchdog), and marks every sample taken while
  the output is forced to 0 V with :data:`motor_id.contracts.FLAG_LIMIT`.

:class:`motor_id.card.session.Session` puts it to work with the profiles.
"""

from collections.abc import Callable
from dataclasses import dataclass, replace
import math
import time

import numpy as np

from motor_id.card.protocol import Command, Sample, SetVoltage, Stop
from motor_id.contracts import channel_units, DiagnosticValue, FLAG_LIMIT
from motor_id.errors import ConfigError, MotorIdError

_F32_EPS = float(np.finfo(np.float32).eps)


@dataclass(frozen=True)
class Limits:
    """Safety limits of one motor; 0 switches a limit off (except ``max_voltage``).

    Attributes
    ----------
    max_voltage : float
        Largest |input| [V] (torque [N m] on a torque card): commands are clamped to
        it, a profile with a larger amplitude is refused, and a sample reporting more
        (the card disobeys) trips.
    max_speed : float
        |speed| [rad/s] beyond which the excitation stops (0: no limit).
    max_current : float
        |current| [A] beyond which the excitation stops (0: no limit).
    command_timeout : float
        Seconds without an external voltage command after which 0 V is held
        (0: no watchdog).
    """

    max_voltage: float = 12.0
    max_speed: float = 0.0
    max_current: float = 0.0
    command_timeout: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_voltage) and self.max_voltage > 0):
            raise ConfigError(f'max_voltage must be a finite value > 0 V, got '
                              f'{self.max_voltage}')
        for name in ('max_speed', 'max_current', 'command_timeout'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f'{name} must be finite and >= 0 (0: off), got {value}')

    def clamp(self, voltage: float) -> float:
        """``voltage`` [V] limited to +-:attr:`max_voltage`."""
        return min(max(float(voltage), -self.max_voltage), self.max_voltage)

    def check_profile(self, name: str, amplitude: float) -> None:
        """Raise :class:`ConfigError` when a profile's amplitude exceeds :attr:`max_voltage`."""
        if abs(amplitude) > self.max_voltage:
            raise ConfigError(f'profile {name} with amplitude {amplitude:g} V exceeds '
                              f'max_voltage {self.max_voltage:g} V; lower the amplitude or '
                              'raise max_voltage')

    def exceeded(self, sample: Sample) -> tuple[str, float, float] | None:
        """The first limit ``sample`` exceeds, as ``(name, value, limit)``, or None.

        ``name`` is ``'voltage'``, ``'speed'`` or ``'current'``. The voltage check
        allows the float32 rounding of the wire.
        """
        if abs(sample.voltage) > self.max_voltage * (1 + 4 * _F32_EPS):
            return 'voltage', sample.voltage, self.max_voltage
        if self.max_speed and abs(sample.speed) > self.max_speed:
            return 'speed', sample.speed, self.max_speed
        if self.max_current and sample.has_current and abs(sample.current) > self.max_current:
            return 'current', sample.current, self.max_current
        return None


@dataclass(frozen=True)
class Trip:
    """Why the supervisor stopped the excitation.

    Attributes
    ----------
    limit : {'voltage', 'speed', 'current'}
    value : float
        The sample's value beyond the limit (V, rad/s or A).
    threshold : float
        The limit.
    seq : int
        Sequence number of the sample that tripped.
    """

    limit: str
    value: float
    threshold: float
    seq: int

    def describe(self) -> str:
        """One line for people."""
        unit = channel_units()[self.limit]
        return (f'{self.limit} limit: |{self.value:.4g}| {unit} > {self.threshold:g} {unit} '
                f'at seq {self.seq}')


class Supervisor:
    """Apply :class:`Limits` to the sample stream and to the commands going out.

    Parameters
    ----------
    limits : Limits
    send : callable
        ``send(command)`` writes one protocol command to the card; it may raise
        :class:`motor_id.errors.MotorIdError` (device absent), which is counted.
    clock : callable
        Monotonic seconds (for the watchdog).

    Attributes
    ----------
    trip : Trip or None
        The latched trip (None: armed).
    trips : int
        Trips so far.
    watchdog_holding : bool
        The watchdog forced 0 V and no command has come since.
    watchdog_trips : int
    clamped : int
        Commands clamped to ``max_voltage``.
    refused : int
        Commands refused while a trip is latched.
    send_failures : int
    """

    def __init__(self, limits: Limits, send: Callable[[Command], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.limits = limits
        self._send = send
        self._clock = clock
        self.trip: Trip | None = None
        self.trips = 0
        self.watchdog_holding = False
        self.watchdog_trips = 0
        self.clamped = self.refused = self.send_failures = 0
        self._last_command: float | None = None

    @property
    def holding_zero(self) -> bool:
        """True while a limit or the watchdog forces the output to 0 V."""
        return self.trip is not None or self.watchdog_holding

    def _try_send(self, command: Command) -> bool:
        try:
            self._send(command)
        except MotorIdError:
            self.send_failures += 1
            return False
        return True

    def on_sample(self, sample: Sample) -> tuple[Sample, Trip | None]:
        """Check one sample; trip on a limit; return it, flagged while 0 V is forced.

        Returns
        -------
        (Sample, Trip or None)
            The sample (with :data:`FLAG_LIMIT` set while the output is forced to 0 V)
            and the trip this very sample caused, if any.
        """
        new = None
        if self.trip is None:
            hit = self.limits.exceeded(sample)
            if hit is not None:
                new = self.trip = Trip(*hit, seq=sample.seq)
                self.trips += 1
                self._try_send(Stop())
        if self.holding_zero:
            sample = replace(sample, flags=sample.flags | FLAG_LIMIT)
        return sample, new

    def command(self, voltage: float) -> float | None:
        """Pass an external voltage command through the limits.

        Returns
        -------
        float or None
            The voltage to send (clamped to ``max_voltage``), or None when a trip is
            latched (the command is refused) or the value is not finite.
        """
        voltage = float(voltage)
        if self.trip is not None or not math.isfinite(voltage):
            self.refused += 1
            return None
        self._last_command = self._clock()
        self.watchdog_holding = False
        out = self.limits.clamp(voltage)
        self.clamped += out != voltage
        return out

    def check_watchdog(self) -> bool:
        """Hold 0 V if external commands stopped; return True when it fires now."""
        timeout = self.limits.command_timeout
        if not timeout or self._last_command is None or self.watchdog_holding:
            return False
        if self._clock() - self._last_command <= timeout:
            return False
        self.watchdog_holding = True
        self.watchdog_trips += 1
        self._try_send(SetVoltage(0.0))
        return True

    def reset(self) -> None:
        """Clear a latched trip and the watchdog (the user restarts on purpose)."""
        self.trip = None
        self.watchdog_holding = False
        self._last_command = None

    def values(self) -> dict[str, DiagnosticValue]:
        """Diagnostic key/values."""
        trip = self.trip
        return {'limit_state': 'tripped' if trip else ('watchdog' if self.watchdog_holding
                                                        else 'armed'),
                'limit_tripped': trip.limit if trip else '',
                'limit_value': trip.value if trip else '',
                'limit_threshold': trip.threshold if trip else '',
                'limit_seq': trip.seq if trip else '',
                'limit_trips': self.trips, 'watchdog_trips': self.watchdog_trips,
                'commands_clamped': self.clamped, 'commands_refused': self.refused,
                'max_voltage': self.limits.max_voltage, 'max_speed': self.limits.max_speed,
                'max_current': self.limits.max_current,
                'command_timeout_s': self.limits.command_timeout}
