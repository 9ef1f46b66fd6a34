"""The simulated serial card: a :class:`VirtualCard` served on a pseudo-terminal.

:class:`CardSimulator` puts a :class:`~motor_id.card.virtual_card.VirtualCard` on a pty
(``os.openpty``, raw mode), paces it in real time (or ``speedup`` times faster, or as
fast as the reader takes), and injects the faults of :mod:`motor_id.card.faults`:
garbage bytes, dropped, corrupted, duplicated and reordered frames, current spikes, and
disconnects with the device coming back at the same ``link`` path.
"""

from collections import Counter
from dataclasses import asdict, dataclass
from dataclasses import fields as dataclass_fields
import math
import os
import select
import threading
import time
import tty

import numpy as np

from motor_id.card.faults import FaultConfig, FaultInjector
from motor_id.card.protocol import encode_reply, encode_sample, Stop
from motor_id.card.stream import CommandParser
from motor_id.card.virtual_card import CardTruth, VirtualCard
from motor_id.errors import ConfigError, ProtocolError
from motor_id.model import Plant
from motor_id.records import written

__all__ = ['CardSimulator', 'CardTruth', 'FaultConfig', 'FaultInjector', 'SimulatorTruth',
           'VirtualCard']


@dataclass(frozen=True)
class SimulatorTruth(CardTruth):
    """What a :class:`CardSimulator` simulates: its card's truth, pacing and faults.

    Attributes
    ----------
    watchdog : float
        As in :class:`CardTruth` but in wall seconds (0: off).
    speedup : float
    faults : FaultConfig
    device : str or None
        The pty's path while it exists.
    """

    speedup: float = 1.0
    faults: FaultConfig = written(asdict, FaultConfig())
    device: str | None = None


