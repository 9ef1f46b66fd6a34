"""Any rosbag2 recording (MCAP, sqlite3 .db3, split folders) to a Recording by a field mapping.

Bags are read through ``rosbags.highlevel.AnyReader``. Without a mapping the bag must hold
this project's ``/samples`` topic; with one, each channel comes from ``TOPIC[:FIELD]``:

==========================  =========================================================
``--speed``                 measured speed [rad/s]; the time base of the recording
``--input``                 plant input: voltage command [V] or torque [N m]
``--current``               measured current [A] (optional)
==========================  =========================================================

FIELD is a dotted attribute path with optional indices (``data[2]``,
``twist.linear.x``); ``sensor_msgs/msg/JointState`` fields (``position``, ``velocity``,
``effort``) are taken at the joint chosen with ``joint`` (a name or an index).
Without FIELD: ``data`` (std_msgs scalars, one-element arrays), and for a JointState
``velocity`` for the speed, ``effort`` for the input and the current.

Plant kind (the rule): a JointState effort used as the input is a torque (torque plant);
``effort_is='torque'`` with no input given makes the speed topic's effort the input;
``effort_is='current'`` with no current given makes it the current. Any other input is
a voltage unless ``input_kind='torque'``. An effort cannot be both the torque input and
the current, nor a voltage.

Times: the header stamp where the message has a (non-zero) header, else the receive
(log) time. Commands from another topic are held onto the speed's times by the rule of
:mod:`motor_id.data.align` (``hold`` or ``next``); a current from another topic is
interpolated linearly. Samples outside a stream's span are dropped at the ends.
"""

import contextlib
from dataclasses import asdict, dataclass
import json
from pathlib import Path
import re

import numpy as np

from motor_id.contracts import BAG_META_TOPIC, BAG_SAMPLES_TOPIC, batch_rows
from motor_id.data.align import ALIGN_RULES, held_command_index
from motor_id.errors import BagError, ConfigError, MotorIdError
from motor_id.recording import Recording

JOINT_STATE = 'sensor_msgs/msg/JointState'
JOINT_FIELDS = ('position', 'velocity', 'effort')
ROLES = ('input', 'speed', 'current')
EFFORT_KINDS = ('current', 'torque')
INPUT_KINDS = ('voltage', 'torque')
PROFILE_KEYS = ('input', 'speed', 'current', 'joint', 'effort_is', 'align', 'input_kind',
                'shift', 'columns')
"""Keys of a YAML mapping profile (one per robot); flags override them."""
_DEFAULT_JOINT_FIELD = {'speed': 'velocity', 'input': 'effort', 'current': 'effort'}
_STEP_RE = re.compile(r'^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$')


@dataclass
class Mapping:
    """Where each channel of the recording comes from in a bag.

    Attributes
    ----------
    input, speed, current : str or None
        ``TOPIC[:FIELD]`` specifications (see the module docstring).
    joint : str or None
        JointState joint name, or its index as digits.
    effort_is : {'current', 'torque'} or None
        What a JointState effort means.
    align : {'hold', 'next'}
        Command alignment rule (:data:`motor_id.data.align.ALIGN_RULES`).
    input_kind : {'voltage', 'torque'} or None
        Plant kind when the input's source cannot tell.
    """

    input: str | None = None
    speed: str | None = None
    current: str | None = None
    joint: str | None = None
    effort_is: str | None = None
    align: str = 'hold'
    input_kind: str | None = None

    @property
    def is_empty(self):
        """True when no channel is mapped (the bag's /samples topic is used)."""
        return not (self.input or self.speed or self.current or self.effort_is)

    def to_dict(self):
        """The settings that are set, for reports."""
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class FieldSpec:
    """A parsed ``TOPIC[:FIELD]``: the topic and the attribute path ((name, indices), ...)."""

    topic: str
    path: tuple
    text: str

    @property
    def first(self):
        """Name of the first attribute of the path (None without a path)."""
        return self.path[0][0] if self.path else None


