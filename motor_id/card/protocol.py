"""The binary serial protocol between host and card: frames, messages, CRC (bytes only).

Every message travels in one frame (all integers little-endian)::

    +------+------+------+-----+-----------------+-------------+
    | 0xA5 | 0x5A | type | len | payload (len B) | CRC-32 (4B) |
    +------+------+------+-----+-----------------+-------------+

The CRC is :func:`zlib.crc32` of ``type, len, payload`` (not of the sync bytes).
Real numbers are IEEE-754 binary32 (float32); times are whole microseconds. The full
specification, with the payload of every frame type, is ``docs/protocol.md``.

Public API (stable; the driver node and the simulated card import it):

* card -> host: :class:`Sample`, :class:`Reply`; :func:`encode_sample`,
  :func:`encode_reply`; :func:`parse_frame` (one frame -> Sample or Reply).
* host -> card: :class:`SetVoltage`, :class:`StartProfile`, :class:`Stop`,
  :class:`SetPeriod`, :class:`Ping`; :func:`encode_command`, :func:`parse_command`.

A byte stream is cut into frames by :mod:`motor_id.card.stream` (``FrameParser``,
``CommandParser``); :mod:`motor_id.card.sequence` classifies successive sequence numbers
and :mod:`motor_id.card.transport` opens a device path, a pty or ``loop://``.

Decoding never raises anything but :class:`motor_id.errors.ProtocolError`, whose
``kind`` is one of :data:`ERROR_KINDS`; encoding raises
:class:`motor_id.errors.ConfigError` for values the format cannot carry. Nothing here
logs, sleeps or touches a device: callers count and report.
"""

from collections.abc import Callable
from dataclasses import dataclass
import math
import struct
from typing import Any
import zlib

from motor_id.contracts import (  # noqa: F401  (re-exported: the wire format)
    FLAG_CURRENT,
    FLAG_LIMIT,
    FLAG_NAMES,
    FLAG_OVERRUN,
    FLAG_PROFILE,
    FLAG_PROFILE_END,
    FLAG_STARTUP,
)
from motor_id.errors import ConfigError, ProtocolError

SYNC = b'\xa5\x5a'
"""Start-of-frame marker."""

HEADER = struct.Struct('<2sBB')
"""Sync, frame type, payload length."""

CRC = struct.Struct('<I')
OVERHEAD = HEADER.size + CRC.size
"""Bytes of a frame that are not payload (8)."""

MAX_FRAME = OVERHEAD + 255

ERROR_KINDS = ('short', 'bad_sync', 'bad_length', 'bad_crc', 'bad_type', 'bad_value')
"""``ProtocolError.kind`` values.

``short``: fewer bytes than a frame (or than its header announces); ``bad_sync``: no
start marker; ``bad_length``: more bytes than announced, or a payload length the frame
type does not allow; ``bad_crc``: checksum mismatch; ``bad_type``: a frame type that
does not travel in this direction; ``bad_value``: a field out of its domain
(non-finite number, unknown status code, undecodable name).
"""

# Frame types. Card -> host below 0x10, host -> card from 0x10.
TYPE_SAMPLE = 0x01
TYPE_REPLY = 0x02
TYPE_SET_VOLTAGE = 0x10
TYPE_START_PROFILE = 0x11
TYPE_STOP = 0x12
TYPE_SET_PERIOD = 0x13
TYPE_PING = 0x14

# Sample status flags (uint16): the samples carry them bit for bit, so they live in
# motor_id.contracts.
STATUS_CODES = {0: 'ok', 1: 'bad_value', 2: 'unknown_profile', 3: 'busy', 4: 'unsupported'}
"""Reply status on the wire -> name."""
STATUS_NAMES = {v: k for k, v in STATUS_CODES.items()}

MAX_NAME = 32
"""Longest profile name a StartProfile frame carries (ASCII bytes)."""

_U32 = 2 ** 32
_U64 = 2 ** 64
_F32_MAX = 3.4028234663852886e38


