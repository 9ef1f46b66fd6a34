"""The host's end of the serial line: open with back-off, read, parse, count, batch (no ROS).

:class:`CardLink` owns the port (opened with :func:`serial.serial_for_url`, so a device
path, a pty or ``loop://``), the :class:`~motor_id.card.stream.FrameParser` and the
:class:`~motor_id.card.sequence.SequenceTracker`. One thread calls :meth:`CardLink.poll`
in a loop; any thread may call :meth:`CardLink.send`. It logs through a plain callable,
each kind of fault once per outage, and counts everything for diagnostics.
"""

from collections import Counter
from collections.abc import Callable
import math
import threading
import time

import serial

from motor_id.card.protocol import (
    Command,
    encode_command,
    MAX_FRAME,
    OVERHEAD,
    Reply,
    Sample,
)
from motor_id.card.sequence import SequenceTracker
from motor_id.card.stream import FrameParser
from motor_id.card.transport import open_transport, read_available, TransportError, write_all
from motor_id.contracts import DiagnosticValue, FLAG_STARTUP
from motor_id.errors import ConfigError, MotorIdError, ProtocolError

GARBLED_BYTES = 4 * MAX_FRAME
"""Bytes in a row without one valid frame that mark the link garbled (wrong baud rate,
wrong device, electrical noise): longer than any frame, so a torn or corrupt frame or
a burst of line noise between good frames never does."""

BITS_PER_BYTE = 10
"""A UART byte on the line: start bit, 8 data bits, stop bit (8N1)."""

SAMPLE_FRAME_BYTES = {False: OVERHEAD + 22, True: OVERHEAD + 26}
"""Bytes of a sample frame without and with current (30 and 34)."""


def max_frame_rate(baudrate: int, frame_bytes: int) -> float:
    """Most frames per second a line of ``baudrate`` bit/s carries (8N1).

    Parameters
    ----------
    baudrate : int
        [bit/s]
    frame_bytes : int

    Returns
    -------
    float
        [1/s]; e.g. 34-byte frames at 115200 bit/s: 338.8.
    """
    return baudrate / (BITS_PER_BYTE * frame_bytes)


LogFn = Callable[[str, str], None]
"""``log(level, text)`` with level ``'info'``, ``'warning'`` or ``'error'``."""


def _quiet(level: str, text: str) -> None:
    """The default log: nothing."""


