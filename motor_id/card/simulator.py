"""A virtual motor-control card on a pseudo-terminal, speaking the frame protocol.

Two layers:

* :class:`VirtualCard` is the card's behaviour without any I/O: it answers commands and
  produces :class:`~motor_id.card.protocol.Sample` objects in card time. The plant is
  advanced with :func:`motor_id.simulate.simulate_batch`, the same code the fitter
  uses, so every named effect of :data:`motor_id.model.EFFECTS` behaves identically.
* :class:`CardSimulator` puts a VirtualCard on a pty (``os.openpty``, raw mode), paces
  it in real time (or ``speedup`` times faster, or as fast as the reader takes), and
  injects transport faults (:class:`FaultConfig`): garbage bytes, dropped, corrupted,
  duplicated and reordered frames, and disconnects with the device coming back at the
  same ``link`` path.

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
"""

from collections import Counter
from dataclasses import asdict, dataclass
import math
import os
import select
import threading
import time
import tty

import numpy as np

from motor_id.card.protocol import (
    CommandParser, encode_reply, encode_sample, FLAG_PROFILE, FLAG_PROFILE_END,
    FLAG_STARTUP, HEADER, Ping, ProtocolError, Reply, Sample, SetPeriod, SetVoltage,
    StartProfile, Stop)
from motor_id.errors import ConfigError
from motor_id.excitation import make_excitation, PROFILES
from motor_id.model import METHODS, Plant
from motor_id.simulate import simulate_batch

MIN_PERIOD = 1e-4
MAX_PERIOD = 10.0
MAX_PROFILE_SAMPLES = 10_000_000


def _rng(random_state):
    if isinstance(random_state, np.random.Generator):
        return random_state
    return np.random.default_rng(random_state)


