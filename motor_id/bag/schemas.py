"""Message types of a motor_id bag: ROS 2 Jazzy definitions, CDR and type hashes (rosbags)."""

import functools
import struct
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError
from rosbags.typesys import get_typestore, Stores, TypesysError

from motor_id.errors import BagError, ConfigError

FLOAT64_MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'
FLOAT64 = 'std_msgs/msg/Float64'
STRING = 'std_msgs/msg/String'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
MESSAGE_TYPES = (FLOAT64_MULTI_ARRAY, FLOAT64, STRING, DIAGNOSTIC_ARRAY)
"""The top-level types a motor_id bag holds."""

SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'

_DTYPES = {'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'int8': np.int8,
           'uint8': np.uint8, 'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32,
           'uint32': np.uint32, 'int64': np.int64, 'uint64': np.uint64,
           'float32': np.float32, 'float64': np.float64}
"""numpy dtype of each primitive ROS type (rosbags wants primitive sequences as arrays)."""


@functools.cache
def typestore() -> Any:
    """The rosbags type store of ROS 2 Jazzy (built once, on first use)."""
    return get_typestore(Stores.ROS2_JAZZY)


def _known(msgtype: str) -> str:
    if msgtype not in typestore().fielddefs:
        raise ConfigError(f'unknown message type {msgtype!r}; a motor_id bag holds '
                          f'{", ".join(MESSAGE_TYPES)}')
    return msgtype


def message_definition(msgtype: str) -> str:
    """The complete ``ros2msg`` definition of a message type, as a bag's schema stores it.

    The type's own fields come first; every type it uses follows after a line of 80
    ``=`` and a ``MSG: pkg/Type`` line (the layout rosbag2, Foxglove and rosbags read).
    Generated from the Jazzy type store, so it matches what :func:`serialize` writes.

    Parameters
    ----------
    msgtype : str
        ``'pkg/msg/Type'``, a type of ROS 2 Jazzy.

    Returns
    -------
    str
    """
    text, _ = typestore().generate_msgdef(_known(msgtype), ros_version=2)
    return text


def type_hash(msgtype: str) -> str:
    """The ROS 2 type description hash (``RIHS01_...``) of a Jazzy message type."""
    return typestore().hash_rihs01(_known(msgtype))


def build(msgtype: str, fields: Any) -> Any:
    """A message object of the type store from a dict shaped like the ROS message.

    Parameters
    ----------
    msgtype : str
    fields : dict or message object
        Field values; nested dicts for sub-messages, sequences for arrays; a missing
        field takes its ROS default (0, '', empty). A message object is returned as is.

    Returns
    -------
    object
        An instance of ``typestore().types[msgtype]``.
    """
    if not isinstance(fields, dict):
        return fields
    _, entries = typestore().fielddefs[_known(msgtype)]
    names = {name for name, _ in entries}
    unknown = sorted(set(fields) - names)
    if unknown:
        raise ConfigError(f'{msgtype} has no field(s) {unknown}; fields: {sorted(names)}')
    values = {name: _field_value(desc, fields.get(name)) for name, desc in entries}
    return typestore().types[msgtype](**values)


def _field_value(desc: Any, value: Any) -> Any:
    kind, arg = desc
    if kind == Nodetype.NAME:
        return build(arg, {} if value is None else value)
    if kind == Nodetype.BASE:
        if value is None:
            return '' if arg[0] == 'string' else _DTYPES[arg[0]](0).item()
        return value
    (item_kind, item_arg), _ = arg
    items = [] if value is None else value
    if item_kind == Nodetype.BASE and item_arg[0] in _DTYPES:
        return np.asarray(items, dtype=_DTYPES[item_arg[0]])
    if item_kind == Nodetype.NAME:
        return [build(item_arg, item) for item in items]
    return list(items)


def serialize(msgtype: str, fields: Any) -> bytes:
    """CDR bytes (little endian) of a message given as a dict or a message object.

    Raises
    ------
    BagError
        When a value does not fit its field.
    """
    msg = build(msgtype, fields)
    try:
        return bytes(typestore().serialize_cdr(msg, msgtype))
    except (SerdeError, TypesysError, ValueError, TypeError, AttributeError, OverflowError,
            struct.error) as exc:
        raise BagError(f'cannot serialise a {msgtype}: {exc}') from exc


def deserialize(data: bytes, msgtype: str) -> Any:
    """The message object of CDR bytes (raises SerdeError, ValueError on bad bytes)."""
    return typestore().deserialize_cdr(data, _known(msgtype))


DECODE_ERRORS = (SerdeError, ValueError, TypeError, AttributeError, IndexError,
                 OverflowError, struct.error)
"""What decoding damaged CDR bytes with :func:`deserialize` raises."""


def topic_name(topic: str) -> str:
    """An absolute topic name (a relative one gets a leading ``/``)."""
    topic = str(topic)
    if not topic or topic == '/':
        raise ConfigError('topic name is empty')
    return topic if topic.startswith('/') else '/' + topic