class CardLink:
    """A card connection that survives absent and vanishing devices.

    Parameters
    ----------
    url : str
        Device path or pyserial URL (``loop://``, ``socket://host:port``, a pty).
    baudrate : int
        [bit/s]
    read_timeout : float
        Longest blocking read [s]; :meth:`poll` returns at least this often.
    backoff_max : float
        Longest wait between reopen attempts [s] (the wait doubles from 0.05 s).
    stall_timeout : float
        No frame for this long: :attr:`state` becomes ``stalled`` [s].
    batch_size : int
        Samples per batch; a batch also goes out when a read brings nothing or after
        ``batch_age`` seconds.
    batch_age : float
        [s]
    sample_period : float, optional
        The period the card is set to [s]; with it the first sample checks that the
        line can carry the frames (:meth:`line_capacity`).
    log : callable, optional
        ``log(level, text)`` with level ``'info'``, ``'warning'`` or ``'error'``.
    on_open : callable, optional
        ``on_open()`` after each (re)open, in the polling thread (send the
        configuration here; a :class:`MotorIdError` it raises is counted and logged).
    on_sample : callable, optional
        ``on_sample(sample) -> sample`` for each accepted sample, before batching.
    on_reply : callable, optional
        ``on_reply(reply)`` for each reply of the card.
    stop : threading.Event, optional
        Set it to end back-off waits at once.

    Attributes
    ----------
    state : str
        ``connecting``, ``connected``, ``stalled`` (no frame for ``stall_timeout``),
        ``garbled`` (bytes but no valid frame: a wrong baud rate?) or ``disconnected``.
    counts : collections.Counter
        ``frames_ok``, ``frame_<kind>`` per ProtocolError kind, ``opened``,
        ``lost_device``, ``open_failed``, ``commands_sent``, ``lost_frames``,
        ``duplicate_frames``, ``late_frames``, ``card_reset``, ``reply_<status>``, ...
    parser : FrameParser
    tracker : SequenceTracker
    last_sent : float
        :func:`time.monotonic` when the last command went out (-inf: none yet).
    capacity_warning : str
        ``''`` until the first sample, then ``'ok'``, ``'not checked'`` (no
        ``sample_period``) or, when the line cannot carry the sample rate, the warning
        (logged once, and listed by :meth:`values` as ``line_overload``).
    """

    def __init__(self, url: str, baudrate: int = 115200, read_timeout: float = 0.05,
                 backoff_max: float = 5.0, stall_timeout: float = 1.0, batch_size: int = 10,
                 batch_age: float = 0.1, sample_period: float | None = None,
                 log: LogFn | None = None, on_open: Callable[[], None] | None = None,
                 on_sample: Callable[[Sample], Sample] | None = None,
                 on_reply: Callable[[Reply], None] | None = None,
                 stop: threading.Event | None = None) -> None:
        if not isinstance(url, str) or not url:
            raise ConfigError(f'the card URL must be a non-empty string, got {url!r}')
        if int(batch_size) < 1:
            raise ConfigError(f'batch_size must be >= 1, got {batch_size}')
        self.url = url
        self.baudrate = int(baudrate)
        self.read_timeout = float(read_timeout)
        self.backoff_max = float(backoff_max)
        self.stall_timeout = float(stall_timeout)
        self.batch_size = int(batch_size)
        self.batch_age = float(batch_age)
        self.sample_period = sample_period
        self._log = log or _quiet
        self._on_open = on_open
        self._on_sample = on_sample
        self._on_reply = on_reply
        self._stop = stop or threading.Event()
        self.parser = FrameParser()
        self.tracker = SequenceTracker()
        self.counts: Counter[str] = Counter()
        self.state = 'connecting'
        self.capacity_warning = ''
        self._logged: set[str] = set()
        self._port: serial.SerialBase | None = None
        self._lock = threading.Lock()
        self._backoff = 0.05
        self._last_frame: float | None = None
        self._bytes_since_frame = 0
        self._batch: list[Sample] = []
        self._flush_at = time.monotonic()
        self.last_sent = -math.inf

    # ------------------------------------------------------------ faults and logging
    def fault(self, kind: str, text: str, level: str = 'warning') -> None:
        """Count a fault; log it the first time its kind occurs (per outage)."""
        self.counts[kind] += 1
        if kind in self._logged:
            return
        self._logged.add(kind)
        self._log(level, f'{text} (further {kind} faults are counted in /diagnostics, '
                         'not logged)')

    # ------------------------------------------------------------ the port
    @property
    def is_open(self) -> bool:
        """True while the device is open."""
        return self._port is not None

    @property
    def port(self) -> serial.SerialBase | None:
        """The open ``serial`` port, or None (for tools and tests that write raw bytes)."""
        return self._port

    def _open(self) -> bool:
        try:
            port = open_transport(self.url, self.baudrate, self.read_timeout)
        except TransportError as exc:
            self.state = 'disconnected'
            self.fault('open_failed', f'{exc}; retrying with backoff')
            return False
        self.parser.reset()
        again = self.counts['opened'] or self.counts['lost_device']
        self._log('info', f'device {self.url} {"reopened" if again else "open"}')
        self.counts['opened'] += 1
        self._logged -= {'open_failed', 'lost_device'}
        with self._lock:
            self._port = port
        self._backoff = 0.05
        self.state = 'connected'
        self._last_frame = time.monotonic()
        self._bytes_since_frame = 0
        if self._on_open is not None:
            try:
                self._on_open()
            except MotorIdError as exc:
                self.fault('command_failed', f'configuring the card failed: {exc}')
        return True

    def _lose_device(self, text: str) -> None:
        self.state = 'disconnected'
        self.fault('lost_device', f'device lost: {text}; reopening with backoff')
        self._close_port()

    def _close_port(self) -> None:
        with self._lock:
            port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, ValueError):
                pass

    def send(self, command: Command) -> None:
        """Encode and write one command; :class:`TransportError` when the device is not open.

        Thread-safe. Encoding errors raise :class:`ConfigError`.
        """
        data = encode_command(command)
        with self._lock:
            if self._port is None:
                raise TransportError(f'device {self.url} is not open')
            write_all(self._port, data)
            self.last_sent = time.monotonic()
        self.counts['commands_sent'] += 1

    def close(self) -> None:
        """Close the device (a later :meth:`poll` opens it again)."""
        self._close_port()

    # ------------------------------------------------------------ reading
    def poll(self) -> list[list[Sample]]:
        """Open the device if needed, read once, and return the batches ready to publish.

        Blocks for at most the read timeout, or the back-off wait (ended early by
        ``stop``) while the device is missing.

        Returns
        -------
        list of list of Sample
            Batches of at most ``batch_size`` accepted samples (no duplicates or late
            frames; gaps are left as gaps), processed by ``on_sample``, in stream order;
            empty when no batch is due.
        """
        if self._port is None and not self._open():
            self._stop.wait(self._backoff)
            self._backoff = min(2 * self._backoff, self.backoff_max)
            return []
        try:
            data = read_available(self._port)
        except TransportError as exc:
            batches = self.flush()   # what was read before the loss goes out now
            self._lose_device(f'{exc}')
            return batches
        if data:
            self._bytes_since_frame += len(data)
            self._handle(self.parser.feed(data))
            self._check_garbled()
        now = time.monotonic()
        out = []
        if self._batch and (len(self._batch) >= self.batch_size or not data or
                            now - self._flush_at > self.batch_age):
            out = self.flush()
        if not self._batch:
            self._flush_at = now
        if self._last_frame is not None and self.state == 'connected' and \
                now - self._last_frame > self.stall_timeout:
            self.state = 'stalled'
        return out

    def flush(self) -> list[list[Sample]]:
        """Return the samples kept so far in batches of ``batch_size`` (and forget them)."""
        rows, self._batch = self._batch, []
        n = self.batch_size
        return [rows[k:k + n] for k in range(0, len(rows), n)]

    def _check_garbled(self) -> None:
        if self._bytes_since_frame < GARBLED_BYTES or self.state == 'garbled':
            return
        self.state = 'garbled'
        self.fault('garbled', f'no valid frame in {self._bytes_since_frame} bytes: check '
                   f'the baud rate (the driver uses {self.baudrate} bit/s) and the device')

    def _handle(self, items: list[Sample | ProtocolError]) -> None:
        for item in items:
            if isinstance(item, ProtocolError):
                self.fault(f'frame_{item.kind}', f'bad frame from the card: {item}')
                continue
            self.counts['frames_ok'] += 1
            self._last_frame = time.monotonic()
            self._bytes_since_frame = 0
            if self.state in ('stalled', 'garbled'):
                self.state = 'connected'
            if not self.capacity_warning:
                self._check_capacity(item.has_current)
            ev = self.tracker.update(item.seq, restart=bool(item.flags & FLAG_STARTUP))
            if ev.kind == 'gap':
                self.fault('lost_frames', f'{ev.lost} frame(s) lost before seq {ev.seq}')
            elif ev.kind == 'reset':
                self.fault('card_reset', f'the card restarted its sequence at {ev.seq}',
                           'info')
            elif ev.kind in ('duplicate', 'late'):
                self.fault(f'{ev.kind}_frames', f'{ev.kind} frame seq {ev.seq} dropped')
                continue
            if self._on_sample is not None:
                item = self._on_sample(item)
            self._batch.append(item)
        while self.parser.replies:
            reply = self.parser.replies.popleft()
            if reply.status != 'ok':
                self.fault(f'reply_{reply.status}', f'the card answered {reply.status} to '
                           f'{reply.command}')
            if self._on_reply is not None:
                self._on_reply(reply)

    def line_capacity(self, with_current: bool = True) -> float:
        """Most sample frames per second the line carries at :attr:`baudrate`."""
        return max_frame_rate(self.baudrate, SAMPLE_FRAME_BYTES[bool(with_current)])

    def _check_capacity(self, with_current: bool) -> None:
        if not self.sample_period:
            self.capacity_warning = 'not checked'
            return
        rate = 1.0 / self.sample_period
        most = self.line_capacity(with_current)
        if rate <= most:
            self.capacity_warning = 'ok'
            return
        frame = SAMPLE_FRAME_BYTES[bool(with_current)]
        self.capacity_warning = (
            f'{rate:g} samples/s of {frame}-byte frames need '
            f'{rate * frame * BITS_PER_BYTE:.0f} bit/s but the line runs at {self.baudrate} '
            f'bit/s (at most {most:.0f} frames/s): frames will be lost; raise baud or '
            'sample_period')
        self.fault('line_overload', self.capacity_warning)

    # ------------------------------------------------------------ diagnostics
    def values(self) -> dict[str, DiagnosticValue]:
        """Diagnostic key/values of the link (counters and state)."""
        tr = self.tracker
        bad = {k: v for k, v in sorted(self.counts.items()) if k.startswith('frame_')}
        values: dict[str, DiagnosticValue] = {
            'link': self.state, 'device': self.url, 'frames_ok': self.counts['frames_ok'],
            'frames_bad': sum(bad.values()), 'garbage_bytes': self.parser.garbage_bytes,
            'lost': tr.lost, 'duplicates': tr.duplicates, 'late': tr.late,
            'resets': tr.resets, 'last_seq': tr.last, 'opens': self.counts['opened'],
            'device_lost': self.counts['lost_device'],
            'open_failures': self.counts['open_failed'],
            'commands_sent': self.counts['commands_sent']}
        values.update(bad)
        if self.capacity_warning not in ('', 'ok', 'not checked'):
            values['line_overload'] = self.capacity_warning
        return values