def parse_field_spec(text, option='--input'):
    """Parse ``/topic``, ``/topic:field``, ``/topic:data[2]`` or ``/topic:a.b[0].c``.

    Raises
    ------
    ConfigError
        An empty topic or a malformed field path.
    """
    text = str(text).strip()
    topic, _, fieldtext = text.partition(':')
    topic = topic.strip()
    if not topic:
        raise ConfigError(f'{option} {text!r}: the topic is empty (want TOPIC[:FIELD])')
    if not topic.startswith('/'):
        topic = '/' + topic
    path = []
    for step in filter(None, fieldtext.strip().split('.')):
        match = _STEP_RE.match(step.strip())
        if not match:
            raise ConfigError(f'{option} {text!r}: bad field {step!r} (want names with '
                              'optional [index], e.g. velocity or data[2])')
        indices = tuple(int(i) for i in re.findall(r'\[(\d+)\]', match.group(2)))
        path.append((match.group(1), indices))
    return FieldSpec(topic, tuple(path), text)


def load_profile(path):
    """Read a YAML mapping profile (keys :data:`PROFILE_KEYS`).

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        Unreadable file, YAML error, not a mapping, unknown key.
    """
    import yaml
    try:
        with open(path, encoding='utf-8') as fh:
            data = yaml.safe_load(fh)
    except OSError as exc:
        raise ConfigError(f'--profile {path}: cannot read ({exc.strerror})') from None
    except yaml.YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        line = f' line {where.line + 1}' if where is not None else ''
        raise ConfigError(f'--profile {path}:{line} not valid YAML') from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f'--profile {path}: expected a mapping of {", ".join(PROFILE_KEYS)}')
    data = {str(k).replace('-', '_'): v for k, v in data.items()}
    unknown = sorted(set(data) - set(PROFILE_KEYS))
    if unknown:
        raise ConfigError(f'--profile {path}: unknown key(s) {", ".join(unknown)} (known: '
                          f'{", ".join(PROFILE_KEYS)})')
    return data


def is_rosbag(path):
    """True for a path this module reads: a directory, an ``.mcap`` or a ``.db3`` file."""
    p = Path(path)
    return p.is_dir() or p.suffix in ('.mcap', '.db3')


def _open(path):
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import get_typestore, Stores
    p = Path(path)
    if not p.exists():
        raise BagError(f'{path}: no such file or directory')
    reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BagError(f'{path}: not a readable rosbag2 recording ({text})') from None
    return reader


@contextlib.contextmanager
def _reading(path):
    """Turn what rosbags raises on a damaged file or an unknown type into one BagError."""
    from rosbags.rosbag2 import ReaderError
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError
    try:
        yield
    except (ReaderError, SerdeError, TypesysError, KeyError, ValueError, EOFError,
            OSError) as exc:
        if isinstance(exc, MotorIdError):
            raise
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BagError(f'{path}: cannot read the messages ({text})') from None


def topic_table(topics):
    """``/a (pkg/msg/T, n), ...``: one line naming the topics of a bag."""
    return ', '.join(f'{name} ({info.msgtype}, {info.msgcount})'
                     for name, info in sorted(topics.items())) or 'none'


def read_bag(path, mapping=None):
    """Read a rosbag2 recording as a :class:`Recording` (not validated).

    Parameters
    ----------
    path : str or os.PathLike
        An MCAP file, a ``.db3`` file or a rosbag2 folder (``metadata.yaml``, split files).
    mapping : Mapping, optional
        Empty or None: the project's ``/samples`` topic.

    Returns
    -------
    Recording
        Times [s] from the first speed sample; ``meta`` names the source, the mapping,
        the time source per topic and the samples dropped at the ends.

    Raises
    ------
    BagError
        Unreadable bag, missing topic, field or joint, wrong type (one line naming what
        exists).
    ConfigError
        Contradicting mapping settings.
    """
    mapping = mapping or Mapping()
    if mapping.is_empty:
        rec = _read_samples_any(path)
        if mapping.input_kind is not None:
            rec.input_kind = mapping.input_kind
        return rec
    reader = _open(path)
    try:
        return _read_mapped(reader, path, mapping)
    finally:
        reader.close()