@dataclass(frozen=True, eq=False)
class Sample:
    """One measurement from the card.

    Attributes
    ----------
    seq : int
        Sequence number, uint32, +1 per sample, wrapping at 2**32.
    t_card : float
        The card's own clock at the sample [s] (whole microseconds on the wire).
    voltage : float
        Input applied from this sample to the next [V] (torque [N m] on torque plants).
    speed : float
        Measured speed [rad/s].
    current : float
        Measured current [A]; ``nan`` when the card sends none.
    flags : int
        Status bits ``FLAG_*`` (uint16).
    """

    seq: int
    t_card: float
    voltage: float
    speed: float
    current: float = float('nan')
    flags: int = 0

    @property
    def has_current(self) -> bool:
        """True when the sample carries a current value."""
        return not math.isnan(self.current)

    def _key(self) -> tuple[Any, ...]:
        return (self.seq, self.t_card, self.voltage, self.speed,
                self.current if self.has_current else None, self.flags)

    def __eq__(self, other: object) -> bool:
        """Field-wise equality; two absent (nan) currents are equal."""
        if not isinstance(other, Sample):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


@dataclass(frozen=True)
class Reply:
    """The card's answer to one command.

    Attributes
    ----------
    command : str
        Name of the command answered (``'set_voltage'``, ``'start_profile'``, ``'stop'``,
        ``'set_period'``, ``'ping'``).
    status : str
        One of :data:`STATUS_CODES` values: ``'ok'``, ``'bad_value'``,
        ``'unknown_profile'``, ``'busy'``, ``'unsupported'``.
    value : int
        uint32: for ``ping`` the echoed token, otherwise the sequence number of the first
        sample the command affects.
    """

    command: str
    status: str = 'ok'
    value: int = 0


@dataclass(frozen=True)
class SetVoltage:
    """Hold ``voltage`` [V] from the next sample on (aborts a running profile)."""

    voltage: float


@dataclass(frozen=True)
class StartProfile:
    """Run an excitation profile from :data:`motor_id.excitation.PROFILES`.

    Attributes
    ----------
    name : str
        Profile name (ASCII, 1..32 bytes).
    amplitude : float
        Amplitude [V].
    seed : int
        uint32 seed of random profiles (prbs, multisine).
    duration : float
        Length of the profile [s]; the card holds 0 V afterwards.
    """

    name: str
    amplitude: float = 9.0
    seed: int = 0
    duration: float = 40.0


@dataclass(frozen=True)
class Stop:
    """Abort any profile and hold 0 V."""


@dataclass(frozen=True)
class SetPeriod:
    """Sample every ``period`` seconds (whole microseconds on the wire)."""

    period: float


@dataclass(frozen=True)
class Ping:
    """Ask for a reply echoing ``token`` (uint32)."""

    token: int = 0


COMMANDS = (SetVoltage, StartProfile, Stop, SetPeriod, Ping)
Command = SetVoltage | StartProfile | Stop | SetPeriod | Ping
"""A host -> card message."""


# ---------------------------------------------------------------------------------------
# field helpers


def crc(data: bytes) -> int:
    """CRC-32 (:func:`zlib.crc32`) of ``data`` as an unsigned int."""
    return zlib.crc32(data) & 0xFFFFFFFF


