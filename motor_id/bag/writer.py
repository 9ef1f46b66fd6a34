"""The MCAP writer: rosbag2-compatible, chunked, a chunk on disk at most a second late.

Crash safety: messages are gathered in a chunk of at most ``chunk_size`` bytes
(uncompressed) that is written to the operating system as soon as it is full or
``flush_interval`` seconds after the previous chunk, whichever comes first, with no buffer
in user space. A writer killed with SIGKILL therefore loses at most the chunk in progress:
``min(chunk_size of data, flush_interval seconds of data)``. The file then has no summary
and no footer; :func:`motor_id.bag.recover` salvages every complete chunk into a clean
file. (A power cut can lose more: the writer does not fsync.)
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
import json
import os
import threading
import time
from typing import Any, cast, IO

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
import numpy as np
from numpy.typing import ArrayLike

from motor_id import __version__
from motor_id.bag.metadata import (
    channel_metadata,
    default_qos,
    METADATA_RECORD,
    QosProfile,
    rosbag2_metadata,
)
from motor_id.bag.schemas import (
    DIAGNOSTIC_ARRAY,
    FLOAT64,
    FLOAT64_MULTI_ARRAY,
    message_definition,
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    serialize,
    STRING,
    topic_name,
)
from motor_id.contracts import (
    BAG_ESTIMATE_TOPIC,
    BAG_META_TOPIC,
    BAG_POSITION_TOPIC,
    BAG_SAMPLES_TOPIC,
    BATCH_LABEL,
    CHANNEL_TOPICS,
    channel_units,
    DiagnosticValue,
    POSITION_LABEL,
    SAMPLE_COLUMNS,
    SAMPLES_LABEL,
    SEQ,
)
from motor_id.errors import BagError, ConfigError
from motor_id.output import to_jsonable
from motor_id.recording import Recording

DEFAULT_CHUNK_SIZE = 64 * 1024
"""Uncompressed bytes per chunk: the most a killed writer can lose (about 13 s of samples
at 100 Hz)."""
DEFAULT_FLUSH_INTERVAL = 1.0
"""Seconds after which a chunk is written even if it is not full."""
COMPRESSIONS = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}


class _DirectFile:
    """A write-only file without a user-space buffer: every write reaches the OS at once.

    The mcap writer writes a chunk when it is full without flushing its stream; with a
    buffered file that chunk could wait in this process and die with it.
    """

    def __init__(self, path: str) -> None:
        self._raw = open(path, 'wb', buffering=0)

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        done = 0
        while done < len(view):
            done += self._raw.write(view[done:])
        return done

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        """Nothing is buffered."""

    def close(self) -> None:
        self._raw.close()


@dataclass
class _Topic:
    name: str
    msgtype: str
    channel_id: int
    metadata: dict
    count: int = 0


class BagWriter:
    """Write a rosbag2-compatible MCAP file (``ros2 bag play``, Foxglove, rosbags read it).

    Profile ``ros2``, ``ros2msg`` schemas, CDR messages, the QoS offered per channel in
    its metadata (``offered_qos_profiles``, ``topic_type_hash``) and, on :meth:`close`,
    the ``rosbag2`` metadata record (the ``metadata.yaml`` of a Jazzy bag, version 9),
    the summary (statistics, indexes) and the footer. Use as a context manager.

    Parameters
    ----------
    path : str or Path
        Output ``.mcap`` file (replaced if it exists).
    chunk_size : int
        Uncompressed bytes gathered before a chunk is written (the loss bound on SIGKILL).
    compression : {'zstd', 'lz4', 'none'}
        Chunk compression; rosbag2's MCAP plugin and Foxglove read all three.
    flush_interval : float or None
        Seconds after which a partly filled chunk is written anyway; None: only when full.
    clock : callable
        Monotonic clock for ``flush_interval`` (tests inject one).

    Notes
    -----
    Times are integer nanoseconds: ``log_time_ns`` is when the message was received
    (rosbag2's receive time, used for playback timing), ``publish_time_ns`` defaults to it.
    The methods are thread-safe (one lock); writing after :meth:`close` raises BagError.
    """

    def __init__(self, path: str | os.PathLike[str], chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str = 'zstd', flush_interval: float | None = DEFAULT_FLUSH_INTERVAL,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if compression not in COMPRESSIONS:
            raise ConfigError(f'compression must be one of {tuple(COMPRESSIONS)}, '
                              f'got {compression!r}')
        if int(chunk_size) < 1:
            raise ConfigError(f'chunk_size must be >= 1 byte, got {chunk_size}')
        if flush_interval is not None and not flush_interval > 0:
            raise ConfigError(f'flush_interval must be > 0 s or None, got {flush_interval}')
        self.path = str(path)
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self.flush_interval = flush_interval
        self._clock = clock
        try:
            self._file = _DirectFile(self.path)
        except OSError as exc:
            raise BagError(f'{self.path}: cannot create ({exc.strerror})') from exc
        self._writer = McapWriter(cast(IO[Any], self._file), chunk_size=self.chunk_size,
                                  compression=COMPRESSIONS[compression])
        self._writer.start(profile='ros2', library=library_string())
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._topics: dict[str, _Topic] = {}
        self._start_ns: int | None = None
        self._end_ns: int | None = None
        self._last_flush = clock()
        self._closed = False
        self._lock = threading.RLock()

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(t.count for t in self._topics.values())

    def add_topic(self, topic: str, msgtype: str,
                  qos: QosProfile | None = None) -> '_Topic':
        """Declare a topic (done implicitly by the first write with the default QoS).

        Parameters
        ----------
        topic : str
            Topic name; a relative name gets a leading ``/``.
        msgtype : str
            A ROS 2 Jazzy message type, e.g. ``'std_msgs/msg/String'``.
        qos : QosProfile, optional
            Offered QoS (:func:`~motor_id.bag.metadata.qos_profile`); default
            :func:`~motor_id.bag.metadata.default_qos`.
        """
        with self._lock:
            name = topic_name(topic)
            known = self._topics.get(name)
            if known is not None:
                if known.msgtype != msgtype:
                    raise ConfigError(f'topic {name} was declared as {known.msgtype}, '
                                      f'cannot write {msgtype}')
                return known
            definition = message_definition(msgtype)
            qos = default_qos(name) if qos is None else qos
            schema_id = self._schema_id(msgtype, SCHEMA_ENCODING, definition.encode())
            meta = channel_metadata(msgtype, qos)
            channel_id = self._writer.register_channel(name, MESSAGE_ENCODING, schema_id, meta)
            entry = _Topic(name, msgtype, channel_id, meta)
            self._topics[name] = entry
            return entry

    def _schema_id(self, name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding, data)
        if key not in self._schemas:
            self._schemas[key] = self._writer.register_schema(name, encoding, data)
        return self._schemas[key]

    def write(self, topic: str, msgtype: str, msg: Any, log_time_ns: int,
              publish_time_ns: int | None = None, sequence: int = 0) -> None:
        """Serialise one message to CDR and write it.

        Parameters
        ----------
        topic : str
        msgtype : str
        msg : dict or message object
            Field values (nested dicts for sub-messages, sequences for arrays), or an
            instance of the rosbags Jazzy type store's class for ``msgtype``.
        log_time_ns : int
            Receive time [ns], >= 0.
        publish_time_ns : int, optional
        sequence : int
        """
        with self._lock:
            self._check_open()
            entry = self.add_topic(topic, msgtype)
            try:
                data = serialize(msgtype, msg)
            except BagError as exc:
                raise BagError(f'{entry.name}: {exc}') from None
            self._add(entry, data, log_time_ns, publish_time_ns, sequence)

    def _add(self, entry: _Topic, data: bytes, log_time_ns: int, publish_time_ns: int | None,
             sequence: int) -> None:
        log_time = int(log_time_ns)
        if log_time < 0:
            raise ConfigError(f'log time must be >= 0 ns, got {log_time}')
        pub = log_time if publish_time_ns is None else int(publish_time_ns)
        self._writer.add_message(entry.channel_id, log_time, data, pub, int(sequence))
        entry.count += 1
        self._start_ns = log_time if self._start_ns is None else min(self._start_ns, log_time)
        self._end_ns = log_time if self._end_ns is None else max(self._end_ns, log_time)
        if self.flush_interval is not None:
            if self._clock() - self._last_flush >= self.flush_interval:
                self.flush()

    def write_serialized(self, topic: str, msgtype: str, data: bytes, log_time_ns: int,
                         publish_time_ns: int | None = None) -> None:
        """Write one message already serialised to CDR (as rclpy's ``serialize_message``
        gives it), on a topic declared with ``msgtype``'s schema.

        Parameters
        ----------
        topic, msgtype : str
        data : bytes
            The CDR bytes with their encapsulation header.
        log_time_ns : int
            Receive (or send) time [ns].
        """
        with self._lock:
            self._check_open()
            entry = self.add_topic(topic, msgtype)
            self._add(entry, bytes(data), log_time_ns, publish_time_ns, 0)

    def flush(self) -> None:
        """Write the chunk in progress now (a SIGKILL after this loses nothing so far)."""
        with self._lock:
            self._check_open()
            self._writer.flush()
            self._last_flush = self._clock()

    def write_samples(self, rows: ArrayLike, log_time_ns: int,
                      publish_time_ns: int | None = None, sequence: int = 0,
                      topic: str = BAG_SAMPLES_TOPIC) -> None:
        """Write a batch of sample rows on ``/samples`` (layout: :mod:`motor_id.contracts`).

        Parameters
        ----------
        rows : array_like, shape (n, 6) or (6,)
            Columns ``seq, t [s], voltage [V] (or torque), speed [rad/s], current [A]
            (NaN if none), flags``.
        log_time_ns : int
            Receive time of the batch [ns].
        """
        arr = np.asarray(rows, dtype=float)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1)
        width = len(SAMPLE_COLUMNS)
        if arr.ndim != 2 or arr.shape[1] != width:
            raise ConfigError(f'sample rows must have {width} columns ({SAMPLES_LABEL}), '
                              f'got shape {np.shape(rows)}')
        n = arr.shape[0]
        msg = {'layout': {'dim': [{'label': BATCH_LABEL, 'size': n, 'stride': width * n},
                                  {'label': SAMPLES_LABEL, 'size': width, 'stride': width}],
                          'data_offset': 0},
               'data': arr.ravel()}
        self.write(topic, FLOAT64_MULTI_ARRAY, msg, log_time_ns, publish_time_ns, sequence)

    def write_positions(self, seq: ArrayLike, position: ArrayLike, log_time_ns: int) -> None:
        """Write a batch of measured positions on ``/motor_id/position`` (rows
        ``seq, position``; see :data:`motor_id.contracts.BAG_POSITION_TOPIC`)."""
        arr = np.column_stack([np.asarray(seq, dtype=float), np.asarray(position, dtype=float)])
        n = arr.shape[0]
        msg = {'layout': {'dim': [{'label': BATCH_LABEL, 'size': n, 'stride': 2 * n},
                                  {'label': POSITION_LABEL, 'size': 2, 'stride': 2}],
                          'data_offset': 0},
               'data': arr.ravel()}
        self.write(BAG_POSITION_TOPIC, FLOAT64_MULTI_ARRAY, msg, log_time_ns)

    def write_meta(self, meta: dict[str, Any], log_time_ns: int = 0) -> None:
        """Write the recording's metadata as JSON on ``/motor_id/meta`` (latched).

        Parameters
        ----------
        meta : dict
            ``input_kind``, ``provenance``, ``units``, ``truth`` ... (converted by
            :func:`motor_id.output.to_jsonable`: numpy values to Python, NaN/inf to null).
        """
        try:
            text = json.dumps(to_jsonable(meta))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f'bag metadata is not JSON-serialisable: {exc}') from exc
        self.write(BAG_META_TOPIC, STRING, {'data': text}, log_time_ns)

    def write_estimate(self, values: Mapping[str, DiagnosticValue], log_time_ns: int,
                       name: str = 'motor_id identifier', message: str = '', level: int = 0,
                       hardware_id: str = '', topic: str = BAG_ESTIMATE_TOPIC) -> None:
        """Write a DiagnosticArray with one status holding ``values`` as key/value strings.

        Parameters
        ----------
        values : dict
            E.g. ``{'J': 0.052, 'J_std': 0.001, 'J_determined': True}``; floats are written
            with ``repr`` (round-trip exact).
        log_time_ns : int
            Also the header stamp.
        level : int
            0 OK, 1 WARN, 2 ERROR, 3 STALE.
        """
        if int(level) not in (0, 1, 2, 3):
            raise ConfigError(f'diagnostic level must be 0..3, got {level}')
        sec, nanosec = divmod(int(log_time_ns), 1_000_000_000)
        kv = [{'key': str(k), 'value': _kv_text(v)} for k, v in values.items()]
        msg = {'header': {'stamp': {'sec': sec, 'nanosec': nanosec}, 'frame_id': ''},
               'status': [{'level': int(level), 'name': name, 'message': message,
                           'hardware_id': hardware_id, 'values': kv}]}
        self.write(topic, DIAGNOSTIC_ARRAY, msg, log_time_ns)

    def write_channel(self, name: str, value: float, log_time_ns: int) -> None:
        """Write one value on a per-channel ``std_msgs/Float64`` topic (voltage, speed,
        current)."""
        if name not in CHANNEL_TOPICS:
            raise ConfigError(f'channel must be one of {CHANNEL_TOPICS}, got {name!r}')
        self.write('/' + name, FLOAT64, {'data': float(value)}, log_time_ns)

    def write_raw(self, topic: str, schema: Any, message_encoding: str, data: bytes,
                  log_time_ns: int, publish_time_ns: int | None = None, sequence: int = 0,
                  channel_metadata: dict[str, str] | None = None) -> None:
        """Copy an already serialised message (used by :func:`motor_id.bag.recover`).

        Parameters
        ----------
        schema : mcap.records.Schema or None
        channel_metadata : dict, optional
            Copied verbatim (QoS, type hash).
        """
        with self._lock:
            self._check_open()
            name = topic_name(topic)
            entry = self._topics.get(name)
            if entry is None:
                if schema is None:
                    schema_id, msgtype = 0, ''
                else:
                    schema_id = self._schema_id(schema.name, schema.encoding, schema.data)
                    msgtype = schema.name
                meta = dict(channel_metadata or {})
                channel_id = self._writer.register_channel(name, message_encoding, schema_id,
                                                           meta)
                entry = _Topic(name, msgtype, channel_id, meta)
                self._topics[name] = entry
            self._add(entry, data, log_time_ns, publish_time_ns, sequence)

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f'{self.path}: bag writer is closed')

    def close(self) -> None:
        """Write the rosbag2 metadata record, the summary (statistics, indexes), the footer."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                text = rosbag2_metadata(os.path.basename(self.path), self._topics.values(),
                                        self._start_ns, self._end_ns)
                self._writer.add_metadata(METADATA_RECORD, {'serialized_metadata': text})
                self._writer.finish()
            finally:
                self._file.close()