def _read_samples_any(path):
    """The /samples recording: this project's MCAP reader for one MCAP, else rosbags."""
    if is_single_mcap(path):
        from motor_id.bag import read_recording
        try:
            return read_recording(path)
        except BagError as exc:
            if f'no {BAG_SAMPLES_TOPIC} topic' not in str(exc):
                raise
            raise BagError(f'{exc}; map the channels with --input TOPIC[:FIELD] --speed '
                           'TOPIC[:FIELD] [--current ...]') from None
    reader = _open(path)
    try:
        topics = reader.topics
        if BAG_SAMPLES_TOPIC not in topics:
            raise BagError(f'{path}: no {BAG_SAMPLES_TOPIC} topic; map the channels with '
                           '--input TOPIC[:FIELD] --speed TOPIC[:FIELD] [--current ...] '
                           f'(topics: {topic_table(topics)})')
        return _read_samples(reader, path)
    finally:
        reader.close()


def is_single_mcap(path):
    """True for one MCAP file, or a folder holding exactly one (this project's bags)."""
    p = Path(path)
    if p.is_file():
        return p.suffix == '.mcap'
    return p.is_dir() and len(list(p.glob('*.mcap'))) == 1 and not list(p.glob('*.db3'))


def resolve(mapping, topics, path=''):  # noqa: C901 - TODO: split in task 4
    """Field specs per role and the plant kind, by the rule of the module docstring.

    Returns
    -------
    specs : dict
        ``{role: FieldSpec}``.
    input_kind : {'voltage', 'torque'}
    effort_is : str or None
    """
    m = mapping
    if m.effort_is is not None and m.effort_is not in EFFORT_KINDS:
        raise ConfigError(f'--effort-is must be current or torque, got {m.effort_is!r}')
    if m.input_kind is not None and m.input_kind not in INPUT_KINDS:
        raise ConfigError(f'--input-kind must be voltage or torque, got {m.input_kind!r}')
    if m.align not in ALIGN_RULES:
        raise ConfigError(f'--align must be one of {", ".join(ALIGN_RULES)}, got {m.align!r}')
    specs = {r: parse_field_spec(getattr(m, r), '--' + r) for r in ROLES if getattr(m, r)}
    for role, spec in specs.items():
        if spec.topic not in topics:
            raise BagError(f'{path}: --{role}: no topic {spec.topic} (topics: '
                           f'{topic_table(topics)})')
    if 'speed' not in specs:
        js = [t for t, info in topics.items() if info.msgtype == JOINT_STATE]
        if len(js) != 1:
            raise BagError(f'{path}: give --speed TOPIC[:FIELD] (topics: '
                           f'{topic_table(topics)})')
        specs['speed'] = FieldSpec(js[0], (('velocity', ()),), js[0] + ':velocity')

    def is_joint(spec):
        return topics[spec.topic].msgtype == JOINT_STATE

    def is_effort(spec, role):
        return is_joint(spec) and (spec.first or _DEFAULT_JOINT_FIELD[role]) == 'effort'

    speed = specs['speed']
    effort = FieldSpec(speed.topic, (('effort', ()),), speed.topic + ':effort')
    if m.effort_is == 'torque' and 'input' not in specs and is_joint(speed):
        specs['input'] = effort
    if m.effort_is == 'current' and 'current' not in specs and is_joint(speed):
        specs['current'] = effort
    if 'input' not in specs:
        raise BagError(f'{path}: no input: give --input TOPIC[:FIELD] (the voltage command), '
                       'or --effort-is torque to take the joint effort as a torque input '
                       f'(topics: {topic_table(topics)})')
    input_effort = is_effort(specs['input'], 'input')
    current_effort = 'current' in specs and is_effort(specs['current'], 'current')
    effort_is = m.effort_is
    if effort_is == 'torque' and current_effort:
        raise ConfigError(f'--effort-is torque: the joint effort is a torque, it cannot be '
                          f'the --current ({specs["current"].text})')
    if effort_is == 'torque' and not input_effort:
        raise ConfigError(f'--effort-is torque makes the joint effort the plant input (a '
                          f'torque plant), but --input is {specs["input"].text}: drop '
                          '--input to fit the torque plant, or use --effort-is current')
    if effort_is == 'current' and input_effort:
        raise ConfigError(f'--effort-is current: the joint effort is the measured current, '
                          f'it cannot be the --input ({specs["input"].text})')
    if input_effort and current_effort:
        raise ConfigError('the joint effort cannot be both the input (a torque) and the '
                          'current; set --effort-is')
    if effort_is is not None and not (input_effort or current_effort):
        raise ConfigError(f'--effort-is {effort_is} but no JointState effort is mapped (the '
                          f'speed comes from {speed.text}, a {topics[speed.topic].msgtype})')
    if input_effort:
        if m.input_kind == 'voltage':
            raise ConfigError(f'--input {specs["input"].text} is a joint effort (a torque), '
                              'not a voltage: drop --input-kind voltage')
        kind, effort_is = 'torque', 'torque'
    else:
        kind = m.input_kind or 'voltage'
        if current_effort:
            effort_is = 'current'
    return specs, kind, effort_is