class SampleClock:
    """Map card time to host time and integrate speed into position.

    The offset between the two clocks is taken at the first sample (and again when the
    card's time goes back, i.e. it restarted), so stamps keep the card's own spacing
    exactly; a card clock that drifts from the host's shows up as a slowly growing
    difference between stamps and arrival times.

    Attributes
    ----------
    position : float
        Speed integrated over card time since the first sample (trapezoidal rule,
        across gaps too) [rad]; restarts at 0 when the card restarts.
    """

    def __init__(self) -> None:
        self._offset_ns: int | None = None
        self._last: tuple[float, float] | None = None
        self.position = 0.0

    def update(self, sample: Sample, host_now_ns: int) -> int:
        """Account for one sample; return its host time [ns].

        Parameters
        ----------
        sample : Sample
        host_now_ns : int
            Host time when the sample was handled [ns].
        """
        t_ns = round(sample.t_card * 1e9)
        if self._offset_ns is None or (self._last is not None and
                                       sample.t_card <= self._last[0]):
            self._offset_ns = int(host_now_ns) - t_ns
            self._last = None
            self.position = 0.0
        if self._last is not None:
            t0, w0 = self._last
            self.position += 0.5 * (w0 + sample.speed) * (sample.t_card - t0)
        self._last = (sample.t_card, sample.speed)
        return t_ns + self._offset_ns
