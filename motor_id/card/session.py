"""One motor run from the host: profiles (on the card or streamed), commands, stop, reset.

:class:`Session` is the driver's logic without ROS: it starts the excitation (a
``StartProfile`` to the card, or :class:`HostProfile` as ``SetVoltage`` commands when
the card answers ``unsupported``), forwards external voltage commands, and runs every
sample and command through a :class:`~motor_id.card.supervisor.Supervisor`. It talks
to the card through a :class:`~motor_id.card.link.CardLink` (``send``, ``fault``).

While anything drives the motor (a profile on the card or played here, a non-zero
external command) :meth:`Session.keep_alive` pings the card whenever no command went
out for ``keepalive`` seconds: the card's watchdog stops the motor when the pings stop,
so a driver that dies (SIGKILL, a crash, a pulled cable) leaves the motor at 0 V even
while the card plays a profile on its own.
"""

from dataclasses import replace
import time

from motor_id.card.link import CardLink, LogFn
from motor_id.card.profile import profile_samples
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
from motor_id.card.supervisor import Limits, Supervisor
from motor_id.contracts import DiagnosticValue, FLAG_PROFILE, FLAG_PROFILE_END
from motor_id.errors import MotorIdError


class SessionClosedError(MotorIdError):
    """The session has ended (the driver shuts down): nothing starts any more."""

EXTERNAL = 'external'
"""The excitation name for "forward external voltage commands"."""

KEEPALIVE = 0.1
"""Default longest silence towards a driving card [s]: a fifth of the firmware's 0.5 s
watchdog, so that a busy host thread still keeps it fed."""


class HostProfile:
    """A profile played by the host: one ``SetVoltage`` per card sample.

    Parameters
    ----------
    name : str
    amplitude, seed, duration, period
        As :func:`motor_id.card.profile.profile_samples` (the card's own definition).

    Notes
    -----
    The schedule runs on the card's clock: the first sample received after the start
    is profile sample -1 (the command sent then acts from the next sample), and each
    later sample at card time ``t`` is profile sample ``round((t - t0) / period)``.
    After each sample the value of the next profile sample is sent if it differs from
    the last one sent. Samples inside the schedule are flagged :data:`FLAG_PROFILE`,
    the last one (or the first after it when frames were lost)
    :data:`FLAG_PROFILE_END`, as a card playing the profile flags them; 0 V follows.
    The voltage a sample reports is the one the card applied, which may lag the
    schedule by the link's latency (a few samples): the fit uses the reported value,
    so the lag costs nothing but a slightly different input from the card's own.
    """

    def __init__(self, name: str, amplitude: float, seed: int, duration: float,
                 period: float) -> None:
        self.values = profile_samples(name, amplitude, seed, duration, period)
        self.name = name
        self.period = float(period)
        self._t0: float | None = None
        self._last_sent: float | None = None
        self.done = False
        self.sent = 0

    def on_sample(self, sample: Sample) -> tuple[Sample, float | None]:
        """Flag ``sample`` and return ``(sample, voltage to send or None)``."""
        if self.done:
            return sample, None
        if self._t0 is None:
            self._t0 = sample.t_card + self.period
            k = -1
        else:
            k = round((sample.t_card - self._t0) / self.period)
        n = self.values.size
        flags = sample.flags
        if k >= n - 1:   # the last sample (or the first after it, if frames were lost)
            flags |= FLAG_PROFILE | FLAG_PROFILE_END
            self.done = True
            value = 0.0
        else:
            flags |= FLAG_PROFILE if k >= 0 else 0
            value = float(self.values[k + 1])
        out = None
        if value != self._last_sent or self.done:
            out = self._last_sent = value
            self.sent += 1
        return replace(sample, flags=flags), out