def _read_mapped(reader, path, mapping):
    topics = reader.topics
    specs, kind, effort_is = resolve(mapping, topics, path)
    by_topic = {}
    for role, spec in specs.items():
        by_topic.setdefault(spec.topic, []).append(role)
    conns = [c for c in reader.connections if c.topic in by_topic]
    streams = {t: _Stream(t, topics[t].msgtype, [(r, specs[r]) for r in roles], mapping.joint,
                          path)
               for t, roles in by_topic.items()}
    with _reading(path):
        for conn, log_ns, raw in reader.messages(connections=conns):
            streams[conn.topic].add(reader.deserialize(raw, conn.msgtype), log_ns)
    for stream in streams.values():
        stream.finish()
    base = streams[specs['speed'].topic]
    t_ns = base.stamps
    if t_ns.size == 0:
        raise BagError(f'{path}: {specs["speed"].topic} has no messages')
    t0 = int(t_ns[0])
    t = (t_ns - t0) * 1e-9
    valid = np.ones(t.size, dtype=bool)
    chans = {}
    for role, spec in specs.items():
        stream = streams[spec.topic]
        if stream is base:
            chans[role] = base.values[role]
            continue
        ts = (stream.stamps - t0) * 1e-9
        if ts.size == 0:
            raise BagError(f'{path}: {spec.topic} has no messages')
        if role == 'input':
            idx = held_command_index(t, ts, mapping.align)
            ok = idx >= 0
            chans[role] = np.where(ok, stream.values[role][np.maximum(idx, 0)], np.nan)
        else:
            ok = (t >= ts[0]) & (t <= ts[-1])
            chans[role] = np.interp(t, ts, stream.values[role])
        valid &= ok
    keep = np.flatnonzero(valid)
    if keep.size == 0:
        sources = ', '.join(f'{s.topic}: {s.time_source} time'
                            for s in sorted(streams.values(), key=lambda s: s.topic))
        raise BagError(f'{path}: the streams do not overlap in time ({sources}); check that '
                       'the stamps share one clock')
    lo, hi = int(keep[0]), int(keep[-1]) + 1
    meta = {
        'source': str(path), 'bag': str(path), 'input_kind_rule': _kind_note(kind, effort_is),
        'mapping': {r: s.text for r, s in specs.items()},
        'align': mapping.align, 'time_origin_ns': t0 + int(t_ns[lo] - t_ns[0]),
        'time_source': {s.topic: s.time_source for s in streams.values()},
        'messages': {s.topic: s.count for s in streams.values()},
        'dropped_at_ends': {'start': lo, 'end': t.size - hi},
    }
    if mapping.joint is not None:
        meta['joint'] = mapping.joint
    if effort_is:
        meta['effort_is'] = effort_is
    if base.duplicates:
        meta['duplicate_stamps_dropped'] = base.duplicates
    cur = chans.get('current')
    return Recording(t[lo:hi] - t[lo], chans['input'][lo:hi], chans['speed'][lo:hi],
                     None if cur is None else cur[lo:hi], kind, meta)