def _check_period(period):
    if not (isinstance(period, (int, float)) and MIN_PERIOD <= period <= MAX_PERIOD):
        raise ConfigError(f'sample period must be in [{MIN_PERIOD}, {MAX_PERIOD}] s, '
                          f'got {period!r}')
    return round(period * 1e6)


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
    """

    def __init__(self, plant=None, period=0.01, with_current=True, speed_noise=0.0,
                 current_noise=0.0, method='zoh', max_input=100.0, horizon=1024,
                 max_history=200_000, random_state=None):
        self.plant = Plant() if plant is None else plant
        if not isinstance(self.plant, Plant):
            raise ConfigError(f'plant must be a motor_id.model.Plant, got {plant!r}')
        if method not in METHODS:
            raise ConfigError(f'method must be one of {METHODS}, got {method!r}')
        for name, value in (('speed_noise', speed_noise), ('current_noise', current_noise)):
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f'{name} must be a finite std >= 0, got {value}')
        if not (math.isfinite(max_input) and max_input > 0):
            raise ConfigError(f'max_input must be > 0, got {max_input}')
        if int(horizon) < 2 or int(max_history) < int(horizon):
            raise ConfigError('horizon must be >= 2 and max_history >= horizon')
        self.period_us = _check_period(period)
        self.with_current = bool(with_current) and self.plant.input_kind == 'voltage'
        self.speed_noise = float(speed_noise)
        self.current_noise = float(current_noise)
        self.method = method
        self.max_input = float(max_input)
        self.horizon = int(horizon)
        self.max_history = int(max_history)
        self._rng = _rng(random_state)
        self._theta = self.plant.params.to_dict()
        self.seq = 0
        """Sequence number of the next sample (not wrapped)."""
        self.t_us = 0
        """Card time of the next sample [us]."""
        self._hold = 0.0
        self._profile = None
        self._startup = True
        self._x0 = None
        self._hist_t = np.zeros(0, dtype=np.int64)
        self._hist_u = np.zeros(0)
        self._plan_t = np.zeros(0, dtype=np.int64)
        self._plan_u = np.zeros(0)
        self._pos = 0
        self._replan()

    @property
    def period(self):
        """Current sample period [s]."""
        return self.period_us / 1e6

    @property
    def profile_running(self):
        """True while the next sample belongs to an excitation profile."""
        return self._profile is not None and self.seq < self._profile[1] + self._profile[0].size

    def truth(self):
        """JSON-ready description of the simulated card: plant, noise, settings."""
        return {**self.plant.to_dict(), 'method': self.method,
                'period': self.period, 'with_current': self.with_current,
                'speed_noise': self.speed_noise, 'current_noise': self.current_noise,
                'units': {'speed_noise': 'rad/s', 'current_noise': 'A', 'period': 's'}}

    # -- planning -----------------------------------------------------------------------

    def _inputs(self, seqs):
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

    def _replan(self, extend=False):
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

    def step(self):
        """Produce the next sample and advance the card by one period.

        Returns
        -------
        motor_id.card.protocol.Sample
        """
        if self._pos >= self._plan_t.size - 1:
            self._replan(extend=True)
        k = self._pos
        speed = float(self._plan_speed[k])
        if self.speed_noise:
            speed += self.speed_noise * self._rng.standard_normal()
        current = float('nan')
        if self.with_current:
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

    def samples(self, n):
        """The next ``n`` samples as a list."""
        return [self.step() for _ in range(int(n))]

    def handle(self, command):
        """Execute one command from the next sample on.

        Parameters
        ----------
        command : SetVoltage, StartProfile, Stop, SetPeriod or Ping

        Returns
        -------
        motor_id.card.protocol.Reply
        """
        handler = self._HANDLERS.get(type(command))
        if handler is None:
            raise ConfigError(f'the card has no command {type(command).__name__}')
        name, method = handler
        status, value = method(self, command)
        return Reply(name, status, value % 2 ** 32)

    def _input_ok(self, value):
        return math.isfinite(value) and abs(value) <= self.max_input

    def _set_voltage(self, cmd):
        if not self._input_ok(cmd.voltage):
            return 'bad_value', self.seq
        self._hold = float(np.float32(cmd.voltage))
        self._profile = None
        self._replan()
        return 'ok', self.seq

    def _start_profile(self, cmd):
        if cmd.name not in PROFILES:
            return 'unknown_profile', self.seq
        n = math.ceil(cmd.duration / self.period - 1e-9) if math.isfinite(cmd.duration) else 0
        if not (self._input_ok(cmd.amplitude) and 0 < n <= MAX_PROFILE_SAMPLES):
            return 'bad_value', self.seq
        tau = np.arange(n) * self.period
        values = make_excitation(cmd.name, tau, cmd.amplitude, cmd.seed)
        self._profile = (np.asarray(values, dtype=np.float32).astype(float), self.seq)
        self._hold = 0.0
        self._replan()
        return 'ok', self.seq

    def _stop(self, cmd):
        self._profile = None
        self._hold = 0.0
        self._replan()
        return 'ok', self.seq

    def _set_period(self, cmd):
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

    def _ping(self, cmd):
        return 'ok', cmd.token

    _HANDLERS = {SetVoltage: ('set_voltage', _set_voltage),
                 StartProfile: ('start_profile', _start_profile),
                 Stop: ('stop', _stop), SetPeriod: ('set_period', _set_period),
                 Ping: ('ping', _ping)}


# ---------------------------------------------------------------------------------------
# faults


@dataclass(frozen=True)
class FaultConfig:
    """Transport faults the simulated card injects into its sample frames.

    Attributes
    ----------
    garbage : float
        Probability per frame of a burst of 1..``garbage_max`` random bytes before it.
        The bytes never contain 0xA5 (the first sync byte), so each one is counted
        exactly once as garbage by :class:`~motor_id.card.protocol.FrameParser`.
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

    def __post_init__(self):
        for name in ('garbage', 'drop', 'bad_crc', 'duplicate', 'reorder'):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ConfigError(f'fault {name} is a probability in [0, 1], got {p}')
        if not 1 <= self.garbage_max <= 4096:
            raise ConfigError(f'garbage_max must be in [1, 4096], got {self.garbage_max}')
        if not (self.disconnect_every >= 0 and self.disconnect_for > 0):
            raise ConfigError('disconnect needs EVERY >= 0 and DOWN > 0 seconds')

    @property
    def any(self):
        """True when some fault is switched on."""
        return any((self.garbage, self.drop, self.bad_crc, self.duplicate, self.reorder,
                    self.disconnect_every))

    @classmethod
    def parse(cls, items):
        """Build from CLI items.

        ``garbage=P[:MAX]``, ``drop=P``, ``bad_crc=P``, ``duplicate=P``, ``reorder=P``
        (probabilities per frame) and ``disconnect=EVERY[:DOWN]`` (wall-clock seconds).
        """
        values = {}
        for item in items or ():
            name, _, value = item.partition('=')
            first, _, second = value.partition(':')
            if name not in ('garbage', 'drop', 'bad_crc', 'duplicate', 'reorder',
                            'disconnect') or (second and name not in ('garbage', 'disconnect')):
                raise ConfigError(
                    f'unknown fault {item!r}; use garbage=P[:MAX], drop=P, bad_crc=P, '
                    'duplicate=P, reorder=P or disconnect=EVERY[:DOWN]')
            try:
                if name == 'disconnect':
                    values['disconnect_every'] = float(first)
                    if second:
                        values['disconnect_for'] = float(second)
                elif name == 'garbage':
                    values['garbage'] = float(first)
                    if second:
                        values['garbage_max'] = int(second)
                else:
                    values[name] = float(first)
            except ValueError:
                raise ConfigError(f'fault {item!r} needs a number, e.g. {name}=0.01') from None
        return cls(**values)


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
        ``garbage_bytes``, ``garbage_bursts``.
    """

    def __init__(self, config=None, random_state=None):
        self.config = config or FaultConfig()
        self._rng = _rng(random_state)
        self._held = None
        self.stats = Counter()

    def reset(self):
        """Forget a held-back frame (the link went down)."""
        self._held = None

    def apply(self, frame):
        """Return the bytes to send for one frame (may be empty or hold two frames)."""
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


# ---------------------------------------------------------------------------------------
# the card on a pseudo-terminal


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
    with_current, speed_noise, current_noise, method
        As :class:`VirtualCard`.
    faults : FaultConfig, optional
    link : str, optional
        A symlink kept pointing at the current pty; the stable device path across
        disconnects. An existing regular file there is never replaced.
    random_state : int, Generator or None
        Seeds the noise and the faults (independent streams).

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
    Use as a context manager, or call :meth:`start` and :meth:`stop`. The simulator
    keeps its own handle on the pty's slave side, so the host may open and close the
    device at will; a real-time card that nobody reads drops frames (``tx_overflow``)
    as a UART would.
    """

    PENDING_MAX = 1 << 20
    ASAP_LOW_WATER = 1 << 12

    def __init__(self, plant=None, period=0.01, speedup=1.0, with_current=True,
                 speed_noise=0.0, current_noise=0.0, method='zoh', faults=None, link=None,
                 random_state=None):
        if not speedup >= 0:
            raise ConfigError(f'speedup must be >= 0 (0: as fast as possible), got {speedup}')
        card_rng, fault_rng = _rng(random_state).spawn(2)
        self.card = VirtualCard(plant, period, with_current, speed_noise, current_noise,
                                method, random_state=card_rng)
        self.speedup = float(speedup)
        self.asap = self.speedup == 0 or math.isinf(self.speedup)
        self.faults = faults or FaultConfig()
        self.link = os.path.abspath(link) if link else None
        self._injector = FaultInjector(self.faults, fault_rng)
        self._commands = CommandParser()
        self._stats = Counter()
        self.error = None
        self._master = self._slave = None
        self._device = None
        self._pending = bytearray()
        self._stop = threading.Event()
        self._thread = None
        self._lock = threading.Lock()

    # -- pty ----------------------------------------------------------------------------

    @property
    def device(self):
        """The current pty slave path (changes after a disconnect)."""
        return self._device

    @property
    def path(self):
        """The path a host should open: the link if there is one, else the pty."""
        return self.link or self._device

    @property
    def stats(self):
        """Counters of the card and of the injected faults (a snapshot)."""
        return self._stats.copy() + self._injector.stats.copy()

    @property
    def connected(self):
        """True while the pty exists."""
        return self._master is not None

    @property
    def running(self):
        """True while the serving thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def truth(self):
        """The card's true plant and settings plus the fault configuration (JSON-ready)."""
        return {**self.card.truth(), 'speedup': self.speedup,
                'faults': asdict(self.faults), 'device': self.path}

    def _open_pty(self):
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

    def _close_pty(self):
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

    def start(self):
        """Open the pty (and link) and start serving; returns self."""
        if self._thread is not None:
            raise ConfigError('the card simulator is already started')
        if self.link:
            if os.path.lexists(self.link) and not os.path.islink(self.link):
                raise ConfigError(f'--link {self.link} exists and is not a symlink; '
                                  'choose another path')
            if not os.path.isdir(os.path.dirname(self.link)):
                raise ConfigError(f'--link {self.link}: the directory does not exist')
        self._open_pty()
        self._thread = threading.Thread(target=self._serve, name='card-sim', daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout=5.0):
        """Stop serving, close the pty and remove the link."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._master is not None:
            self._close_pty()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # -- serving loop ---------------------------------------------------------------------

    def _serve(self):
        try:
            self._loop()
        except Exception as exc:  # reported through .error; the thread must not vanish
            self.error = exc

    def _emit(self, n):
        for _ in range(n):
            sample = self.card.step()
            if self._master is None:
                self._stats['lost_offline'] += 1
                continue
            data = self._injector.apply(encode_sample(sample))
            if not self.asap and len(self._pending) + len(data) > self.PENDING_MAX:
                self._stats['tx_overflow'] += 1
                continue
            self._pending += data
            self._stats['sent'] += 1

    def _due(self, now):
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

    def _loop(self):  # noqa: C901 - the event loop, kept in one place
        self._wall0 = time.monotonic()
        self._t0 = self.card.t_us / 1e6
        faults = self.faults
        while not self._stop.is_set():
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

    def _read_commands(self):
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        for item in self._commands.feed(data):
            if isinstance(item, ProtocolError):
                self._stats['bad_commands'] += 1
                continue
            self._pending += encode_reply(self.card.handle(item))
            self._stats['replies'] += 1
