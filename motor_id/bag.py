"""MCAP recordings: a rosbag2-compatible writer, reading back to a Recording, info, recovery.

Layout of a motor_id bag (profile ``ros2``, CDR messages, ``ros2msg`` schemas holding the
complete message definitions exactly as rosbag2 writes them, chunked and indexed, with a
Statistics record and the ``rosbag2`` metadata record of a Jazzy bag, version 9):

==========================  ====================================  ========================
topic                       type                                  QoS offered
==========================  ====================================  ========================
``/samples``                std_msgs/msg/Float64MultiArray        reliable, volatile, 100
``/motor_id/meta``          std_msgs/msg/String (JSON)            reliable, transient local
``/identifier/estimate``    diagnostic_msgs/msg/DiagnosticArray   reliable, transient local
``/voltage`` ``/speed``     std_msgs/msg/Float64 (optional)       reliable, volatile, 10
``/current``
==========================  ====================================  ========================

A ``/samples`` message is a batch of rows ``seq, t, voltage, speed, current, flags``
(row-major, ``layout.dim[0] = ('samples', n, 6 n)``, ``layout.dim[1] =
('seq,t,voltage,speed,current,flags', 6, 6)``); see docs/CONTRACTS.md.

Crash safety: messages are gathered in a chunk of at most ``chunk_size`` bytes
(uncompressed) that is written to the operating system as soon as it is full or
``flush_interval`` seconds after the previous chunk, whichever comes first, with no buffer
in user space. A writer killed with SIGKILL therefore loses at most the chunk in progress:
``min(chunk_size of data, flush_interval seconds of data)``. The file then has no summary
and no footer; :func:`recover` salvages every complete chunk into a clean file.
(A power cut can lose more: the writer does not fsync.)
"""

import contextlib
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
import io
import json
import os
from pathlib import Path
import re
import struct
import threading
import time

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema, Statistics
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
import mcap_ros2
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2._vendor.rosidl_adapter.parser import InvalidSpecification, InvalidValue
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import zstandard

from motor_id import __version__
from motor_id.contracts import (batch_rows, BAG_ESTIMATE_TOPIC, BAG_META_TOPIC, BAG_SAMPLES_TOPIC,
                                CHANNEL_TOPICS, SAMPLE_COLUMNS,
                                SAMPLES_LABEL)
from motor_id.errors import BagError, ConfigError
from motor_id.recording import Recording

MAGIC = b'\x89MCAP0\r\n'
SAMPLES_TOPIC = BAG_SAMPLES_TOPIC
META_TOPIC = BAG_META_TOPIC
ESTIMATE_TOPIC = BAG_ESTIMATE_TOPIC
CHANNEL_NAMES = CHANNEL_TOPICS

FLOAT64_MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'
FLOAT64 = 'std_msgs/msg/Float64'
STRING = 'std_msgs/msg/String'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'

DEFAULT_CHUNK_SIZE = 64 * 1024
"""Uncompressed bytes per chunk: the most a killed writer can lose (about 13 s of samples
at 100 Hz)."""
DEFAULT_FLUSH_INTERVAL = 1.0
"""Seconds after which a chunk is written even if it is not full."""
COMPRESSIONS = ('zstd', 'lz4', 'none')
ROS_DISTRO = 'jazzy'
ROSBAG2_METADATA_VERSION = 9

_STD_MSGS_PREAMBLE = (
    '# This was originally provided as an example message.\n'
    '# It is deprecated as of Foxy\n'
    '# It is recommended to create your own semantically meaningful message.\n'
    '# However if you would like to continue using this please use the equivalent in '
    'example_msgs.\n'
    '\n'
)