def _kind_note(kind, effort_is):
    if kind == 'torque' and effort_is == 'torque':
        return 'torque plant: the joint effort is the input torque'
    if kind == 'torque':
        return 'torque plant (input kind given)'
    return 'voltage plant: the input is a voltage command'


class _Stream:
    """Stamps and the mapped values of one topic, gathered message by message."""

    def __init__(self, topic, msgtype, roles, joint, path):
        self.topic, self.msgtype, self.path = topic, msgtype, path
        self.roles = roles
        self.joint = joint
        self.getters = None
        self.time_source = None
        self._stamps = []
        self._values = {r: [] for r, _ in roles}
        self.count = 0
        self.stamps = self.values = None
        self.duplicates = 0

    def _setup(self, msg):
        header = getattr(msg, 'header', None)
        stamp = getattr(header, 'stamp', None)
        has_stamp = stamp is not None and (stamp.sec or stamp.nanosec)
        self.time_source = 'header' if has_stamp else 'receive'
        self.getters = [(r, _getter(self.topic, self.msgtype, spec, r, self.joint, msg,
                                    self.path)) for r, spec in self.roles]

    def add(self, msg, log_ns):
        if self.getters is None:
            self._setup(msg)
        if self.time_source == 'header':
            st = msg.header.stamp
            self._stamps.append(st.sec * 1_000_000_000 + st.nanosec)
        else:
            self._stamps.append(log_ns)
        for role, get in self.getters:
            try:
                self._values[role].append(get(msg))
            except (AttributeError, IndexError, KeyError, TypeError, ValueError) as exc:
                raise BagError(f'{self.path}: {self.topic} message {self.count}: cannot read '
                               f'the {role} ({exc})') from None
        self.count += 1

    def finish(self):
        stamps = np.asarray(self._stamps, dtype=np.int64)
        order = np.argsort(stamps, kind='stable')
        stamps = stamps[order]
        keep = np.r_[True, np.diff(stamps) > 0] if stamps.size else np.zeros(0, bool)
        self.duplicates = int(stamps.size - np.count_nonzero(keep))
        self.stamps = stamps[keep]
        self.values = {r: np.asarray(v, dtype=float)[order][keep]
                       for r, v in self._values.items()}


def _fields(obj):
    names = getattr(type(obj), '__dataclass_fields__', None)
    return [n for n in (names or ()) if not n.startswith('_')]


def _typename(obj):
    return getattr(type(obj), '__msgtype__', type(obj).__name__)


def _getter(topic, msgtype, spec, role, joint, msg, path):  # noqa: C901 - TODO: task 4
    """A function message -> float for one role, checked on the first message."""
    where = f'{path}: --{role} {spec.text}'
    if msgtype == JOINT_STATE:
        return _joint_getter(where, topic, spec, role, joint, msg)
    if joint is not None and role == 'speed':
        raise BagError(f'{where}: --joint {joint} given but {topic} is {msgtype}, not '
                       f'{JOINT_STATE}')
    steps = spec.path
    if not steps:
        if 'data' not in _fields(msg):
            raise BagError(f'{where}: {topic} is {msgtype}; name the field, e.g. '
                           f'{topic}:FIELD (fields: {", ".join(_fields(msg))})')
        data = msg.data
        if np.ndim(data) == 1 and len(data) != 1:
            raise BagError(f'{where}: {topic} ({msgtype}) data holds {len(data)} values; pick '
                           f'one with {topic}:data[i]')
        steps = (('data', (0,) if np.ndim(data) == 1 else ()),)
    obj, parent = msg, None
    for name, indices in steps:
        if not _fields(obj) and parent is not None:
            raise BagError(f'{where}: {parent} is a {type(obj).__name__}, it has no field '
                           f'{name!r}')
        if name not in _fields(obj):
            raise BagError(f'{where}: no field {name!r} in {_typename(obj)} '
                           f'(fields: {", ".join(_fields(obj)) or "none"})')
        obj, parent = getattr(obj, name), name
        for i in indices:
            if np.ndim(obj) != 1:
                raise BagError(f'{where}: {name} is not an array; drop the [{i}]')
            if i >= len(obj):
                raise BagError(f'{where}: {name}[{i}] out of range ({name} has {len(obj)} '
                               'values)')
            obj = obj[i]
    if np.ndim(obj) == 1:
        raise BagError(f'{where}: {steps[-1][0]} is an array of {len(obj)}; pick one with '
                       f'[i]')
    if not isinstance(obj, (int, float, np.integer, np.floating)) or isinstance(obj, bool):
        raise BagError(f'{where}: {steps[-1][0]} is {type(obj).__name__}, not a number '
                       f'(fields: {", ".join(_fields(msg))})')

    def get(m):
        for name, indices in steps:
            m = getattr(m, name)
            for i in indices:
                m = m[i]
        return float(m)
    return get