def _kv_text(value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        return 'true' if value else 'false'
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def library_string() -> str:
    """The MCAP header's library field: who wrote the file."""
    return (f'motor_id {__version__}; mcap-python {_version("mcap")}; '
            f'rosbags {_version("rosbags")}')


def _version(dist: str) -> str:
    try:
        return version(dist)
    except PackageNotFoundError:
        return 'unknown'


@dataclass(frozen=True)
class WrittenBag:
    """A bag :func:`write_recording` wrote: its path, sample rows and messages."""

    path: str
    samples: int
    messages: int


def write_recording(rec: Recording, path: str | os.PathLike[str],
                    meta: dict[str, Any] | None = None, batch: int = 50, start_ns: int = 0,
                    channels: bool = False, **writer_kw: Any) -> 'WrittenBag':
    """Write a :class:`~motor_id.recording.Recording` to an MCAP bag.

    Parameters
    ----------
    rec : Recording
    path : str or Path
    meta : dict, optional
        Extra metadata merged over ``rec.meta`` into the ``/motor_id/meta`` JSON (which
        always holds ``input_kind`` and ``units``, and ``runs``, the ``[first, end)``
        sequence numbers of each run, for a recording of several runs).
    batch : int
        Rows per ``/samples`` message.
    start_ns : int
        Log time of the first sample [ns]; sample k is logged at
        ``start_ns + (t_k - t_0)`` (a batch at the time of its last row).
    channels : bool
        Also write the per-channel ``/voltage``, ``/speed``, ``/current`` topics.
    **writer_kw
        Passed to :class:`BagWriter` (chunk_size, compression).

    Returns
    -------
    WrittenBag
    """
    if int(batch) < 1:
        raise ConfigError(f'batch must be >= 1 row, got {batch}')
    if len(rec) == 0:
        raise ConfigError('the recording is empty')
    with BagWriter(path, **writer_kw) as bag:
        write_recording_into(bag, rec, meta, batch, start_ns, channels)
        count = bag.message_count
    return WrittenBag(str(path), len(rec), count)


def write_recording_into(bag: BagWriter, rec: Recording, meta: dict[str, Any] | None = None,
                         batch: int = 50, start_ns: int = 0, channels: bool = False) -> None:
    """Write a recording's ``/motor_id/meta``, ``/samples`` (and ``/motor_id/position``)
    into an open bag (the arguments as :func:`write_recording`'s)."""
    if int(batch) < 1:
        raise ConfigError(f'batch must be >= 1 row, got {batch}')
    n = len(rec)
    if n == 0:
        raise ConfigError('the recording is empty')
    rows = rec.sample_rows()
    log_ns = int(start_ns) + np.rint((rec.time - rec.time[0]) * 1e9).astype(np.int64)
    info = {k: v for k, v in rec.meta.items() if k not in ('bag', 'gaps')}
    info.update(meta or {})
    info['input_kind'] = rec.input_kind
    info.setdefault('units', channel_units(rec.input_kind))
    if rec.segments:   # separate runs (a SysId log's tests): by sequence number
        info['runs'] = [[int(a), int(b)] for a, b in rec.segments]
    bag.write_meta(info, int(start_ns))
    for k0 in range(0, n, int(batch)):
        k1 = min(n, k0 + int(batch))
        bag.write_samples(rows[k0:k1], int(log_ns[k1 - 1]))
        if rec.position is not None:
            bag.write_positions(rows[k0:k1, SEQ], rec.position[k0:k1], int(log_ns[k1 - 1]))
        if channels:
            for k in range(k0, k1):
                bag.write_channel('voltage', rec.input[k], int(log_ns[k]))
                bag.write_channel('speed', rec.speed[k], int(log_ns[k]))
                if rec.current is not None:
                    bag.write_channel('current', rec.current[k], int(log_ns[k]))