MSG_TEXT = {
    'std_msgs/msg/Float64MultiArray': _STD_MSGS_PREAMBLE + (
        '# Please look at the MultiArrayLayout message definition for\n'
        '# documentation on all multiarrays.\n'
        '\n'
        'MultiArrayLayout  layout        # specification of data layout\n'
        'float64[]         data          # array of data\n'
    ),
    'std_msgs/msg/MultiArrayLayout': _STD_MSGS_PREAMBLE + (
        '# The multiarray declares a generic multi-dimensional array of a\n'
        '# particular data type.  Dimensions are ordered from outer most\n'
        '# to inner most.\n'
        '#\n'
        '# Accessors should ALWAYS be written in terms of dimension stride\n'
        '# and specified outer-most dimension first.\n'
        '#\n'
        '# multiarray(i,j,k) = data[data_offset + dim_stride[1]*i + dim_stride[2]*j + k]\n'
        '#\n'
        '# A standard, 3-channel 640x480 image with interleaved color channels\n'
        '# would be specified as:\n'
        '#\n'
        '# dim[0].label  = "height"\n'
        '# dim[0].size   = 480\n'
        '# dim[0].stride = 3*640*480 = 921600  (note dim[0] stride is just size of image)\n'
        '# dim[1].label  = "width"\n'
        '# dim[1].size   = 640\n'
        '# dim[1].stride = 3*640 = 1920\n'
        '# dim[2].label  = "channel"\n'
        '# dim[2].size   = 3\n'
        '# dim[2].stride = 3\n'
        '#\n'
        '# multiarray(i,j,k) refers to the ith row, jth column, and kth channel.\n'
        '\n'
        'MultiArrayDimension[] dim # Array of dimension properties\n'
        'uint32 data_offset        # padding bytes at front of data\n'
    ),
    'std_msgs/msg/MultiArrayDimension': _STD_MSGS_PREAMBLE + (
        'string label   # label of given dimension\n'
        'uint32 size    # size of given dimension (in type units)\n'
        'uint32 stride  # stride of given dimension\n'
    ),
    'std_msgs/msg/Float64': _STD_MSGS_PREAMBLE + 'float64 data\n',
    'std_msgs/msg/String': _STD_MSGS_PREAMBLE + 'string data\n',
    'std_msgs/msg/Header': (
        '# Standard metadata for higher-level stamped data types.\n'
        '# This is generally used to communicate timestamped data\n'
        '# in a particular coordinate frame.\n'
        '\n'
        '# Two-integer timestamp that is expressed as seconds and nanoseconds.\n'
        'builtin_interfaces/Time stamp\n'
        '\n'
        '# Transform frame with which this data is associated.\n'
        'string frame_id\n'
    ),
    'builtin_interfaces/msg/Time': (
        '# This message communicates ROS Time defined here:\n'
        '# https://design.ros2.org/articles/clock_and_time.html\n'
        '\n'
        '# The seconds component, valid over all int32 values.\n'
        'int32 sec\n'
        '\n'
        '# The nanoseconds component, valid in the range [0, 1e9), to be added to the '
        'seconds component. \n'
        '# e.g.\n'
        '# The time -1.7 seconds is represented as {sec: -2, nanosec: 3e8}\n'
        '# The time 1.7 seconds is represented as {sec: 1, nanosec: 7e8}\n'
        'uint32 nanosec\n'
    ),
    'diagnostic_msgs/msg/DiagnosticArray': (
        '# This message is used to send diagnostic information about the state of the '
        'robot.\n'
        'std_msgs/Header header # for timestamp\n'
        'DiagnosticStatus[] status # an array of components being reported on\n'
    ),
    'diagnostic_msgs/msg/DiagnosticStatus': (
        '# This message holds the status of an individual component of the robot.\n'
        '\n'
        '# Possible levels of operations.\n'
        'byte OK=0\n'
        'byte WARN=1\n'
        'byte ERROR=2\n'
        'byte STALE=3\n'
        '\n'
        '# Level of operation enumerated above.\n'
        'byte level\n'
        '# A description of the test/component reporting.\n'
        'string name\n'
        '# A description of the status.\n'
        'string message\n'
        '# A hardware unique string.\n'
        'string hardware_id\n'
        '# An array of values associated with the status.\n'
        'KeyValue[] values\n'
        '\n'
    ),
    'diagnostic_msgs/msg/KeyValue': (
        '# What to label this value when viewing.\n'
        'string key\n'
        '# A value to track over time.\n'
        'string value\n'
    ),
}
"""The .msg files of ROS 2 Jazzy, verbatim (comments included), keyed by type name."""

TYPE_HASHES = {
    FLOAT64_MULTI_ARRAY:
        'RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f',
    FLOAT64: 'RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a',
    STRING: 'RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18',
    DIAGNOSTIC_ARRAY:
        'RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e',
}
"""Jazzy type description hashes (channel metadata ``topic_type_hash``)."""

_PRIMITIVES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string'))
_FIELD_TYPE_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_DELIMITER = '=' * 80 + '\n'
_MAX_DEPTH = 50

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_STATISTICS, _OP_METADATA, _OP_DATA_END = 0x0B, 0x0C, 0x0F
_DECODE_ERRORS = (McapError, ValueError, struct.error, RuntimeError, EOFError, IndexError,
                  ArithmeticError, zstandard.ZstdError, InvalidSpecification, InvalidValue)
_FIELD_ERRORS = _DECODE_ERRORS + (AttributeError, TypeError)
"""Also what reading fields of a message decoded with a damaged definition raises."""
_SCHEMA_ERRORS = _DECODE_ERRORS + (NameError, TypeError)
"""What parsing a damaged message definition raises (NameError, TypeError: bad names)."""


def message_definition(msgtype):
    """The complete ``ros2msg`` definition of a message type, as rosbag2 stores it.

    The type's own .msg text comes first; every type it depends on follows (depth first,
    dependencies of one type in sorted order, each once) after a line of 80 ``=`` and a
    ``MSG: pkg/Type`` line, as ``rosbag2_cpp::LocalMessageDefinitionSource`` does.

    Parameters
    ----------
    msgtype : str
        ``'pkg/msg/Type'``; one of :data:`MSG_TEXT`.

    Returns
    -------
    str
    """
    seen = set()

    def expand(name, depth):
        if depth <= 0:
            raise ConfigError(f'message definition of {msgtype} nests too deeply')
        text = _msg_text(name)
        package = name.split('/', 1)[0]
        out = text
        for dep in _dependencies(text, package):
            if dep not in seen:
                seen.add(dep)
                out += '\n' + _DELIMITER + 'MSG: ' + dep + '\n' + expand(dep, depth - 1)
        return out

    return expand(msgtype, _MAX_DEPTH)


def _msg_text(name):
    parts = name.split('/')
    key = f'{parts[0]}/msg/{parts[-1]}'
    if len(parts) not in (2, 3) or key not in MSG_TEXT:
        raise ConfigError(f'no message definition for {name!r}; known: {sorted(MSG_TEXT)}')
    return MSG_TEXT[key]