def _joint_getter(where, topic, spec, role, joint, msg):
    field = spec.first or _DEFAULT_JOINT_FIELD[role]
    if field not in JOINT_FIELDS or len(spec.path) > 1 or (spec.path and spec.path[0][1]):
        raise BagError(f'{where}: {topic} is a JointState; the field is one of '
                       f'{", ".join(JOINT_FIELDS)} (the joint is chosen with --joint)')
    names = list(msg.name)
    if joint is None:
        if len(names) > 1:
            raise BagError(f'{where}: {topic} has joints {", ".join(names)}; choose one with '
                           '--joint NAME')
        index = 0
    elif joint in names:
        index = names.index(joint)
    elif str(joint).isdigit() and int(joint) < max(len(names), len(getattr(msg, field))):
        index = int(joint)
    else:
        raise BagError(f'{where}: no joint {joint!r} in {topic} (joints: '
                       f'{", ".join(names) or "unnamed"})')
    if len(getattr(msg, field)) <= index:
        have = [f for f in JOINT_FIELDS if len(getattr(msg, f)) > index]
        raise BagError(f'{where}: {topic} carries no {field} for joint {joint or index} '
                       f'(it has {", ".join(have) or "no values"})')
    by_name = joint is not None and joint in names
    cache = {'names': names, 'index': index}

    def get(m):
        if by_name and m.name != cache['names']:
            cache['names'] = list(m.name)
            cache['index'] = cache['names'].index(joint)
        return float(getattr(m, field)[cache['index']])
    return get


def _read_samples(reader, path):
    """The project's /samples rows (and /motor_id/meta) from any rosbag2 storage."""
    from motor_id.bag import samples_recording, sorted_samples
    conns = [c for c in reader.connections if c.topic in (BAG_SAMPLES_TOPIC, BAG_META_TOPIC)]
    rows, log_times, meta = [], [], {}
    with _reading(path):
        messages = [(c.topic, log_ns, reader.deserialize(raw, c.msgtype))
                    for c, log_ns, raw in reader.messages(connections=conns)]
    for topic, log_ns, msg in messages:
        if topic == BAG_META_TOPIC:
            try:
                item = json.loads(msg.data)
            except (ValueError, AttributeError):
                raise BagError(f'{path}: a {BAG_META_TOPIC} message is not JSON') from None
            if isinstance(item, dict):
                meta.update(item)
            continue
        try:
            dims = msg.layout.dim
            rows.append(batch_rows([d.label for d in dims], [d.size for d in dims],
                                   msg.layout.data_offset, msg.data))
        except (AttributeError, ValueError) as exc:
            raise BagError(f'{path}: {BAG_SAMPLES_TOPIC} is not a sample batch ({exc})') \
                from None
        log_times.append(np.full(rows[-1].shape[0], log_ns, dtype=np.int64))
    if not rows or sum(r.shape[0] for r in rows) == 0:
        raise BagError(f'{path}: {BAG_SAMPLES_TOPIC} holds no sample rows')
    samples = sorted_samples(np.concatenate(rows), np.concatenate(log_times))
    rec = samples_recording(samples, meta, path)
    rec.meta['source'] = str(path)
    return rec