class CardSimulator:
    """A :class:`VirtualCard` served on a pseudo-terminal by a background thread.

    Parameters
    ----------
    plant : motor_id.model.Plant, optional
    period : float
        Initial sample period [s].
    speedup : float
        Card seconds per wall-clock second; 0 (or inf) runs as fast as the reader takes
        the frames (the card waits while the pty is full).
    with_current, speed_noise, current_noise, method, profiles
        As :class:`VirtualCard`.
    faults : FaultConfig, optional
    link : str, optional
        A symlink kept pointing at the current pty; the stable device path across
        disconnects. An existing regular file there is never replaced.
    random_state : int, Generator or None
        Seeds the noise and the faults (independent streams).
    profiles : bool
        As :class:`VirtualCard`.
    watchdog : float
        Wall-clock seconds without a command (a ``Ping`` will do) after which a held
        voltage or a running profile drops to 0 V, as on the firmware; the card counts
        ``watchdog * speedup`` card seconds. 0: off; always off as fast as possible
        (``speedup`` 0), where card time has no relation to the host's.

    Attributes
    ----------
    card : VirtualCard
    stats : collections.Counter
        Faults injected (see :class:`FaultInjector`) plus ``sent`` (sample frames
        queued for the pty, faults applied after counting),
        ``replies``, ``bad_commands``, ``disconnects``, ``lost_offline`` (samples taken
        while disconnected), ``tx_overflow`` (frames dropped because nobody read).
    error : BaseException or None
        What stopped the serving thread, if it failed.

    Notes
    -----
    Use as a context manager, or call :meth:`start` and :meth:`stop`; :meth:`stop` (and
    :meth:`halt`, from any thread) puts the card at 0 V first, as a host's ``Stop``
    would, and every wait in it is bounded. The simulator
    keeps its own handle on the pty's slave side, so the host may open and close the
    device at will; a real-time card that nobody reads drops frames (``tx_overflow``)
    as a UART would.
    """

    PENDING_MAX = 1 << 20
    ASAP_LOW_WATER = 1 << 12

    def __init__(self, plant: Plant | None = None, period: float = 0.01, speedup: float = 1.0,
                 with_current: bool = True, speed_noise: float = 0.0,
                 current_noise: float = 0.0, method: str = 'zoh',
                 faults: FaultConfig | None = None, link: str | None = None,
                 random_state: int | np.random.Generator | None = None,
                 profiles: bool = True, watchdog: float = 0.0) -> None:
        if not speedup >= 0:
            raise ConfigError(f'speedup must be >= 0 (0: as fast as possible), got {speedup}')
        if not (math.isfinite(watchdog) and watchdog >= 0):
            raise ConfigError(f'watchdog must be a finite time >= 0 s (0: off), got '
                              f'{watchdog}')
        card_rng, fault_rng = np.random.default_rng(random_state).spawn(2)
        self.speedup = float(speedup)
        self.asap = self.speedup == 0 or math.isinf(self.speedup)
        self.watchdog = 0.0 if self.asap else float(watchdog)
        self.card = VirtualCard(plant, period, with_current, speed_noise, current_noise,
                                method, profiles=profiles, watchdog=self.watchdog * self.speedup,
                                random_state=card_rng)
        self.faults = faults or FaultConfig()
        self.link = os.path.abspath(link) if link else None
        self._injector = FaultInjector(self.faults, fault_rng)
        self._commands = CommandParser()
        self._stats: Counter[str] = Counter()
        self.error: BaseException | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._device: str | None = None
        self._pending = bytearray()
        self._stop = threading.Event()
        self._halt = threading.Event()
        self._halted = threading.Event()
        self.halted_at: int | None = None
        """Sequence number of the first 0 V sample after :meth:`halt` (None before)."""
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._wall0 = self._t0 = 0.0   # set when serving starts: wall and card time then

    # -- pty ----------------------------------------------------------------------------

    @property
    def device(self) -> str | None:
        """The current pty slave path (changes after a disconnect)."""
        return self._device

    @property
    def path(self) -> str | None:
        """The path a host should open: the link if there is one, else the pty."""
        return self.link or self._device

    @property
    def stats(self) -> Counter[str]:
        """Counters of the card and of the injected faults (a snapshot)."""
        return self._stats.copy() + self._injector.stats.copy()

    @property
    def connected(self) -> bool:
        """True while the pty exists."""
        return self._master is not None

    @property
    def running(self) -> bool:
        """True while the serving thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def wall_time(self, t_card: float) -> float | None:
        """The :func:`time.monotonic` instant card time ``t_card`` [s] was (or will be)
        due; None before serving starts or as fast as possible."""
        if self.asap or self._thread is None:
            return None
        return self._wall0 + (t_card - self._t0) / self.speedup

    def truth(self) -> SimulatorTruth:
        """The card's true plant and settings plus the fault configuration
        (``to_dict()``: JSON)."""
        card = self.card.truth()
        fields = {f.name: getattr(card, f.name) for f in dataclass_fields(card)}
        return SimulatorTruth(**{**fields, 'watchdog': self.watchdog}, speedup=self.speedup,
                              faults=self.faults, device=self.path)

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._device = os.ttyname(slave)
        if self.link:
            tmp = f'{self.link}.{os.getpid()}.tmp'
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self._device, tmp)
            os.replace(tmp, self.link)
        self._connected_at = time.monotonic()

    def _close_pty(self) -> None:
        if self.link and os.path.islink(self.link) and os.readlink(self.link) == self._device:
            os.unlink(self.link)
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None
        self._pending.clear()
        self._injector.reset()
        self._commands.reset()

    # -- life cycle -----------------------------------------------------------------------

    def start(self) -> 'CardSimulator':
        """Open the pty (and link) and start serving; returns self."""
        if self._thread is not None:
            raise ConfigError('the card simulator is already started')
        if self.link:
            if os.path.lexists(self.link) and not os.path.islink(self.link):
                raise ConfigError(f'link {self.link} exists and is not a symlink; '
                                  'choose another path', params=('link',))
            if not os.path.isdir(os.path.dirname(self.link)):
                raise ConfigError(f'link {self.link}: the directory does not exist',
                                  params=('link',))
        self._open_pty()
        self._thread = threading.Thread(target=self._serve, name='card-sim', daemon=True)
        self._thread.start()
        return self

    def halt(self) -> None:
        """0 V at the card from its next sample on, as a host's ``Stop`` (from any
        thread: the serving thread applies it; :attr:`halted_at` tells when)."""
        self._halt.set()

    def stop(self, timeout: float = 2.0) -> None:
        """0 V at the card, stop serving, close the pty and remove the link.

        Waits at most ``timeout`` [s] for the serving thread to apply the 0 V and as long
        again for it to end; one that does not (stuck) is left behind, a daemon, and the
        card is put at 0 V from here.
        """
        self.halt()
        thread = self._thread
        if thread is not None and thread.is_alive():
            self._halted.wait(timeout)
        self._stop.set()
        if thread is not None:
            thread.join(timeout)
        if self.halted_at is None:   # never served, ended, or stuck: 0 V from here
            self._apply_halt()
        if self._master is not None:
            self._close_pty()

    def _apply_halt(self) -> None:
        """The card holds 0 V from its next sample (idempotent)."""
        if self.halted_at is None:
            self.card.handle(Stop())
            self.halted_at = self.card.seq
            self._halted.set()

    def __enter__(self) -> 'CardSimulator':
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- serving loop ---------------------------------------------------------------------

    def _serve(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001 - reported via .error; the thread lives on
            self.error = exc
        finally:   # whatever ended the serving: 0 V
            try:
                self._apply_halt()
            except Exception as exc:  # noqa: BLE001 - reported via .error
                self.error = self.error or exc
            self._halted.set()

    def _emit(self, n: int) -> None:
        for _ in range(n):
            sample = self._injector.sample(self.card.step())
            if self._master is None:
                self._stats['lost_offline'] += 1
                continue
            data = self._injector.apply(encode_sample(sample))
            if not self.asap and len(self._pending) + len(data) > self.PENDING_MAX:
                self._stats['tx_overflow'] += 1
                continue
            self._pending += data
            self._stats['sent'] += 1

    def _due(self, now: float) -> tuple[int, float]:
        """Samples due by wall time ``now`` (real-time mode) or wanted (ASAP mode)."""
        if self.asap:
            if self._master is None or len(self._pending) >= self.ASAP_LOW_WATER:
                return 0, 0.05
            return 64, 0.0
        target = self._t0 + (now - self._wall0) * self.speedup
        lag = target - self.card.t_us / 1e6
        if lag < 0:
            return 0, min(0.05, -lag / self.speedup)
        return min(int(lag / self.card.period) + 1, 10_000), 0.0

    def _loop(self) -> None:
        self._wall0 = time.monotonic()
        self._t0 = self.card.t_us / 1e6
        faults = self.faults
        while not self._stop.is_set():
            if self._halt.is_set():
                self._apply_halt()
            now = time.monotonic()
            if faults.disconnect_every:
                if self._master is not None and \
                        now - self._connected_at >= faults.disconnect_every:
                    self._close_pty()
                    self._stats['disconnects'] += 1
                    self._reconnect_at = now + faults.disconnect_for
                elif self._master is None and now >= self._reconnect_at:
                    self._open_pty()
            n, timeout = self._due(now)
            self._emit(n)
            if self._master is None:
                self._stop.wait(min(timeout or 0.01, 0.05))
                continue
            r, w, _ = select.select([self._master], [self._master] if self._pending else [],
                                    [], timeout)
            if r:
                self._read_commands()
            if w and self._pending:
                try:
                    sent = os.write(self._master, self._pending[:1 << 16])
                except BlockingIOError:
                    sent = 0
                del self._pending[:sent]

    def _read_commands(self) -> None:
        if self._master is None:
            return
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        t_us = None
        if not self.asap:   # the card time now: the watchdog counts from it
            now = self._t0 + (time.monotonic() - self._wall0) * self.speedup
            t_us = min(round(now * 1e6), self.card.t_us)
        for item in self._commands.feed(data):
            if isinstance(item, ProtocolError):
                self._stats['bad_commands'] += 1
                continue
            self._pending += encode_reply(self.card.handle(item, t_us))
            self._stats['replies'] += 1