def _dependencies(text, package):
    deps = set()
    for match in _FIELD_TYPE_RE.finditer(text):
        name = match.group(1)
        if name in _PRIMITIVES:
            continue
        deps.add(name if '/' in name else f'{package}/{name}')
    return sorted(deps)


def qos_profile(reliability='reliable', durability='volatile', depth=10):
    """An offered QoS profile in the form rosbag2 (metadata version 9) stores.

    Parameters
    ----------
    reliability : {'reliable', 'best_effort'}
    durability : {'volatile', 'transient_local'}
    depth : int
        History depth (keep last).

    Returns
    -------
    dict
    """
    if reliability not in ('reliable', 'best_effort'):
        raise ConfigError(f'reliability must be reliable or best_effort, got {reliability!r}')
    if durability not in ('volatile', 'transient_local'):
        raise ConfigError(f'durability must be volatile or transient_local, got {durability!r}')
    if int(depth) < 1:
        raise ConfigError(f'QoS depth must be >= 1, got {depth}')
    unset = {'sec': 0, 'nsec': 0}
    return {'history': 'keep_last', 'depth': int(depth), 'reliability': reliability,
            'durability': durability, 'deadline': dict(unset), 'lifespan': dict(unset),
            'liveliness': 'automatic', 'liveliness_lease_duration': dict(unset),
            'avoid_ros_namespace_conventions': False}


def default_qos(topic):
    """The QoS a topic of the motor_id layout is offered with (see the module table)."""
    topic = _topic_name(topic)
    if topic == SAMPLES_TOPIC:
        return qos_profile('reliable', 'volatile', 100)
    if topic in (META_TOPIC, ESTIMATE_TOPIC):
        return qos_profile('reliable', 'transient_local', 1)
    return qos_profile('reliable', 'volatile', 10)


def _topic_name(topic):
    topic = str(topic)
    if not topic or topic == '/':
        raise ConfigError('topic name is empty')
    return topic if topic.startswith('/') else '/' + topic


_PLAIN_YAML = re.compile(r'^[A-Za-z_/][A-Za-z0-9_./-]*$')
_YAML_WORDS = frozenset(('true', 'false', 'yes', 'no', 'on', 'off', 'null', 'y', 'n'))


def _yaml_scalar(value):
    if value is None:
        return '~'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, dict):
        return '{}'
    if isinstance(value, list):
        return '[]'
    text = str(value)
    if _PLAIN_YAML.match(text) and text.lower() not in _YAML_WORDS:
        return text
    return json.dumps(text)


def _yaml(value, indent=0):
    """Block-style YAML of dicts, lists, strings, ints, bools and None (as yaml-cpp dumps)."""
    pad = ' ' * indent
    lines = []
    if isinstance(value, dict) and value:
        for key, item in value.items():
            if isinstance(item, (dict, list)) and item:
                lines.append(f'{pad}{key}:')
                lines.append(_yaml(item, indent + 2))
            else:
                lines.append(f'{pad}{key}: {_yaml_scalar(item)}')
    elif isinstance(value, list) and value:
        for item in value:
            if isinstance(item, (dict, list)) and item:
                body = _yaml(item, indent + 2)
                lines.append(pad + '- ' + body[indent + 2:])
            else:
                lines.append(f'{pad}- {_yaml_scalar(item)}')
    else:
        lines.append(pad + _yaml_scalar(value))
    return '\n'.join(lines)


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, tuple)):
        return list(obj)
    raise TypeError(f'cannot store {type(obj).__name__} in bag metadata JSON')


class _DirectFile:
    """A write-only file without a user-space buffer: every write reaches the OS at once."""

    def __init__(self, path):
        self._raw = open(path, 'wb', buffering=0)

    def write(self, data):
        view = memoryview(data)
        done = 0
        while done < len(view):
            done += self._raw.write(view[done:])
        return done

    def tell(self):
        return self._raw.tell()

    def flush(self):
        """Nothing is buffered."""

    def close(self):
        self._raw.close()


@dataclass
class _Topic:
    name: str
    msgtype: str
    channel_id: int
    encoder: object = None
    qos: dict = None
    count: int = 0