def _f32(name: str, value: Any, finite: bool = True) -> float:
    """Check that ``value`` fits a float32 field (for encoding)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f'{name} must be a number, got {value!r}') from None
    if finite and not math.isfinite(v):
        raise ConfigError(f'{name} must be finite, got {v}')
    if math.isfinite(v) and abs(v) > _F32_MAX:
        raise ConfigError(f'{name} = {v} does not fit a float32 (|x| <= 3.4e38)')
    return v


def check_uint(name: str, value: Any, limit: int) -> int:
    """``value`` as an int in ``[0, limit)`` (for encoding); ConfigError otherwise."""
    if isinstance(value, bool) or not isinstance(value, int):
        try:
            if float(value) != int(value):
                raise ValueError
            value = int(value)
        except (TypeError, ValueError, OverflowError):
            raise ConfigError(f'{name} must be an integer, got {value!r}') from None
    checked: int = value   # given as an int, or converted to one above
    if not 0 <= checked < limit:
        raise ConfigError(f'{name} must be in [0, {limit - 1}], got {checked}')
    return checked


def _micros(name: str, seconds: float, limit: int, minimum: int = 0) -> int:
    s = _f32(name, seconds)
    us = round(s * 1e6)
    if not minimum <= us < limit:
        raise ConfigError(f'{name} = {s} s is outside the wire range '
                          f'[{minimum * 1e-6}, {(limit - 1) * 1e-6}] s')
    return us


def _finite(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise ProtocolError('bad_value', f'{name} is {value}')
    return value


# ---------------------------------------------------------------------------------------
# payload codecs, one pair per frame type

_SAMPLE = struct.Struct('<IQHff')
_SAMPLE_I = struct.Struct('<IQHfff')
_REPLY = struct.Struct('<BBI')
_F = struct.Struct('<f')
_U = struct.Struct('<I')
_PROFILE = struct.Struct('<ffIB')


def _enc_sample(s: Sample) -> bytes:
    has_current = not math.isnan(_f32('current', s.current, finite=False))
    if has_current and math.isinf(s.current):
        raise ConfigError(f'current must be finite or nan, got {s.current}')
    flags = check_uint('flags', s.flags, 2 ** 16)
    flags = (flags | FLAG_CURRENT) if has_current else (flags & ~FLAG_CURRENT)
    head = (check_uint('seq', s.seq, _U32), _micros('t_card', s.t_card, _U64), flags,
            _f32('voltage', s.voltage), _f32('speed', s.speed))
    if has_current:
        return _SAMPLE_I.pack(*head, s.current)
    return _SAMPLE.pack(*head)


def _dec_sample(p: bytes) -> Sample:
    if len(p) == _SAMPLE_I.size:
        seq, t_us, flags, v, w, i = _SAMPLE_I.unpack(p)
        if not flags & FLAG_CURRENT:
            raise ProtocolError('bad_length', 'sample carries a current but its flag is clear')
        _finite('current', i)
    else:
        seq, t_us, flags, v, w = _SAMPLE.unpack(p)
        i = float('nan')
        if flags & FLAG_CURRENT:
            raise ProtocolError('bad_length', 'current flag set but the sample has none')
    return Sample(seq, t_us / 1e6, _finite('voltage', v), _finite('speed', w), i, flags)


def _enc_reply(r: Reply) -> bytes:
    command = _COMMAND_CODES.get(r.command)
    if command is None:
        raise ConfigError(f'reply to unknown command {r.command!r}; '
                          f'expected one of {sorted(_COMMAND_CODES)}')
    if r.status not in STATUS_NAMES:
        raise ConfigError(f'unknown reply status {r.status!r}; '
                          f'expected one of {sorted(STATUS_NAMES)}')
    return _REPLY.pack(command, STATUS_NAMES[r.status], check_uint('value', r.value, _U32))


def _dec_reply(p: bytes) -> Reply:
    command, status, value = _REPLY.unpack(p)
    if command not in _COMMAND_TYPES or status not in STATUS_CODES:
        raise ProtocolError('bad_value', f'reply to command {command:#04x} with status {status}')
    return Reply(_COMMAND_TYPES[command].name, STATUS_CODES[status], value)


def _enc_set_voltage(c: SetVoltage) -> bytes:
    return _F.pack(_f32('voltage', c.voltage))


def _dec_set_voltage(p: bytes) -> SetVoltage:
    return SetVoltage(_finite('voltage', _F.unpack(p)[0]))


def _enc_start_profile(c: StartProfile) -> bytes:
    if not isinstance(c.name, str):
        raise ConfigError(f'profile name must be a string, got {c.name!r}')
    try:
        name = c.name.encode('ascii')
    except UnicodeEncodeError:
        raise ConfigError(f'profile name must be ASCII, got {c.name!r}') from None
    if not 1 <= len(name) <= MAX_NAME:
        raise ConfigError(f'profile name must have 1..{MAX_NAME} characters, got {c.name!r}')
    return _PROFILE.pack(_f32('amplitude', c.amplitude), _f32('duration', c.duration),
                         check_uint('seed', c.seed, _U32), len(name)) + name


def _dec_start_profile(p: bytes) -> StartProfile:
    amplitude, duration, seed, n = _PROFILE.unpack_from(p)
    name = p[_PROFILE.size:]
    if len(name) != n:
        raise ProtocolError('bad_length', f'profile name announces {n} bytes, has {len(name)}')
    if not name.isascii() or not name.decode('ascii').isprintable():
        raise ProtocolError('bad_value', f'profile name {name!r} is not printable ASCII')
    return StartProfile(name.decode('ascii'), _finite('amplitude', amplitude), seed,
                        _finite('duration', duration))


def _enc_set_period(c: SetPeriod) -> bytes:
    return _U.pack(_micros('period', c.period, _U32, minimum=1))


def _dec_set_period(p: bytes) -> SetPeriod:
    us = _U.unpack(p)[0]
    if us == 0:
        raise ProtocolError('bad_value', 'sample period of 0 us')
    return SetPeriod(us / 1e6)


@dataclass(frozen=True)
class _Kind:
    """One row of the frame table."""

    code: int
    name: str
    cls: type
    lengths: frozenset[int]
    encode: Callable[[Any], bytes]
    decode: Callable[[bytes], Any]


_CARD_KINDS = (
    _Kind(TYPE_SAMPLE, 'sample', Sample, frozenset((_SAMPLE.size, _SAMPLE_I.size)),
          _enc_sample, _dec_sample),
    _Kind(TYPE_REPLY, 'reply', Reply, frozenset((_REPLY.size,)), _enc_reply, _dec_reply),
)
_HOST_KINDS = (
    _Kind(TYPE_SET_VOLTAGE, 'set_voltage', SetVoltage, frozenset((_F.size,)),
          _enc_set_voltage, _dec_set_voltage),
    _Kind(TYPE_START_PROFILE, 'start_profile', StartProfile,
          frozenset(range(_PROFILE.size + 1, _PROFILE.size + MAX_NAME + 1)),
          _enc_start_profile, _dec_start_profile),
    _Kind(TYPE_STOP, 'stop', Stop, frozenset((0,)), lambda c: b'', lambda p: Stop()),
    _Kind(TYPE_SET_PERIOD, 'set_period', SetPeriod, frozenset((_U.size,)),
          _enc_set_period, _dec_set_period),
    _Kind(TYPE_PING, 'ping', Ping, frozenset((_U.size,)),
          lambda c: _U.pack(check_uint('token', c.token, _U32)), lambda p: Ping(_U.unpack(p)[0])),
)
CARD_TYPES = {k.code: k for k in _CARD_KINDS}
"""Frame types the card sends: code -> table row."""
HOST_TYPES = {k.code: k for k in _HOST_KINDS}
"""Frame types the host sends: code -> table row."""
_BY_CLASS = {k.cls: k for k in _CARD_KINDS + _HOST_KINDS}
_COMMAND_TYPES = HOST_TYPES
_COMMAND_CODES = {k.name: k.code for k in _HOST_KINDS}


# ---------------------------------------------------------------------------------------
# frames


def _frame(kind: _Kind, payload: bytes) -> bytes:
    body = struct.pack('<BB', kind.code, len(payload)) + payload
    return SYNC + body + CRC.pack(crc(body))


def _encode(message: Any, allowed: dict[int, _Kind]) -> bytes:
    kind = _BY_CLASS.get(type(message))
    if kind is None or kind.code not in allowed:
        raise ConfigError(f'cannot encode {type(message).__name__} here; expected one of '
                          f'{[k.cls.__name__ for k in allowed.values()]}')
    return _frame(kind, kind.encode(message))


def encode_sample(sample: Sample) -> bytes:
    """Encode a :class:`Sample` as one frame.

    Parameters
    ----------
    sample : Sample
        ``current`` nan means "no current": the field is left out and the
        :data:`FLAG_CURRENT` bit cleared; otherwise the bit is set.

    Returns
    -------
    bytes
        22 + 8 bytes without current, 26 + 8 with.

    Notes
    -----
    ``voltage``, ``speed`` and ``current`` are rounded to float32 and ``t_card`` to whole
    microseconds, so ``parse_frame(encode_sample(s)) == s`` exactly when those values
    are already float32 numbers and ``t_card`` is ``n / 1e6``.
    """
    if not isinstance(sample, Sample):
        raise ConfigError(f'encode_sample takes a Sample, got {type(sample).__name__}')
    return _encode(sample, CARD_TYPES)


def encode_reply(reply: Reply) -> bytes:
    """Encode a :class:`Reply` (card -> host) as one frame."""
    if not isinstance(reply, Reply):
        raise ConfigError(f'encode_reply takes a Reply, got {type(reply).__name__}')
    return _encode(reply, CARD_TYPES)


def encode_command(command: Command) -> bytes:
    """Encode a host -> card command (:data:`COMMANDS`) as one frame.

    Real numbers are sent as float32; ``SetPeriod.period`` as whole microseconds
    (1 us .. 4294 s).
    """
    return _encode(command, HOST_TYPES)


def _split(frame: bytes) -> tuple[int, bytes]:
    """Check framing and CRC of one complete frame; return (type, payload)."""
    frame = bytes(frame)
    if len(frame) < OVERHEAD:
        raise ProtocolError('short', f'{len(frame)} bytes, a frame has at least {OVERHEAD}')
    sync, ftype, length = HEADER.unpack_from(frame)
    if sync != SYNC:
        raise ProtocolError('bad_sync', f'starts with {sync.hex()}, expected {SYNC.hex()}')
    if len(frame) < OVERHEAD + length:
        raise ProtocolError('short', f'{len(frame)} bytes, the header announces '
                            f'{OVERHEAD + length}')
    if len(frame) > OVERHEAD + length:
        raise ProtocolError('bad_length', f'{len(frame)} bytes, the header announces '
                            f'{OVERHEAD + length}')
    body = frame[2:-CRC.size]
    got = CRC.unpack_from(frame, len(frame) - CRC.size)[0]
    if crc(body) != got:
        raise ProtocolError('bad_crc', f'CRC {got:08x} != computed {crc(body):08x}')
    return ftype, frame[HEADER.size:-CRC.size]


def _decode(ftype: int, payload: bytes, table: dict[int, _Kind]) -> Any:
    kind = table.get(ftype)
    if kind is None:
        raise ProtocolError('bad_type', f'frame type {ftype:#04x} is not one of '
                            f'{", ".join(f"{k:#04x}" for k in table)}')
    if len(payload) not in kind.lengths:
        raise ProtocolError('bad_length', f'{kind.name} payload of {len(payload)} bytes; '
                            f'allowed: {sorted(kind.lengths)}')
    return kind.decode(payload)


def parse_frame(frame: bytes) -> Sample | Reply:
    """Decode one complete card -> host frame.

    Parameters
    ----------
    frame : bytes
        Exactly one frame, sync marker to CRC.

    Returns
    -------
    Sample or Reply

    Raises
    ------
    ProtocolError
        ``kind`` in :data:`ERROR_KINDS`, checked in this order: ``short``, ``bad_sync``,
        ``short``/``bad_length`` (size vs header), ``bad_crc``, ``bad_type``,
        ``bad_length`` (payload size vs type), ``bad_value``.
    """
    ftype, payload = _split(frame)
    decoded: Sample | Reply = _decode(ftype, payload, CARD_TYPES)
    return decoded


def parse_command(frame: bytes) -> Command:
    """Decode one complete host -> card frame into a command; errors as :func:`parse_frame`."""
    ftype, payload = _split(frame)
    command: Command = _decode(ftype, payload, HOST_TYPES)
    return command
