"""Where each channel of a recording comes from in a robot's bag: the topic/field mapping.

A mapping names, per channel, ``TOPIC[:FIELD]``:

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

This module parses and checks mappings (flags or a YAML profile), resolves them against
a bag's topics and builds the function that reads one channel from a message; the
reading itself is :mod:`motor_id.data.rosbag`.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
import os
import re
from typing import Any, TYPE_CHECKING

import numpy as np

from motor_id.bag.anyreader import topic_table
from motor_id.contracts import INPUT_KINDS
from motor_id.data.align import ALIGN_RULES
from motor_id.errors import BagError, ConfigError

if TYPE_CHECKING:
    from rosbags.interfaces import TopicInfo

JOINT_STATE = 'sensor_msgs/msg/JointState'
JOINT_FIELDS = ('position', 'velocity', 'effort')
ROLES = ('input', 'speed', 'current')
EFFORT_KINDS = ('current', 'torque')
PROFILE_KEYS = ('input', 'speed', 'current', 'joint', 'effort_is', 'align', 'input_kind',
                'shift', 'columns')
"""Keys of a YAML mapping profile (one per robot); flags override them."""
_DEFAULT_JOINT_FIELD = {'speed': 'velocity', 'input': 'effort', 'current': 'effort'}
_STEP_RE = re.compile(r'^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$')


@dataclass
class TopicMapping:
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
    def is_empty(self) -> bool:
        """True when no channel is mapped (the bag's /samples topic is used)."""
        return not (self.input or self.speed or self.current or self.effort_is)

    def to_dict(self) -> dict[str, Any]:
        """The settings that are set, for reports."""
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class FieldSpec:
    """A parsed ``TOPIC[:FIELD]``: the topic and the attribute path ((name, indices), ...)."""

    topic: str
    path: tuple
    text: str

    @property
    def first(self) -> str | None:
        """Name of the first attribute of the path (None without a path)."""
        return self.path[0][0] if self.path else None


def parse_field_spec(text: str, option: str = 'input') -> FieldSpec:
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
        raise ConfigError(f'{option} {text!r}: the topic is empty (want TOPIC[:FIELD])',
                          params=(option,))
    if not topic.startswith('/'):
        topic = '/' + topic
    path = []
    for step in filter(None, fieldtext.strip().split('.')):
        match = _STEP_RE.match(step.strip())
        if not match:
            raise ConfigError(f'{option} {text!r}: bad field {step!r} (want names with '
                              'optional [index], e.g. velocity or data[2])', params=(option,))
        indices = tuple(int(i) for i in re.findall(r'\[(\d+)\]', match.group(2)))
        path.append((match.group(1), indices))
    return FieldSpec(topic, tuple(path), text)


def read_yaml(path: str | os.PathLike[str], option: str = 'profile') -> Any:
    """The YAML document of a profile file; one-line errors naming the file and line."""
    import yaml
    try:
        with open(path, encoding='utf-8') as fh:
            return yaml.safe_load(fh)
    except OSError as exc:
        raise ConfigError(f'{option} {path}: cannot read ({exc.strerror})',
                          params=(option,)) from exc
    except yaml.YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        line = f' line {where.line + 1}' if where is not None else ''
        raise ConfigError(f'{option} {path}:{line} not valid YAML', params=(option,)) from exc


def load_profile(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a YAML mapping profile (keys :data:`PROFILE_KEYS`).

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        Unreadable file, YAML error, not a mapping, unknown key.
    """
    data = read_yaml(path)
    if data is None:
        return {}
    return check_keys(data, f'profile {path}', PROFILE_KEYS)


def mapping_settings(settings: dict[str, Any], where: str) -> tuple[TopicMapping, int | None]:
    """The bag mapping and the input shift that a profile's keys describe.

    The one reading of :data:`PROFILE_KEYS` (``columns`` aside): ``--profile`` with the
    flags over it, and every motor of a fleet profile.

    Parameters
    ----------
    settings : dict
        Profile keys to values (missing or None: not set).
    where : str
        Where the settings come from, for messages.

    Returns
    -------
    mapping : TopicMapping
        ``joint`` as text (YAML reads an index as a number), ``align`` ``'hold'`` unless
        set.
    shift : int or None
        Samples the input is shifted by (:func:`motor_id.data.shift.shift_input`).

    Raises
    ------
    ConfigError
        Naming ``where``: a shift that is not a whole number, an unknown plant kind.
    """
    shift = settings.get('shift')
    if shift is not None and (isinstance(shift, bool) or not isinstance(shift, int)):
        raise ConfigError(f'{where}: shift must be a whole number of samples, got {shift!r}')
    kind = settings.get('input_kind')
    if kind is not None and kind not in INPUT_KINDS:
        raise ConfigError(f'{where}: input_kind must be {" or ".join(INPUT_KINDS)}, got '
                          f'{kind!r}')
    joint = settings.get('joint')
    mapping = TopicMapping(input=settings.get('input'), speed=settings.get('speed'),
                      current=settings.get('current'),
                      joint=None if joint is None else str(joint),
                      effort_is=settings.get('effort_is'),
                      align=settings.get('align') or 'hold', input_kind=kind)
    return mapping, shift


def check_keys(entry: Any, where: str, known: Sequence[str]) -> dict[str, Any]:
    """A profile mapping with ``-`` in keys read as ``_``; ConfigError naming ``where``
    for a non-mapping or an unknown key."""
    if not isinstance(entry, dict):
        raise ConfigError(f'{where}: expected a mapping of {", ".join(known)}, got {entry!r}')
    entry = {str(k).replace('-', '_'): v for k, v in entry.items()}
    unknown = sorted(set(entry) - set(known))
    if unknown:
        raise ConfigError(f'{where}: unknown key(s) {", ".join(unknown)} (known: '
                          f'{", ".join(known)})')
    return entry


def resolve(mapping: TopicMapping, topics: Mapping[str, 'TopicInfo'],
            path: str | os.PathLike[str] = '') -> tuple[dict[str, FieldSpec], str, str | None]:
    """Field specs per role and the plant kind, by the rule of the module docstring.

    Parameters
    ----------
    mapping : TopicMapping
    topics : dict
        ``reader.topics`` of the bag: name -> info with ``msgtype`` and ``msgcount``.
    path : str
        The bag, for messages.

    Returns
    -------
    specs : dict
        ``{role: FieldSpec}``.
    input_kind : {'voltage', 'torque'}
    effort_is : str or None

    Raises
    ------
    ConfigError
        Settings out of their domain or contradicting each other.
    BagError
        A mapped topic the bag does not have, or no way to find the speed or the input.
    """
    _check_settings(mapping)
    specs = _field_specs(mapping, topics, path)
    input_effort, current_effort = _effort_roles(mapping, specs, topics, path)
    kind, effort_is = _plant_kind(mapping, specs, topics, input_effort, current_effort)
    return specs, kind, effort_is


def _check_settings(m: TopicMapping) -> None:
    if m.effort_is is not None and m.effort_is not in EFFORT_KINDS:
        raise ConfigError(f'effort_is must be current or torque, got {m.effort_is!r}',
                          params=('effort_is',))
    if m.input_kind is not None and m.input_kind not in INPUT_KINDS:
        raise ConfigError(f'input_kind must be voltage or torque, got {m.input_kind!r}',
                          params=('input_kind',))
    if m.align not in ALIGN_RULES:
        raise ConfigError(f'align must be one of {", ".join(ALIGN_RULES)}, got {m.align!r}',
                          params=('align',))


def _field_specs(m: TopicMapping, topics: Mapping[str, 'TopicInfo'],
                 path: str | os.PathLike[str]) -> dict[str, FieldSpec]:
    """The mapped specs, each on a topic of the bag; the speed defaults to a JointState's."""
    specs = {r: parse_field_spec(getattr(m, r), r) for r in ROLES if getattr(m, r)}
    for role, spec in specs.items():
        if spec.topic not in topics:
            raise BagError(f'{path}: {role}: no topic {spec.topic} (topics: '
                           f'{topic_table(topics)})', params=(role,))
    if 'speed' not in specs:
        js = [t for t, info in topics.items() if info.msgtype == JOINT_STATE]
        if len(js) != 1:
            raise BagError(f'{path}: give speed as TOPIC[:FIELD] (topics: '
                           f'{topic_table(topics)})', params=('speed',))
        specs['speed'] = FieldSpec(js[0], (('velocity', ()),), js[0] + ':velocity')
    return specs


def _is_joint(spec: FieldSpec, topics: Mapping[str, 'TopicInfo']) -> bool:
    return topics[spec.topic].msgtype == JOINT_STATE


def _is_effort(spec: FieldSpec, role: str, topics: Mapping[str, 'TopicInfo']) -> bool:
    return _is_joint(spec, topics) and (spec.first or _DEFAULT_JOINT_FIELD[role]) == 'effort'


def _effort_roles(m: TopicMapping, specs: dict[str, FieldSpec], topics: Mapping[str, 'TopicInfo'],
                  path: str | os.PathLike[str]) -> tuple[bool, bool]:
    """Map the speed topic's effort by ``effort_is``; whether the input / current is an effort."""
    speed = specs['speed']
    effort = FieldSpec(speed.topic, (('effort', ()),), speed.topic + ':effort')
    if m.effort_is == 'torque' and 'input' not in specs and _is_joint(speed, topics):
        specs['input'] = effort
    if m.effort_is == 'current' and 'current' not in specs and _is_joint(speed, topics):
        specs['current'] = effort
    if 'input' not in specs:
        raise BagError(f'{path}: no input: give input as TOPIC[:FIELD] (the voltage command), '
                       "or effort_is 'torque' to take the joint effort as a torque input "
                       f'(topics: {topic_table(topics)})', params=('input', 'effort_is'))
    input_effort = _is_effort(specs['input'], 'input', topics)
    current_effort = 'current' in specs and _is_effort(specs['current'], 'current', topics)
    return input_effort, current_effort


def _plant_kind(m: TopicMapping, specs: dict[str, FieldSpec], topics: Mapping[str, 'TopicInfo'],
                input_effort: bool, current_effort: bool) -> tuple[str, str | None]:
    """``(input_kind, effort_is)`` after checking that the settings agree."""
    effort_is = m.effort_is
    if effort_is == 'torque' and current_effort:
        raise ConfigError(f'effort_is torque: the joint effort is a torque, it cannot be '
                          f'the current ({specs["current"].text})',
                          params=('effort_is', 'current'))
    if effort_is == 'torque' and not input_effort:
        raise ConfigError(f'effort_is torque makes the joint effort the plant input (a '
                          f'torque plant), but input is {specs["input"].text}: drop '
                          'input to fit the torque plant, or use effort_is current',
                          params=('effort_is', 'input'))
    if effort_is == 'current' and input_effort:
        raise ConfigError(f'effort_is current: the joint effort is the measured current, '
                          f'it cannot be the input ({specs["input"].text})',
                          params=('effort_is', 'input'))
    if input_effort and current_effort:
        raise ConfigError('the joint effort cannot be both the input (a torque) and the '
                          'current; set effort_is', params=('effort_is',))
    if effort_is is not None and not (input_effort or current_effort):
        speed = specs['speed']
        raise ConfigError(f'effort_is {effort_is} but no JointState effort is mapped (the '
                          f'speed comes from {speed.text}, a {topics[speed.topic].msgtype})',
                          params=('effort_is',))
    if input_effort:
        if m.input_kind == 'voltage':
            raise ConfigError(f'input {specs["input"].text} is a joint effort (a torque), '
                              'not a voltage: drop input_kind voltage',
                              params=('input', 'input_kind'))
        return 'torque', 'torque'
    return m.input_kind or 'voltage', 'current' if current_effort else effort_is


def kind_note(kind: str, effort_is: str | None) -> str:
    """How the plant kind was decided, in words (for the recording's meta)."""
    if kind == 'torque' and effort_is == 'torque':
        return 'torque plant: the joint effort is the input torque'
    if kind == 'torque':
        return 'torque plant (input kind given)'
    return 'voltage plant: the input is a voltage command'


def _fields(obj: Any) -> list[str]:
    names = getattr(type(obj), '__dataclass_fields__', None)
    return [n for n in (names or ()) if not n.startswith('_')]


def _typename(obj: Any) -> str:
    return getattr(type(obj), '__msgtype__', type(obj).__name__)


def field_getter(topic: str, msgtype: str, spec: FieldSpec, role: str, joint: str | None,
                 msg: Any, path: str | os.PathLike[str]) -> Callable[[Any], float]:
    """A function message -> float for one role, checked on the first message ``msg``.

    Raises
    ------
    BagError
        The field, index or joint does not exist in ``msg``, or is not a number (one line
        naming what exists).
    """
    where = f'{path}: {role} {spec.text}'
    if msgtype == JOINT_STATE:
        return _joint_getter(where, topic, spec, role, joint, msg)
    if joint is not None and role == 'speed':
        raise BagError(f'{where}: joint {joint} given but {topic} is {msgtype}, not '
                       f'{JOINT_STATE}', params=('joint',))
    steps = spec.path or _default_steps(where, topic, msgtype, msg)
    _check_steps(where, steps, msg)

    def get(m: Any) -> float:
        for name, indices in steps:
            m = getattr(m, name)
            for i in indices:
                m = m[i]
        return float(m)
    return get


def _default_steps(where: str, topic: str, msgtype: str,
                   msg: Any) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """The ``data`` field (its one element for an array) of a message mapped without FIELD."""
    if 'data' not in _fields(msg):
        raise BagError(f'{where}: {topic} is {msgtype}; name the field, e.g. '
                       f'{topic}:FIELD (fields: {", ".join(_fields(msg))})')
    data = msg.data
    if np.ndim(data) == 1 and len(data) != 1:
        raise BagError(f'{where}: {topic} ({msgtype}) data holds {len(data)} values; pick '
                       f'one with {topic}:data[i]')
    return (('data', (0,) if np.ndim(data) == 1 else ()),)


def _check_steps(where: str, steps: tuple[tuple[str, tuple[int, ...]], ...],
                 msg: Any) -> None:
    """Walk ``steps`` on ``msg``; BagError unless they end on one number."""
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


def _joint_getter(where: str, topic: str, spec: FieldSpec, role: str, joint: str | None,
                  msg: Any) -> Callable[[Any], float]:
    field = spec.first or _DEFAULT_JOINT_FIELD[role]
    if field not in JOINT_FIELDS or len(spec.path) > 1 or (spec.path and spec.path[0][1]):
        raise BagError(f'{where}: {topic} is a JointState; the field is one of '
                       f'{", ".join(JOINT_FIELDS)} (the joint is chosen by joint)',
                       params=('joint',))
    names = list(msg.name)
    if joint is None:
        if len(names) > 1:
            raise BagError(f'{where}: {topic} has joints {", ".join(names)}; choose one '
                           '(joint)', params=('joint',))
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
    cache = _JointIndex(names, index)

    def get(m: Any) -> float:
        if by_name and m.name != cache.names:
            cache.names = list(m.name)
            cache.index = cache.names.index(str(joint))
        return float(getattr(m, field)[cache.index])
    return get


@dataclass
class _JointIndex:
    """The joint names last seen on a JointState topic and the index of the mapped joint."""

    names: list[str]
    index: int