class Session:
    """Start, stop and supervise the excitation of one card.

    Parameters
    ----------
    link : motor_id.card.link.CardLink
        Used for ``send`` and ``fault`` (counted, logged once per kind).
    limits : motor_id.card.supervisor.Limits
    excitation : str
        A profile name of :data:`motor_id.excitation.PROFILES` or :data:`EXTERNAL`.
    amplitude, seed, duration : float, int, float
        The profile's settings (see :class:`~motor_id.card.protocol.StartProfile`).
    period : float
        Sample period the card is set to [s].
    autostart : bool
        Start the profile when the device first opens.
    log : callable
        ``log(level, text)`` for events that are always logged (trips, mode changes).
    keepalive : float
        Longest silence towards the card while it drives the motor [s]; 0: no pings.

    Attributes
    ----------
    supervisor : Supervisor
    card_profiles : bool
        False once the card answered ``unsupported`` to a profile.
    host_profile : HostProfile or None
        The profile the host is playing now.
    card_profile_running : bool
        A profile was started on the card and has not ended, been stopped or refused.
    pings : int
        Keep-alive pings sent.
    """

    def __init__(self, link: CardLink, limits: Limits, excitation: str, amplitude: float = 9.0,
                 seed: int = 0, duration: float = 40.0, period: float = 0.01,
                 autostart: bool = False, log: LogFn | None = None,
                 keepalive: float = KEEPALIVE) -> None:
        self.link = link
        self.external = excitation == EXTERNAL
        if not self.external:
            limits = replace(limits, command_timeout=0.0)   # no commands to watch
            limits.check_profile(excitation, amplitude)
        self.supervisor = Supervisor(limits, link.send)
        self.profile = None if self.external else StartProfile(excitation, amplitude, seed,
                                                               duration)
        self.period = float(period)
        self.autostart = bool(autostart)
        self._log = log or (lambda level, text: None)
        self.card_profiles = True
        self.host_profile: HostProfile | None = None
        self._pending: StartProfile | None = None
        self._started = False
        self.keepalive = float(keepalive)
        self.card_profile_running = False
        self._profile_seen = False
        self.pings = 0
        self._commanded = 0.0
        self._closed = False

    @property
    def driving(self) -> bool:
        """Whether a profile or a non-zero command may be driving the motor now."""
        if self._closed or self.supervisor.trip is not None:
            return False
        if self.external:
            return self._commanded != 0.0 and not self.supervisor.watchdog_holding
        return self.card_profile_running or self.host_profile is not None

    # ------------------------------------------------------------ the polling thread
    def on_open(self) -> None:
        """After each (re)open: the sample period; 0 V again while a limit holds it (the
        card may have missed the stop); the first time, an autostart."""
        self.link.send(SetPeriod(self.period))
        if self.supervisor.holding_zero:
            self.link.send(Stop())
        elif self.autostart and not self._started and not self.external:
            self.start()

    def on_sample(self, sample: Sample) -> Sample:
        """Schedule the host profile, check the limits, flag; return the sample."""
        host = self.host_profile
        value = None
        if host is not None:
            sample, value = host.on_sample(sample)
        if host is None and self.card_profile_running:
            self._follow_card_profile(sample)
        sample, trip = self.supervisor.on_sample(sample)
        if trip is not None:
            self.host_profile = None
            self.card_profile_running = False
            self._log('error', f'stopped the excitation: {trip.describe()}; the card holds '
                      '0 V until ~/start or ~/reset')
        elif value is not None and host is self.host_profile:
            self._send(SetVoltage(self.supervisor.limits.clamp(value)))
        if host is not None and host.done and host is self.host_profile:
            self.host_profile = None
            self._log('info', f'host-played {host.name} profile done')
        return sample

    def _follow_card_profile(self, sample: Sample) -> None:
        """The card's profile ends with its end flag; samples without the profile flag
        after flagged ones mean the card abandoned it (its watchdog: no command for its
        watchdog time, the host or the line too slow)."""
        if sample.flags & FLAG_PROFILE_END:
            self.card_profile_running = False
        elif sample.flags & FLAG_PROFILE:
            self._profile_seen = True
        elif self._profile_seen:
            self.card_profile_running = False
            self.link.fault('card_abandoned_profile', f'the card abandoned the profile at '
                            f'seq {sample.seq} and holds 0 V: its watchdog fired (no command '
                            'reached it in time: is this host overloaded, or the line?)',
                            'error')

    def on_reply(self, reply: Reply) -> None:
        """A card reply: ``unsupported`` to our profile switches to playing it here."""
        pending = self._pending
        if reply.command != 'start_profile' or pending is None:
            return
        self._pending = None
        if reply.status != 'ok':
            self.card_profile_running = False
        if reply.status == 'unsupported':
            self.card_profiles = False
            self._log('info', f'the card has no built-in profiles: the driver plays '
                      f'{pending.name} as set-voltage commands every {self.period:g} s')
            self._play_on_host(pending)

    def keep_alive(self) -> None:
        """Ping the card if it drives the motor and no command went out for
        ``keepalive`` s (call it often: the driver's reader thread does after each read)."""
        if not (self.keepalive and self.driving) or \
                time.monotonic() - self.link.last_sent < self.keepalive:
            return
        try:
            self.link.send(Ping(self.pings % 2 ** 32))
        except MotorIdError as exc:
            self.link.fault('ping_failed', f'keep-alive ping not sent: {exc}')
            return
        self.pings += 1

    def check_watchdog(self) -> None:
        """Hold 0 V when external commands stopped (logged once)."""
        if self.external and self.supervisor.check_watchdog():
            self.link.fault('watchdog', f'no voltage_command for '
                            f'{self.supervisor.limits.command_timeout:g} s: holding 0 V')

    # ------------------------------------------------------------ user requests
    def start(self) -> str:
        """Re-arm the limits and start the profile (external: only re-arm).

        Returns
        -------
        str
            What was done, for people.

        Raises
        ------
        MotorIdError
            The command could not be sent (device absent).
        """
        if self._closed:
            raise SessionClosedError('the driver is shutting down')
        self.supervisor.reset()
        cmd = self.profile
        if self.external or cmd is None:
            return 'limits re-armed; excitation is external: publish on voltage_command'
        self._started = True
        if not self.card_profiles:
            self._play_on_host(cmd)
            self.link.send(Stop())   # 0 V until the first scheduled sample
            return f'started {cmd.name} (played by the driver)'
        self.host_profile = None
        self._pending = cmd
        self.card_profile_running = True
        self._profile_seen = False
        self.link.send(cmd)
        return f'started {cmd.name}'

    def stop(self) -> None:
        """Stop any profile; the card holds 0 V (MotorIdError if it cannot be sent)."""
        self.host_profile = None
        self._pending = None
        self.card_profile_running = False
        self._commanded = 0.0
        self.link.send(Stop())

    def close(self) -> None:
        """The end: 0 V now (a :class:`Stop`, if the device is open), and nothing but
        zeros afterwards (starts are refused, commands and host profiles dropped)."""
        self._closed = True
        try:
            self.stop()
        except MotorIdError:
            pass   # the device is not open: the card's watchdog stops it

    def reset(self) -> str:
        """Re-arm the limits and hold 0 V; return what was cleared, for people."""
        trip = self.supervisor.trip
        self.supervisor.reset()
        self.stop()
        return 'limits re-armed' + (f' (was: {trip.describe()})' if trip else '') + \
            '; card holds 0 V'

    def command(self, voltage: float) -> None:
        """Forward one external voltage command [V] through the limits."""
        value = self.supervisor.command(voltage)
        if value is None:
            trip = self.supervisor.trip
            self.link.fault('command_refused', f'voltage command {voltage!r} refused: ' + (
                f'{trip.describe()} (call ~/start or ~/reset)' if trip
                else 'not a finite number'))
            return
        if value != voltage:
            self.link.fault('command_clamped', f'voltage command {voltage:g} V clamped to '
                            f'{value:g} V (max_voltage)')
        self._commanded = value
        self._send(SetVoltage(value))

    # ------------------------------------------------------------ helpers
    def _play_on_host(self, cmd: StartProfile) -> None:
        self.host_profile = HostProfile(cmd.name, cmd.amplitude, cmd.seed, cmd.duration,
                                        self.period)

    def _send(self, command: Command) -> None:
        if self._closed:
            return
        try:
            self.link.send(command)
        except MotorIdError as exc:
            self.link.fault('command_failed', f'{type(command).__name__} not sent: {exc}')

    def values(self) -> dict[str, DiagnosticValue]:
        """Diagnostic key/values (the supervisor's and where profiles are played)."""
        values = self.supervisor.values()
        values['profile_source'] = 'card' if self.card_profiles else 'driver'
        values['host_profile_running'] = self.host_profile is not None
        values['card_profile_running'] = self.card_profile_running
        values['keepalive_pings'] = self.pings
        return values