class BagWriter:
    """Write a rosbag2-compatible MCAP file (``ros2 bag play``, Foxglove, rosbags read it).

    Use as a context manager; :meth:`close` writes the summary and footer.

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

    def __init__(self, path, chunk_size=DEFAULT_CHUNK_SIZE, compression='zstd',
                 flush_interval=DEFAULT_FLUSH_INTERVAL, clock=time.monotonic):
        if compression not in COMPRESSIONS:
            raise ConfigError(f'compression must be one of {COMPRESSIONS}, got {compression!r}')
        if int(chunk_size) < 1:
            raise ConfigError(f'chunk_size must be >= 1 byte, got {chunk_size}')
        if flush_interval is not None and not flush_interval > 0:
            raise ConfigError(f'flush_interval must be > 0 s or None, got {flush_interval}')
        self.path = str(path)
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self.flush_interval = flush_interval
        self._clock = clock
        ctype = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                 'none': CompressionType.NONE}[compression]
        try:
            self._file = _DirectFile(self.path)
        except OSError as exc:
            raise BagError(f'{self.path}: cannot create ({exc.strerror})') from None
        self._writer = McapWriter(self._file, chunk_size=self.chunk_size, compression=ctype)
        self._writer.start(profile='ros2', library=library_string())
        self._schemas = {}
        self._topics = {}
        self._start_ns = None
        self._end_ns = None
        self._last_flush = clock()
        self._closed = False
        self._lock = threading.RLock()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close()

    @property
    def message_count(self):
        """Messages written so far."""
        return sum(t.count for t in self._topics.values())

    def add_topic(self, topic, msgtype, qos=None):
        """Declare a topic (done implicitly by the first write with the default QoS).

        Parameters
        ----------
        topic : str
            Topic name; a relative name gets a leading ``/``.
        msgtype : str
            One of :data:`MSG_TEXT`'s top-level types, e.g. ``'std_msgs/msg/String'``.
        qos : dict, optional
            Offered QoS (:func:`qos_profile`); default :func:`default_qos`.
        """
        name = _topic_name(topic)
        known = self._topics.get(name)
        if known is not None:
            if known.msgtype != msgtype:
                raise ConfigError(f'topic {name} was declared as {known.msgtype}, '
                                  f'cannot write {msgtype}')
            return known
        definition = message_definition(msgtype)
        qos = default_qos(name) if qos is None else qos
        schema_id = self._schema_id(msgtype, 'ros2msg', definition.encode())
        encoder = serialize_dynamic(msgtype, definition)[msgtype]
        meta = {'offered_qos_profiles': _yaml([qos]),
                'topic_type_hash': TYPE_HASHES.get(msgtype, '')}
        channel_id = self._writer.register_channel(name, 'cdr', schema_id, meta)
        entry = _Topic(name, msgtype, channel_id, encoder, qos)
        self._topics[name] = entry
        return entry

    def _schema_id(self, name, encoding, data):
        key = (name, encoding, data)
        if key not in self._schemas:
            self._schemas[key] = self._writer.register_schema(name, encoding, data)
        return self._schemas[key]

    def write(self, topic, msgtype, msg, log_time_ns, publish_time_ns=None, sequence=0):
        """Serialise one message (a dict shaped like the ROS message) to CDR and write it.

        Parameters
        ----------
        topic : str
        msgtype : str
        msg : dict
            Field values, nested dicts for sub-messages, lists for arrays.
        log_time_ns : int
            Receive time [ns], >= 0.
        publish_time_ns : int, optional
        sequence : int
        """
        with self._lock:
            self._check_open()
            entry = self.add_topic(topic, msgtype)
            try:
                data = entry.encoder(msg)
            except (ValueError, TypeError, KeyError, AttributeError, struct.error) as exc:
                raise BagError(f'cannot serialise a {msgtype} for {entry.name}: '
                               f'{exc}') from None
            self._add(entry, data, log_time_ns, publish_time_ns, sequence)

    def _add(self, entry, data, log_time_ns, publish_time_ns, sequence):
        log_time = int(log_time_ns)
        if log_time < 0:
            raise ConfigError(f'log time must be >= 0 ns, got {log_time}')
        pub = log_time if publish_time_ns is None else int(publish_time_ns)
        self._writer.add_message(entry.channel_id, log_time, data, pub, int(sequence))
        entry.count += 1
        self._start_ns = log_time if self._start_ns is None else min(self._start_ns, log_time)
        self._end_ns = log_time if self._end_ns is None else max(self._end_ns, log_time)
        if self.flush_interval is not None:
            now = self._clock()
            if now - self._last_flush >= self.flush_interval:
                self.flush()

    def flush(self):
        """Write the chunk in progress now (a SIGKILL after this loses nothing so far)."""
        with self._lock:
            self._check_open()
            self._writer.flush()
            self._last_flush = self._clock()

    def write_samples(self, rows, log_time_ns, publish_time_ns=None, sequence=0,
                      topic=SAMPLES_TOPIC):
        """Write a batch of sample rows on ``/samples``.

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
        if arr.ndim != 2 or arr.shape[1] != len(SAMPLE_COLUMNS):
            raise ConfigError(f'sample rows must have {len(SAMPLE_COLUMNS)} columns '
                              f'({SAMPLES_LABEL}), got shape {np.shape(rows)}')
        n = arr.shape[0]
        msg = {'layout': {'dim': [{'label': 'samples', 'size': n, 'stride': 6 * n},
                                  {'label': SAMPLES_LABEL, 'size': 6, 'stride': 6}],
                          'data_offset': 0},
               'data': arr.ravel().tolist()}
        self.write(topic, FLOAT64_MULTI_ARRAY, msg, log_time_ns, publish_time_ns, sequence)

    def write_meta(self, meta, log_time_ns=0):
        """Write the recording's metadata as JSON on ``/motor_id/meta`` (latched).

        Parameters
        ----------
        meta : dict
            ``input_kind``, ``provenance``, ``units``, ``truth`` ... (JSON-serialisable;
            numpy values are converted).
        """
        try:
            text = json.dumps(meta, default=_json_default)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f'bag metadata is not JSON-serialisable: {exc}') from None
        self.write(META_TOPIC, STRING, {'data': text}, log_time_ns)

    def write_estimate(self, values, log_time_ns, name='motor_id identifier', message='',
                       level=0, hardware_id='', topic=ESTIMATE_TOPIC):
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

    def write_channel(self, name, value, log_time_ns):
        """Write one value on a per-channel ``std_msgs/Float64`` topic (voltage, speed,
        current)."""
        if name not in CHANNEL_NAMES:
            raise ConfigError(f'channel must be one of {CHANNEL_NAMES}, got {name!r}')
        self.write('/' + name, FLOAT64, {'data': float(value)}, log_time_ns)

    def write_raw(self, topic, schema, message_encoding, data, log_time_ns,
                  publish_time_ns=None, sequence=0, channel_metadata=None):
        """Copy an already serialised message (used by :func:`recover`).

        Parameters
        ----------
        schema : mcap.records.Schema or None
        channel_metadata : dict, optional
            Copied verbatim (QoS, type hash).
        """
        with self._lock:
            self._check_open()
            name = _topic_name(topic)
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
                entry = _Topic(name, msgtype, channel_id)
                self._topics[name] = entry
            self._add(entry, data, log_time_ns, publish_time_ns, sequence)

    def _check_open(self):
        if self._closed:
            raise BagError(f'{self.path}: bag writer is closed')

    def _rosbag2_metadata(self):
        start = self._start_ns or 0
        duration = (self._end_ns - start) if self._end_ns is not None else 0
        count = self.message_count
        base = os.path.basename(self.path)
        topics = [{'topic_metadata': {
                       'name': t.name, 'type': t.msgtype, 'serialization_format': 'cdr',
                       'offered_qos_profiles': [t.qos] if t.qos else [],
                       'type_description_hash': TYPE_HASHES.get(t.msgtype, '')},
                   'message_count': t.count} for t in self._topics.values()]
        info = {
            'version': ROSBAG2_METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': topics,
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [base],
            'files': [{'path': base, 'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration}, 'message_count': count}],
            'custom_data': None,
            'ros_distro': ROS_DISTRO,
        }
        return _yaml(info)

    def close(self):
        """Write the rosbag2 metadata record, the summary (statistics, indexes), the footer."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.add_metadata('rosbag2',
                                          {'serialized_metadata': self._rosbag2_metadata()})
                self._writer.finish()
            finally:
                self._file.close()


def _kv_text(value):
    if isinstance(value, (bool, np.bool_)):
        return 'true' if value else 'false'
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def library_string():
    """The MCAP header's library field: who wrote the file."""
    return (f'motor_id {__version__}; mcap-python {_version("mcap")}; '
            f'mcap-ros2-support {mcap_ros2.__version__}')


def _version(dist):
    try:
        return version(dist)
    except PackageNotFoundError:
        return 'unknown'


def default_units(input_kind):
    """Units of the sample columns for a plant kind (rotary motor)."""
    return {'t': 's', 'voltage': 'V' if input_kind == 'voltage' else 'N m',
            'speed': 'rad/s', 'current': 'A', 'flags': '1'}


def write_recording(rec, path, meta=None, batch=50, start_ns=0, channels=False, **writer_kw):
    """Write a :class:`~motor_id.recording.Recording` to an MCAP bag.

    Parameters
    ----------
    rec : Recording
    path : str or Path
    meta : dict, optional
        Extra metadata merged over ``rec.meta`` into the ``/motor_id/meta`` JSON (which
        always holds ``input_kind`` and ``units``).
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
    dict
        ``{'path', 'samples', 'messages'}``.
    """
    if int(batch) < 1:
        raise ConfigError(f'batch must be >= 1 row, got {batch}')
    n = len(rec)
    if n == 0:
        raise ConfigError('the recording is empty')
    current = rec.current if rec.has_current else np.full(n, np.nan)
    rows = np.column_stack([np.arange(n, dtype=float), rec.time, rec.input, rec.speed,
                            current, np.zeros(n)])
    log_ns = int(start_ns) + np.rint((rec.time - rec.time[0]) * 1e9).astype(np.int64)
    info = {k: v for k, v in rec.meta.items() if k not in ('bag', 'gaps')}
    info.update(meta or {})
    info['input_kind'] = rec.input_kind
    info.setdefault('units', default_units(rec.input_kind))
    with BagWriter(path, **writer_kw) as bag:
        bag.write_meta(info, int(start_ns))
        for k0 in range(0, n, int(batch)):
            k1 = min(n, k0 + int(batch))
            bag.write_samples(rows[k0:k1], int(log_ns[k1 - 1]))
            if channels:
                for k in range(k0, k1):
                    bag.write_channel('voltage', rec.input[k], int(log_ns[k]))
                    bag.write_channel('speed', rec.speed[k], int(log_ns[k]))
                    if rec.has_current:
                        bag.write_channel('current', rec.current[k], int(log_ns[k]))
        count = bag.message_count
    return {'path': str(path), 'samples': n, 'messages': count}


@dataclass
class _Scan:
    """What a tolerant linear pass over an MCAP file found."""

    path: str
    size: int = 0
    profile: str = ''
    library: str = ''
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    messages: list = field(default_factory=list)
    metadata: list = field(default_factory=list)
    statistics: object = None
    chunks: int = 0
    compressions: set = field(default_factory=set)
    bad_chunks: list = field(default_factory=list)
    bad_records: list = field(default_factory=list)
    data_end: bool = False
    footer: bool = False
    end_magic: bool = False
    stop_offset: int = 0
    stop_reason: str = ''

    @property
    def data_complete(self):
        """True when every message the writer wrote is here."""
        return self.data_end and not self.bad_chunks and not self.bad_records

    def problem(self):
        """One line on what is wrong, or '' when the file is whole."""
        parts = []
        if not self.data_end:
            parts.append(self.stop_reason or 'the data section does not end')
        if self.bad_chunks:
            off, why = self.bad_chunks[0]
            parts.append(f'{len(self.bad_chunks)} corrupt chunk(s), first at byte {off} '
                         f'({why})')
        if self.bad_records:
            off, why = self.bad_records[0]
            parts.append(f'{len(self.bad_records)} unreadable record(s), first at byte {off} '
                         f'({why})')
        if self.data_end and not self.footer:
            parts.append('summary/footer missing (' + (self.stop_reason or 'cut') + ')')
        elif self.footer and not self.end_magic:
            parts.append('closing magic missing')
        return '; '.join(parts)

    def topic_counts(self):
        counts = {}
        for msg in self.messages:
            ch = self.channels.get(msg.channel_id)
            name = ch.topic if ch else f'<channel {msg.channel_id}>'
            counts[name] = counts.get(name, 0) + 1
        return counts


def _resolve(path):
    p = Path(path)
    if p.is_dir():
        found = sorted(p.glob('*.mcap'))
        if len(found) != 1:
            raise BagError(f'{path}: is a directory with {len(found)} .mcap file(s); '
                           'pass the .mcap file itself')
        return found[0]
    return p


def _scan_file(path):
    """Read every complete record of an MCAP file, tolerating a missing or cut end."""
    p = _resolve(path)
    name = str(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise BagError(f'{name}: no such file') from None
    except OSError as exc:
        raise BagError(f'{name}: cannot read ({exc.strerror})') from None
    if not data:
        raise BagError(f'{name}: empty file, not an MCAP recording')
    if data[:len(MAGIC)] != MAGIC:
        raise BagError(f'{name}: not an MCAP file (starts with {data[:8]!r}, '
                       f'expected the MCAP magic {MAGIC!r})')
    scan = _Scan(name, len(data))
    pos = len(MAGIC)
    n = len(data)
    while True:
        if pos == n:
            scan.stop_reason = f'file ends at byte {n} without a footer'
            break
        if pos + 9 > n:
            scan.stop_reason = f'cut inside a record header at byte {pos} of {n}'
            break
        op = data[pos]
        length = int.from_bytes(data[pos + 1:pos + 9], 'little')
        end = pos + 9 + length
        if end > n:
            scan.stop_reason = (f'record at byte {pos} cut short ({n - pos - 9} of '
                                f'{length} bytes present)')
            break
        _handle_record(scan, op, data[pos + 9:end], pos)
        pos = end
        if op == _OP_FOOTER:
            scan.footer = True
            scan.end_magic = data[pos:pos + len(MAGIC)] == MAGIC
            break
    scan.stop_offset = pos
    return scan


def _handle_record(scan, op, body, offset):
    stream = ReadDataStream(io.BytesIO(body))
    try:
        if op == _OP_HEADER:
            header = Header.read(stream)
            scan.profile, scan.library = header.profile, header.library
        elif op == _OP_SCHEMA:
            _add_inner(scan, Schema.read(stream))
        elif op == _OP_CHANNEL:
            _add_inner(scan, Channel.read(stream))
        elif op == _OP_MESSAGE:
            _add_inner(scan, Message.read(stream, len(body)))
        elif op == _OP_CHUNK:
            chunk = Chunk.read(stream)
            scan.compressions.add(chunk.compression or 'none')
            try:
                records = breakup_chunk(chunk, validate_crc=True)
            except _DECODE_ERRORS as exc:
                scan.bad_chunks.append((offset, str(exc) or type(exc).__name__))
                return
            scan.chunks += 1
            for record in records:
                _add_inner(scan, record)
        elif op == _OP_METADATA:
            record = Metadata.read(stream)
            scan.metadata.append((record.name, dict(record.metadata)))
        elif op == _OP_STATISTICS:
            scan.statistics = Statistics.read(stream)
        elif op == _OP_DATA_END:
            scan.data_end = True
    except _DECODE_ERRORS as exc:
        scan.bad_records.append((offset, str(exc) or type(exc).__name__))


def _add_inner(scan, record):
    if isinstance(record, Schema):
        scan.schemas[record.id] = record
    elif isinstance(record, Channel):
        scan.channels[record.id] = record
    elif isinstance(record, Message):
        scan.messages.append(record)


def _recover_hint(scan):
    counts = scan.topic_counts()
    total = sum(counts.values())
    return (f'{total} message(s) ({counts.get(SAMPLES_TOPIC, 0)} on {SAMPLES_TOPIC}) can be '
            f'recovered: motor-id bag recover {scan.path} OUT.mcap')


def _require_complete(scan):
    if not scan.data_complete:
        raise BagError(f'{scan.path}: truncated or corrupt MCAP ({scan.problem()}); '
                       + _recover_hint(scan))


def _topic_list(scan):
    counts = scan.topic_counts()
    if not scan.channels:
        return 'the file has no topics'
    items = []
    for ch in scan.channels.values():
        schema = scan.schemas.get(ch.schema_id)
        items.append(f'{ch.topic} ({schema.name if schema else "no schema"}, '
                     f'{counts.get(ch.topic, 0)} msgs)')
    return 'topics present: ' + ', '.join(sorted(items))


def _decoder(scan, channel):
    schema = scan.schemas.get(channel.schema_id)
    if schema is None:
        raise BagError(f'{scan.path}: {channel.topic} has no schema, cannot decode it')
    if schema.encoding != 'ros2msg' or channel.message_encoding != 'cdr':
        raise BagError(f'{scan.path}: cannot decode {channel.topic}: schema encoding '
                       f'{schema.encoding!r}, message encoding {channel.message_encoding!r} '
                       "(need 'ros2msg' and 'cdr')")
    try:
        with contextlib.redirect_stderr(io.StringIO()):   # the msg parser prints errors
            return schema, DecoderFactory().decoder_for('cdr', schema)
    except _SCHEMA_ERRORS as exc:
        raise BagError(f'{scan.path}: cannot parse the message definition {schema.name!r} '
                       f'of {channel.topic}: {exc}') from None


def _channels_for(scan, topic):
    name = _topic_name(topic)
    return [ch for ch in scan.channels.values() if _topic_name(ch.topic) == name]


def _samples_from_scan(scan, topic=SAMPLES_TOPIC):
    chans = _channels_for(scan, topic)
    if not chans:
        raise BagError(f'{scan.path}: no {_topic_name(topic)} topic; {_topic_list(scan)}')
    decoders = {}
    for ch in chans:
        schema, decode = _decoder(scan, ch)
        if schema.name != FLOAT64_MULTI_ARRAY:
            raise BagError(f'{scan.path}: {ch.topic} has type {schema.name!r}, expected '
                           f'{FLOAT64_MULTI_ARRAY}')
        decoders[ch.id] = decode
    blocks, log_times = [], []
    for i, msg in enumerate(m for m in scan.messages if m.channel_id in decoders):
        try:
            decoded = decoders[msg.channel_id](msg.data)
            dims = list(decoded.layout.dim)
            values = np.asarray(decoded.data, dtype=float)
            offset = decoded.layout.data_offset
        except _FIELD_ERRORS as exc:
            raise BagError(f'{scan.path}: {topic} message {i} (log time {msg.log_time} ns) '
                           f'is not a valid {FLOAT64_MULTI_ARRAY}: {exc}') from None
        try:
            rows_i = batch_rows([d.label for d in dims], [d.size for d in dims], offset,
                                values)
        except ValueError as exc:
            raise BagError(f'{scan.path}: {topic} message {i}: {exc}') from None
        blocks.append(rows_i)
        log_times.append(np.full(dims[0].size, msg.log_time, dtype=np.int64))
    if not blocks or sum(b.shape[0] for b in blocks) == 0:
        raise BagError(f'{scan.path}: {_topic_name(topic)} holds no sample rows')
    rows = np.concatenate(blocks)
    log_ns = np.concatenate(log_times)
    order = np.argsort(rows[:, 0], kind='stable')
    rows, log_ns = rows[order], log_ns[order]
    keep = np.ones(rows.shape[0], dtype=bool)
    keep[1:] = np.diff(rows[:, 0]) != 0
    duplicates = int(np.count_nonzero(~keep))
    rows, log_ns = rows[keep], log_ns[keep]
    seq = rows[:, 0]
    gaps = []
    for k in np.flatnonzero(np.diff(seq) > 1):
        gaps.append({'after_seq': int(seq[k]), 'missing': int(seq[k + 1] - seq[k] - 1),
                     't_before': float(rows[k, 1]), 't_after': float(rows[k + 1, 1])})
    out = {name: rows[:, j].copy() for j, name in enumerate(SAMPLE_COLUMNS)}
    out['log_time_ns'] = log_ns
    out['gaps'] = gaps
    out['duplicates'] = duplicates
    return out


def _meta_from_scan(scan):
    meta = {}
    for ch in _channels_for(scan, META_TOPIC):
        schema, decode = _decoder(scan, ch)
        if schema.name != STRING:
            raise BagError(f'{scan.path}: {META_TOPIC} has type {schema.name!r}, expected '
                           f'{STRING}')
        for msg in (m for m in scan.messages if m.channel_id == ch.id):
            try:
                text = decode(msg.data).data
                item = json.loads(text)
            except _FIELD_ERRORS as exc:
                raise BagError(f'{scan.path}: a {META_TOPIC} message is not valid JSON '
                               f'({exc})') from None
            if not isinstance(item, dict):
                raise BagError(f'{scan.path}: a {META_TOPIC} message is not a JSON object')
            meta.update(item)
    return meta


def read_samples(path, topic=SAMPLES_TOPIC):
    """All rows of the ``/samples`` topic, sorted by sequence number.

    Parameters
    ----------
    path : str or Path
        An ``.mcap`` file (or a rosbag2 directory holding exactly one).
    topic : str

    Returns
    -------
    dict
        Arrays ``seq, t, voltage, speed, current, flags, log_time_ns`` (one entry per
        row; a repeated ``seq`` keeps its first row), ``gaps`` (list of
        ``{after_seq, missing, t_before, t_after}``; never filled) and ``duplicates``.

    Raises
    ------
    BagError
        One line: missing file, not an MCAP, truncated/corrupt (with the count that
        :func:`recover` would salvage), no such topic (with the topics present), wrong
        or undecodable type, unexpected layout.
    """
    scan = _scan_file(path)
    _require_complete(scan)
    return _samples_from_scan(scan, topic)


def read_meta(path):
    """The merged JSON objects of ``/motor_id/meta`` ({} when the bag has none)."""
    scan = _scan_file(path)
    _require_complete(scan)
    return _meta_from_scan(scan)


def read_recording(path):
    """Rebuild a :class:`~motor_id.recording.Recording` from a bag's ``/samples`` topic.

    Rows are sorted by ``seq``; gaps in ``seq`` are kept as they are (time simply jumps)
    and listed in ``rec.meta['gaps']``; ``input_kind`` and the rest of the metadata come
    from ``/motor_id/meta``. The current channel is None when it is NaN throughout.
    The recording is not validated here (``Recording.validate`` or the fitter does it).

    Raises
    ------
    BagError
        See :func:`read_samples`.
    """
    scan = _scan_file(path)
    _require_complete(scan)
    samples = _samples_from_scan(scan)
    meta = _meta_from_scan(scan)
    kind = meta.pop('input_kind', 'voltage')
    if kind not in ('voltage', 'torque'):
        raise BagError(f'{scan.path}: {META_TOPIC} input_kind must be voltage or torque, '
                       f'got {kind!r}')
    current = samples['current']
    current = current if np.any(np.isfinite(current)) else None
    meta['bag'] = scan.path
    meta['gaps'] = samples['gaps']
    if samples['duplicates']:
        meta['duplicate_rows'] = samples['duplicates']
    nonzero = int(np.count_nonzero(samples['flags']))
    if nonzero:
        meta['flagged_rows'] = nonzero
    if not scan.footer:
        meta['bag_note'] = 'data complete but the summary/footer is missing'
    return Recording(samples['t'], samples['voltage'], samples['speed'], current, kind, meta)


def bag_info(path):
    """Summary of an MCAP file: topics, types, counts, time span, integrity.

    Works on truncated files too (then ``complete`` is False and ``problem`` says why).

    Returns
    -------
    dict
        ``path, size_bytes, profile, library, complete, problem, messages, chunks,
        compression, start_ns, end_ns, duration_s, topics`` (list of ``{topic, type,
        count, encoding, qos}``), ``metadata`` (record names), ``ros_distro``.
    """
    scan = _scan_file(path)
    counts = scan.topic_counts()
    topics = []
    for ch in sorted(scan.channels.values(), key=lambda c: c.topic):
        schema = scan.schemas.get(ch.schema_id)
        topics.append({'topic': ch.topic, 'type': schema.name if schema else '',
                       'count': counts.get(ch.topic, 0), 'encoding': ch.message_encoding,
                       'qos': ch.metadata.get('offered_qos_profiles', '')})
    times = [m.log_time for m in scan.messages]
    start = min(times) if times else 0
    end = max(times) if times else 0
    distro = ''
    for name, values in scan.metadata:
        if name == 'rosbag2':
            found = re.search(r'^ros_distro: *(\S+)', values.get('serialized_metadata', ''),
                              re.MULTILINE)
            distro = found.group(1).strip('"') if found else values.get('ROS_DISTRO', '')
    return {
        'path': scan.path, 'size_bytes': scan.size, 'profile': scan.profile,
        'library': scan.library, 'complete': scan.data_complete and scan.footer,
        'problem': scan.problem(), 'messages': len(scan.messages), 'chunks': scan.chunks,
        'compression': sorted(scan.compressions), 'start_ns': start, 'end_ns': end,
        'duration_s': (end - start) * 1e-9, 'topics': topics,
        'metadata': [name for name, _ in scan.metadata], 'ros_distro': distro,
    }


def recover(path, out_path, chunk_size=DEFAULT_CHUNK_SIZE, compression='zstd'):
    """Salvage a truncated or damaged MCAP (e.g. its writer was killed) into a clean file.

    A tolerant linear reader (no seeking, no summary, no footer needed) takes every
    complete record up to where the file is cut: all complete chunks (CRC-checked;
    a corrupt chunk is skipped, later ones are still read), and copies their schemas,
    channels (with their QoS metadata) and messages, bytes unchanged, to ``out_path``.

    Returns
    -------
    dict
        ``{'out', 'messages', 'topics' ({topic: count}), 'chunks', 'chunks_lost',
        'bytes_dropped' (the cut tail), 'was_complete', 'problem'}``.

    Notes
    -----
    What a killed :class:`BagWriter` loses is the chunk it was filling: at most
    ``chunk_size`` bytes of messages, or ``flush_interval`` seconds of them.
    Messages of a channel whose definition was only in a lost chunk cannot be copied and
    are counted in ``orphans``.
    """
    src, dst = _resolve(path), Path(out_path)
    if dst.exists() and dst.resolve() == src.resolve():
        raise BagError(f'{out_path}: the output must differ from the input')
    scan = _scan_file(path)
    if not scan.messages:
        raise BagError(f'{scan.path}: nothing to recover ({scan.problem() or "no messages"})')
    counts = {}
    orphans = 0
    with BagWriter(out_path, chunk_size=chunk_size, compression=compression,
                   flush_interval=None) as bag:
        for msg in scan.messages:
            ch = scan.channels.get(msg.channel_id)
            if ch is None:
                orphans += 1
                continue
            schema = scan.schemas.get(ch.schema_id) if ch.schema_id else None
            bag.write_raw(ch.topic, schema, ch.message_encoding, msg.data, msg.log_time,
                          msg.publish_time, msg.sequence, ch.metadata)
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
    return {'out': str(out_path), 'messages': sum(counts.values()), 'topics': counts,
            'chunks': scan.chunks, 'chunks_lost': len(scan.bad_chunks),
            'bytes_dropped': scan.size - scan.stop_offset if not scan.footer else 0,
            'orphans': orphans, 'was_complete': scan.data_complete and scan.footer,
            'problem': scan.problem()}
